//! A Modbus master line against a tiny Modbus RTU device on the other end of a real pty pair.
//!
//! The device is written here with proto-core's codec (RTU framing, PDU decode/encode): it serves
//! holding and input registers for one or more slave addresses on the same line, counts the reads,
//! can fall silent, and answers exception 04 for a write to a read-only register (as the Altivar
//! does for ETA, W3201). Real I/O timing is involved, so these tests run on the real clock.

use std::collections::{BTreeMap, HashSet};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use gateway::image::{ProcessImage, Quality, Table};
use gateway::line::{LineHandle, EVENT_PORT_LOST, EVENT_PORT_SETUP};
use gateway::protocols::{
    spawn_modbus_master_line, AddrRange, DeviceLimits, DeviceSettings, LineSettings, PollGroup,
};
use gateway::serial::{Interface, PortSettings, Rs485};
use gateway::unit::UnitService;
use proto_core::event::EventId;
use proto_core::modbus::pdu::{ExceptionCode, ExceptionResponse, Request, Response};
use proto_core::modbus::rtu::{decode_frame, encode_frame, expected_request_len, FrameLen};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_serial::{SerialPort, SerialStream};
use tokio_util::sync::CancellationToken;

// === the test device ===

/// One slave of the test device.
#[derive(Debug, Default)]
struct Slave {
    holding: Mutex<BTreeMap<u16, u16>>,
    input: Mutex<BTreeMap<u16, u16>>,
    read_only: HashSet<u16>,
    /// Reads received (answered or not).
    reads: AtomicU64,
    /// When set, the slave does not answer.
    silent: AtomicBool,
}

impl Slave {
    fn with_holding(values: &[(u16, u16)]) -> Self {
        let slave = Self::default();
        slave.holding.lock().unwrap().extend(values.iter().copied());
        slave
    }

    fn holding(&self, address: u16) -> Option<u16> {
        self.holding.lock().unwrap().get(&address).copied()
    }

    fn answer(&self, request: &Request) -> Result<Response, ExceptionCode> {
        let read = |table: &Mutex<BTreeMap<u16, u16>>, address: u16, quantity: u16| {
            let table = table.lock().unwrap();
            (address..address.saturating_add(quantity))
                .map(|a| table.get(&a).copied())
                .collect::<Option<Vec<u16>>>()
                .ok_or(ExceptionCode::IllegalDataAddress)
        };
        match *request {
            Request::ReadHoldingRegisters { address, quantity } => {
                self.reads.fetch_add(1, Ordering::Relaxed);
                read(&self.holding, address, quantity).map(Response::ReadHoldingRegisters)
            }
            Request::ReadInputRegisters { address, quantity } => {
                self.reads.fetch_add(1, Ordering::Relaxed);
                read(&self.input, address, quantity).map(Response::ReadInputRegisters)
            }
            Request::WriteSingleRegister { address, value } => {
                if self.read_only.contains(&address) {
                    return Err(ExceptionCode::ServerDeviceFailure);
                }
                self.holding.lock().unwrap().insert(address, value);
                Ok(Response::WriteSingleRegister { address, value })
            }
            Request::WriteMultipleRegisters {
                address,
                ref values,
            } => {
                let mut holding = self.holding.lock().unwrap();
                for (a, v) in (address..).zip(values) {
                    holding.insert(a, *v);
                }
                Ok(Response::WriteMultipleRegisters {
                    address,
                    quantity: values.len() as u16,
                })
            }
            _ => Err(ExceptionCode::IllegalFunction),
        }
    }
}

