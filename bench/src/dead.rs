//! One dead device among ten: the poll rate of the nine others once the tenth has been declared
//! offline, against their rate with none dead, and how soon the dead one is polled again once it
//! answers.
//!
//! Ten devices (10 registers each, every 500 ms) on one paced 19200 Bd line, the line about half
//! busy, in the same rig as the poll-rate rows. What is measured:
//!
//! - none dead: the nine first devices' answered polls per second over `alive_window`, after a
//!   warm-up;
//! - the tenth silent from the start: the nine others' answered polls per second over
//!   `dead_window`, counted from the moment the line declared the tenth offline (its first poll
//!   waited the whole reply monitoring time: the detection, reported in the note with what the
//!   probes in the window held the line for, from the master tap);
//! - (with `recover`) the tenth answers again at some moment: the time until the line has it
//!   online again, `recoveries` times, each with the back-off at its maximum.
//!
//! The same rig with nine devices, three of them dead (a station with three drives switched off
//! among its meters): the six others' rate against their rate with none dead.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use gateway::config::{
    DEFAULT_FULL_PROBE_EVERY, DEFAULT_OFFLINE_AFTER, DEFAULT_OFFLINE_BACKOFF_MIN,
    DEFAULT_PROBE_TIMEOUT_MIN,
};
use gateway::protocols::PROBE_TIMEOUT_FACTOR;

use crate::device::{Bus, FlatDevice};
use crate::poll::{polled, polls_ok, rig, trouble, Rig};
use crate::report::{Row, Target};
use crate::stats::{ms, percentile};
use crate::tap::lock;
use crate::Plan;

const BAUD: u32 = 19_200;
/// Devices on the line and how many of the last ones are silent from the start.
#[derive(Clone, Copy)]
pub(crate) struct Shape {
    pub(crate) devices: u8,
    pub(crate) dead: u8,
}
/// One dead device among ten (the recovery row uses the tenth).
pub(crate) const ONE_OF_TEN: Shape = Shape {
    devices: 10,
    dead: 1,
};
/// Three dead devices among nine (the station of three drives and six meters).
pub(crate) const THREE_OF_NINE: Shape = Shape {
    devices: 9,
    dead: 3,
};
const COUNT: u16 = 10;
const PERIOD: Duration = Duration::from_millis(500);
/// Warm-up of the run with none dead: every device polled a few times.
const WARM_UP: Duration = Duration::from_millis(1500);
/// The gateway's default longest back-off between probes of an offline device.
const BACKOFF_MAX: Duration = gateway::config::DEFAULT_OFFLINE_BACKOFF_MAX;
/// Target of the recovery row: the maximum back-off and one second for the probe and the polls
/// due before it.
const RECOVERY_TARGET: Duration = BACKOFF_MAX.saturating_add(Duration::from_secs(1));
/// When, after the back-off reached its maximum, the dead device answers again in each recovery
/// (spread over the 5 s probe period).
const RETURN_AFTER: [Duration; 3] = [
    Duration::from_millis(700),
    Duration::from_millis(2300),
    Duration::from_millis(3900),
];
/// Back-off before the maximum is reached: 1 s, 2 s, 4 s (the defaults), with slack for their
/// probes.
const BACKOFF_RAMP: Duration = Duration::from_secs(8);

/// How long the line may take to declare the dead device offline: `offline_after` polls in a row
/// (the default, 6) without an answer, each waiting the whole reply monitoring time, one more for
/// a poll in flight, and 5 s for the polls of the others between them (12 s at 2 s: the window
/// of 2 x the reply monitoring time + 5 s used before ended first, and the row read NaN).
fn detection_limit(reply_timeout: Duration) -> Duration {
    reply_timeout.saturating_mul(DEFAULT_OFFLINE_AFTER + 1) + Duration::from_secs(5)
}

