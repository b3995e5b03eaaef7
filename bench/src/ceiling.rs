//! One gateway's ceiling, the basis of a fleet's arithmetic (docs/fleet.md): 32 Modbus
//! master lines on plain ptys, 7 generic devices each (224, one unit id each), 100 000 u16 tags
//! polled every second with changing values, every change published on zenoh (a peer on
//! loopback) to one subscriber of `gw/bench/**`, `/metrics` served. Three rows from one run, beside
//! the 10 000-tag memory row; with `--baseline-gateway PATH` that binary is measured the same way
//! right after, its figures in the reference column:
//!
//! - RSS: VmRSS of the gateway, largest of the samples over the window (target <= 64 MiB);
//! - CPU per 10 000 tag updates a second: the process's CPU time (utime + stime of
//!   `/proc/PID/stat`) over the window, in cores, divided by the tag updates a second the devices
//!   answered, times 10 000 (target <= 0.06 core);
//! - zenoh samples received at the subscriber / tag updates offered, over the window (target at
//!   least 0.9; a newer value replaces one not yet published, so what is not received was
//!   superseded, not lost).

use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use gateway::sim::serve_modbus;
use proto_core::modbus::rtu::CharTiming;
use tokio_util::sync::CancellationToken;

use crate::child::free_port;
use crate::device::{Bus, FlatDevice};
use crate::process::{head, master_line, pty, start, zenoh_client, BAUD};
use crate::report::{Row, Target};
use crate::Plan;

const LINES: u8 = 32;
/// Seven devices a line: 224 in all, each with its own unit id (1..=247).
const DEVICES: u8 = 7;
const POINTS: usize = 100_000;
/// `[zenoh] tag_queue`: a pending value for every tag.
const TAG_QUEUE: usize = 131_072;

/// The names of the three rows (also for the failure rows).
pub(crate) const ROWS: [&str; 3] = [
    "RSS, 32 lines / 224 devices / 100 000 points",
    "CPU per 10 000 tag updates/s on zenoh, 100 000 points",
    "zenoh: tag samples / updates offered, 100 000 points",
];

/// The clock ticks per second of `/proc/PID/stat` (USER_HZ, 100 on Linux).
const USER_HZ: f64 = 100.0;

/// utime + stime of a process, in seconds.
fn cpu_seconds(pid: u32) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command name may hold spaces: the fields after its closing parenthesis.
    let rest = stat.rsplit_once(')')?.1;
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // After the name: state(0) ppid(1) ... utime(11) stime(12).
    let utime: f64 = fields.get(11)?.parse().ok()?;
    let stime: f64 = fields.get(12)?.parse().ok()?;
    Some((utime + stime) / USER_HZ)
}

/// What one run of a gateway binary measured.
struct Figures {
    /// Largest VmRSS and the anonymous part of that sample, KiB.
    rss: u64,
    anon: u64,
    /// Cores the process used over the window.
    cores: f64,
    /// Tag updates offered and samples received, a second.
    updates: f64,
    samples: f64,
    elapsed: f64,
    panicked: bool,
}

// === impl Figures ===

impl Figures {
    /// `v` as a row's score: none when the gateway panicked.
    fn valid(&self, v: f64) -> f64 {
        if self.panicked {
            f64::NAN
        } else {
            v
        }
    }

    /// Cores per 10 000 tag updates a second.
    fn per_10k(&self) -> f64 {
        self.cores / (self.updates / 10_000.0).max(f64::MIN_POSITIVE)
    }

    /// Samples received / tag updates offered.
    fn ratio(&self) -> f64 {
        self.samples / self.updates.max(1.0)
    }
}

fn mib(kib: u64) -> f64 {
    kib as f64 / 1024.0
}

/// The three rows of `bin`, each with the figure of `baseline` (run after it, the same way) as
/// its reference when one is given.
pub(crate) async fn ceiling(
    bin: &Path,
    baseline: Option<&Path>,
    plan: &Plan,
) -> std::io::Result<Vec<Row>> {
    let new = measure(bin, plan).await?;
    let old = match baseline {
        Some(path) => {
            eprintln!("  the same with the baseline {}", path.display());
            Some(measure(path, plan).await?)
        }
        None => None,
    };
    let reference = |f: &dyn Fn(&Figures) -> String| old.as_ref().map_or("-".into(), f);
    let beside = |f: &dyn Fn(&Figures) -> String| {
        old.as_ref()
            .map_or(String::new(), |o| format!("; the baseline: {}", f(o)))
    };
    let setup = format!(
        "{LINES} Modbus master lines on plain ptys, {DEVICES} generic devices each, {POINTS} u16 \
         tags polled every second, values changing, published on zenoh (peer on loopback, \
         tag_queue {TAG_QUEUE}) to one subscriber of gw/bench/**, /metrics served; window \
         {:.1} s{}",
        new.elapsed,
        baseline.map_or(String::new(), |p| format!(
            "; reference: {} measured after it the same way",
            p.display()
        ))
    );
    // The CPU grows with the samples published: per sample it compares runs whose share of
    // the updates published differs (the machine's other load decides it).
    let cpu = |f: &Figures| {
        format!(
            "{:.3} cores for {:.0} tag updates/s, {:.1} us per sample received",
            f.cores,
            f.updates,
            1e6 * f.cores / f.samples.max(1.0)
        )
    };
    let share = |f: &Figures| {
        format!(
            "{:.0} samples/s of {:.0} updates/s ({:.1} %)",
            f.samples,
            f.updates,
            100.0 * f.ratio()
        )
    };
    Ok(vec![
        Row {
            name: ROWS[0].to_owned(),
            measured: format!("{:.1} MiB", mib(new.rss)),
            reference: reference(&|o| format!("{:.1} MiB", mib(o.rss))),
            score: new.valid(if new.rss == 0 { f64::NAN } else { mib(new.rss) }),
            target: Target::at_most(64.0).with_unit(" MiB"),
            note: format!(
                "VmRSS of the gateway, largest of the samples; {setup}. Of it: anonymous {:.1} MiB{}",
                mib(new.anon),
                beside(&|o| format!("anonymous {:.1} MiB", mib(o.anon)))
            ),
        },
        Row {
            name: ROWS[1].to_owned(),
            measured: format!("{:.3} core", new.per_10k()),
            reference: reference(&|o| format!("{:.3} core", o.per_10k())),
            score: new.valid(new.per_10k()),
            target: Target::at_most(0.06).with_unit(" core"),
            note: format!(
                "the gateway's CPU time (utime + stime) over the window, in cores, per 10 000 tag \
                 updates a second: {}{}; {setup}",
                cpu(&new),
                beside(&cpu)
            ),
        },
        Row {
            name: ROWS[2].to_owned(),
            measured: format!("{:.3}", new.ratio()),
            reference: reference(&|o| format!("{:.3}", o.ratio())),
            score: new.valid(new.ratio()),
            target: Target::at_least(0.9),
            note: format!(
                "samples received a second / tag updates offered a second: {}{}; a newer value \
                 replaces one not yet published; {setup}",
                share(&new),
                beside(&share)
            ),
        },
    ])
}

