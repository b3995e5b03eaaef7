//! The Modbus TCP server on real sockets (127.0.0.1, port 0): a tokio-modbus client for the
//! normal traffic, raw `TcpStream`s for the bad input.

#[path = "modbus_tcp/support.rs"]
mod support;

use std::sync::Arc;
use std::time::Duration;

use gateway::modbus_tcp::{CloseReason, FrameReject, RejectReason, RequestResult, ServerOptions};
use gateway::unit::write_policy::{WritePolicy, WriteRange, WriteTable};
use gateway::unit::UnitMap;
use proto_core::modbus::pdu::{ExceptionCode, Response};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_modbus::prelude::*;

use support::{
    adu, assert_closed, eventually, read_adu, start, start_with, within, FixedUnit, MemoryUnit,
    SlowUnit,
};

// === normal traffic ===

#[tokio::test]
async fn reads_and_writes_through_a_tokio_modbus_client() {
    let server = start(ServerOptions::default()).await;
    let mut client = server.client(1).await;
    let read = client
        .read_holding_registers(10, 3)
        .await
        .expect("transport");
    assert_eq!(read, Ok(vec![10, 11, 12]));
    client
        .write_multiple_registers(20, &[0xAAAA, 0x5555])
        .await
        .expect("transport")
        .expect("ok");
    client
        .write_single_register(22, 7)
        .await
        .expect("transport")
        .expect("ok");
    let read = client
        .read_holding_registers(20, 3)
        .await
        .expect("transport");
    assert_eq!(read, Ok(vec![0xAAAA, 0x5555, 7]));
    client
        .write_single_coil(3, true)
        .await
        .expect("transport")
        .expect("ok");
    let coils = client.read_coils(0, 5).await.expect("transport");
    assert_eq!(coils, Ok(vec![false, false, false, true, false]));
    // The unit's own exception passes through.
    let past_end = client
        .read_holding_registers(99, 2)
        .await
        .expect("transport");
    assert_eq!(
        past_end,
        Err(tokio_modbus::ExceptionCode::IllegalDataAddress)
    );
    assert_eq!(server.stats.request_count(0x03, RequestResult::Ok), 2);
    assert_eq!(
        server.stats.request_count(
            0x03,
            RequestResult::Exception(ExceptionCode::IllegalDataAddress)
        ),
        1
    );
    server.stop().await;
}

#[tokio::test]
async fn unknown_unit_answers_0a() {
    let server = start(ServerOptions::default()).await;
    let mut client = server.client(77).await;
    let read = client
        .read_holding_registers(0, 1)
        .await
        .expect("transport");
    assert_eq!(
        read,
        Err(tokio_modbus::ExceptionCode::GatewayPathUnavailable)
    );
    server.still_serves().await;
    server.stop().await;
}

#[tokio::test]
async fn units_can_be_replaced_while_serving() {
    let server = start(ServerOptions::default()).await;
    let mut client = server.client(5).await;
    let read = client
        .read_holding_registers(0, 1)
        .await
        .expect("transport");
    assert_eq!(
        read,
        Err(tokio_modbus::ExceptionCode::GatewayPathUnavailable)
    );
    server
        .units
        .write()
        .expect("lock")
        .insert(5, MemoryUnit::new(4));
    let read = client
        .read_holding_registers(1, 3)
        .await
        .expect("transport");
    assert_eq!(read, Ok(vec![1, 2, 3]));
    server.stop().await;
}

#[tokio::test]
async fn silent_unit_answers_0b_after_the_request_timeout() {
    let timeout = Duration::from_millis(300);
    let server = start(ServerOptions {
        request_timeout: timeout,
        ..ServerOptions::default()
    })
    .await;
    let mut client = server.client(9).await;
    let started = tokio::time::Instant::now();
    let read = client
        .read_holding_registers(0, 1)
        .await
        .expect("transport");
    assert_eq!(read, Err(tokio_modbus::ExceptionCode::GatewayTargetDevice));
    assert!(
        started.elapsed() >= timeout,
        "answered before the timeout: {:?}",
        started.elapsed()
    );
    // The same connection goes on serving other units.
    client.set_slave(Slave(1));
    assert_eq!(
        client
            .read_holding_registers(2, 1)
            .await
            .expect("transport"),
        Ok(vec![2])
    );
    server.stop().await;
}

