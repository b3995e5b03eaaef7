//! The transparent-forwarding rows: a forwarded unit hammered by a client does not take the bus
//! from the polls of a declared device on the same line.
//!
//! Two flat devices on one paced 19200 Bd link, a multi-drop bus: the declared device at address 1
//! (holding registers 0..3 polled every 100 ms, served as unit 1) and a device at address 2 that no
//! device block declares, reached through `transparent` (unit 2 forwarded to address 2). A cached
//! reader reads unit 1 from the image every 10 ms throughout. The line runs a quiet window, then a
//! window in which two clients hammer unit 2 in closed loops (FC 03 and FC 06 of one register, as
//! the closed-loop rows' clients do), each request going to the device on demand. The rows give the
//! declared device's poll rate in both windows (answered polls per second, from the line's status),
//! the ratio of the two, the cached reads answered while the hammering ran, and the longest
//! achieved poll cycle against the bound of the line's fairness rule.
//!
//! The rate holds while the commands allowed before a due poll (`commands_in_row`, 2) fit in its
//! period beside it; a command that holds the bus longer (an FC 03 of 125 registers is 146 ms on
//! the wire at 19200 Bd) stretches the cycle towards the bound, which the last row checks.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use gateway::protocols::TransparentSettings;
use gateway::sim::bus::Bus;
use gateway::sim::ModbusDevice;
use tokio_util::sync::CancellationToken;

use crate::device::FlatDevice;
use crate::mbap::Client;
use crate::poll::{polled, polls_ok, rig_with, trouble};
use crate::report::{Row, Target};
use crate::stats::ms;
use crate::tcp::serve_gateway;
use crate::Plan;

/// The declared device's slave address and unit id.
const DECLARED: u8 = 1;
/// The forwarded device's slave address and unit id.
const FORWARDED: u8 = 2;
/// The baud rate of the line.
const BAUD: u32 = 19_200;
/// The poll period of the declared device.
const PERIOD: Duration = Duration::from_millis(100);
/// The registers its group polls (0..COUNT).
const COUNT: u16 = 4;
/// The pause of the cached reader between reads.
const CACHED_PAUSE: Duration = Duration::from_millis(10);

/// What one window saw.
struct Window {
    /// Answered polls of the declared device per second.
    poll_rate: f64,
    cached_reads: u64,
    cached_failed: u64,
}

/// Reads unit 1 from the image every [`CACHED_PAUSE`] for `window`, counting the polls the line
/// answered meanwhile.
async fn measure(
    cached: &mut Client,
    line: &gateway::line::LineHandle,
    window: Duration,
) -> std::io::Result<Window> {
    let polls_before = polls_ok(line, 0..1);
    let start = tokio::time::Instant::now();
    let (mut cached_reads, mut cached_failed) = (0u64, 0u64);
    while start.elapsed() < window {
        cached_reads += 1;
        match cached.read_one(DECLARED, 0).await {
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::Other => cached_failed += 1,
            Err(e) => return Err(e),
        }
        tokio::time::sleep(CACHED_PAUSE).await;
    }
    let polls = polls_ok(line, 0..1).saturating_sub(polls_before);
    Ok(Window {
        poll_rate: polls as f64 / start.elapsed().as_secs_f64(),
        cached_reads,
        cached_failed,
    })
}

