//! Serial rows: the poll rate of a master line against the physical best case (the dead-device
//! rows in [`crate::dead`] use the same rig).
//!
//! Each run puts the gateway's master line (the library, in-process) on a [`paced`] link to a
//! simulated device, with a [`MasterTap`] between line and link and a [`device_relay`] on the
//! device's end (see [`crate::tap`]).
//!
//! The physical best case of one poll of N registers: the request (8 characters) and the response
//! (5 + 2N characters) on the wire, 11 bits a character (8E1), the device's t3.5 of silence before
//! it may answer, the master's t3.5 of silence before the next request, and whatever the device
//! takes beyond its t3.5:
//!
//! ```text
//! T_cycle = (13 + 2N) x 11 / baud + t3.5 (device) + t3.5 (master) + turnaround
//!         = (13 + 2N) x 11 / baud + t3.5 (master) + (request end -> answer start, measured at
//!           the device)
//! ```
//!
//! The two t3.5 differ above 19200 Bd: the simulated device follows the Modbus over Serial Line
//! specification (fixed 1.75 ms), the gateway's line the CP's table (3.5 character times at every
//! baud rate, 003 6.4.3: 1 ms at 38400 Bd), as `gateway::line::rtu_timing` says.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use gateway::image::{ImageConfig, ProcessImage, Table};
use gateway::line::LineHandle;
use gateway::paced::{self, Direction, LinkCounters, PacedDuplex, PacedSettings};
use gateway::protocols::{
    spawn_modbus_master_line, AddrRange, DeviceLimits, DeviceSettings, LineSettings, PollGroup,
};
use gateway::serial::PortSettings;
use gateway::sim::{serve_modbus, ModbusDevice};
use proto_core::modbus::rtu::CharTiming;
use tokio::sync::broadcast;
use tokio_util::sync::CancellationToken;

use crate::device::FlatDevice;
use crate::report::{Row, Target};
use crate::stats::{mean, ms, percentile};
use crate::tap::{device_relay, lock, DeviceLog, MasterTap};
use crate::Plan;

/// Bits a character: start, 8 data, even parity, stop (003 6.4.2.1 counts 11 for 8E1).
const BITS_PER_CHAR: u8 = 11;
/// Baud rates of the poll-rate rows.
pub(crate) const BAUDS: [u32; 4] = [9600, 19_200, 38_400, 115_200];
/// Registers a poll of the poll-rate rows.
pub(crate) const REGISTERS: [u16; 4] = [1, 10, 60, 125];
/// The poll period of the poll-rate rows: shorter than any cycle, so the line never rests.
const FLAT_OUT: Duration = Duration::from_millis(1);

/// A master line on a tapped paced link to a simulated device; stopped when dropped.
pub(crate) struct Rig {
    pub(crate) line: LineHandle,
    pub(crate) master: MasterTap,
    pub(crate) device: Arc<Mutex<DeviceLog>>,
    pub(crate) timing: CharTiming,
    /// The master line's own timing (its t3.5 before the next request).
    pub(crate) master_timing: CharTiming,
    /// The paced link's counters (bytes, the latest delivery).
    pub(crate) link: Arc<LinkCounters>,
    /// The line's process image (the cached values and when each was read).
    pub(crate) image: ProcessImage,
    shutdown: CancellationToken,
}

impl Drop for Rig {
    fn drop(&mut self) {
        self.shutdown.cancel();
    }
}

/// Starts a paced link at `baud` (8E1), `device` on its far end, and a master line polling
/// `devices` through a tap on its near end. The line opens a pty of its own; the link's ends are
/// in-process streams (see [`crate::tap`]).
pub(crate) async fn rig(
    baud: u32,
    device: impl ModbusDevice + 'static,
    devices: Vec<DeviceSettings>,
    reply_timeout: Option<Duration>,
) -> std::io::Result<Rig> {
    rig_with(baud, device, devices, reply_timeout, |_| {}).await
}