#[tokio::test]
async fn responses_that_do_not_fit_the_request_answer_04() {
    let memory = MemoryUnit::new(1);
    let mut map = UnitMap::new();
    map.insert(
        2,
        Arc::new(FixedUnit(Response::ReadHoldingRegisters(vec![0; 200]))),
    );
    map.insert(3, Arc::new(FixedUnit(Response::ReadCoils(vec![true]))));
    let server = start_with(ServerOptions::default(), map, memory).await;
    let mut stream = server.raw().await;
    for unit in [2, 3] {
        stream
            .write_all(&adu(1, unit, &[0x03, 0, 0, 0, 1]))
            .await
            .expect("write");
        assert_eq!(
            read_adu(&mut stream).await,
            [0, 1, 0, 0, 0, 3, unit, 0x83, 0x04]
        );
    }
    server.stop().await;
}

#[tokio::test]
async fn read_only_mode_answers_01_to_writes() {
    let server = start(ServerOptions {
        writes: WritePolicy {
            read_only: true,
            write_ranges: None,
        },
        ..ServerOptions::default()
    })
    .await;
    let mut client = server.client(1).await;
    let illegal = Err(tokio_modbus::ExceptionCode::IllegalFunction);
    assert_eq!(
        client
            .write_single_register(4, 1234)
            .await
            .expect("transport"),
        illegal
    );
    assert_eq!(
        client
            .write_multiple_registers(4, &[1, 2])
            .await
            .expect("transport"),
        illegal
    );
    assert_eq!(
        client.write_single_coil(4, true).await.expect("transport"),
        illegal
    );
    assert_eq!(
        client
            .read_holding_registers(4, 2)
            .await
            .expect("transport"),
        Ok(vec![4, 5])
    );
    assert_eq!(server.memory.register(4), Some(4), "nothing written");
    server.stop().await;
}

#[tokio::test]
async fn writes_outside_the_write_ranges_answer_02() {
    let ranges = vec![
        WriteRange {
            unit: 1,
            table: WriteTable::HoldingRegisters,
            first: 10,
            last: 19,
        },
        WriteRange {
            unit: 1,
            table: WriteTable::Coils,
            first: 0,
            last: 3,
        },
    ];
    let server = start(ServerOptions {
        writes: WritePolicy {
            read_only: false,
            write_ranges: Some(ranges),
        },
        ..ServerOptions::default()
    })
    .await;
    let mut client = server.client(1).await;
    let illegal = Err(tokio_modbus::ExceptionCode::IllegalDataAddress);
    assert_eq!(
        client
            .write_multiple_registers(10, &[1; 10])
            .await
            .expect("transport"),
        Ok(())
    );
    assert_eq!(
        client
            .write_multiple_registers(18, &[2; 3])
            .await
            .expect("transport"),
        illegal
    );
    assert_eq!(
        client.write_single_register(9, 3).await.expect("transport"),
        illegal
    );
    assert_eq!(
        client.write_single_coil(3, true).await.expect("transport"),
        Ok(())
    );
    assert_eq!(
        client.write_single_coil(4, true).await.expect("transport"),
        illegal
    );
    assert_eq!(server.memory.register(18), Some(1));
    assert_eq!(
        server.memory.register(20),
        Some(20),
        "refused write left no trace"
    );
    server.stop().await;
}