/// The rows of one reply monitoring time: the rate row, and the recovery row with `recover`.
pub(crate) async fn dead_device(
    plan: &Plan,
    shape: Shape,
    reply_timeout: Duration,
    recover: bool,
) -> std::io::Result<Vec<Row>> {
    let Shape { devices, dead } = shape;
    let name = format!(
        "{dead} dead of {devices}, reply timeout {} ms: others' polls/s / none dead",
        reply_timeout.as_millis()
    );
    let others = 0..usize::from(devices - dead);
    let target = if dead == 1 { 0.95 } else { 0.8 };

    // None dead.
    let (rig_alive, _) = line(reply_timeout, devices, 0).await?;
    tokio::time::sleep(WARM_UP).await;
    let alive = rate(&rig_alive, others.clone(), plan.alive_window).await;
    drop(rig_alive);

    // The last ones silent from the start: the window opens when the line declares them offline.
    let (rig, silent) = line(reply_timeout, devices, dead).await?;
    let limit = detection_limit(reply_timeout).saturating_mul(u32::from(dead));
    let Some(offline_after) = wait_for(&rig, others.end..usize::from(devices), false, limit).await
    else {
        return Ok(vec![crate::poll::failed(
            name,
            &format!(
                "the dead devices were never declared offline{}",
                trouble(&rig.line)
            ),
        )]);
    };
    let window_start = Instant::now();
    let with_dead = rate(&rig, others, plan.dead_window).await;
    let holds = dead_holds(&rig, devices, window_start, Instant::now());
    let trouble_dead = trouble(&rig.line);

    let expected = f64::from(devices - dead) / PERIOD.as_secs_f64();
    let mut rows = vec![Row {
        name,
        measured: format!("{with_dead:.2}/s"),
        reference: format!("{alive:.2}/s"),
        score: with_dead / alive,
        target: Target::at_least(target),
        note: format!(
            "{devices} devices x {COUNT} registers every {} ms at {BAUD} Bd 8E1 (the line about \
             half busy with all; the {} others should make {expected:.0} polls/s), reply \
             monitoring time \
             {} ms, the gateway's defaults otherwise (offline back-off {} s doubling to {} s, a \
             probe one attempt of {PROBE_TIMEOUT_FACTOR} x the device's reply delay and at least \
             {} ms, every {DEFAULT_FULL_PROBE_EVERY}th the full time); none dead: {:.0} s after \
             {:.1} s of warm-up; with {dead} dead: {:.0} s from the moment the last was declared \
             offline, {:.1} s after the start; the first detection held the line {}; requests \
             to the last dead device: {}{trouble_dead}",
            PERIOD.as_millis(),
            devices - dead,
            reply_timeout.as_millis(),
            DEFAULT_OFFLINE_BACKOFF_MIN.as_secs_f64(),
            BACKOFF_MAX.as_secs_f64(),
            DEFAULT_PROBE_TIMEOUT_MIN.as_millis(),
            plan.alive_window.as_secs_f64(),
            WARM_UP.as_secs_f64(),
            plan.dead_window.as_secs_f64(),
            offline_after.as_secs_f64(),
            holds.detection.map_or_else(|| "?".to_owned(), ms),
            holds.text(),
        ),
    }];
    if recover {
        rows.push(recovery(plan, reply_timeout, &rig, &silent).await);
    }
    Ok(rows)
}

/// A line of `devices` devices, the last `dead` silent from the start, and the last one's silence
/// switch.
async fn line(
    reply_timeout: Duration,
    devices: u8,
    dead: u8,
) -> std::io::Result<(Rig, Arc<AtomicBool>)> {
    let bus: Vec<FlatDevice> = (1..=devices).map(FlatDevice::new).collect();
    for d in &bus[usize::from(devices - dead)..] {
        d.silence_switch().store(true, Ordering::Relaxed);
    }
    let silent = bus
        .last()
        .map(FlatDevice::silence_switch)
        .unwrap_or_default();
    let devices = (1..=devices)
        .map(|slave| polled(&format!("d{slave}"), slave, COUNT, PERIOD))
        .collect();
    let rig = rig(BAUD, Bus(bus), devices, Some(reply_timeout)).await?;
    Ok((rig, silent))
}

/// Answered polls per second of the devices `which` over `window`.
async fn rate(rig: &Rig, which: std::ops::Range<usize>, window: Duration) -> f64 {
    let (p0, t0) = (polls_ok(&rig.line, which.clone()), Instant::now());
    tokio::time::sleep(window).await;
    let (p1, t1) = (polls_ok(&rig.line, which), Instant::now());
    (p1 - p0) as f64 / t1.saturating_duration_since(t0).as_secs_f64()
}