/// [`rig`] with the line's settings changed by `tune` before it starts.
pub(crate) async fn rig_with(
    baud: u32,
    device: impl ModbusDevice + 'static,
    devices: Vec<DeviceSettings>,
    reply_timeout: Option<Duration>,
    tune: impl FnOnce(&mut LineSettings),
) -> std::io::Result<Rig> {
    let shutdown = CancellationToken::new();
    let settings = PacedSettings::from_frame(baud, 8, true, 1);
    let (link, _relay) = paced::paced_duplex(settings, None, shutdown.clone())?;
    let PacedDuplex { a, b, counters } = link;
    let timing = CharTiming::new(baud, BITS_PER_CHAR);
    let (port, device_log) = device_relay(b, shutdown.clone());
    tokio::spawn(serve_modbus(port, device, timing, shutdown.clone()));
    let master_timing = gateway::line::rtu_timing(&PortSettings::new(String::new(), baud));
    let master = MasterTap::spawn(
        a,
        master_timing.char_time,
        master_timing.t3_5(),
        shutdown.clone(),
    )?;
    let mut port = PortSettings::new(master.path.clone(), baud);
    port.monitor_frames = crate::monitor_frames();
    let mut line = LineSettings::rtu("bench", port);
    if let Some(timeout) = reply_timeout {
        line.master.reply_timeout = timeout;
    }
    tune(&mut line);
    let image = ProcessImage::new(ImageConfig::default());
    let line = spawn_modbus_master_line(line, devices, image.clone(), shutdown.clone());
    Ok(Rig {
        line,
        master,
        device: device_log,
        timing,
        master_timing,
        link: counters,
        image,
        shutdown,
    })
}

/// A device polling `count` holding registers from 0 every `period`.
pub(crate) fn polled(name: &str, slave: u8, count: u16, period: Duration) -> DeviceSettings {
    DeviceSettings {
        limits: DeviceLimits::CP341,
        groups: vec![PollGroup {
            period,
            table: Table::HoldingRegisters,
            ranges: vec![AddrRange::new(0, count)],
        }],
        ..DeviceSettings::new(name, slave, slave)
    }
}

/// Answered polls of the devices `which` of the line.
pub(crate) fn polls_ok(line: &LineHandle, which: std::ops::Range<usize>) -> u64 {
    line.status()
        .devices
        .get(which)
        .map_or(0, |d| d.iter().map(|d| d.polls_ok).sum())
}