#[tokio::test]
async fn transaction_ids_are_echoed_and_pipelined_requests_answered_in_order() {
    let server = start(ServerOptions::default()).await;
    let mut stream = server.raw().await;
    let ids: Vec<u16> = (0..10).map(|i| 0xFFFA_u16.wrapping_add(i * 7)).collect();
    let mut burst = Vec::new();
    for (i, id) in (0u8..).zip(&ids) {
        burst.extend_from_slice(&adu(*id, 1, &[0x03, 0, 30 + i, 0, 1]));
    }
    stream.write_all(&burst).await.expect("one write");
    for (i, id) in (0u8..).zip(&ids) {
        let response = read_adu(&mut stream).await;
        let mut expected = adu(*id, 1, &[0x03, 2, 0, 30 + i]);
        expected[4..6].copy_from_slice(&5u16.to_be_bytes());
        assert_eq!(response, expected, "response {i}");
    }
    server.stop().await;
}

#[tokio::test]
async fn a_pipelined_burst_is_answered_in_one_write() {
    let server = start(ServerOptions::default()).await;
    let mut stream = server.raw().await;
    let (mut burst, mut expected) = (Vec::new(), Vec::new());
    for i in 0u8..10 {
        burst.extend_from_slice(&adu(u16::from(i), 1, &[0x03, 0, 30 + i, 0, 1]));
        expected.extend_from_slice(&adu(u16::from(i), 1, &[0x03, 2, 0, 30 + i]));
    }
    stream.write_all(&burst).await.expect("one write");
    // The ten answers left in one segment: the first read takes them all.
    let mut answers = vec![0u8; 2 * expected.len()];
    let n = within("answers", stream.read(&mut answers))
        .await
        .expect("read");
    assert_eq!(answers.get(..n), Some(&expected[..]));
    server.stop().await;
}

#[tokio::test]
async fn answers_before_a_waiting_unit_leave_before_it_answers() {
    let memory = MemoryUnit::new(10);
    let (started_tx, mut started_rx) = tokio::sync::mpsc::unbounded_channel();
    let slow = SlowUnit {
        inner: memory.clone(),
        delay: Duration::from_secs(2),
        started: started_tx,
    };
    let mut map = UnitMap::new();
    map.insert(1, memory.clone());
    map.insert(2, Arc::new(slow));
    let server = start_with(ServerOptions::default(), map, memory).await;
    let mut stream = server.raw().await;
    let mut burst = adu(1, 1, &[0x03, 0, 4, 0, 1]);
    burst.extend_from_slice(&adu(2, 2, &[0x03, 0, 5, 0, 1]));
    stream.write_all(&burst).await.expect("one write");
    within("request reaches the slow unit", started_rx.recv())
        .await
        .expect("started");
    // Unit 1's answer is there while unit 2 still waits (2 s); unit 2's follows.
    let first = tokio::time::timeout(Duration::from_secs(1), read_adu(&mut stream))
        .await
        .expect("the first answer before the slow unit's");
    assert_eq!(first, adu(1, 1, &[0x03, 2, 0, 4]));
    assert_eq!(read_adu(&mut stream).await, adu(2, 2, &[0x03, 2, 0, 5]));
    server.stop().await;
}

// === bad input ===

