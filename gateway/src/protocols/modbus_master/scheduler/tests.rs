use std::time::Duration;

use tokio::time::Instant;

use super::*;
use crate::image::Table;
use crate::protocols::{AddrRange, DeviceLimits, PollGroup};

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn device(name: &str, slave: u8, period: Duration, ranges: Vec<AddrRange>) -> DeviceSettings {
    let mut d = DeviceSettings::new(name, slave, slave);
    d.limits = DeviceLimits::ALTIVAR;
    d.groups = vec![PollGroup {
        period,
        table: Table::HoldingRegisters,
        ranges,
    }];
    d.backoff_min = ms(500);
    d.backoff_max = ms(2000);
    // Offline after one failed poll: these tests are about the back-off.
    d.offline_after = 1;
    d
}

fn poll(job: Option<Job<&'static str>>) -> PollJob {
    match job {
        Some(Job::Poll(p)) => p,
        other => panic!("expected a poll, got {other:?}"),
    }
}

#[test]
fn writes_go_before_on_demand_reads_and_both_before_polls_not_yet_due() {
    let t0 = Instant::now();
    let mut s = Scheduler::new(
        &[device("atv", 2, ms(100), vec![AddrRange::new(3201, 1)])],
        t0,
    );
    let first = poll(s.next_job(t0));
    s.poll_done(first, true, t0);
    s.push_read("read 1", None);
    s.push_write("write 1");
    s.push_read("read 2", None);
    s.push_write("write 2");
    assert!(s.has_commands());
    let order: Vec<_> = std::iter::from_fn(|| match s.next_job(t0 + ms(50)) {
        Some(Job::Command(c)) => Some(c),
        _ => None,
    })
    .collect();
    assert_eq!(order, vec!["write 1", "write 2", "read 1", "read 2"]);
    assert!(!s.has_commands());
    let p = poll(s.next_job(t0 + ms(100)));
    assert_eq!(p.read.range, AddrRange::new(3201, 1));
}

#[test]
fn while_a_poll_is_due_at_most_commands_in_row_commands_go_before_it() {
    let t0 = Instant::now();
    let mut s = Scheduler::new(
        &[device("atv", 2, ms(100), vec![AddrRange::new(3201, 1)])],
        t0,
    )
    .with_commands_in_row(2);
    for c in ["w1", "w2", "w3", "w4", "w5"] {
        s.push_write(c);
    }
    s.push_read("r1", None);
    let mut order = Vec::new();
    let mut now = t0;
    while let Some(job) = s.next_job(now) {
        match job {
            Job::Command(c) => order.push(c.to_owned()),
            Job::Poll(p) => {
                order.push("poll".to_owned());
                s.poll_done(p, true, now);
            }
        }
        now += ms(10);
    }
    // The poll due at t0 waits for two writes; the next falls due at t0 + 100 ms, after the
    // queue ran dry.
    assert_eq!(
        order,
        vec!["w1", "w2", "poll", "w3", "w4", "w5", "r1"],
        "{order:?}"
    );
    // With 0 a due poll always goes first.
    let mut s = Scheduler::new(
        &[device("atv", 2, ms(100), vec![AddrRange::new(3201, 1)])],
        t0,
    )
    .with_commands_in_row(0);
    s.push_write("w1");
    poll(s.next_job(t0));
}

#[test]
fn a_read_that_a_due_poll_covers_rides_on_it() {
    let t0 = Instant::now();
    let mut s = Scheduler::new(
        &[device("atv", 2, ms(100), vec![AddrRange::new(3100, 10)])],
        t0,
    );
    let key = |start, count| {
        Some(ReadKey {
            device: 0,
            table: Table::HoldingRegisters,
            range: AddrRange::new(start, count),
        })
    };
    s.push_read("covered", key(3102, 4));
    s.push_read("beyond", key(3108, 4));
    s.push_read("input table", None);
    // The first read is covered by the due poll: the poll goes and takes it along.
    let p = poll(s.next_job(t0));
    assert_eq!(s.riders(&p), vec!["covered"]);
    s.poll_done(p, true, t0 + ms(10));
    // Not covered, or no poll due: the reads go to the device themselves.
    assert_eq!(s.next_job(t0 + ms(10)), Some(Job::Command("beyond")));
    s.push_read("covered later", key(3100, 1));
    assert_eq!(s.next_job(t0 + ms(20)), Some(Job::Command("input table")));
    assert_eq!(s.next_job(t0 + ms(30)), Some(Job::Command("covered later")));
    assert!(!s.has_commands());
}