/// Waits until the line has `n` answered polls of its first device, at most `limit`.
async fn warm_up(line: &LineHandle, n: u64, limit: Duration) -> bool {
    let deadline = Instant::now() + limit;
    while polls_ok(line, 0..1) < n {
        if Instant::now() > deadline {
            return false;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    true
}

/// The result of one poll-rate run.
pub(crate) struct PollRun {
    pub(crate) row: Row,
    /// Requests that started less than t3.5 after the previous frame.
    pub(crate) violations: u64,
    /// Requests seen.
    pub(crate) requests: u64,
    /// The master's own time before each request beyond t3.5 (see [`OwnTime`]).
    pub(crate) own: Vec<Duration>,
}

/// The gateway's own time per cycle, from its frame monitor: from the moment the line read the
/// answer's last byte to the moment it had written the next request, minus the t3.5 of silence
/// it must leave (003 6.4.3). The tap's "master gap" adds two pty hops (the answer into the line's
/// port, the request out of it), which belong to neither the gateway nor the wire.
#[derive(Default)]
struct OwnTime {
    /// The last byte of the last received frame, if the last frame was received.
    answer_end: Option<Duration>,
    /// Each request's time beyond t3.5 after the answer before it.
    beyond: Vec<Duration>,
}

// === impl OwnTime ===

impl OwnTime {
    fn frame(&mut self, frame: &gateway::line::Frame, t35: Duration) {
        if frame.direction == proto_core::monitor::Direction::Tx {
            if let Some(end) = self.answer_end.take() {
                let gap = frame.first_mono.saturating_sub(end);
                self.beyond.push(gap.saturating_sub(t35));
            }
        } else {
            self.answer_end = Some(frame.last_mono);
        }
    }
}

/// The row of the gateway's own time per cycle over every poll-rate run: median and p99 of the
/// time beyond t3.5 (target: median <= 30 us, so that 115200 Bd N = 1 reaches 0.95 of the best
/// case).
pub(crate) fn own_time_row(own: &[Duration]) -> Row {
    let name = "master's own time per cycle beyond t3.5, median".to_owned();
    if own.is_empty() {
        return failed(name, "no frames: the rows ran without the frame monitor");
    }
    let us = |d: Duration| d.as_secs_f64() * 1e6;
    let median = percentile(own, 50.0);
    Row {
        name,
        measured: format!("{:.1} us", us(median)),
        reference: "-".into(),
        score: us(median),
        target: Target::at_most(30.0).with_unit(" us"),
        note: format!(
            "{} requests of the poll-rate runs; line read the answer's last byte -> line wrote \
             the next request, minus the line's t3.5 (frame monitor's times); p99 {:.1} us, max \
             {:.1} us",
            own.len(),
            us(percentile(own, 99.0)),
            us(percentile(own, 100.0)),
        ),
    }
}

/// Polls `n` registers flat out at `baud` and compares the rate with the best case.
pub(crate) async fn poll_rate(baud: u32, n: u16, plan: &Plan) -> std::io::Result<PollRun> {
    let name = format!("poll rate {baud} Bd, N={n}: polls/s / best case");
    let rig = rig(
        baud,
        FlatDevice::new(1),
        vec![polled("d1", 1, n, FLAT_OUT)],
        None,
    )
    .await?;
    let timing = rig.timing;
    let t35 = timing.t3_5();
    let master_t35 = rig.master_timing.t3_5();
    let wire = timing.char_time * (13 + 2 * u32::from(n));
    if !warm_up(&rig.line, 3, Duration::from_secs(10)).await {
        return Ok(PollRun {
            row: failed(
                name,
                &format!("the line never polled{}", trouble(&rig.line)),
            ),
            violations: 0,
            requests: 0,
            own: Vec::new(),
        });
    }
    // Long enough for the plan's number of cycles (estimated with a 1 ms turnaround).
    let estimate = wire + t35 * 2 + master_t35 + Duration::from_millis(2);
    let window = plan.poll_window.max(estimate * plan.poll_cycles);

    let (p0, t0) = (polls_ok(&rig.line, 0..1), Instant::now());
    let (ex0, v0, g0) = {
        let log = lock(&rig.master.log);
        (log.exchanges.len(), log.violations, log.gaps.len())
    };
    let d0 = lock(&rig.device).turnarounds.len();
    let mut own = OwnTime::default();
    match rig.line.monitor().map(|m| m.subscribe()) {
        Some(mut frames) => {
            let end = tokio::time::sleep(window);
            tokio::pin!(end);
            loop {
                tokio::select! {
                    () = &mut end => break,
                    frame = frames.recv() => match frame {
                        Ok(frame) => own.frame(&frame, master_t35),
                        // Frames missed: the pair around the gap is not known.
                        Err(broadcast::error::RecvError::Lagged(_)) => own.answer_end = None,
                        Err(broadcast::error::RecvError::Closed) => {
                            end.as_mut().await;
                            break;
                        }
                    },
                }
            }
        }
        None => tokio::time::sleep(window).await,
    }
    let (p1, t1) = (polls_ok(&rig.line, 0..1), Instant::now());
    let (serial, violations, requests, gap, cycle) = {
        let log = lock(&rig.master.log);
        let window = log.exchanges.get(ex0..).unwrap_or_default();
        let serial: Vec<Duration> = window
            .iter()
            .filter_map(|e| e.answered.map(|a| a.saturating_duration_since(e.sent)))
            .collect();
        // The mean time from one request to the next, over the whole window.
        let cycle = match (window.first(), window.last()) {
            (Some(first), Some(last)) if window.len() > 1 => {
                let intervals = u32::try_from(window.len() - 1).unwrap_or(u32::MAX);
                last.sent.saturating_duration_since(first.sent) / intervals
            }
            _ => Duration::MAX,
        };
        let gaps = log.gaps.get(g0..).unwrap_or_default();
        (
            mean(&serial),
            log.violations - v0,
            window.len() as u64,
            mean(gaps),
            cycle,
        )
    };
    let turnaround = mean(lock(&rig.device).turnarounds.get(d0..).unwrap_or_default());
    let trouble = trouble(&rig.line);
    // The latest the relay delivered a byte after its time, over the whole run (a gap inside a
    // frame is at most one character time plus this).
    let to_device = rig.link.direction(Direction::AToB).max_lateness;
    let to_master = rig.link.direction(Direction::BToA).max_lateness;
    drop(rig);

    let elapsed = t1.saturating_duration_since(t0).as_secs_f64();
    let polls = p1 - p0;
    let achieved = 1.0 / cycle.as_secs_f64();
    let best_cycle = wire + master_t35 + turnaround;
    let best = 1.0 / best_cycle.as_secs_f64();
    let link_excess = serial.saturating_sub(wire + turnaround);
    let without_link = best_cycle.as_secs_f64() / cycle.saturating_sub(link_excess).as_secs_f64();
    let note = format!(
        "{polls} polls answered in {elapsed:.1} s ({requests} requests); cycle {} = wire {} + \
         device {} (t3.5 {} + its own {}) + link and tap lateness {} + master gap {} (t3.5 {}); \
         frames < t3.5 after the previous: {violations}; without the link's lateness the ratio \
         would be {without_link:.3}; the relay's latest byte {} to the device, {} to the master\
         {trouble}",
        ms(cycle),
        ms(wire),
        ms(turnaround),
        ms(t35),
        ms(turnaround.saturating_sub(t35)),
        ms(link_excess),
        ms(gap),
        ms(master_t35),
        ms(to_device),
        ms(to_master),
    );
    // Every request answered: a failed poll would make the rate meaningless.
    let score = if polls + 1 >= requests && requests > 1 {
        achieved / best
    } else {
        f64::NAN
    };
    Ok(PollRun {
        row: Row {
            name,
            measured: format!("{achieved:.2}/s"),
            reference: format!("{best:.2}/s"),
            score,
            target: Target::at_least(0.95),
            note,
        },
        violations,
        requests,
        own: own.beyond,
    })
}

/// Failed polls and events of the line, if any (", failed polls 3, events 0830 x3").
pub(crate) fn trouble(line: &LineHandle) -> String {
    let status = line.status();
    let failed: u64 = status
        .devices
        .iter()
        .map(|d| d.polls_failed + d.polls_exception)
        .sum();
    // Class 00 (start-up) events are not trouble.
    let events: Vec<String> = status
        .event_counts
        .iter()
        .filter(|(id, _)| id.class != 0)
        .map(|(id, n)| format!("{id} x{n}"))
        .collect();
    let mut out = String::new();
    if failed > 0 {
        out.push_str(&format!("; failed polls {failed}"));
    }
    if !events.is_empty() {
        out.push_str(&format!("; events {}", events.join(", ")));
    }
    out
}

/// A row for a run that could not measure.
pub(crate) fn failed(name: String, why: &str) -> Row {
    Row {
        name,
        measured: "-".into(),
        reference: "-".into(),
        score: f64::NAN,
        target: Target::at_least(0.95),
        note: why.to_owned(),
    }
}
