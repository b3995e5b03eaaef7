//! Bad input to the running gateway's Modbus TCP server: each gets the right exception or a closed
//! connection, the server keeps serving others, 300 connections at once do not stop it, and the
//! process never panics (checked by the harness when the gateway stops).

use std::time::Duration;

use gateway_tests::Gateway;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_modbus::client::{tcp, Reader};
use tokio_modbus::prelude::Slave;

/// An MBAP frame: transaction id 0x0102, protocol `proto`, unit 2, the given PDU.
fn frame(proto: u16, pdu: &[u8]) -> Vec<u8> {
    let len = u16::try_from(pdu.len() + 1).expect("short PDU");
    let mut f = vec![0x01, 0x02];
    f.extend_from_slice(&proto.to_be_bytes());
    f.extend_from_slice(&len.to_be_bytes());
    f.push(2);
    f.extend_from_slice(pdu);
    f
}

/// Sends `bytes` and returns the PDU of the answer, or `None` when the server closed the
/// connection instead.
async fn exchange(stream: &mut TcpStream, bytes: &[u8]) -> Option<Vec<u8>> {
    stream.write_all(bytes).await.expect("write");
    let mut header = [0u8; 7];
    match tokio::time::timeout(Duration::from_secs(10), stream.read_exact(&mut header)).await {
        Ok(Ok(_)) => {}
        Ok(Err(_)) => return None,
        Err(_) => panic!("no answer and no close within 10 s to {bytes:02X?}"),
    }
    assert_eq!(&header[..2], &[0x01, 0x02], "transaction id echoed");
    let len = usize::from(u16::from_be_bytes([header[4], header[5]]));
    let mut pdu = vec![0u8; len - 1];
    stream.read_exact(&mut pdu).await.expect("PDU");
    Some(pdu)
}

