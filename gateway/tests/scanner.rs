//! The Altivar communication scanner end to end on a real pty pair against the gateway's own
//! Altivar simulator: the line reads the output words once with FC 03, then exchanges FC 23 each
//! cycle (NC1..NC2 written, NM1..NM2 read, 002 "Kommunikationsscanner"); the input words reach
//! the image and the Modbus TCP unit, a Modbus TCP write of an output word reaches the drive and
//! stays in the following exchanges, and CMD is never written as zero.

use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use gateway::image::{ProcessImage, Quality, Table};
use gateway::protocols::{
    spawn_modbus_master_line, DeviceLimits, DeviceSettings, LineSettings, ScannerSettings,
};
use gateway::serial::PortSettings;
use gateway::sim::altivar::AltivarSim;
use gateway::sim::{serve_modbus, Faults, ModbusDevice};
use gateway::unit::UnitService;
use proto_core::modbus::pdu::{Request, Response};
use proto_core::modbus::rtu::{decode_frame, CharTiming};
use proto_core::profiles::altivar::{self as profile};
use tokio_serial::{SerialPort, SerialStream};
use tokio_util::sync::CancellationToken;

const BAUD: u32 = 19_200;
const CYCLE: Duration = Duration::from_millis(50);

/// The drive, and every request it received, decoded.
struct Recorder {
    drive: Arc<Mutex<AltivarSim>>,
    seen: Arc<Mutex<Vec<Request>>>,
}

impl ModbusDevice for Recorder {
    fn handle_frame(&mut self, adu: &[u8]) -> Option<Vec<u8>> {
        if let Some(request) = decode_frame(adu)
            .ok()
            .and_then(|f| Request::decode(f.pdu).ok())
        {
            self.seen
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .push(request);
        }
        self.drive.handle_frame(adu)
    }

    fn tick(&mut self, elapsed: Duration) {
        self.drive.tick(elapsed);
    }

    fn faults(&self) -> Faults {
        self.drive.faults()
    }
}

/// The FC 23 requests seen so far.
fn exchanges(seen: &Mutex<Vec<Request>>) -> Vec<Request> {
    seen.lock()
        .unwrap_or_else(PoisonError::into_inner)
        .iter()
        .filter(|r| matches!(r, Request::ReadWriteMultipleRegisters { .. }))
        .cloned()
        .collect()
}