#[test]
fn only_the_devices_own_polls_put_it_offline_after_offline_after_failures() {
    let t0 = Instant::now();
    let mut d = device("atv", 2, ms(100), vec![AddrRange::new(3201, 1)]);
    d.offline_after = 3;
    let mut s: Scheduler<&str> = Scheduler::new(&[d], t0);
    // Any number of commands without an answer: still online, still polled.
    for i in 0..10 {
        assert_eq!(s.command_done(0, false, t0 + ms(i)), Transition::Unchanged);
    }
    assert!(s.is_online(0));
    // Two failed polls, an answer, two more: the count starts again.
    assert_eq!(s.observe(0, false, t0), Transition::Unchanged);
    assert_eq!(s.observe(0, false, t0), Transition::Unchanged);
    assert_eq!(s.observe(0, true, t0), Transition::Unchanged);
    assert_eq!(s.observe(0, false, t0), Transition::Unchanged);
    assert_eq!(s.observe(0, false, t0), Transition::Unchanged);
    assert!(s.is_online(0));
    // The third in a row.
    assert_eq!(
        s.observe(0, false, t0 + ms(300)),
        Transition::WentOffline { retry_in: ms(500) }
    );
    // Offline: a command sent as its probe that fails backs it off further, one answered brings
    // it back.
    assert_eq!(
        s.command_done(0, false, t0 + ms(800)),
        Transition::StillOffline { retry_in: ms(1000) }
    );
    assert_eq!(s.command_done(0, true, t0 + ms(1800)), Transition::CameBack);
}

#[test]
fn under_a_flood_of_commands_every_cycle_stays_within_its_bound() {
    let t0 = Instant::now();
    let devices = [
        device("a", 2, ms(100), vec![AddrRange::new(3201, 1)]),
        device("b", 3, ms(250), vec![AddrRange::new(3102, 4)]),
    ];
    let exchange = ms(20);
    for in_row in [0, 1, 2, 5] {
        let mut s: Scheduler<u32> = Scheduler::new(&devices, t0).with_commands_in_row(in_row);
        let mut now = t0;
        let mut commands = 0;
        // A closed-loop client: a new command as soon as one is answered, for 10 s of bus time.
        s.push_write(0);
        while now < t0 + ms(10_000) {
            match s.next_job(now) {
                Some(Job::Command(_)) => {
                    now += exchange;
                    commands += 1;
                    s.push_write(commands);
                }
                Some(Job::Poll(p)) => {
                    now += exchange;
                    s.poll_done(p, true, now);
                }
                None => now = s.next_wake().unwrap_or(now + ms(1)).max(now),
            }
        }
        for d in 0..devices.len() {
            for c in s.cycles(d) {
                let bound = cycle_bound(c.read.period, s.blocks(), in_row, exchange);
                let max = c.max.expect("polled");
                assert!(
                    max <= bound,
                    "{in_row} in a row: device {d} cycle {max:?} > bound {bound:?}"
                );
            }
        }
        // The clients still got most of the bus.
        assert!(commands > 300, "{in_row} in a row: {commands} commands");
    }
}

#[test]
fn polls_follow_their_periods_and_the_longest_due_goes_first() {
    let t0 = Instant::now();
    let devices = [
        device("fast", 2, ms(100), vec![AddrRange::new(3201, 1)]),
        device(
            "slow",
            3,
            ms(1000),
            vec![AddrRange::new(3102, 4), AddrRange::new(8000, 100)],
        ),
    ];
    let mut s: Scheduler<&str> = Scheduler::new(&devices, t0);
    // Every block is due at start: one read for the fast device, three for the slow one (the 100
    // words split 63 + 37 by the Altivar's limit).
    let mut first = Vec::new();
    while let Some(job) = s.next_job(t0) {
        let p = poll(Some(job));
        first.push((p.device, p.read.range));
        s.poll_done(p, true, t0);
    }
    assert_eq!(
        first,
        vec![
            (0, AddrRange::new(3201, 1)),
            (1, AddrRange::new(3102, 4)),
            (1, AddrRange::new(8000, 63)),
            (1, AddrRange::new(8063, 37))
        ]
    );
    assert_eq!(s.next_wake(), Some(t0 + ms(100)));
    assert!(s.next_job(t0 + ms(99)).is_none());
    let p = poll(s.next_job(t0 + ms(100)));
    assert_eq!(p.device, 0);
    // Finished late: the next poll is one period after it was due, not after it finished.
    s.poll_done(p, true, t0 + ms(130));
    assert_eq!(s.next_wake(), Some(t0 + ms(200)));
    // Far behind: due now, no burst of missed polls.
    let p = poll(s.next_job(t0 + ms(900)));
    s.poll_done(p, true, t0 + ms(900));
    assert_eq!(s.next_wake(), Some(t0 + ms(900)));
}

