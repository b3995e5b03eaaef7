//! The probing policy through the scheduler, on a simulated clock: the instants are fed, nothing
//! sleeps. A small line model turns each job into the time it holds the line: a poll the device
//! answers takes the exchange on the wire plus the device's reply delay, a request it does not
//! answer takes the request on the wire plus the wait for the reply, per attempt.

use std::time::Duration;

use proto_core::modbus::master::{Attempts, MasterConfig};
use tokio::time::Instant;

use super::*;
use crate::image::Table;
use crate::protocols::modbus_master::probe::ProbeSettings;
use crate::protocols::{AddrRange, DeviceLimits, PollGroup};

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

/// 19200 Bd 8E1 with the CP's default reply monitoring time of 2000 ms (003 6.4.2.1).
fn cp_line() -> MasterConfig {
    MasterConfig::rtu(19_200, 11)
}

/// At 19200 Bd 8E1 (0.573 ms a character): a read of 10 registers, request (8 characters) and
/// answer (25) on the wire plus t3.5 before the next request, without the device's reply delay.
const EXCHANGE: Duration = Duration::from_micros(20_900);
/// The reply delay of a healthy device: its t3.5 (2 ms) and 1 ms of its own.
const HEALTHY_DELAY: Duration = Duration::from_millis(3);
/// A request nobody answers: 8 characters on the wire and t3.5, besides the wait itself.
const REQUEST: Duration = Duration::from_micros(6_600);

/// A device polling 10 holding registers every 500 ms, with the default back-off and probes,
/// offline after its first failed poll (the probing starts there, whatever the count before).
fn drive(slave: u8) -> DeviceSettings {
    let mut d = DeviceSettings::new(format!("d{slave}"), slave, slave);
    d.offline_after = 1;
    d.limits = DeviceLimits::CP341;
    d.groups = vec![PollGroup {
        period: ms(500),
        table: Table::HoldingRegisters,
        ranges: vec![AddrRange::new(0, 10)],
    }];
    d
}

/// What a simulated run saw.
#[derive(Debug, Default)]
struct Run {
    /// Polls answered, by device.
    answered: Vec<u64>,
    /// When a device came back, by device.
    came_back: Vec<(usize, Instant)>,
    /// The reply monitoring time of every request to a device that did not answer.
    waits: Vec<(usize, Duration)>,
}

impl Run {
    /// How long after `since` `device` was first seen back, if it was.
    fn came_back_after(&self, device: usize, since: Instant) -> Option<Duration> {
        self.came_back
            .iter()
            .find(|(d, _)| *d == device)
            .map(|(_, at)| at.saturating_duration_since(since))
    }
}

/// Runs the scheduler on the line model from `t0` to `until`; `delay(device, now)` is the
/// device's reply delay at `now`, `None` while it is silent.
fn simulate(
    devices: &[DeviceSettings],
    line: &MasterConfig,
    t0: Instant,
    until: Instant,
    delay: impl Fn(usize, Instant) -> Option<Duration>,
) -> Run {
    let mut s: Scheduler<()> = Scheduler::new(devices, t0);
    let mut run = Run {
        answered: vec![0; devices.len()],
        ..Run::default()
    };
    let mut now = t0;
    while now < until {
        let Some(job) = s.next_job(now) else {
            now = s.next_wake().unwrap_or(until).max(now);
            continue;
        };
        let Job::Poll(p) = job else {
            unreachable!("no commands in this model")
        };
        let attempts = s.poll_attempts(p.device, line);
        let wait = attempts.reply_timeout.unwrap_or(line.reply_timeout);
        match delay(p.device, now) {
            Some(d) if d <= wait => {
                now += EXCHANGE + d;
                s.heard(p.device, Some(d));
                if s.poll_done(p, true, now) == Transition::CameBack {
                    run.came_back.push((p.device, now));
                }
                run.answered[p.device] += 1;
            }
            _ => {
                let tries = 1 + u32::from(attempts.retries.unwrap_or(line.retries));
                now += (REQUEST + wait) * tries;
                run.waits.push((p.device, wait));
                s.poll_done(p, false, now);
            }
        }
    }
    run
}

