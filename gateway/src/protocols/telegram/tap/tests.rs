//! The 3964(R) tap line on two in-process ports: the test's ends play the two partners' transmit
//! lines (and, with `PARMRK` marks, a UART's line errors a pty cannot produce).

use std::collections::VecDeque;

use proto_core::modbus::pdu::{ExceptionCode, Request};
use proto_core::monitor::Direction;
use proto_core::proc3964::frame::encode;
use proto_core::proc3964::{DLE, NAK, STX};
use proto_core::serial_marks::{self, Received};
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

use super::*;
use crate::line::testing::{events, eventually, Ports};
use crate::mailbox::layout;

/// A tap line on two in-process ports; the partners' ends.
fn tap_line(shutdown: &CancellationToken) -> (LineHandle, DuplexStream, DuplexStream) {
    let (a, partner_a) = tokio::io::duplex(256);
    let (b, partner_b) = tokio::io::duplex(256);
    let mut settings = Tap3964LineSettings::new(
        "y",
        PortSettings::new("/dev/in-process-a", 9600),
        "/dev/in-process-b",
        Variant::P3964R,
    );
    settings.mailbox_depth = 2;
    settings.unit_id = Some(40);
    let line = spawn_on(
        settings,
        shutdown.clone(),
        Ports(Mutex::new(VecDeque::from([Ok(a), Ok(b)]))),
    );
    (line, partner_a, partner_b)
}

/// One exchange of `sender` (its port `tx`) with the receiver (`rx`): STX, DLE, the telegram,
/// `ack`, with a little time between the steps and after the last as on a line (a partner answers
/// what it has received; bytes both ports hold at the same instant are taken first port first).
async fn exchange(tx: &mut DuplexStream, rx: &mut DuplexStream, data: &[u8], ack: u8) {
    let step = Duration::from_millis(5);
    tx.write_all(&[STX]).await.expect("write");
    tokio::time::sleep(step).await;
    rx.write_all(&[DLE]).await.expect("write");
    tokio::time::sleep(step).await;
    tx.write_all(&encode(data, Variant::P3964R))
        .await
        .expect("write");
    tokio::time::sleep(step).await;
    rx.write_all(&[ack]).await.expect("write");
    tokio::time::sleep(step).await;
}

#[tokio::test]
async fn both_partners_telegrams_land_in_the_mailbox_with_their_side_and_frames_in_the_monitor() {
    let shutdown = CancellationToken::new();
    let (line, mut a, mut b) = tap_line(&shutdown);
    assert_eq!(line.protocol(), "3964r-tap");
    eventually("the ports open", || line.status().port_open).await;
    let mailbox = line.mailbox().expect("a mailbox");

    exchange(&mut a, &mut b, b"from A", DLE).await;
    exchange(&mut b, &mut a, &[0x10, 0x02], DLE).await;
    eventually("two telegrams", || mailbox.waiting().len() == 2).await;
    let waiting = mailbox.waiting();
    assert_eq!(
        waiting
            .iter()
            .map(|t| (t.side, t.data.to_vec()))
            .collect::<Vec<_>>(),
        [
            (Some(Side::A), b"from A".to_vec()),
            (Some(Side::B), vec![0x10, 0x02]),
        ]
    );
    let status = line.telegram_status().expect("telegram status");
    assert_eq!(status.protocol, "3964R");
    assert_eq!(status.counters.received, 2);

    // The monitor has each partner's frames under its side, B's telegram (beginning with a
    // doubled DLE) as one frame.
    let monitor = Arc::clone(line.monitor().expect("a monitor"));
    eventually("eight frames", || monitor.frames_since(0).0.len() == 8).await;
    let (frames, _) = monitor.frames_since(0);
    let seen: Vec<(Direction, usize)> = frames
        .iter()
        .map(|f| (f.direction, f.bytes.len()))
        .collect();
    assert_eq!(
        seen,
        [
            (Direction::A, 1),
            (Direction::B, 1),
            (Direction::A, 9),
            (Direction::B, 1),
            (Direction::B, 1),
            (Direction::A, 1),
            (Direction::B, 6),
            (Direction::A, 1),
        ]
    );
    let telegram_b = monitor.describe(&frames[6]);
    assert_eq!(telegram_b.verdict.as_str(), "ok", "{}", telegram_b.summary);

    // A third telegram in a mailbox of two: the oldest goes (08 0Ah), nobody was refused.
    exchange(&mut a, &mut b, b"third", DLE).await;
    eventually("08 0Ah", || events(&line, ids::NO_FREE_RECEIVE_BUFFER) == 1).await;
    let seqs: Vec<u16> = mailbox.waiting().iter().map(|t| t.seq).collect();
    assert_eq!(seqs, [2, 3]);

    // Nothing was ever written to either port.
    let mut byte = [0u8; 1];
    for partner in [&mut a, &mut b] {
        let read = tokio::time::timeout(Duration::from_millis(50), partner.read(&mut byte)).await;
        assert!(read.is_err(), "the tap wrote {read:?}");
    }

    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(2), line.join())
        .await
        .expect("the line stops");
}

