//! A listen-only tap line on a real pty: the test writes a master's requests and the slaves'
//! answers into the tap's port with real silences between the frames (as on a shared RS485 bus),
//! and reads what the tap stored through the Modbus TCP server, as SCADA would.
//!
//! The line runs at 1200 Bd (8E1, 11 bits a character): t1.5 = 13.8 ms, t3.5 = 32 ms (003 6.4.3),
//! and the frames are 150 ms apart, so that a loaded machine's scheduling does not merge or split
//! them. A pty delivers a frame written at once in one read, so there is no gap inside a frame.

use std::sync::{Arc, RwLock};
use std::time::Duration;

use gateway::app::Metrics;
use gateway::image::{ProcessImage, Table};
use gateway::line::LineHandle;
use gateway::metrics::encode_text;
use gateway::modbus_tcp::{bind, serve, ServerOptions, ServerStats};
use gateway::protocols::{spawn_modbus_tap_line, DeviceSettings, TapLineSettings};
use gateway::serial::PortSettings;
use gateway::unit::{SharedUnits, UnitMap};
use prometheus::Registry;
use proto_core::modbus::rtu::encode_frame;
use proto_core::monitor::{Direction, Verdict};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_modbus::prelude::*;
use tokio_serial::{SerialPort, SerialStream};
use tokio_util::sync::CancellationToken;

/// Between two frames on the bus: far above t3.5 (32 ms at 1200 Bd).
const GAP: Duration = Duration::from_millis(150);

fn frame(address: u8, pdu: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    encode_frame(address, pdu, &mut out);
    out
}

/// Writes `frames` onto the bus, one after the other with [`GAP`] of silence after each.
async fn on_the_bus(bus: &mut SerialStream, frames: &[Vec<u8>]) {
    for f in frames {
        bus.write_all(f).await.expect("write to the bus");
        tokio::time::sleep(GAP).await;
    }
}