/// Serves `slaves` (address, slave) on `port` until the port fails.
async fn run_device(mut port: SerialStream, slaves: Vec<(u8, Arc<Slave>)>) {
    let mut buf: Vec<u8> = Vec::new();
    let mut chunk = [0u8; 256];
    loop {
        let n = match port.read(&mut chunk).await {
            Ok(0) | Err(_) => return,
            Ok(n) => n,
        };
        buf.extend_from_slice(&chunk[..n]);
        while let FrameLen::Complete(len) = expected_request_len(&buf) {
            let frame: Vec<u8> = buf.drain(..len).collect();
            let Ok(frame) = decode_frame(&frame) else {
                buf.clear(); // resync: a pty does not corrupt bytes, so this is not expected
                break;
            };
            let Some((_, slave)) = slaves.iter().find(|(a, _)| *a == frame.address) else {
                continue;
            };
            let Ok(request) = Request::decode(frame.pdu) else {
                continue;
            };
            let answer = slave.answer(&request);
            if slave.silent.load(Ordering::Relaxed) {
                continue;
            }
            let mut pdu = Vec::new();
            match answer {
                Ok(response) => response.encode(&mut pdu),
                Err(code) => ExceptionResponse::new(request.function(), code).encode(&mut pdu),
            }
            let mut out = Vec::new();
            encode_frame(frame.address, &pdu, &mut out);
            if port.write_all(&out).await.is_err() {
                return;
            }
        }
    }
}

// === helpers ===

const POLL: Duration = Duration::from_millis(50);

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

/// A pty pair: the device's end, the line's path, and the line end's first handle, kept open so
/// that the device's end does not see a hang-up before the line opens the path.
fn pty() -> (SerialStream, String, SerialStream) {
    let (device, line_end) = SerialStream::pair().expect("pty pair");
    let path = line_end.name().expect("pty path");
    (device, path, line_end)
}

fn line_settings(path: &str) -> LineSettings {
    let mut settings = LineSettings::rtu("drive", PortSettings::new(path, 19200));
    settings.master.reply_timeout = ms(100);
    settings.reopen_min = ms(50);
    settings.reopen_max = ms(200);
    settings
}

fn altivar(name: &str, slave: u8, ranges: Vec<AddrRange>) -> DeviceSettings {
    let mut device = DeviceSettings::new(name, slave, slave);
    device.limits = DeviceLimits::ALTIVAR;
    device.groups = vec![PollGroup {
        period: POLL,
        table: Table::HoldingRegisters,
        ranges,
    }];
    device.backoff_min = ms(1000);
    device.backoff_max = ms(4000);
    device
}

/// Waits up to 5 s for `check` to hold.
async fn eventually(what: &str, mut check: impl FnMut() -> bool) {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
    while !check() {
        assert!(
            tokio::time::Instant::now() < deadline,
            "timed out waiting for {what}"
        );
        tokio::time::sleep(ms(10)).await;
    }
}

fn event_count(line: &LineHandle, id: EventId) -> u64 {
    line.status().event_counts.get(&id).copied().unwrap_or(0)
}

/// The unit's answer given at once (`UnitService::answer_now`): the response PDU or exception.
fn answer_now(unit: &dyn UnitService, request: &Request) -> Option<Result<Vec<u8>, ExceptionCode>> {
    let mut out = Vec::new();
    let answer = unit.answer_now(request, &mut out)?;
    if answer.is_err() {
        assert!(out.is_empty(), "nothing appended with an exception");
    }
    Some(answer.map(|()| out))
}

/// A response PDU as the Modbus TCP server sends it.
fn encoded(response: &Response) -> Vec<u8> {
    let mut out = Vec::new();
    response.encode(&mut out);
    out
}

async fn stop(line: LineHandle, shutdown: CancellationToken) {
    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(5), line.join())
        .await
        .expect("line stops");
}

// === tests ===

