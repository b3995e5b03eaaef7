//! What the Modbus TCP tests share: in-memory units as the server's peer, a server on
//! 127.0.0.1 port 0, raw frame helpers.

use std::future::Future;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, PoisonError, RwLock};
use std::time::Duration;

use gateway::modbus_tcp::{bind, serve, ServerOptions, ServerStats};
use gateway::unit::{SharedUnits, UnitFuture, UnitMap, UnitService};
use proto_core::modbus::pdu::{ExceptionCode, Request, Response};
use tokio::io::AsyncReadExt;
use tokio::net::TcpStream;
use tokio::task::JoinHandle;
use tokio_modbus::client::Context;
use tokio_modbus::prelude::*;
use tokio_util::sync::CancellationToken;

/// How long a test waits for something that should happen at once.
pub(crate) const PATIENCE: Duration = Duration::from_secs(10);

// === the peer: an in-memory unit ===

/// Holding registers and coils in memory.
pub(crate) struct MemoryUnit {
    registers: Mutex<Vec<u16>>,
    coils: Mutex<Vec<bool>>,
}

impl MemoryUnit {
    pub(crate) fn new(size: usize) -> Arc<Self> {
        let registers = (0..size)
            .map(|i| u16::try_from(i).unwrap_or(u16::MAX))
            .collect();
        Arc::new(Self {
            registers: Mutex::new(registers),
            coils: Mutex::new(vec![false; size]),
        })
    }

    pub(crate) fn register(&self, address: usize) -> Option<u16> {
        self.registers
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .get(address)
            .copied()
    }

    pub(crate) fn answer(&self, request: Request) -> Result<Response, ExceptionCode> {
        let mut registers = self
            .registers
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let mut coils = self.coils.lock().unwrap_or_else(PoisonError::into_inner);
        let span = |address: u16, count: usize| usize::from(address)..usize::from(address) + count;
        let bad = ExceptionCode::IllegalDataAddress;
        Ok(match request {
            Request::ReadHoldingRegisters { address, quantity } => Response::ReadHoldingRegisters(
                registers
                    .get(span(address, usize::from(quantity)))
                    .ok_or(bad)?
                    .to_vec(),
            ),
            Request::WriteSingleRegister { address, value } => {
                *registers.get_mut(usize::from(address)).ok_or(bad)? = value;
                Response::WriteSingleRegister { address, value }
            }
            Request::WriteMultipleRegisters { address, values } => {
                registers
                    .get_mut(span(address, values.len()))
                    .ok_or(bad)?
                    .copy_from_slice(&values);
                let quantity = u16::try_from(values.len()).map_err(|_| bad)?;
                Response::WriteMultipleRegisters { address, quantity }
            }
            Request::ReadCoils { address, quantity } => Response::ReadCoils(
                coils
                    .get(span(address, usize::from(quantity)))
                    .ok_or(bad)?
                    .to_vec(),
            ),
            Request::WriteSingleCoil { address, value } => {
                *coils.get_mut(usize::from(address)).ok_or(bad)? = value;
                Response::WriteSingleCoil { address, value }
            }
            _ => return Err(ExceptionCode::IllegalFunction),
        })
    }
}

impl UnitService for MemoryUnit {
    fn call(&self, request: Request) -> UnitFuture {
        let result = self.answer(request);
        Box::pin(async move { result })
    }
}

/// A device that never answers.
pub(crate) struct SilentUnit;

impl UnitService for SilentUnit {
    fn call(&self, _request: Request) -> UnitFuture {
        Box::pin(std::future::pending())
    }
}

/// Answers every request with the same (wrong) response.
pub(crate) struct FixedUnit(pub(crate) Response);

impl UnitService for FixedUnit {
    fn call(&self, _request: Request) -> UnitFuture {
        let response = self.0.clone();
        Box::pin(async move { Ok(response) })
    }
}

/// Answers like the memory unit, after telling the test it started and waiting `delay`.
pub(crate) struct SlowUnit {
    pub(crate) inner: Arc<MemoryUnit>,
    pub(crate) delay: Duration,
    pub(crate) started: tokio::sync::mpsc::UnboundedSender<()>,
}

impl UnitService for SlowUnit {
    fn call(&self, request: Request) -> UnitFuture {
        let inner = Arc::clone(&self.inner);
        let delay = self.delay;
        let _ = self.started.send(());
        Box::pin(async move {
            tokio::time::sleep(delay).await;
            inner.answer(request)
        })
    }
}

// === the server under test ===

