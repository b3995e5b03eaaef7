use std::sync::Mutex;
use std::time::Duration;

use proto_core::event::ids;
use proto_core::modbus::rtu::{encode_frame, expected_request_len, FrameLen};
use proto_core::serial_marks::{encode, Received};
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

use super::*;
use crate::line::testing::OnePort;
use crate::protocols::{AddrRange, PollGroup};
use crate::serial::PortSettings;

/// Reads one FC 03 request of the line.
async fn request(device: &mut DuplexStream) -> Vec<u8> {
    let mut buf = Vec::new();
    let mut byte = [0u8; 1];
    loop {
        device.read_exact(&mut byte).await.expect("request");
        buf.extend_from_slice(&byte);
        if let FrameLen::Complete(len) = expected_request_len(&buf) {
            if buf.len() >= len {
                return buf;
            }
        }
    }
}

#[tokio::test]
async fn a_reply_with_a_parity_error_fails_with_080c_and_its_values_are_not_taken() {
    let (port, mut device) = tokio::io::duplex(256);
    let mut settings = LineSettings::rtu("drive", PortSettings::new("/dev/in-process", 19200));
    settings.master.reply_timeout = Duration::from_millis(200);
    let mut atv = DeviceSettings::new("atv", 2, 2);
    atv.groups = vec![PollGroup {
        period: Duration::from_millis(50),
        table: Table::HoldingRegisters,
        ranges: vec![AddrRange::new(3201, 1)],
    }];
    atv.backoff_min = Duration::from_millis(50);
    atv.backoff_max = Duration::from_millis(100);
    let image = ProcessImage::default();
    let shutdown = CancellationToken::new();
    let line = spawn_on(
        settings,
        vec![atv],
        image.clone(),
        shutdown.clone(),
        OnePort(Mutex::new(Some(port))),
    );

    // The first reply (ETA = 0637h) arrives with its first data byte received with a parity
    // error: 08 0Ch for slave 2 (003 7.2), the reply discarded, nothing in the image.
    let req = request(&mut device).await;
    assert_eq!(req.get(..2), Some(&[2, 3][..]));
    let mut reply = Vec::new();
    encode_frame(2, &[0x03, 0x02, 0x06, 0x37], &mut reply);
    let mut marked = reply.get(..3).unwrap_or_default().to_vec();
    encode([Received::Faulty(0x06)], &mut marked);
    marked.extend_from_slice(reply.get(4..).unwrap_or_default());
    device.write_all(&marked).await.expect("write");
    let mut ok = false;
    for _ in 0..200 {
        let status = line.status();
        if status.event_counts.get(&ids::CHARACTER_ERROR) == Some(&1) {
            ok = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert!(ok, "no 08 0Ch: {:?}", line.status());
    assert!(image
        .read_words(2, Table::HoldingRegisters, 3201, 1)
        .is_err());

    // The line keeps running: the next poll's clean reply is taken.
    let req = request(&mut device).await;
    assert_eq!(req.get(..2), Some(&[2, 3][..]));
    device.write_all(&reply).await.expect("write");
    let mut read = None;
    for _ in 0..200 {
        if let Ok(r) = image.read_words(2, Table::HoldingRegisters, 3201, 1) {
            read = Some(r.values);
            break;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    assert_eq!(read, Some(vec![0x0637]));
    assert_eq!(
        line.status().event_counts.get(&ids::CHARACTER_ERROR),
        Some(&1)
    );
    shutdown.cancel();
    line.join().await;
}

#[tokio::test]
async fn a_silent_forwarded_address_is_answered_0b_at_once_while_it_is_offline() {
    let (port, mut device) = tokio::io::duplex(256);
    let mut settings = LineSettings::rtu("bus", PortSettings::new("/dev/in-process", 19200));
    settings.master.reply_timeout = Duration::from_millis(50);
    let mut transparent = TransparentSettings::new(5..=5);
    transparent.offline_after = 2;
    transparent.backoff_min = Duration::from_secs(30);
    transparent.backoff_max = Duration::from_secs(30);
    settings.transparent = Some(transparent);
    let shutdown = CancellationToken::new();
    let line = spawn_on(
        settings,
        Vec::new(),
        ProcessImage::default(),
        shutdown.clone(),
        OnePort(Mutex::new(Some(port))),
    );
    let units = line.transparent_units();
    assert_eq!(units.iter().map(|(id, _)| *id).collect::<Vec<_>>(), [5]);
    let unit = Arc::clone(&units[0].1);
    let read = Request::ReadHoldingRegisters {
        address: 0,
        quantity: 1,
    };

    // Two requests reach the bus and get no reply: 0B after the reply monitoring time, and
    // the address is offline.
    for _ in 0..2 {
        let answer = tokio::spawn(unit.call(read.clone()));
        let req = request(&mut device).await;
        assert_eq!(req.get(..2), Some(&[5, 3][..]));
        assert_eq!(
            answer.await.expect("join"),
            Err(proto_core::modbus::pdu::ExceptionCode::GatewayTargetFailedToRespond)
        );
    }
    // Within its back-off the next one is answered at once and nothing goes to the bus.
    let started = Instant::now();
    assert_eq!(
        unit.call(read.clone()).await,
        Err(proto_core::modbus::pdu::ExceptionCode::GatewayTargetFailedToRespond)
    );
    assert!(
        started.elapsed() < Duration::from_millis(50),
        "{:?}",
        started.elapsed()
    );
    let mut byte = [0u8; 1];
    assert!(
        tokio::time::timeout(Duration::from_millis(150), device.read_exact(&mut byte))
            .await
            .is_err(),
        "a request of an offline forwarded address reached the bus"
    );
    shutdown.cancel();
    line.join().await;
}