#[tokio::test]
async fn the_line_polls_the_device_and_the_image_fills() {
    let (device_end, path, _keep) = pty();
    // W3102..W3105 = SFr, tFr, HSP, LSP as in the Altivar manual's FC03 example.
    let slave = Arc::new(Slave::with_holding(&[
        (3102, 40),
        (3103, 600),
        (3104, 500),
        (3105, 0),
        (3201, 0x0637),
    ]));
    tokio::spawn(run_device(device_end, vec![(2, slave.clone())]));

    let image = ProcessImage::default();
    let shutdown = CancellationToken::new();
    let ranges = vec![AddrRange::new(3102, 4), AddrRange::new(3201, 1)];
    let line = spawn_modbus_master_line(
        line_settings(&path),
        vec![altivar("atv", 2, ranges)],
        image.clone(),
        shutdown.clone(),
    );

    eventually("the image to fill", || {
        image
            .read_words(2, Table::HoldingRegisters, 3102, 4)
            .is_ok()
    })
    .await;
    let read = image
        .read_words(2, Table::HoldingRegisters, 3102, 4)
        .unwrap();
    assert_eq!(
        (read.values, read.quality),
        (vec![40, 600, 500, 0], Quality::Good)
    );
    eventually("ETA", || {
        image
            .read_words(2, Table::HoldingRegisters, 3201, 1)
            .is_ok_and(|r| r.values == [0x0637])
    })
    .await;
    // The unpolled gap between the two ranges was not read (no bridging by default).
    assert!(image
        .read_words(2, Table::HoldingRegisters, 3106, 1)
        .is_err());

    // Values keep coming: the poll count grows.
    let before = slave.reads.load(Ordering::Relaxed);
    eventually("more polls", || {
        slave.reads.load(Ordering::Relaxed) >= before + 4
    })
    .await;
    let status = line.status();
    assert!(status.port_open);
    assert_eq!(status.port_opens, 1);
    assert!(
        status.devices[0].online && status.devices[0].polls_ok >= 2,
        "{status:?}"
    );

    // Served from the image through the unit.
    let unit = line.device_unit("atv").unwrap();
    let answer = unit
        .call(Request::ReadHoldingRegisters {
            address: 3103,
            quantity: 2,
        })
        .await;
    assert_eq!(answer, Ok(Response::ReadHoldingRegisters(vec![600, 500])));
    // The same answer at once, encoded from the image; what is not a polled read takes `call`.
    let read = Request::ReadHoldingRegisters {
        address: 3103,
        quantity: 2,
    };
    assert_eq!(
        answer_now(&unit, &read),
        Some(Ok(encoded(&Response::ReadHoldingRegisters(vec![600, 500]))))
    );
    for request in [
        Request::ReadHoldingRegisters {
            address: 3105,
            quantity: 2,
        },
        Request::ReadInputRegisters {
            address: 3103,
            quantity: 2,
        },
        Request::WriteSingleRegister {
            address: 3103,
            value: 1,
        },
    ] {
        assert_eq!(answer_now(&unit, &request), None, "{request:?}");
    }
    stop(line, shutdown).await;
}

#[tokio::test]
async fn a_write_through_the_unit_lands_in_the_device_and_the_image() {
    let (device_end, path, _keep) = pty();
    let mut slave = Slave::with_holding(&[(9001, 30), (9002, 30), (3201, 0x0637)]);
    slave.read_only.insert(3201);
    let slave = Arc::new(slave);
    tokio::spawn(run_device(device_end, vec![(2, slave.clone())]));

    let image = ProcessImage::default();
    let shutdown = CancellationToken::new();
    let ranges = vec![AddrRange::new(9001, 2)];
    let line = spawn_modbus_master_line(
        line_settings(&path),
        vec![altivar("atv", 2, ranges)],
        image.clone(),
        shutdown.clone(),
    );
    let (unit_id, unit) = line.device_units().pop().unwrap();
    assert_eq!(unit_id, 2);
    eventually("the image to fill", || {
        image
            .read_words(2, Table::HoldingRegisters, 9001, 2)
            .is_ok()
    })
    .await;

    // FC06 ACC = 13 (the Altivar manual's example): the device's echo comes back.
    let answer = unit
        .call(Request::WriteSingleRegister {
            address: 9001,
            value: 13,
        })
        .await;
    assert_eq!(
        answer,
        Ok(Response::WriteSingleRegister {
            address: 9001,
            value: 13
        })
    );
    assert_eq!(slave.holding(9001), Some(13));
    // The image has it at once, without waiting for the next poll.
    assert_eq!(
        image
            .read_words(2, Table::HoldingRegisters, 9001, 1)
            .unwrap()
            .values,
        vec![13]
    );

    // FC16 ACC, DEC = 20, 30.
    let answer = unit
        .call(Request::WriteMultipleRegisters {
            address: 9001,
            values: vec![20, 30],
        })
        .await;
    assert_eq!(
        answer,
        Ok(Response::WriteMultipleRegisters {
            address: 9001,
            quantity: 2
        })
    );
    assert_eq!(
        (slave.holding(9001), slave.holding(9002)),
        (Some(20), Some(30))
    );

    // The device's exception is passed through: ETA is read-only (exception 04).
    let answer = unit
        .call(Request::WriteSingleRegister {
            address: 3201,
            value: 1,
        })
        .await;
    assert_eq!(answer, Err(ExceptionCode::ServerDeviceFailure));
    assert_eq!(slave.holding(3201), Some(0x0637));
    assert!(line.status().commands_answered >= 3);
    stop(line, shutdown).await;
}