fn ten() -> Vec<DeviceSettings> {
    (1..=10).map(drive).collect()
}

#[test]
fn a_probe_is_one_attempt_of_four_reply_delays_and_every_nth_waits_the_full_time() {
    let t0 = Instant::now();
    let mut d = drive(2);
    d.backoff_min = ms(500);
    d.backoff_max = ms(2000);
    d.probe = ProbeSettings {
        timeout_min: ms(100),
        full_every: 3,
    };
    let mut line = cp_line();
    line.retries = 2;
    let mut s: Scheduler<()> = Scheduler::new(&[d], t0);
    // Online: as configured.
    let p = poll(s.next_job(t0));
    assert_eq!(s.poll_attempts(p.device, &line), Attempts::default());
    s.heard(0, Some(ms(40)));
    assert_eq!(s.poll_done(p, true, t0 + ms(60)), Transition::Unchanged);
    // Silent: offline once the configured three attempts of 2 s have failed.
    let p = poll(s.next_job(t0 + ms(500)));
    assert_eq!(s.poll_attempts(p.device, &line), Attempts::default());
    assert_eq!(
        s.poll_done(p, false, t0 + ms(6500)),
        Transition::WentOffline { retry_in: ms(500) }
    );
    // Probes: one attempt each, 4 x its 40 ms reply delay, every third the full 2 s.
    let mut waits = Vec::new();
    for _ in 0..6 {
        let now = s.next_wake().expect("a probe is due");
        let p = poll(s.next_job(now));
        let attempts = s.poll_attempts(p.device, &line);
        assert_eq!(attempts.retries, Some(0));
        let wait = attempts.reply_timeout.expect("a probe's own time");
        waits.push(wait);
        s.poll_done(p, false, now + wait);
    }
    assert_eq!(
        waits,
        [ms(160), ms(160), ms(2000), ms(160), ms(160), ms(2000)]
    );
    // It answers a probe: online, polled as configured again.
    let now = s.next_wake().expect("a probe is due");
    let p = poll(s.next_job(now));
    assert_eq!(s.poll_attempts(p.device, &line).retries, Some(0));
    s.heard(0, Some(ms(40)));
    assert_eq!(s.poll_done(p, true, now + ms(60)), Transition::CameBack);
    let p = poll(s.next_job(now + ms(60)));
    assert_eq!(s.poll_attempts(p.device, &line), Attempts::default());
}

#[test]
fn a_command_sent_as_the_probe_counts_as_a_full_wait() {
    let t0 = Instant::now();
    let mut d = drive(2);
    d.probe = ProbeSettings {
        timeout_min: ms(100),
        full_every: 2,
    };
    let line = cp_line();
    let mut s: Scheduler<()> = Scheduler::new(&[d], t0);
    s.observe(0, false, t0);
    let p = poll(s.next_job(t0 + ms(1000)));
    assert_eq!(
        s.poll_attempts(p.device, &line).reply_timeout,
        Some(ms(100))
    );
    s.poll_done(p, false, t0 + ms(1100));
    // Without the command the next probe would be the full one.
    s.observe(0, false, t0 + ms(5000));
    let now = s.next_wake().expect("a probe is due");
    let p = poll(s.next_job(now));
    assert_eq!(
        s.poll_attempts(p.device, &line).reply_timeout,
        Some(ms(100))
    );
}

#[test]
fn a_late_reply_after_a_short_probe_makes_the_next_probe_full() {
    let t0 = Instant::now();
    let line = cp_line();
    let mut s: Scheduler<()> = Scheduler::new(&[drive(2)], t0);
    s.observe(0, false, t0);
    let probe_wait = |s: &mut Scheduler<()>| {
        let now = s.next_wake().expect("a probe is due");
        let p = poll(s.next_job(now));
        let wait = s
            .poll_attempts(p.device, &line)
            .reply_timeout
            .expect("probe");
        s.poll_done(p, false, now + wait);
        (now + wait, wait)
    };
    // Bytes long after the short probe's 2 s window: nothing changes.
    let (end, wait) = probe_wait(&mut s);
    assert_eq!(wait, ms(100));
    s.unexpected_reply(end + ms(1901));
    // Bytes within it: the next probe waits the full time, the one after is short again.
    let (end, wait) = probe_wait(&mut s);
    assert_eq!(wait, ms(100));
    s.unexpected_reply(end + ms(400));
    assert_eq!(probe_wait(&mut s).1, ms(2000));
    assert_eq!(probe_wait(&mut s).1, ms(100));
}