#[tokio::test]
async fn bad_pdus_get_exceptions_on_the_same_connection() {
    let server = start(ServerOptions::default()).await;
    let mut stream = server.raw().await;
    let cases: [(&str, Vec<u8>, [u8; 2]); 6] = [
        ("unknown function 0x42", vec![0x42, 0, 0], [0xC2, 0x01]),
        ("FC03 quantity 0", vec![0x03, 0, 0, 0, 0], [0x83, 0x03]),
        ("FC03 quantity 126", vec![0x03, 0, 0, 0, 126], [0x83, 0x03]),
        (
            "FC15 1969 coils in 6 bytes",
            vec![
                0x0F, 0, 0, 0x07, 0xB1, 6, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF,
            ],
            [0x8F, 0x03],
        ),
        (
            "FC16 byte count 3 for 2 registers",
            vec![0x10, 0, 0, 0, 2, 3, 0, 1, 0],
            [0x90, 0x03],
        ),
        (
            "FC16 byte count 4, 2 bytes sent",
            vec![0x10, 0, 0, 0, 2, 4, 0, 1],
            [0x90, 0x03],
        ),
    ];
    for (id, (what, pdu, exception)) in (1u16..).zip(&cases) {
        stream.write_all(&adu(id, 1, pdu)).await.expect("write");
        let response = read_adu(&mut stream).await;
        assert_eq!(response, adu(id, 1, exception), "{what}");
    }
    stream
        .write_all(&adu(99, 1, &[0x03, 0, 7, 0, 1]))
        .await
        .expect("write");
    assert_eq!(
        read_adu(&mut stream).await,
        adu(99, 1, &[0x03, 2, 0, 7]),
        "the connection still serves"
    );
    let value_03 = RequestResult::Exception(ExceptionCode::IllegalDataValue);
    assert_eq!(
        server.stats.request_count(
            0x42,
            RequestResult::Exception(ExceptionCode::IllegalFunction)
        ),
        1
    );
    assert_eq!(server.stats.request_count(0x03, value_03), 2);
    assert_eq!(server.stats.request_count(0x0F, value_03), 1);
    assert_eq!(server.stats.request_count(0x10, value_03), 2);
    server.stop().await;
}

#[tokio::test]
async fn bad_mbap_headers_close_the_connection_and_others_go_on() {
    let server = start(ServerOptions::default()).await;
    let mut bystander = server.client(1).await;
    let cases: [(&str, &[u8], FrameReject); 4] = [
        (
            "length 0",
            &[0, 1, 0, 0, 0, 0, 1, 0x03, 0, 0, 0, 1],
            FrameReject::Length,
        ),
        // Only the header: the server must not wait for 65535 bytes.
        (
            "length 65535",
            &[0, 1, 0, 0, 0xFF, 0xFF, 1],
            FrameReject::Length,
        ),
        (
            "protocol id 1",
            &[0, 1, 0, 1, 0, 6, 1, 0x03, 0, 0, 0, 1],
            FrameReject::ProtocolId,
        ),
        (
            "length 1, no function code",
            &[0, 1, 0, 0, 0, 1, 1],
            FrameReject::EmptyPdu,
        ),
    ];
    for (what, bytes, reason) in cases {
        let before = server.stats.frames_rejected(reason);
        let mut stream = server.raw().await;
        stream.write_all(bytes).await.expect("write");
        assert_closed(&mut stream, what).await;
        eventually(what, || server.stats.frames_rejected(reason) == before + 1).await;
        let read = bystander
            .read_holding_registers(1, 2)
            .await
            .expect("transport");
        assert_eq!(read, Ok(vec![1, 2]), "after {what}");
    }
    assert_eq!(server.stats.connections_closed(CloseReason::BadFrame), 4);
    server.still_serves().await;
    server.stop().await;
}