#[tokio::test]
async fn an_unpolled_address_is_read_on_demand() {
    let (device_end, path, _keep) = pty();
    let slave = Arc::new(Slave::with_holding(&[(3201, 1), (8401, 3), (8402, 2)]));
    tokio::spawn(run_device(device_end, vec![(2, slave.clone())]));

    let image = ProcessImage::default();
    let shutdown = CancellationToken::new();
    let line = spawn_modbus_master_line(
        line_settings(&path),
        vec![altivar("atv", 2, vec![AddrRange::new(3201, 1)])],
        image.clone(),
        shutdown.clone(),
    );
    let unit = line.device_unit("atv").unwrap();
    // CHCF, COP (W8401, W8402): nobody polls them, the device answers.
    let answer = unit
        .call(Request::ReadHoldingRegisters {
            address: 8401,
            quantity: 2,
        })
        .await;
    assert_eq!(answer, Ok(Response::ReadHoldingRegisters(vec![3, 2])));
    assert!(
        image
            .read_words(2, Table::HoldingRegisters, 8401, 1)
            .is_err(),
        "on-demand values stay out of the image"
    );
    // An address the device does not have: its exception 02 passes through.
    let answer = unit
        .call(Request::ReadHoldingRegisters {
            address: 8400,
            quantity: 1,
        })
        .await;
    assert_eq!(answer, Err(ExceptionCode::IllegalDataAddress));
    stop(line, shutdown).await;
}

#[tokio::test]
async fn a_silent_device_goes_offline_answers_0x0b_and_the_other_keeps_its_rate() {
    let (device_end, path, _keep) = pty();
    let good = Arc::new(Slave::with_holding(&[(3201, 7)]));
    let flaky = Arc::new(Slave::with_holding(&[(3201, 9)]));
    tokio::spawn(run_device(
        device_end,
        vec![(2, good.clone()), (3, flaky.clone())],
    ));

    let image = ProcessImage::default();
    let shutdown = CancellationToken::new();
    let devices = vec![
        altivar("good", 2, vec![AddrRange::new(3201, 1)]),
        altivar("flaky", 3, vec![AddrRange::new(3201, 1)]),
    ];
    let line = spawn_modbus_master_line(
        line_settings(&path),
        devices,
        image.clone(),
        shutdown.clone(),
    );
    eventually("both devices in the image", || {
        image
            .read_words(2, Table::HoldingRegisters, 3201, 1)
            .is_ok()
            && image
                .read_words(3, Table::HoldingRegisters, 3201, 1)
                .is_ok()
    })
    .await;

    flaky.silent.store(true, Ordering::Relaxed);
    eventually("the flaky device offline", || {
        !line.status().devices[1].online
    })
    .await;
    let read = image
        .read_words(3, Table::HoldingRegisters, 3201, 1)
        .unwrap();
    assert_eq!(read.quality, Quality::CommFailure);
    assert!(
        event_count(&line, EventId::new(0x08, 0x30)) >= 1,
        "08 30h no reply counted"
    );
    assert_eq!(line.status().status_word, 0x0830);

    let flaky_unit = line.device_unit("flaky").unwrap();
    let answer = flaky_unit
        .call(Request::ReadHoldingRegisters {
            address: 3201,
            quantity: 1,
        })
        .await;
    assert_eq!(answer, Err(ExceptionCode::GatewayTargetFailedToRespond));
    let read = Request::ReadHoldingRegisters {
        address: 3201,
        quantity: 1,
    };
    assert_eq!(
        answer_now(&flaky_unit, &read),
        Some(Err(ExceptionCode::GatewayTargetFailedToRespond))
    );
    let answer = flaky_unit
        .call(Request::WriteSingleRegister {
            address: 3201,
            value: 1,
        })
        .await;
    assert_eq!(answer, Err(ExceptionCode::GatewayTargetFailedToRespond));
    let good_unit = line.device_unit("good").unwrap();
    assert_eq!(
        good_unit
            .call(Request::ReadHoldingRegisters {
                address: 3201,
                quantity: 1
            })
            .await,
        Ok(Response::ReadHoldingRegisters(vec![7]))
    );
    assert_eq!(
        answer_now(&good_unit, &read),
        Some(Ok(encoded(&Response::ReadHoldingRegisters(vec![7]))))
    );

    // Over 2 s at a 50 ms period the good device is polled about 40 times. The silent one costs a
    // 100 ms reply timeout per probe, one probe per 1..4 s back-off: without the back-off the good
    // device would get about 13 polls (one per 150 ms).
    let before = good.reads.load(Ordering::Relaxed);
    let probes_before = flaky.reads.load(Ordering::Relaxed);
    tokio::time::sleep(Duration::from_secs(2)).await;
    let polls = good.reads.load(Ordering::Relaxed) - before;
    assert!(polls >= 28, "the good device got only {polls} polls in 2 s");
    let probes = flaky.reads.load(Ordering::Relaxed) - probes_before;
    assert!(
        probes <= 3,
        "the silent device was asked {probes} times in 2 s"
    );

    // It answers again: back online after its next probe, values good again.
    flaky.silent.store(false, Ordering::Relaxed);
    eventually("the flaky device back", || line.status().devices[1].online).await;
    eventually("its value good again", || {
        image
            .read_words(3, Table::HoldingRegisters, 3201, 1)
            .is_ok_and(|r| r.quality == Quality::Good)
    })
    .await;
    stop(line, shutdown).await;
}

