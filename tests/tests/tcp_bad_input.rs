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