/// One run of `bin`: the figures over the window once every device was read twice.
async fn measure(bin: &Path, plan: &Plan) -> std::io::Result<Figures> {
    let shutdown = CancellationToken::new();
    let _stop = shutdown.clone().drop_guard();
    let mut config = head("bench");
    let mut reads = Vec::new();
    let devices_total = usize::from(LINES) * usize::from(DEVICES);
    let per_device = POINTS / devices_total;
    let mut extra = POINTS % devices_total;
    let mut tags_of = Vec::new();
    for line in 0..LINES {
        let (path, port) = pty(&shutdown)?;
        let mut bus = Vec::new();
        let mut devices = Vec::new();
        for slave in 1..=DEVICES {
            let device = FlatDevice::new(slave).changing();
            let tags = per_device + usize::from(extra > 0);
            extra = extra.saturating_sub(1);
            reads.push(device.reads());
            tags_of.push(tags);
            bus.push(device);
            devices.push((slave, line * DEVICES + slave, tags));
        }
        tokio::spawn(serve_modbus(
            port,
            Bus(bus),
            CharTiming::new(BAUD, 11),
            shutdown.clone(),
        ));
        config.push_str(&master_line(&format!("l{line}"), &path, &devices, "1s"));
    }
    let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
    // A peer on loopback as `--zenoh-listen` makes it, with room for a pending value of every
    // tag (the default tag_queue of 4096 keys drops new keys beyond it, counted).
    config.push_str(&format!(
        "[zenoh]\nmode = \"peer\"\nlisten = [\"{endpoint}\"]\nconnect = []\n\
         multicast_scouting = false\ntag_queue = {TAG_QUEUE}\n\n"
    ));
    let gw = start(
        bin,
        "ceiling",
        config,
        &["--http".to_owned(), "127.0.0.1:0".to_owned()],
    )
    .await?;
    let session = zenoh_client(&endpoint).await?;
    let count = Arc::new(AtomicU64::new(0));
    let counter = Arc::clone(&count);
    let _subscriber = session
        .declare_subscriber("gw/bench/**")
        .callback(move |_| {
            counter.fetch_add(1, Ordering::Relaxed);
        })
        .await
        .map_err(|e| std::io::Error::other(e.to_string()))?;
    // Every device read completely at least twice (at most 125 registers a read).
    let blocks: Vec<u64> = tags_of.iter().map(|t| t.div_ceil(125) as u64).collect();
    let deadline = Instant::now() + Duration::from_secs(120);
    while reads
        .iter()
        .zip(&blocks)
        .any(|(r, b)| r.load(Ordering::Relaxed) < 2 * b)
    {
        if Instant::now() > deadline {
            return Err(std::io::Error::other("not every device was polled"));
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // Tag updates offered: every register of every read (each read changes every value).
    let offered = || -> f64 {
        reads
            .iter()
            .zip(&tags_of)
            .zip(&blocks)
            .map(|((r, &t), &b)| r.load(Ordering::Relaxed) as f64 * t as f64 / b as f64)
            .sum()
    };
    let pid = gw.pid();
    let window = plan.memory_window.max(Duration::from_secs(5));
    let (c0, o0, cpu0, t0) = (
        count.load(Ordering::Relaxed),
        offered(),
        cpu_seconds(pid),
        Instant::now(),
    );
    let mut rss = 0u64;
    let mut anon = 0u64;
    let stop = t0 + window;
    while Instant::now() < stop {
        if let Some(m) = gw.memory_kib() {
            if m.rss > rss {
                rss = m.rss;
                anon = m.anon;
            }
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let (c1, o1, cpu1, t1) = (
        count.load(Ordering::Relaxed),
        offered(),
        cpu_seconds(pid),
        Instant::now(),
    );
    let elapsed = t1.saturating_duration_since(t0).as_secs_f64();
    let samples = (c1 - c0) as f64 / elapsed;
    let updates = (o1 - o0) / elapsed;
    let cores = match (cpu0, cpu1) {
        (Some(a), Some(b)) => (b - a) / elapsed,
        _ => f64::NAN,
    };
    Ok(Figures {
        rss,
        anon,
        cores,
        updates,
        samples,
        elapsed,
        panicked: gw.panicked(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cpu_time_of_this_process_is_read() {
        assert!(cpu_seconds(std::process::id()).is_some_and(|s| s >= 0.0));
    }
}