#[tokio::test]
async fn a_full_queue_answers_0x06_and_no_answer_0x0b() {
    let (device_end, path, _keep) = pty();
    // Nobody answers slave 9 on this line.
    tokio::spawn(run_device(device_end, vec![]));
    let image = ProcessImage::default();
    let shutdown = CancellationToken::new();
    let mut settings = line_settings(&path);
    settings.queue_depth = 2;
    settings.master.reply_timeout = ms(300);
    let ghost = DeviceSettings::new("ghost", 9, 9);
    let line = spawn_modbus_master_line(settings, vec![ghost], image, shutdown.clone());
    let client = line.client().expect("a master line");
    let unit = line.device_unit("ghost").unwrap();

    let request = Request::ReadHoldingRegisters {
        address: 0,
        quantity: 1,
    };
    let first = client.try_submit(9, request.clone()).unwrap();
    let second = client.try_submit(9, request.clone()).unwrap();
    // Both places taken (one in flight, one waiting): the next is refused at once.
    assert_eq!(
        unit.call(request.clone()).await,
        Err(ExceptionCode::ServerDeviceBusy)
    );

    // Each times out (08 30h) for its own client: a command without an answer does not put the
    // device offline, so the second is sent too.
    let no_reply = Err(gateway::protocols::CommandError::NoReply {
        slave: 9,
        event: EventId::new(0x08, 0x30),
    });
    assert_eq!(first.await.unwrap(), no_reply);
    assert_eq!(second.await.unwrap(), no_reply);
    assert!(line.status().devices[0].online);
    assert_eq!(line.status().devices[0].commands_failed, 2);
    // Places free again; a device that does not answer gives 0x0B.
    assert_eq!(
        unit.call(request).await,
        Err(ExceptionCode::GatewayTargetFailedToRespond)
    );
    stop(line, shutdown).await;
}