pub(crate) struct TestServer {
    pub(crate) addr: SocketAddr,
    pub(crate) units: SharedUnits,
    pub(crate) memory: Arc<MemoryUnit>,
    pub(crate) stats: Arc<ServerStats>,
    pub(crate) shutdown: CancellationToken,
    pub(crate) task: JoinHandle<std::io::Result<()>>,
}

/// Unit 1: memory (100 registers and coils); unit 9: silent.
pub(crate) async fn start(options: ServerOptions) -> TestServer {
    let memory = MemoryUnit::new(100);
    let mut map = UnitMap::new();
    map.insert(1, memory.clone());
    map.insert(9, Arc::new(SilentUnit));
    start_with(options, map, memory).await
}

pub(crate) async fn start_with(
    options: ServerOptions,
    map: UnitMap,
    memory: Arc<MemoryUnit>,
) -> TestServer {
    let listener = bind(([127, 0, 0, 1], 0).into()).expect("bind");
    let addr = listener.local_addr().expect("local addr");
    let units: SharedUnits = Arc::new(RwLock::new(map));
    let stats = Arc::new(ServerStats::new());
    let shutdown = CancellationToken::new();
    let task = tokio::spawn(serve(
        listener,
        units.clone(),
        options,
        shutdown.clone(),
        stats.clone(),
    ));
    TestServer {
        addr,
        units,
        memory,
        stats,
        shutdown,
        task,
    }
}

impl TestServer {
    pub(crate) async fn client(&self, unit: u8) -> Context {
        tcp::connect_slave(self.addr, Slave(unit))
            .await
            .expect("connect")
    }

    pub(crate) async fn raw(&self) -> TcpStream {
        TcpStream::connect(self.addr).await.expect("connect")
    }

    /// Shows the server still serves: a fresh client reads register 5 of unit 1.
    pub(crate) async fn still_serves(&self) {
        let mut client = self.client(1).await;
        let value = client
            .read_holding_registers(5, 1)
            .await
            .expect("transport")
            .expect("no exception");
        assert_eq!(value, [self.memory.register(5).expect("register 5")]);
    }

    pub(crate) async fn stop(self) {
        self.shutdown.cancel();
        let result = tokio::time::timeout(PATIENCE, self.task)
            .await
            .expect("serve returns")
            .expect("no panic");
        result.expect("serve ends with Ok");
    }
}

/// Waits until `check` holds (it reads counters that other tasks update).
pub(crate) async fn eventually(what: &str, mut check: impl FnMut() -> bool) {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    while !check() {
        assert!(
            tokio::time::Instant::now() < deadline,
            "timed out waiting for: {what}"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

pub(crate) async fn within<T>(what: &str, future: impl Future<Output = T>) -> T {
    tokio::time::timeout(PATIENCE, future)
        .await
        .unwrap_or_else(|_| panic!("timed out: {what}"))
}

// === raw frames ===

/// An ADU: MBAP header (protocol 0, length from `pdu`) and `pdu`.
pub(crate) fn adu(transaction_id: u16, unit: u8, pdu: &[u8]) -> Vec<u8> {
    let length = u16::try_from(pdu.len() + 1).expect("short PDU");
    let mut frame = transaction_id.to_be_bytes().to_vec();
    frame.extend_from_slice(&[0, 0]);
    frame.extend_from_slice(&length.to_be_bytes());
    frame.push(unit);
    frame.extend_from_slice(pdu);
    frame
}

/// Reads one response ADU.
pub(crate) async fn read_adu(stream: &mut TcpStream) -> Vec<u8> {
    within("response", async {
        let mut frame = vec![0u8; 7];
        stream
            .read_exact(&mut frame)
            .await
            .expect("response header");
        let length = usize::from(u16::from_be_bytes([frame[4], frame[5]]));
        frame.resize(6 + length, 0);
        stream
            .read_exact(&mut frame[7..])
            .await
            .expect("response PDU");
        frame
    })
    .await
}

/// Asserts the server closed the connection (end of stream or reset), without sending anything.
pub(crate) async fn assert_closed(stream: &mut TcpStream, what: &str) {
    let mut buf = [0u8; 16];
    match within(what, stream.read(&mut buf)).await {
        Ok(0) => {}
        Ok(n) => panic!(
            "{what}: got {n} bytes instead of a close: {:02X?}",
            &buf[..n]
        ),
        Err(error) => assert_eq!(
            error.kind(),
            std::io::ErrorKind::ConnectionReset,
            "{what}: {error}"
        ),
    }
}
