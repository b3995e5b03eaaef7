//! One dead drive among four on a Modbus master line with the CP's default reply monitoring time
//! of 2 s (003 6.4.2.1), on a real pty pair against the gateway's own Altivar simulators
//! (`gateway::sim`): the others keep their poll rate while it is offline, it is polled again soon
//! after it answers, and when it comes back slower than a short probe waits, its late reply is
//! counted and the next probe, waiting the full time, finds it. Real I/O timing is involved, so
//! these tests run on the real clock, with wide margins.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use gateway::image::{ProcessImage, Quality, Table};
use gateway::line::LineHandle;
use gateway::protocols::{
    spawn_modbus_master_line, AddrRange, DeviceLimits, DeviceSettings, LineSettings, PollGroup,
};
use gateway::serial::PortSettings;
use gateway::sim::altivar::AltivarSim;
use gateway::sim::{serve_modbus, Faults, ModbusDevice};
use proto_core::event::{ids, EventId};
use proto_core::modbus::rtu::CharTiming;
use tokio_serial::{SerialPort, SerialStream};
use tokio_util::sync::CancellationToken;

const BAUD: u32 = 19_200;
const POLL: Duration = Duration::from_millis(100);
/// The drives' slave addresses; the last one dies.
const SLAVES: [u8; 4] = [2, 3, 4, 5];
const DEAD: usize = 3;

/// Several drives on one line; the runner delays an answer by the faults of the drive that gave
/// it.
struct Bus {
    drives: Vec<Arc<Mutex<AltivarSim>>>,
    last: Faults,
}

impl ModbusDevice for Bus {
    fn handle_frame(&mut self, adu: &[u8]) -> Option<Vec<u8>> {
        for drive in &mut self.drives {
            if let Some(answer) = drive.handle_frame(adu) {
                self.last = drive.faults();
                return Some(answer);
            }
        }
        None
    }

    fn tick(&mut self, elapsed: Duration) {
        for drive in &mut self.drives {
            drive.tick(elapsed);
        }
    }

    fn faults(&self) -> Faults {
        self.last
    }
}

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

/// W3102..W3105 (SFr, tFr, HSP, LSP, 002's FC03 example) every 100 ms; offline after the first
/// failed poll (these tests are about what follows), back-off 200 ms to 1 s, the default probes.
fn drive(slave: u8) -> DeviceSettings {
    let mut d = DeviceSettings::new(format!("atv{slave}"), slave, slave);
    d.limits = DeviceLimits::ALTIVAR;
    d.groups = vec![PollGroup {
        period: POLL,
        table: Table::HoldingRegisters,
        ranges: vec![AddrRange::new(3102, 4)],
    }];
    d.backoff_min = ms(200);
    d.backoff_max = ms(1000);
    d.offline_after = 1;
    d
}

/// Waits up to `limit` for `check`; how long it took.
async fn within(what: &str, limit: Duration, mut check: impl FnMut() -> bool) -> Duration {
    let start = Instant::now();
    while !check() {
        assert!(start.elapsed() < limit, "timed out waiting for {what}");
        tokio::time::sleep(ms(5)).await;
    }
    start.elapsed()
}

fn online(line: &LineHandle, i: usize) -> bool {
    line.status().devices[i].online
}

fn polls_ok(line: &LineHandle, which: std::ops::Range<usize>) -> u64 {
    line.status().devices[which]
        .iter()
        .map(|d| d.polls_ok)
        .sum()
}

fn events(line: &LineHandle, id: EventId) -> u64 {
    line.status().event_counts.get(&id).copied().unwrap_or(0)
}

fn set_faults(drive: &Mutex<AltivarSim>, faults: Faults) {
    drive.lock().unwrap().set_faults(faults);
}