/// Waits until the `online` flag of the devices `which` is `online`, at most `limit`; the time it
/// took.
async fn wait_for(
    rig: &Rig,
    which: std::ops::Range<usize>,
    online: bool,
    limit: Duration,
) -> Option<Duration> {
    let start = Instant::now();
    loop {
        let status = rig.line.status();
        if which
            .clone()
            .all(|i| status.devices.get(i).is_some_and(|d| d.online == online))
        {
            return Some(start.elapsed());
        }
        if start.elapsed() > limit {
            return None;
        }
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
}

/// How long requests to the dead device held the line, as the master tap saw them: from the
/// request to the next request (the line's idle time before the next poll falls due included).
struct Holds {
    /// The first request to it (never answered: the detection).
    detection: Option<Duration>,
    /// The requests in the window (probes), in order.
    probes: Vec<Duration>,
}

impl Holds {
    fn text(&self) -> String {
        let mut sorted = self.probes.clone();
        sorted.sort_unstable();
        match (sorted.first(), sorted.last()) {
            (Some(first), Some(last)) => format!(
                "{} probes in the window, each holding the line from its request to the next \
                 (idle time included) {} to {} (median {}), {} in all",
                sorted.len(),
                ms(*first),
                ms(*last),
                ms(percentile(&sorted, 50.0)),
                ms(sorted.iter().sum()),
            ),
            _ => "no probe in the window".to_owned(),
        }
    }
}

fn dead_holds(rig: &Rig, last: u8, window_start: Instant, window_end: Instant) -> Holds {
    let log = lock(&rig.master.log);
    let dead = Some(last);
    let holds: Vec<(Instant, Duration)> = log
        .exchanges
        .windows(2)
        .filter_map(|pair| match pair {
            [e, next] if e.slave == dead => Some((e.sent, next.sent.duration_since(e.sent))),
            _ => None,
        })
        .collect();
    Holds {
        detection: holds.first().map(|(_, hold)| *hold),
        probes: holds
            .iter()
            .filter(|(sent, _)| (window_start..window_end).contains(sent))
            .map(|(_, hold)| *hold)
            .collect(),
    }
}

/// The dead device answers again `recoveries` times, each once its back-off is at the maximum:
/// the worst time until the line has it online again.
async fn recovery(plan: &Plan, reply_timeout: Duration, rig: &Rig, silent: &AtomicBool) -> Row {
    let name = format!(
        "1 dead of 10, reply timeout {} ms: polled again after it answers",
        reply_timeout.as_millis()
    );
    let last = usize::from(ONE_OF_TEN.devices) - 1;
    let mut found = Vec::new();
    let mut trouble_text = String::new();
    // The back-off reaches its maximum 7 s after the device went offline (1 + 2 + 4 s).
    tokio::time::sleep(BACKOFF_RAMP.saturating_sub(plan.dead_window)).await;
    for after in RETURN_AFTER.iter().cycle().take(plan.recoveries) {
        // The device has been offline long enough for the back-off to be at its maximum.
        tokio::time::sleep(*after).await;
        silent.store(false, Ordering::Relaxed);
        match wait_for(rig, last..last + 1, true, Duration::from_secs(60)).await {
            Some(took) => found.push(took),
            None => {
                trouble_text = "; not back within 60 s".into();
                break;
            }
        }
        silent.store(true, Ordering::Relaxed);
        if wait_for(rig, last..last + 1, false, detection_limit(reply_timeout))
            .await
            .is_none()
        {
            trouble_text = "; not declared offline again".into();
            break;
        }
        tokio::time::sleep(BACKOFF_RAMP).await;
    }
    let worst = found.iter().max().copied();
    let all: Vec<String> = found.iter().map(|d| ms(*d)).collect();
    Row {
        name,
        measured: worst.map_or_else(|| "-".to_owned(), |w| format!("{:.2} s", w.as_secs_f64())),
        reference: "-".into(),
        score: worst.map_or(f64::NAN, |w| w.as_secs_f64()),
        target: Target::at_most(RECOVERY_TARGET.as_secs_f64()).with_unit(" s"),
        note: format!(
            "the dead device of the row above answers again {} times, each once its back-off \
             was at its {} s maximum, at moments spread over the probe period: the time until \
             the line had it online again (its answered probe), worst of {}; the target is the \
             maximum back-off and 1 s for the probe and the polls due before it{trouble_text}",
            found.len(),
            BACKOFF_MAX.as_secs(),
            all.join(", "),
        ),
    }
}