/// Waits up to 10 s for `check` to hold.
async fn eventually(what: &str, mut check: impl FnMut() -> bool) {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    while !check() {
        assert!(
            tokio::time::Instant::now() < deadline,
            "timed out waiting for {what}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// The value of the first sample of `family` whose labels contain every one of `labels`.
fn sample(text: &str, family: &str, labels: &[&str]) -> Option<f64> {
    text.lines()
        .filter(|l| l.starts_with(family) && labels.iter().all(|x| l.contains(x)))
        .find_map(|l| l.rsplit(' ').next()?.trim().parse().ok())
}

/// FC 03 of W3102..W3105 of the Altivar at `slave`.
fn read_request(slave: u8) -> Vec<u8> {
    frame(slave, &[0x03, 0x0C, 0x1E, 0x00, 0x04])
}

/// The answer with SFr, tFr, HSP, LSP.
fn read_answer(slave: u8, values: [u16; 4]) -> Vec<u8> {
    let mut pdu = vec![0x03, 0x08];
    for v in values {
        pdu.extend_from_slice(&v.to_be_bytes());
    }
    frame(slave, &pdu)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tap_fills_the_image_from_another_masters_traffic_and_never_transmits() {
    let (mut bus, line_end) = SerialStream::pair().expect("pty pair");
    let path = line_end.name().expect("pty path");
    let registry = Registry::new();
    let metrics = Metrics::register(&registry).expect("register");

    // The tap lists the drive at slave 2 (unit 2); slave 5 on the same bus is not listed.
    let mut settings = TapLineSettings::new("tap", PortSettings::new(path, 1200));
    settings.tap.answer_timeout = Duration::from_millis(400);
    settings.expected_cycle = Duration::from_secs(30);
    settings.metrics = Some(metrics.line().clone());
    let image = ProcessImage::default();
    let shutdown = CancellationToken::new();
    let line: LineHandle = spawn_modbus_tap_line(
        settings,
        vec![DeviceSettings::new("atv", 2, 2)],
        image.clone(),
        shutdown.clone(),
    );
    assert_eq!(line.protocol(), "modbus-rtu-tap");
    assert!(line.is_tap());
    eventually("the port open", || line.status().port_open).await;

    // Modbus TCP on 127.0.0.1, port 0, serving the tap's units.
    let mut map = UnitMap::new();
    for (unit, service) in line.units() {
        map.insert(unit, service);
    }
    let units: SharedUnits = Arc::new(RwLock::new(map));
    let listener = bind(([127, 0, 0, 1], 0).into()).expect("bind");
    let addr = listener.local_addr().expect("address");
    let server_stop = CancellationToken::new();
    let server = tokio::spawn(serve(
        listener,
        units,
        ServerOptions::default(),
        server_stop.clone(),
        Arc::new(ServerStats::default()),
    ));
    let mut client = tcp::connect_slave(addr, Slave(2)).await.expect("connect");

    // Before the bus showed anything the tap has no value: 0x0B, not a made-up one.
    let before = client
        .read_holding_registers(3102, 4)
        .await
        .expect("transport");
    assert_eq!(before, Err(ExceptionCode::GatewayTargetDevice));

    // The other master reads the drive, the drive answers: 40 600 500 0.
    on_the_bus(
        &mut bus,
        &[read_request(2), read_answer(2, [40, 600, 500, 0])],
    )
    .await;
    eventually("the read answer in the image", || {
        image
            .read_words(2, Table::HoldingRegisters, 3102, 4)
            .is_ok_and(|r| r.values == [40, 600, 500, 0])
    })
    .await;
    let read = client
        .read_holding_registers(3102, 4)
        .await
        .expect("transport");
    assert_eq!(read, Ok(vec![40, 600, 500, 0]));

    // A confirmed write: ACC (W9001) = 13, the drive echoes it.
    let write = frame(2, &[0x06, 0x23, 0x29, 0x00, 0x0D]);
    on_the_bus(&mut bus, &[write.clone(), write]).await;
    eventually("the confirmed write in the image", || {
        image
            .read_words(2, Table::HoldingRegisters, 9001, 1)
            .is_ok_and(|r| r.values == [13])
    })
    .await;

    // Slave 5 is not listed: its exchange is counted, nothing is stored under its address.
    on_the_bus(&mut bus, &[read_request(5), read_answer(5, [1, 2, 3, 4])]).await;

    // A broken answer (one bit flipped after the CRC was computed): counted, not stored, and
    // its request goes unanswered.
    let mut broken = read_answer(2, [41, 601, 501, 1]);
    if let Some(b) = broken.get_mut(4) {
        *b ^= 0x01;
    }
    on_the_bus(&mut bus, &[read_request(2), broken]).await;
    let text = || encode_text(&registry);
    eventually("the bad CRC and the missing answer counted", || {
        let t = text();
        sample(
            &t,
            "gateway_frames_discarded_total",
            &["line=\"tap\"", "reason=\"bad_crc\""],
        ) == Some(1.0)
            && sample(
                &t,
                "gateway_modbus_requests_total",
                &["line=\"tap\"", "device=\"atv\"", "result=\"timeout\""],
            ) == Some(1.0)
    })
    .await;
    let t = text();
    assert_eq!(
        sample(
            &t,
            "gateway_modbus_requests_total",
            &["line=\"tap\"", "device=\"unknown\"", "result=\"ok\""]
        ),
        Some(1.0),
        "{t}"
    );
    assert_eq!(
        sample(
            &t,
            "gateway_modbus_requests_total",
            &[
                "line=\"tap\"",
                "device=\"atv\"",
                "function=\"03\"",
                "result=\"ok\""
            ]
        ),
        Some(1.0),
        "{t}"
    );
    assert_eq!(
        sample(
            &t,
            "gateway_modbus_requests_total",
            &[
                "line=\"tap\"",
                "device=\"atv\"",
                "function=\"06\"",
                "result=\"ok\""
            ]
        ),
        Some(1.0),
        "{t}"
    );
    assert_eq!(
        sample(
            &t,
            "gateway_telegrams_total",
            &["line=\"tap\"", "direction=\"rx\""]
        ),
        Some(8.0),
        "every frame seen: {t}"
    );
    assert!(image
        .read_words(5, Table::HoldingRegisters, 3102, 4)
        .is_err());
    let read = client
        .read_holding_registers(3102, 4)
        .await
        .expect("transport");
    assert_eq!(
        read,
        Ok(vec![40, 600, 500, 0]),
        "the broken answer not taken"
    );
    let traffic = line.traffic();
    assert_eq!(
        (traffic.commands_answered, traffic.commands_failed),
        (3, 1),
        "exchanges seen with and without an answer"
    );

    // A write to the tapped device over Modbus TCP: exception 01, nothing reaches the bus.
    let write = client
        .write_single_register(9001, 20)
        .await
        .expect("transport");
    assert_eq!(write, Err(ExceptionCode::IllegalFunction));

    // The line's frame monitor saw the eight frames, all received, none sent; the broken
    // answer is the one with a bad checksum.
    let monitor = line.monitor().expect("a frame monitor");
    let (frames, _) = monitor.frames_since(0);
    assert_eq!(frames.len(), 8);
    assert!(frames.iter().all(|f| f.direction == Direction::Rx));
    let bad: Vec<usize> = frames
        .iter()
        .enumerate()
        .filter(|(_, f)| monitor.describe(f).verdict == Verdict::BadChecksum)
        .map(|(i, _)| i)
        .collect();
    assert_eq!(bad, [7]);

    // The tap never wrote a byte to its port.
    let mut buf = [0u8; 64];
    let silent = tokio::time::timeout(Duration::from_millis(500), bus.read(&mut buf)).await;
    assert!(silent.is_err(), "the tap transmitted: {:?}", silent);
    assert_eq!(line.traffic().bytes_sent, 0);

    server_stop.cancel();
    let _ = server.await;
    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(5), line.join())
        .await
        .expect("the line stops");
    drop(line_end);
}