/// The drive stops answering.
fn silence(drive: &Mutex<AltivarSim>) {
    set_faults(
        drive,
        Faults {
            silent: true,
            ..Faults::default()
        },
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_dead_drive_does_not_starve_the_others_and_is_found_again() {
    let (device_end, line_end) = SerialStream::pair().expect("pty pair");
    let path = line_end.name().expect("pty path");
    let shutdown = CancellationToken::new();
    let drives: Vec<Arc<Mutex<AltivarSim>>> = SLAVES
        .iter()
        .map(|&a| Arc::new(Mutex::new(AltivarSim::new(a))))
        .collect();
    let bus = Bus {
        drives: drives.clone(),
        last: Faults::default(),
    };
    tokio::spawn(serve_modbus(
        device_end,
        bus,
        CharTiming::new(BAUD, 11),
        shutdown.clone(),
    ));
    // The CP's default reply monitoring time: 2000 ms (003 6.4.2.1).
    let settings = LineSettings::rtu("drives", PortSettings::new(&path, BAUD));
    assert_eq!(settings.master.reply_timeout, ms(2000));
    let image = ProcessImage::default();
    let line = spawn_modbus_master_line(
        settings,
        SLAVES.iter().map(|&a| drive(a)).collect(),
        image.clone(),
        shutdown.clone(),
    );
    within("every drive in the image", Duration::from_secs(5), || {
        SLAVES.iter().all(|&a| {
            image
                .read_words(a, Table::HoldingRegisters, 3102, 4)
                .is_ok_and(|r| r.quality == Quality::Good)
        })
    })
    .await;

    // The last drive dies: one poll waits the whole 2 s (08 30h), then it is offline.
    silence(&drives[DEAD]);
    within("the dead drive offline", Duration::from_secs(5), || {
        !online(&line, DEAD)
    })
    .await;
    assert_eq!(
        image
            .read_words(SLAVES[DEAD], Table::HoldingRegisters, 3102, 4)
            .map(|r| r.quality),
        Ok(Quality::CommFailure)
    );

    // Over 4 s the three others are due 120 polls. A probe waiting the full 2 s would leave them
    // about a third of that and allow at most two probes; the short probes (100 ms, one attempt)
    // come every 200 ms to 1 s.
    let others = 0..DEAD;
    let failed = |line: &LineHandle| line.status().devices[DEAD].polls_failed;
    let (p0, f0, e0) = (
        polls_ok(&line, others.clone()),
        failed(&line),
        events(&line, ids::MODBUS_NO_REPLY),
    );
    tokio::time::sleep(Duration::from_secs(4)).await;
    let polls = polls_ok(&line, others.clone()) - p0;
    let probes = failed(&line) - f0;
    assert!(polls >= 90, "the others got {polls} of 120 polls in 4 s");
    assert!(
        (3..=12).contains(&probes),
        "{probes} probes of the dead drive in 4 s"
    );
    // Each probe that got no answer is one 08 30h (003 7.2), no repetition (the counters are
    // read one after the other while the line runs: one probe may fall between).
    let no_reply = events(&line, ids::MODBUS_NO_REPLY) - e0;
    assert!(
        (probes..=probes + 1).contains(&no_reply),
        "{no_reply} events 08 30h for {probes} probes"
    );

    // It answers again: polled again within the 1 s back-off and a probe.
    set_faults(&drives[DEAD], Faults::default());
    let took = within("the drive back online", Duration::from_secs(5), || {
        online(&line, DEAD)
    })
    .await;
    assert!(took <= ms(2500), "back online only after {took:?}");
    within("its values good again", Duration::from_secs(2), || {
        image
            .read_words(SLAVES[DEAD], Table::HoldingRegisters, 3102, 4)
            .is_ok_and(|r| r.quality == Quality::Good)
    })
    .await;

    // It dies again and comes back slower than a short probe waits (400 ms after its t3.5,
    // within the 2 s). Its late reply to a short probe is counted (0E 53h while the line is
    // idle, or the event of the exchange it ran into), and the next probe waits the full time.
    silence(&drives[DEAD]);
    within(
        "the dead drive offline again",
        Duration::from_secs(5),
        || !online(&line, DEAD),
    )
    .await;
    // Any event but 08 30h and the start-up class: 0E 53h, or 08 31h, 0E 57h ... of a collision.
    let late_events = |line: &LineHandle| {
        line.status()
            .event_counts
            .iter()
            .filter(|(id, _)| id.class != 0 && **id != ids::MODBUS_NO_REPLY)
            .map(|(_, n)| n)
            .sum::<u64>()
    };
    let l0 = late_events(&line);
    set_faults(
        &drives[DEAD],
        Faults {
            delay: ms(400),
            ..Faults::default()
        },
    );
    let took = within(
        "the slow drive back online",
        Duration::from_secs(10),
        || online(&line, DEAD),
    )
    .await;
    assert!(took <= ms(6000), "the slow drive back only after {took:?}");
    assert!(late_events(&line) > l0, "its late reply was not counted");
    // The others still answer.
    let p1 = polls_ok(&line, others.clone());
    within("the others polled on", Duration::from_secs(3), || {
        polls_ok(&line, others.clone()) >= p1 + 10
    })
    .await;

    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(5), line.join())
        .await
        .expect("line stops");
}