#[tokio::test]
async fn a_vanished_port_raises_events_and_is_reopened_with_back_off() {
    let (device_end, path, keep) = pty();
    let slave = Arc::new(Slave::with_holding(&[(3201, 5)]));
    let device = tokio::spawn(run_device(device_end, vec![(2, slave.clone())]));
    let image = ProcessImage::default();
    let shutdown = CancellationToken::new();
    let line = spawn_modbus_master_line(
        line_settings(&path),
        vec![altivar("atv", 2, vec![AddrRange::new(3201, 1)])],
        image.clone(),
        shutdown.clone(),
    );
    eventually("the image to fill", || {
        image
            .read_words(2, Table::HoldingRegisters, 3201, 1)
            .is_ok()
    })
    .await;

    // The device's end goes away: the pty is gone, the line loses its port.
    device.abort();
    let _ = device.await;
    drop(keep);
    eventually("the port lost", || event_count(&line, EVENT_PORT_LOST) >= 1).await;
    eventually("values marked", || {
        image
            .read_words(2, Table::HoldingRegisters, 3201, 1)
            .is_ok_and(|r| r.quality == Quality::CommFailure)
    })
    .await;
    // Each reopen attempt that fails raises 02 0Fh with the reason.
    eventually("two failed reopen attempts", || {
        event_count(&line, EVENT_PORT_SETUP) >= 2
    })
    .await;
    let status = line.status();
    assert!(!status.port_open);
    assert!(
        status
            .port_error
            .as_deref()
            .is_some_and(|e| e.contains(&path)),
        "{status:?}"
    );
    // Commands meanwhile are answered at once.
    let unit = line.device_unit("atv").unwrap();
    assert_eq!(
        unit.call(Request::WriteSingleRegister {
            address: 3201,
            value: 1
        })
        .await,
        Err(ExceptionCode::GatewayTargetFailedToRespond)
    );
    stop(line, shutdown).await;
}

#[tokio::test]
async fn rs485_on_a_pty_is_reported_as_an_event_with_the_reason() {
    let (_device_end, path, _keep) = pty();
    let mut settings = line_settings(&path);
    settings.port.interface = Interface::Rs485(Rs485::default());
    let shutdown = CancellationToken::new();
    let line =
        spawn_modbus_master_line(settings, vec![], ProcessImage::default(), shutdown.clone());
    eventually("the refusal", || event_count(&line, EVENT_PORT_SETUP) >= 1).await;
    let status = line.status();
    let error = status.port_error.clone().unwrap();
    assert!(
        error.starts_with(&format!("port {path} refused RS485 mode: ")),
        "{error}"
    );
    assert!(
        error.ends_with("(a pseudo-terminal has no RS485 driver)"),
        "{error}"
    );
    assert_eq!(status.status_word, 0x020F);
    stop(line, shutdown).await;
}

#[tokio::test]
async fn a_reply_full_of_ff_bytes_is_decoded_as_it_was_sent() {
    // The device writes plain bytes. The line's end of the pty was opened with PARMRK, so the
    // kernel's line discipline doubles every FF it delivers to the line, exactly as it does for
    // bytes from a UART (termios(3)); the line must undo the doubling before the frame is checked,
    // or the reply is too long and fails its CRC.
    let (device_end, path, _keep) = pty();
    let slave = Arc::new(Slave::with_holding(&[
        (3102, 0xFFFF),
        (3103, 0xFFFF),
        (3104, 0xFF00),
        (3105, 0x00FF),
    ]));
    tokio::spawn(run_device(device_end, vec![(2, slave.clone())]));

    let image = ProcessImage::default();
    let shutdown = CancellationToken::new();
    let line = spawn_modbus_master_line(
        line_settings(&path),
        vec![altivar("atv", 2, vec![AddrRange::new(3102, 4)])],
        image.clone(),
        shutdown.clone(),
    );
    eventually("the image to fill", || {
        image
            .read_words(2, Table::HoldingRegisters, 3102, 4)
            .is_ok()
    })
    .await;
    let read = image
        .read_words(2, Table::HoldingRegisters, 3102, 4)
        .unwrap();
    assert_eq!(read.values, vec![0xFFFF, 0xFFFF, 0xFF00, 0x00FF]);
    let before = slave.reads.load(Ordering::Relaxed);
    eventually("more polls", || {
        slave.reads.load(Ordering::Relaxed) >= before + 3
    })
    .await;
    let status = line.status();
    assert!(status.devices[0].polls_ok >= 3, "{status:?}");
    assert_eq!(status.devices[0].polls_failed, 0, "{status:?}");
    // Only the start-up event: no CRC error, no length error, no line error.
    let ids: Vec<_> = status.event_counts.keys().copied().collect();
    assert_eq!(
        ids,
        vec![proto_core::event::ids::PTP_PARAMS_ACCEPTED],
        "{status:?}"
    );
    stop(line, shutdown).await;
}
