//! The accept loop survives a process out of file descriptors (EMFILE).
//!
//! A test binary of its own: it lowers the process-wide RLIMIT_NOFILE soft limit and fills the
//! descriptor table, which would break any test running beside it.

use std::fs::File;
use std::io::Write;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, PoisonError, RwLock};
use std::time::Duration;

use gateway::modbus_tcp::{serve, AcceptError, ServerOptions, ServerStats};
use gateway::unit::{UnitFuture, UnitMap, UnitService};
use proto_core::modbus::pdu::{ExceptionCode, Request, Response};
use rustix::process::{getrlimit, setrlimit, Resource, Rlimit};
use tokio::io::AsyncReadExt;
use tokio::net::TcpListener;
use tokio_modbus::prelude::*;
use tokio_util::sync::CancellationToken;

const PATIENCE: Duration = Duration::from_secs(10);

/// Holding registers in memory, reads only.
struct Registers(Mutex<Vec<u16>>);

impl UnitService for Registers {
    fn call(&self, request: Request) -> UnitFuture {
        let registers = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        let result = match request {
            Request::ReadHoldingRegisters { address, quantity } => {
                let span = usize::from(address)..usize::from(address) + usize::from(quantity);
                registers
                    .get(span)
                    .map(|values| Response::ReadHoldingRegisters(values.to_vec()))
                    .ok_or(ExceptionCode::IllegalDataAddress)
            }
            _ => Err(ExceptionCode::IllegalFunction),
        };
        Box::pin(async move { result })
    }
}

async fn eventually(what: &str, check: impl Fn() -> bool) {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    while !check() {
        assert!(
            tokio::time::Instant::now() < deadline,
            "timed out waiting for: {what}"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

async fn read_two(addr: SocketAddr) -> Vec<u16> {
    let mut client = tcp::connect_slave(addr, Slave(1)).await.expect("connect");
    client
        .read_holding_registers(2, 2)
        .await
        .expect("transport")
        .expect("no exception")
}

fn open_fds() -> u64 {
    let count = std::fs::read_dir("/proc/self/fd")
        .map(Iterator::count)
        .unwrap_or(64);
    u64::try_from(count).unwrap_or(u64::MAX)
}

// One thread: while the test fills the descriptor table, the server cannot run and take a
// descriptor first, so exactly one is left for the client's socket.
#[tokio::test(flavor = "current_thread")]
async fn accept_loop_survives_emfile() {
    let mut map = UnitMap::new();
    map.insert(1, Arc::new(Registers(Mutex::new((0..10).collect()))));
    let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
    let addr = listener.local_addr().expect("local addr");
    let stats = Arc::new(ServerStats::new());
    let shutdown = CancellationToken::new();
    let units = Arc::new(RwLock::new(map));
    let server = tokio::spawn(serve(
        listener,
        units,
        ServerOptions::default(),
        shutdown.clone(),
        stats.clone(),
    ));

    // A client connected before the shortage keeps its connection through it.
    let mut early = tcp::connect_slave(addr, Slave(1)).await.expect("connect");
    assert_eq!(
        early.read_holding_registers(0, 1).await.expect("transport"),
        Ok(vec![0])
    );

    // Lower the soft limit a little above what is open, and fill the table with /dev/null.
    let original = getrlimit(Resource::Nofile);
    let low = Rlimit {
        current: Some(open_fds() + 32),
        maximum: original.maximum,
    };
    setrlimit(Resource::Nofile, low).expect("lower RLIMIT_NOFILE");
    let mut filler = Vec::new();
    let exhausted = loop {
        match File::open("/dev/null") {
            Ok(file) => filler.push(file),
            Err(error) => break error,
        }
        assert!(filler.len() < 10_000, "the lowered limit does not hold");
    };
    assert_eq!(exhausted.raw_os_error(), Some(libc_emfile()), "{exhausted}");
    // One descriptor for the client; none is left for the server's accept().
    drop(filler.pop());
    let mut pending = std::net::TcpStream::connect(addr).expect("connect into the backlog");
    pending
        .write_all(&[0, 5, 0, 0, 0, 6, 1, 0x03, 0, 4, 0, 1])
        .expect("request");

    eventually("accept() fails with EMFILE, more than once", || {
        stats.accept_errors(AcceptError::ProcessFdLimit) >= 3
    })
    .await;
    assert_eq!(
        stats.connections_accepted(),
        1,
        "only the early client got in"
    );
    assert_eq!(
        early.read_holding_registers(1, 1).await.expect("transport"),
        Ok(vec![1])
    );
    assert!(!server.is_finished(), "the accept loop is still running");

    // Free the descriptors: the waiting client is served, and new ones are too.
    drop(filler);
    setrlimit(Resource::Nofile, original).expect("restore RLIMIT_NOFILE");
    pending.set_nonblocking(true).expect("nonblocking");
    let mut pending = tokio::net::TcpStream::from_std(pending).expect("register");
    let mut response = [0u8; 11];
    tokio::time::timeout(PATIENCE, pending.read_exact(&mut response))
        .await
        .expect("answered in time")
        .expect("response");
    assert_eq!(response, [0, 5, 0, 0, 0, 5, 1, 0x03, 2, 0, 4]);
    assert_eq!(read_two(addr).await, [2, 3]);
    assert_eq!(stats.connections_accepted(), 3);

    shutdown.cancel();
    drop(early);
    let result = tokio::time::timeout(PATIENCE, server)
        .await
        .expect("serve returns")
        .expect("no panic");
    result.expect("serve ends with Ok");
}

/// EMFILE ("Too many open files") as the OS reports it.
fn libc_emfile() -> i32 {
    rustix::io::Errno::MFILE.raw_os_error()
}
