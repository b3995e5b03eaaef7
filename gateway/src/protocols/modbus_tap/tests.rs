//! The tap line on an in-process stream: what its units answer, and a device whose requests go
//! unanswered going offline.

use std::sync::Mutex;

use proto_core::modbus::rtu::encode_frame;
use tokio::io::AsyncWriteExt;

use super::*;
use crate::line::testing::{eventually, OnePort};

fn frame(address: u8, pdu: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    encode_frame(address, pdu, &mut out);
    out
}

fn answer_now(unit: &dyn UnitService, request: &Request) -> Result<Vec<u8>, ExceptionCode> {
    let mut out = Vec::new();
    match unit.answer_now(request, &mut out) {
        Some(Ok(())) => Ok(out),
        Some(Err(code)) => Err(code),
        None => panic!("a tap unit always answers at once"),
    }
}

#[tokio::test]
async fn units_answer_what_the_bus_showed_refuse_writes_and_go_offline_without_answers() {
    let (port, mut bus) = tokio::io::duplex(1024);
    // 19200 Bd: t3.5 = 2 ms (003 6.4.3); an answer 20 ms after its request, within the answer
    // timeout of 200 ms; a request without answer is followed by 300 ms of silence.
    let mut settings = TapLineSettings::new("tap", PortSettings::new("/dev/in-process", 19_200));
    settings.tap.answer_timeout = Duration::from_millis(200);
    let mut device = DeviceSettings::new("ks", 17, 17);
    device.offline_after = 2;
    let image = ProcessImage::default();
    let shutdown = CancellationToken::new();
    let line = spawn_on(
        settings,
        vec![device],
        image.clone(),
        shutdown.clone(),
        OnePort(Mutex::new(Some(port))),
    );
    let units = line.units();
    let unit = &units.first().expect("one unit").1;
    assert!(unit.listen_only());
    let read = Request::ReadInputRegisters {
        address: 1004,
        quantity: 3,
    };
    // Nothing seen yet: 0x0B; a write: 01, whatever the bus showed.
    assert_eq!(
        answer_now(&**unit, &read),
        Err(ExceptionCode::GatewayTargetFailedToRespond)
    );
    let write = Request::WriteSingleRegister {
        address: 1,
        value: 2,
    };
    assert_eq!(
        answer_now(&**unit, &write),
        Err(ExceptionCode::IllegalFunction)
    );
    assert_eq!(unit.call(write).await, Err(ExceptionCode::IllegalFunction));

    // The KS vario's inputs 1004..1006 = 1066 140 4158, read by the other master.
    let step = Duration::from_millis(20);
    for f in [
        frame(17, &[0x04, 0x03, 0xEC, 0x00, 0x03]),
        frame(17, &[0x04, 0x06, 0x04, 0x2A, 0x00, 0x8C, 0x10, 0x3E]),
    ] {
        bus.write_all(&f).await.expect("write");
        tokio::time::sleep(step).await;
    }
    eventually("the values served", || answer_now(&**unit, &read).is_ok()).await;
    assert_eq!(
        unit.call(read.clone()).await,
        Ok(Response::ReadInputRegisters(vec![1066, 140, 4158]))
    );

    // Two requests in a row without an answer (offline_after = 2): offline, values comm failure.
    for _ in 0..2 {
        bus.write_all(&frame(17, &[0x04, 0x03, 0xEC, 0x00, 0x03]))
            .await
            .expect("write");
        tokio::time::sleep(Duration::from_millis(300)).await;
    }
    eventually("the device offline", || {
        line.status().devices.first().is_some_and(|d| !d.online)
    })
    .await;
    assert_eq!(
        answer_now(&**unit, &read),
        Err(ExceptionCode::GatewayTargetFailedToRespond)
    );
    let status = line.status();
    assert_eq!(
        status.event_counts.get(&ids::MODBUS_NO_REPLY),
        Some(&1),
        "08 30h once, when it went offline"
    );
    let device = status.devices.first().expect("device");
    assert_eq!((device.polls_ok, device.polls_failed), (1, 2));

    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(2), line.join())
        .await
        .expect("the line stops");
}