#[test]
fn a_silent_device_is_backed_off_and_cannot_starve_the_others() {
    let t0 = Instant::now();
    let devices = [
        device("ok", 2, ms(100), vec![AddrRange::new(3201, 1)]),
        device("gone", 3, ms(100), vec![AddrRange::new(1, 1)]),
    ];
    let mut s: Scheduler<&str> = Scheduler::new(&devices, t0);
    let ok = poll(s.next_job(t0));
    assert_eq!(s.poll_done(ok, true, t0), Transition::Unchanged);
    let gone = poll(s.next_job(t0));
    assert_eq!(gone.device, 1);
    // Its reply monitoring time ran out: offline, probed again after the minimum back-off.
    assert_eq!(
        s.poll_done(gone, false, t0 + ms(50)),
        Transition::WentOffline { retry_in: ms(500) }
    );
    assert!(!s.is_online(1));
    assert_eq!(s.device_index(3), Some(1));

    // For the next 500 ms only the good device is polled, every 100 ms.
    let mut now = t0 + ms(50);
    let mut polled = Vec::new();
    while now < t0 + ms(550) {
        match s.next_job(now) {
            Some(Job::Poll(p)) => {
                polled.push(p.device);
                s.poll_done(p, true, now);
            }
            Some(Job::Command(_)) => unreachable!(),
            None => now = s.next_wake().unwrap(),
        }
    }
    assert_eq!(polled, vec![0, 0, 0, 0, 0]);

    // The probe fails: the back-off doubles.
    let probe = poll(s.next_job(t0 + ms(550)));
    assert_eq!(probe.device, 1);
    assert_eq!(
        s.poll_done(probe, false, t0 + ms(600)),
        Transition::StillOffline { retry_in: ms(1000) }
    );
    assert_eq!(s.next_wake(), Some(t0 + ms(600)));
    // ... and caps at the maximum.
    assert_eq!(
        s.observe(1, false, t0 + ms(700)),
        Transition::StillOffline { retry_in: ms(2000) }
    );
    assert_eq!(
        s.observe(1, false, t0 + ms(800)),
        Transition::StillOffline { retry_in: ms(2000) }
    );

    // It answers a probe: back online, all its polls due at once, the back-off starts over.
    assert_eq!(s.observe(1, true, t0 + ms(3000)), Transition::CameBack);
    assert!(s.is_online(1));
    assert_eq!(
        s.observe(1, false, t0 + ms(3100)),
        Transition::WentOffline { retry_in: ms(500) }
    );
}

#[test]
fn queued_commands_can_be_drained_and_an_empty_line_never_wakes() {
    let t0 = Instant::now();
    let mut s = Scheduler::new(&[], t0);
    assert_eq!(s.next_wake(), None);
    s.push_write(1);
    s.push_read(2, None);
    assert_eq!(s.drain_commands(), vec![1, 2]);
    assert!(s.next_job(t0).is_none());
    assert_eq!(s.observe(7, false, t0), Transition::Unchanged);
}

#[test]
fn an_offline_device_takes_a_command_as_its_probe_once_the_back_off_ran_out() {
    let t0 = Instant::now();
    // Nobody polls this device: commands are its only probes.
    let mut d = DeviceSettings::new("ghost", 9, 9);
    d.backoff_min = ms(500);
    d.offline_after = 1;
    let mut s: Scheduler<&str> = Scheduler::new(&[d], t0);
    assert!(s.accepts_commands(0, t0));
    assert_eq!(
        s.observe(0, false, t0),
        Transition::WentOffline { retry_in: ms(500) }
    );
    assert!(!s.accepts_commands(0, t0 + ms(499)));
    assert!(s.accepts_commands(0, t0 + ms(500)));
    assert_eq!(s.observe(0, true, t0 + ms(600)), Transition::CameBack);
    assert!(!s.accepts_commands(1, t0));
}