/// Runs the quiet and the hammered window, each `plan.closed_window` long, and returns the rows.
pub(crate) async fn transparent(plan: &Plan) -> std::io::Result<Vec<Row>> {
    let devices: Vec<Box<dyn ModbusDevice>> = vec![
        Box::new(FlatDevice::new(DECLARED)),
        Box::new(FlatDevice::new(FORWARDED)),
    ];
    let rig = rig_with(
        BAUD,
        Bus::new(devices),
        vec![polled("d1", DECLARED, COUNT, PERIOD)],
        Some(Duration::from_millis(300)),
        |line| line.transparent = Some(TransparentSettings::new(FORWARDED..=FORWARDED)),
    )
    .await?;
    let shutdown = CancellationToken::new();
    let _stop_server = shutdown.clone().drop_guard();
    let addr = serve_gateway(&rig.line, shutdown).await?;

    let mut cached = Client::connect(addr).await?;
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    while cached.read_one(DECLARED, 0).await.is_err() {
        if tokio::time::Instant::now() > deadline {
            return Err(std::io::Error::other(format!(
                "the declared device was never polled{}",
                trouble(&rig.line)
            )));
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let quiet = measure(&mut cached, &rig.line, plan.closed_window).await?;

    let stop = Arc::new(AtomicBool::new(false));
    let answered = Arc::new(AtomicU64::new(0));
    let failed = Arc::new(AtomicU64::new(0));
    let mut hammers = Vec::new();
    for write in [false, true] {
        let mut client = Client::connect(addr).await?;
        let (stop, answered, failed) = (
            Arc::clone(&stop),
            Arc::clone(&answered),
            Arc::clone(&failed),
        );
        hammers.push(tokio::spawn(async move {
            let mut value = 0u16;
            while !stop.load(Ordering::Relaxed) {
                value = value.wrapping_add(1);
                let result = if write {
                    client.write_one(FORWARDED, 100, value).await
                } else {
                    client.read_one(FORWARDED, 1000).await.map(|_| ())
                };
                match result {
                    Ok(()) => answered.fetch_add(1, Ordering::Relaxed),
                    Err(e) if e.kind() == std::io::ErrorKind::Other => {
                        failed.fetch_add(1, Ordering::Relaxed)
                    }
                    Err(_) => break,
                };
            }
        }));
    }
    let hammered = measure(&mut cached, &rig.line, plan.closed_window).await?;
    stop.store(true, Ordering::Relaxed);
    for hammer in hammers {
        let _ = tokio::time::timeout(Duration::from_secs(5), hammer).await;
    }
    let cycle = rig
        .line
        .status()
        .devices
        .first()
        .and_then(|d| d.cycles.first().cloned())
        .ok_or_else(|| std::io::Error::other("the device has no poll cycle in its status"))?;
    let trouble = trouble(&rig.line);
    drop(rig);

    let window = plan.closed_window.as_secs_f64();
    let (answered, failed) = (
        answered.load(Ordering::Relaxed),
        failed.load(Ordering::Relaxed),
    );
    let planned = 1.0 / PERIOD.as_secs_f64();
    let ratio = hammered.poll_rate / quiet.poll_rate;
    let achieved_max = cycle.achieved_max.unwrap_or(Duration::MAX);
    let success = if hammered.cached_reads == 0 {
        f64::NAN
    } else {
        (hammered.cached_reads - hammered.cached_failed) as f64 / hammered.cached_reads as f64
    };
    let load = format!(
        "{window:.0} s a window at {BAUD} Bd; unit {FORWARDED} forwarded to address {FORWARDED}: \
         {answered} requests answered ({failed} exceptions), {:.0}/s, FC 03 and FC 06 of one \
         register in two closed loops{trouble}",
        answered as f64 / window
    );
    Ok(vec![
        Row {
            name: "transparent: poll rate, no client on the forwarded unit".into(),
            measured: format!("{:.2} /s", quiet.poll_rate),
            reference: format!("{planned:.2} /s"),
            score: quiet.poll_rate / planned,
            target: Target::at_least(0.95),
            note: format!(
                "answered polls/s of the declared device (registers 0..{} every {}) against its \
                 planned rate; {} of {} cached reads failed",
                COUNT - 1,
                ms(PERIOD),
                quiet.cached_failed,
                quiet.cached_reads
            ),
        },
        Row {
            name: "transparent: poll rate while a client hammers the forwarded unit / without"
                .into(),
            measured: format!("{:.2} /s", hammered.poll_rate),
            reference: format!("{:.2} /s", quiet.poll_rate),
            score: ratio,
            target: Target::at_least(0.95),
            note: format!(
                "the same device's polls/s while two clients hammer the forwarded unit; {load}"
            ),
        },
        Row {
            name: "transparent: cached reads answered while hammered".into(),
            measured: format!("{:.1} %", success * 100.0),
            reference: format!("of {}", hammered.cached_reads),
            score: success,
            target: Target::at_least(1.0),
            note: format!(
                "{} of {} cached FC 03 reads of the declared device (one every {}) failed",
                hammered.cached_failed,
                hammered.cached_reads,
                ms(CACHED_PAUSE)
            ),
        },
        Row {
            name: "transparent: achieved poll cycle (longest) / planned".into(),
            measured: ms(achieved_max),
            reference: ms(cycle.planned),
            score: achieved_max.as_secs_f64() / cycle.planned.as_secs_f64(),
            target: Target::at_most(cycle.bound.as_secs_f64() / cycle.planned.as_secs_f64()),
            note: format!(
                "planned {}, longest achieved {} over both windows, bound {} (the target: bound \
                 / planned)",
                ms(cycle.planned),
                ms(achieved_max),
                ms(cycle.bound)
            ),
        },
    ])
}