#[tokio::test]
async fn faults_are_the_senders_events_with_the_side_and_a_damaged_telegram_is_not_delivered() {
    let shutdown = CancellationToken::new();
    let (line, mut a, mut b) = tap_line(&shutdown);
    eventually("the ports open", || line.status().port_open).await;
    let mailbox = line.mailbox().expect("a mailbox");

    // B refuses A's telegram (07 06h from A's view), then takes the repetition (07 01h).
    let mut feed = line.subscribe_events();
    exchange(&mut a, &mut b, b"one", NAK).await;
    exchange(&mut a, &mut b, b"one", DLE).await;
    eventually("the repetition delivered", || mailbox.waiting().len() == 1).await;
    assert_eq!(events(&line, ids::SEND_END_REJECTED), 1);
    assert_eq!(events(&line, ids::SEND_REPETITION), 1);
    let mut detail = String::new();
    while let Ok(event) = feed.try_recv() {
        if event.id == ids::SEND_END_REJECTED {
            detail = event.detail.unwrap_or_default();
        }
    }
    assert_eq!(detail, "partner a: NAK to its telegram");

    // A bad BCC from B that A acknowledges anyway: 08 08h, not delivered.
    b.write_all(&[STX]).await.expect("write");
    tokio::time::sleep(Duration::from_millis(5)).await;
    a.write_all(&[DLE]).await.expect("write");
    tokio::time::sleep(Duration::from_millis(5)).await;
    let mut bad = encode(b"xyz", Variant::P3964R);
    if let Some(bcc) = bad.last_mut() {
        *bcc ^= 0xFF;
    }
    b.write_all(&bad).await.expect("write");
    tokio::time::sleep(Duration::from_millis(5)).await;
    a.write_all(&[DLE]).await.expect("write");
    eventually("08 08h", || events(&line, ids::BCC_ERROR) == 1).await;

    // A parity error inside B's next telegram (what the tty layer delivers with PARMRK): 08 0Ch,
    // not delivered although A acknowledges it.
    b.write_all(&[STX]).await.expect("write");
    tokio::time::sleep(Duration::from_millis(5)).await;
    a.write_all(&[DLE]).await.expect("write");
    tokio::time::sleep(Duration::from_millis(5)).await;
    let mut marked = Vec::new();
    serial_marks::encode([Received::Byte(b'p'), Received::Faulty(b'q')], &mut marked);
    b.write_all(&marked).await.expect("write");
    b.write_all(&encode(b"r", Variant::P3964R))
        .await
        .expect("write");
    tokio::time::sleep(Duration::from_millis(5)).await;
    a.write_all(&[DLE]).await.expect("write");
    eventually("08 0Ch", || events(&line, ids::CHARACTER_ERROR) == 1).await;
    assert_eq!(mailbox.waiting().len(), 1, "only A's repeated telegram");
    assert_eq!(mailbox.counters().received, 1);

    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(2), line.join())
        .await
        .expect("the line stops");
}

#[tokio::test]
async fn every_way_to_send_is_refused_and_reading_the_mailbox_still_works() {
    let shutdown = CancellationToken::new();
    let (line, mut a, mut b) = tap_line(&shutdown);
    eventually("the ports open", || line.status().port_open).await;

    // REST and zenoh send through the telegram client.
    let client = line.telegram_client().expect("a client");
    assert!(client.is_listen_only());
    let refused = client.send(b"hello".to_vec()).await;
    assert!(
        matches!(refused, Err(TelegramSendError::ListenOnly { ref line }) if line == "y"),
        "{refused:?}"
    );
    let signals = line.signals().expect("signals").read().await;
    assert!(
        matches!(signals, Err(SignalError::ListenOnly { .. })),
        "{signals:?}"
    );

    // Modbus TCP: the send block answers 01, the received part can be read and acknowledged.
    let unit = line.mailbox_unit().expect("a mailbox unit");
    for request in [
        Request::WriteSingleRegister {
            address: layout::TX_LEN,
            value: 2,
        },
        Request::WriteMultipleRegisters {
            address: layout::TX_DATA,
            values: vec![0x4142],
        },
        Request::WriteSingleRegister {
            address: layout::TX_REQ,
            value: 1,
        },
    ] {
        assert_eq!(
            unit.answer(request.clone()),
            Err(ExceptionCode::IllegalFunction),
            "{request:?}"
        );
    }
    exchange(&mut a, &mut b, b"AB", DLE).await;
    let mailbox = line.mailbox().expect("a mailbox");
    eventually("the telegram", || mailbox.waiting().len() == 1).await;
    let read = unit
        .answer(Request::ReadHoldingRegisters {
            address: layout::RX_SEQ,
            quantity: 4,
        })
        .expect("read");
    assert_eq!(
        read,
        proto_core::modbus::pdu::Response::ReadHoldingRegisters(vec![1, 2, 1, 0x4142])
    );
    unit.answer(Request::WriteSingleRegister {
        address: layout::ACK,
        value: 1,
    })
    .expect("acknowledged");
    assert!(mailbox.waiting().is_empty());

    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(2), line.join())
        .await
        .expect("the line stops");
}

#[test]
fn the_discard_series_created_at_start_are_one_per_fault_reason() {
    let labels: Vec<&str> = FAULT_KINDS
        .iter()
        .map(|&fault| crate::line::metrics::FrameDiscard::from(fault).as_label())
        .collect();
    assert_eq!(labels, Fault::REASONS);
}