#[test]
fn nine_drives_keep_their_rate_when_the_tenth_is_dead_with_the_cps_reply_time() {
    let t0 = Instant::now();
    let until = t0 + Duration::from_secs(300);
    let line = cp_line();
    let alive = simulate(&ten(), &line, t0, until, |_, _| Some(HEALTHY_DELAY));
    let dead = simulate(&ten(), &line, t0, until, |d, _| {
        (d != 9).then_some(HEALTHY_DELAY)
    });
    let others = |run: &Run| run.answered.iter().take(9).sum::<u64>() as f64;
    let ratio = others(&dead) / others(&alive);
    // Before short probes: every probe waited 2 s, the back-off went to 30 s.
    let old: Vec<DeviceSettings> = ten()
        .into_iter()
        .map(|mut d| {
            d.backoff_max = Duration::from_secs(30);
            d.probe.full_every = 1;
            d
        })
        .collect();
    let old_dead = simulate(&old, &line, t0, until, |d, _| {
        (d != 9).then_some(HEALTHY_DELAY)
    });
    let old_ratio = others(&old_dead) / others(&alive);
    assert!(
        ratio >= 0.95 && ratio > old_ratio,
        "others' polls with one dead / none dead: {ratio:.3} (every probe 2 s: {old_ratio:.3})"
    );
    // The dead one: probed at most every 5 s once the back-off is at its maximum, one probe in
    // twelve with the full 2 s.
    let waits: Vec<Duration> = dead.waits.iter().map(|(_, w)| *w).collect();
    let full = waits.iter().filter(|w| **w == ms(2000)).count();
    let short = waits.iter().filter(|w| **w == ms(100)).count();
    assert_eq!(full + short, waits.len(), "{waits:?}");
    assert!(
        waits.len() >= 55 && full <= 1 + waits.len() / 12,
        "{short} short and {full} full waits in 300 s"
    );
}

#[test]
fn a_drive_that_comes_back_is_found_within_the_maximum_back_off() {
    let t0 = Instant::now();
    let line = cp_line();
    for back_after in [61_000, 63_500, 64_900, 90_000] {
        let back_at = t0 + ms(back_after);
        let run = simulate(&ten(), &line, t0, back_at + ms(20_000), |d, now| {
            (d != 9 || now >= back_at).then_some(HEALTHY_DELAY)
        });
        let found = run.came_back_after(9, back_at);
        // At most the 5 s back-off, the exchange in flight when it came back (a full probe of
        // 2 s, or a short one of 100 ms), the polls due before the probe and its own poll.
        assert!(
            found.is_some_and(|f| f <= ms(5000 + 2000 + 300)),
            "back after {back_after} ms, found {found:?} later"
        );
    }
}

#[test]
fn a_drive_that_comes_back_slower_than_a_short_probe_is_found_by_a_full_one() {
    let t0 = Instant::now();
    let line = cp_line();
    let back_at = t0 + ms(30_000);
    // It answered in 3 ms before, now in 600 ms: beyond a short probe, within the 2 s.
    let run = simulate(&ten(), &line, t0, back_at + ms(120_000), |d, now| {
        match (d, now >= back_at) {
            (9, false) => None,
            (9, true) => Some(ms(600)),
            _ => Some(HEALTHY_DELAY),
        }
    });
    let found = run.came_back_after(9, back_at);
    // Within twelve probes at the 5 s maximum back-off (and the full probe itself).
    assert!(
        found.is_some_and(|f| f <= ms(12 * 5000 + 2000 + 700)),
        "found {found:?} after it came back"
    );
    assert!(run.answered[9] > 50, "polled again: {:?}", run.answered);
}

fn poll(job: Option<Job<()>>) -> PollJob {
    match job {
        Some(Job::Poll(p)) => p,
        other => panic!("expected a poll, got {other:?}"),
    }
}