/// Waits up to 5 s for `check` to hold.
async fn eventually(what: &str, mut check: impl FnMut() -> bool) {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
    while !check() {
        assert!(
            tokio::time::Instant::now() < deadline,
            "timed out waiting for {what}"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_scanner_exchanges_fc23_each_cycle_without_zeroing_cmd() {
    // The drive is already commanded when the gateway starts: CMD = 0006h, LFRD = 1500; the
    // scanner's factory assignment (NC1 = CMD, NC2 = LFRD, NM1 = ETA, NM2 = RFRD).
    let mut sim = AltivarSim::new(2);
    sim.set_dynamics(false);
    assert!(sim.set_word(profile::CMD, 0x0006));
    assert!(sim.set_word(profile::LFRD, 1500));
    assert!(sim.set_word(profile::ETA, 0x0231));
    assert!(sim.set_word(profile::RFRD, 1490));
    let drive = Arc::new(Mutex::new(sim));
    let seen = Arc::new(Mutex::new(Vec::new()));

    let (device_end, line_end) = SerialStream::pair().expect("pty pair");
    let path = line_end.name().expect("pty path");
    let shutdown = CancellationToken::new();
    tokio::spawn(serve_modbus(
        device_end,
        Recorder {
            drive: Arc::clone(&drive),
            seen: Arc::clone(&seen),
        },
        CharTiming::new(BAUD, 11),
        shutdown.clone(),
    ));
    let mut settings = LineSettings::rtu("drive", PortSettings::new(&path, BAUD));
    settings.master.reply_timeout = Duration::from_millis(200);
    let mut atv = DeviceSettings::new("atv", 2, 2);
    atv.limits = DeviceLimits::ALTIVAR;
    atv.backoff_min = Duration::from_millis(100);
    atv.backoff_max = Duration::from_millis(200);
    atv.scanner = Some(ScannerSettings {
        inputs: 2,
        outputs: 2,
        period: CYCLE,
    });
    // The settings' own check (DeviceSettings::validate is gone: the config checks a device).
    let scanner_issues = atv.scanner.map(|s| s.validate("atv")).unwrap_or_default();
    assert!(scanner_issues.is_empty(), "{scanner_issues:?}");
    let image = ProcessImage::default();
    let line = spawn_modbus_master_line(settings, vec![atv], image.clone(), shutdown.clone());

    // Several cycles, one FC 23 each.
    eventually("five exchanges", || exchanges(&seen).len() >= 5).await;
    drop(line_end);

    // The first request read the output words; the exchanges wrote back what the drive held.
    let first = seen
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .first()
        .cloned();
    assert_eq!(
        first,
        Some(Request::ReadHoldingRegisters {
            address: profile::NC[0],
            quantity: 2
        })
    );
    for request in exchanges(&seen) {
        assert_eq!(
            request,
            Request::ReadWriteMultipleRegisters {
                read_address: profile::NM[0],
                read_quantity: 2,
                write_address: profile::NC[0],
                values: vec![0x0006, 1500],
            }
        );
    }
    // Only the scanner talks to the drive: no separate reads or writes.
    let others = seen
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .iter()
        .skip(1)
        .filter(|r| !matches!(r, Request::ReadWriteMultipleRegisters { .. }))
        .count();
    assert_eq!(others, 0);

    // The input words are in the image, good, and served by the Modbus TCP unit from it.
    let read = image
        .read_words(2, Table::HoldingRegisters, profile::NM[0], 2)
        .expect("NM1..NM2 in the image");
    assert_eq!(
        (read.values, read.quality),
        (vec![0x0231, 1490], Quality::Good)
    );
    let unit = line.device_unit("atv").expect("unit");
    let request = Request::ReadHoldingRegisters {
        address: profile::NM[0],
        quantity: 2,
    };
    let mut out = Vec::new();
    assert_eq!(unit.answer_now(&request, &mut out), Some(Ok(())));
    let mut expected = Vec::new();
    Response::ReadHoldingRegisters(vec![0x0231, 1490]).encode(&mut expected);
    assert_eq!(out, expected);
    assert!(line.status().devices[0].polls_ok >= 5);

    // A Modbus TCP write of NC1 (CMD = 000Fh, enable operation) reaches the drive and the
    // following exchanges carry it.
    let answer = unit
        .call(Request::WriteSingleRegister {
            address: profile::NC[0],
            value: 0x000F,
        })
        .await;
    assert_eq!(
        answer,
        Ok(Response::WriteSingleRegister {
            address: profile::NC[0],
            value: 0x000F,
        })
    );
    let cmd = || {
        drive
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .word(profile::CMD)
    };
    assert_eq!(cmd(), Some(0x000F));
    let before = exchanges(&seen).len();
    eventually("two more exchanges", || {
        exchanges(&seen).len() >= before + 2
    })
    .await;
    assert!(matches!(
        exchanges(&seen).last(),
        Some(Request::ReadWriteMultipleRegisters { values, .. }) if values == &vec![0x000F, 1500]
    ));
    assert_eq!(cmd(), Some(0x000F));

    // The drive stops answering: the device goes offline, its words turn comm failure. Meanwhile
    // CMD is changed at the drive (0007h); when it answers again the output words are read
    // first, and the exchanges carry the drive's CMD, not the gateway's old one.
    let mark = seen.lock().unwrap_or_else(PoisonError::into_inner).len();
    let set_faults = |faults| {
        drive
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .set_faults(faults)
    };
    set_faults(Faults {
        silent: true,
        ..Faults::default()
    });
    eventually("the drive offline", || !line.status().devices[0].online).await;
    assert_eq!(
        image
            .read_words(2, Table::HoldingRegisters, profile::NM[0], 2)
            .map(|r| r.quality),
        Ok(Quality::CommFailure)
    );
    assert!(drive
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .set_word(profile::CMD, 0x0007));
    set_faults(Faults::default());
    eventually("the drive back with its CMD exchanged", || {
        line.status().devices[0].online
            && matches!(
                exchanges(&seen).last(),
                Some(Request::ReadWriteMultipleRegisters { values, .. })
                    if values == &vec![0x0007, 1500]
            )
    })
    .await;
    let after: Vec<Request> = seen
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .get(mark..)
        .unwrap_or_default()
        .to_vec();
    let prime = Request::ReadHoldingRegisters {
        address: profile::NC[0],
        quantity: 2,
    };
    let primed_at = after
        .iter()
        .position(|r| r == &prime)
        .expect("primed again");
    for request in after.get(primed_at..).unwrap_or_default() {
        if let Request::ReadWriteMultipleRegisters { values, .. } = request {
            assert_eq!(values, &vec![0x0007, 1500]);
        }
    }
    assert_eq!(cmd(), Some(0x0007));

    // Never a zero written to CMD.
    for request in seen.lock().unwrap_or_else(PoisonError::into_inner).iter() {
        if let Request::ReadWriteMultipleRegisters { values, .. } = request {
            assert_ne!(values.first(), Some(&0), "{request:?}");
        }
    }
    shutdown.cancel();
    line.join().await;
}