#[tokio::test]
async fn clients_that_never_finish_a_header_are_dropped_after_the_idle_timeout() {
    let idle = Duration::from_millis(400);
    let server = start(ServerOptions {
        idle_timeout: idle,
        ..ServerOptions::default()
    })
    .await;
    // Half a header, then nothing.
    let mut half = server.raw().await;
    half.write_all(&[0, 1, 0]).await.expect("write");
    // One byte every 100 ms: never a complete frame, so never a reason to stay.
    let mut trickle = server.raw().await;
    let started = tokio::time::Instant::now();
    // A header announcing the largest PDU, then PDU bytes: 40 bytes in all, never a whole frame.
    let mut bytes = vec![0u8, 2, 0, 0, 0, 254, 1];
    bytes.resize(40, 0x10);
    let mut closed = false;
    for byte in &bytes {
        if trickle.write_all(std::slice::from_ref(byte)).await.is_err() {
            closed = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
        let mut probe = [0u8; 1];
        if let Ok(read) = tokio::time::timeout(Duration::ZERO, trickle.read(&mut probe)).await {
            assert!(!matches!(read, Ok(n) if n > 0), "no response expected");
            closed = true;
            break;
        }
    }
    assert!(
        closed,
        "trickling client still connected after {:?}",
        started.elapsed()
    );
    assert_closed(&mut half, "half header").await;
    assert!(server.stats.connections_closed(CloseReason::Idle) >= 2);
    server.still_serves().await;
    server.stop().await;
}

// === limits ===

/// Raises this test binary's soft file-descriptor limit to at least `want` (up to the hard limit).
fn raise_fd_limit(want: u64) {
    use rustix::process::{getrlimit, setrlimit, Resource, Rlimit};
    let limit = getrlimit(Resource::Nofile);
    if limit.current.is_some_and(|current| current < want) {
        let current = Some(limit.maximum.map_or(want, |max| max.min(want)));
        setrlimit(
            Resource::Nofile,
            Rlimit {
                current,
                maximum: limit.maximum,
            },
        )
        .expect("setrlimit");
    }
}

/// Sends a read on each stream; `(answered, closed)`.
async fn probe_all(streams: &mut [TcpStream]) -> (usize, usize) {
    let mut answered = 0;
    let mut closed = 0;
    for stream in streams.iter_mut() {
        // A refused stream may already be reset: a failing write counts as closed too.
        if stream
            .write_all(&adu(7, 1, &[0x03, 0, 1, 0, 1]))
            .await
            .is_err()
        {
            closed += 1;
            continue;
        }
        let mut header = [0u8; 11];
        match within("probe", stream.read_exact(&mut header)).await {
            Ok(_) => {
                assert_eq!(header, [0, 7, 0, 0, 0, 5, 1, 0x03, 2, 0, 1]);
                answered += 1;
            }
            Err(_) => closed += 1,
        }
    }
    (answered, closed)
}

#[tokio::test]
async fn three_hundred_clients_at_once_are_served() {
    raise_fd_limit(2048);
    let server = start(ServerOptions {
        max_connections: 400,
        ..ServerOptions::default()
    })
    .await;
    let connects = (0..300).map(|_| TcpStream::connect(server.addr));
    let mut streams: Vec<TcpStream> = futures::future::try_join_all(connects)
        .await
        .expect("300 connects");
    assert_eq!(probe_all(&mut streams).await, (300, 0));
    assert_eq!(server.stats.connections_open(), 300);
    drop(streams);
    eventually("all closed", || server.stats.connections_open() == 0).await;
    server.still_serves().await;
    server.stop().await;
}

#[tokio::test]
async fn clients_over_the_cap_are_closed_and_counted() {
    raise_fd_limit(2048);
    let server = start(ServerOptions {
        max_connections: 20,
        ..ServerOptions::default()
    })
    .await;
    let connects = (0..300).map(|_| TcpStream::connect(server.addr));
    let mut streams: Vec<TcpStream> = futures::future::try_join_all(connects)
        .await
        .expect("300 connects");
    eventually("300 accepted or refused", || {
        server.stats.connections_accepted() + server.stats.connections_rejected(RejectReason::Limit)
            == 300
    })
    .await;
    assert_eq!(server.stats.connections_accepted(), 20);
    assert_eq!(server.stats.connections_rejected(RejectReason::Limit), 280);
    assert_eq!(probe_all(&mut streams).await, (20, 280));
    // Freeing the places lets later clients in.
    drop(streams);
    eventually("all closed", || server.stats.connections_open() == 0).await;
    for _ in 0..3 {
        server.still_serves().await;
    }
    assert_eq!(server.stats.connections_rejected(RejectReason::Limit), 280);
    server.stop().await;
}

/// A connection from `source` (a loopback address of its own) to the server.
async fn connect_from(server: &support::TestServer, source: [u8; 4]) -> TcpStream {
    let socket = tokio::net::TcpSocket::new_v4().expect("socket");
    socket
        .bind(std::net::SocketAddr::from((source, 0)))
        .expect("bind the source address");
    socket.connect(server.addr).await.expect("connect")
}

#[tokio::test]
async fn a_flood_from_one_address_cannot_take_the_last_place_from_another() {
    // Three places, two per client address: 127.0.0.1 floods with 50 connections.
    let server = start(ServerOptions {
        max_connections: 3,
        max_connections_per_client: Some(2),
        ..ServerOptions::default()
    })
    .await;
    let mut flood = Vec::new();
    for _ in 0..50 {
        flood.push(connect_from(&server, [127, 0, 0, 1]).await);
    }
    eventually("50 accepted or refused", || {
        server.stats.connections_accepted() + server.stats.connections_rejected(RejectReason::Limit)
            == 50
    })
    .await;
    assert_eq!(server.stats.connections_accepted(), 2);
    assert_eq!(probe_all(&mut flood).await, (2, 48));
    // The second address still gets the last place and is served.
    let mut scada = vec![connect_from(&server, [127, 0, 0, 2]).await];
    assert_eq!(probe_all(&mut scada).await, (1, 0));
    assert_eq!(server.stats.connections_accepted(), 3);
    // The flood's places come back when its connections leave.
    drop(flood);
    eventually("the flood's connections closed", || {
        server.stats.connections_open() == 1
    })
    .await;
    let mut again = vec![connect_from(&server, [127, 0, 0, 1]).await];
    assert_eq!(probe_all(&mut again).await, (1, 0));
    server.stop().await;
}

#[tokio::test]
async fn clients_outside_the_allowed_networks_are_refused() {
    let outside = ServerOptions {
        allowed_networks: vec!["192.0.2.0/24".parse().expect("net")],
        ..ServerOptions::default()
    };
    let server = start(outside).await;
    let mut stream = server.raw().await;
    let _ = stream.write_all(&adu(1, 1, &[0x03, 0, 0, 0, 1])).await;
    assert_closed(&mut stream, "client outside the allowed networks").await;
    eventually("counted", || {
        server.stats.connections_rejected(RejectReason::Network) == 1
    })
    .await;
    assert_eq!(server.stats.connections_accepted(), 0);
    server.stop().await;

    let inside = ServerOptions {
        allowed_networks: vec![
            "192.0.2.0/24".parse().expect("net"),
            "127.0.0.0/8".parse().expect("net"),
        ],
        ..ServerOptions::default()
    };
    let server = start(inside).await;
    server.still_serves().await;
    assert_eq!(server.stats.connections_rejected(RejectReason::Network), 0);
    server.stop().await;
}

// === shutdown ===

#[tokio::test]
async fn shutdown_finishes_the_request_in_flight() {
    let memory = MemoryUnit::new(10);
    let (started_tx, mut started_rx) = tokio::sync::mpsc::unbounded_channel();
    let slow = SlowUnit {
        inner: memory.clone(),
        delay: Duration::from_millis(300),
        started: started_tx,
    };
    let mut map = UnitMap::new();
    map.insert(1, Arc::new(slow));
    let server = start_with(ServerOptions::default(), map, memory).await;
    let mut idle_client = server.raw().await;
    let mut busy_client = server.raw().await;
    busy_client
        .write_all(&adu(42, 1, &[0x06, 0, 3, 0x12, 0x34]))
        .await
        .expect("write");
    within("request reaches the unit", started_rx.recv())
        .await
        .expect("started");
    let addr = server.addr;
    let memory = server.memory.clone();
    server.shutdown.cancel();
    // The request in flight is answered, then the connection closes.
    assert_eq!(
        read_adu(&mut busy_client).await,
        adu(42, 1, &[0x06, 0, 3, 0x12, 0x34])
    );
    assert_closed(&mut busy_client, "busy client after shutdown").await;
    assert_closed(&mut idle_client, "idle client after shutdown").await;
    assert_eq!(memory.register(3), Some(0x1234));
    let stats = server.stats.clone();
    server.stop().await;
    assert_eq!(stats.connections_closed(CloseReason::Shutdown), 2);
    assert!(TcpStream::connect(addr).await.is_err(), "listener closed");
}