async fn closed(stream: &mut TcpStream) -> bool {
    let mut b = [0u8; 1];
    matches!(
        tokio::time::timeout(Duration::from_secs(10), stream.read(&mut b)).await,
        Ok(Ok(0) | Err(_))
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_requests_get_exceptions_or_a_closed_connection() {
    let gw = Gateway::demo(&[]);
    let mut good = tcp::connect_slave(gw.modbus_tcp, Slave(17))
        .await
        .expect("connect");

    // On one connection: each malformed PDU gets its exception, and the connection stays usable.
    let mut s = TcpStream::connect(gw.modbus_tcp).await.expect("connect");
    let cases: [(&str, Vec<u8>, Vec<u8>); 6] = [
        ("unknown function 0x42", vec![0x42, 0, 0], vec![0xC2, 0x01]),
        (
            "FC03 quantity 0",
            vec![0x03, 0x0C, 0x1E, 0, 0],
            vec![0x83, 0x03],
        ),
        (
            "FC03 quantity 126",
            vec![0x03, 0x0C, 0x1E, 0, 126],
            vec![0x83, 0x03],
        ),
        (
            "FC15 1969 coils in 6 bytes",
            vec![0x0F, 0, 0, 0x07, 0xB1, 6, 1, 2, 3, 4, 5, 6],
            vec![0x8F, 0x03],
        ),
        (
            "FC16 byte count 4 for 1 register",
            vec![0x10, 0x23, 0x29, 0, 1, 4, 0, 13, 0, 14],
            vec![0x90, 0x03],
        ),
        (
            "FC16 byte count 2 for 2 registers",
            vec![0x10, 0x23, 0x29, 0, 2, 2, 0, 13],
            vec![0x90, 0x03],
        ),
    ];
    for (what, pdu, expected) in cases {
        let answer = exchange(&mut s, &frame(0, &pdu)).await;
        assert_eq!(answer.as_deref(), Some(&expected[..]), "{what}");
    }

    // Headers the server cannot trust close the connection.
    for (what, bytes) in [
        ("MBAP length 0", vec![1, 2, 0, 0, 0, 0, 2]),
        ("MBAP length 65535", vec![1, 2, 0, 0, 0xFF, 0xFF, 2]),
        ("protocol id 1", frame(1, &[0x03, 0x0C, 0x1E, 0, 4])),
    ] {
        let mut s = TcpStream::connect(gw.modbus_tcp).await.expect("connect");
        s.write_all(&bytes).await.expect("write");
        assert!(closed(&mut s).await, "{what}: connection not closed");
    }

    // 300 connections at once: those over the cap are closed, the server keeps serving.
    let mut many = Vec::new();
    for _ in 0..300 {
        if let Ok(s) = TcpStream::connect(gw.modbus_tcp).await {
            many.push(s);
        }
    }
    let still = good.read_input_registers(1004, 3).await.expect("transport");
    assert_eq!(still, Ok(vec![1066, 140, 4158]));
    drop(many);
    let mut fresh = tcp::connect_slave(gw.modbus_tcp, Slave(17))
        .await
        .expect("connect after the burst");
    let mut ok = false;
    for _ in 0..50 {
        if fresh
            .read_input_registers(1004, 3)
            .await
            .ok()
            .and_then(Result::ok)
            == Some(vec![1066, 140, 4158])
        {
            ok = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
        fresh = tcp::connect_slave(gw.modbus_tcp, Slave(17))
            .await
            .expect("connect");
    }
    assert!(ok, "the server stopped serving after the burst");
}

/// A xorshift32 generator (Marsaglia 2003): reproducible fuzz input without a dependency.
struct Fuzz(u32);

impl Fuzz {
    fn next(&mut self) -> u32 {
        let mut x = self.0;
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        self.0 = x;
        x
    }

    fn byte(&mut self) -> u8 {
        self.next().to_le_bytes()[0]
    }

    /// One fuzz frame: half of them with a wrong protocol id or length (the connection is
    /// closed), half a well-formed MBAP header with a random PDU to one of the demo's units or
    /// another (an exception, an answer, or a request through to a device).
    fn frame(&mut self) -> Vec<u8> {
        let pdu_len = 1 + usize::from(self.byte() % 12);
        let pdu: Vec<u8> = (0..pdu_len).map(|_| self.byte()).collect();
        if self.next() % 2 == 0 {
            let proto = 1 + u16::from(self.byte());
            frame(proto, &pdu)
        } else {
            let units = [2, 17, 50, 100, 101, self.byte()];
            let unit = units[usize::from(self.byte()) % units.len()];
            let mut f = frame(0, &pdu);
            f[6] = unit;
            f
        }
    }
}

/// How long the fuzzing client runs: the full minute that the limit of 100 log lines is set for
/// (the audit log's and the warnings' intervals are 10 s, so a shorter run would not show a
/// count that grows with time).
const FUZZ_RUN: Duration = Duration::from_secs(60);

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_fuzzing_client_leaves_fewer_than_100_log_lines() {
    let gw = Gateway::demo(&[]);
    // Let the demo's start-up lines pass.
    tokio::time::sleep(Duration::from_secs(2)).await;
    let before = gw.output().lines().count();
    let mut fuzz = Fuzz(0x2545_F491);
    let (mut frames, mut closes) = (0u64, 0u64);
    let start = std::time::Instant::now();
    let mut stream = TcpStream::connect(gw.modbus_tcp).await.expect("connect");
    while start.elapsed() < FUZZ_RUN {
        frames += 1;
        let bytes = fuzz.frame();
        let open = stream.write_all(&bytes).await.is_ok() && {
            let mut answer = [0u8; 300];
            match tokio::time::timeout(Duration::from_millis(500), stream.read(&mut answer)).await {
                Ok(Ok(0) | Err(_)) => false,
                Ok(Ok(_)) | Err(_) => true,
            }
        };
        if !open {
            closes += 1;
            stream = TcpStream::connect(gw.modbus_tcp).await.expect("reconnect");
        }
    }
    let output = gw.output();
    let during: Vec<&str> = output.lines().skip(before).collect();
    eprintln!(
        "fuzzing client, {FUZZ_RUN:?}: {frames} frames, {closes} connections closed by the \
         gateway, {} log lines",
        during.len()
    );
    assert!(frames > 200, "only {frames} fuzz frames in {FUZZ_RUN:?}");
    assert!(closes > 50, "only {closes} bad frames closed a connection");
    assert!(
        during.len() < 100,
        "{} log lines during the fuzzing run:\n{}",
        during.len(),
        during.join("\n")
    );
}
