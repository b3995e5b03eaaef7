//! `gateway-bench`: measures the gateway and prints one table of ratios, each measured against its
//! reference in the same run, back to back.
//!
//! Rows (targets from the issue "Measure and harden"):
//! - poll rate of a master line / the physical best case, N = 1, 10, 60, 125 registers at 9600,
//!   19200, 38400 and 115200 Bd over a paced link (`poll`), and the requests started less than
//!   t3.5 after the previous frame;
//! - one dead device among ten: the others' poll rate once it is offline / their rate with none
//!   dead, and how soon it is polled again once it answers (`dead`);
//! - Modbus TCP cached FC 03 of 125 registers: throughput and p99 against a bare tokio-modbus
//!   server, 1 and 16 connections (`tcp`);
//! - a write through Modbus TCP to a device: latency minus its serial time (`tcp`);
//! - closed loop: a closed-loop FC 06 writer and a closed-loop on-demand reader against one
//!   polled device while a third client reads its cached values: cached reads answered, the
//!   oldest cached value and the achieved poll cycle against the group's bound (`closed`);
//! - transparent forwarding: a declared device's poll rate with and without two clients hammering
//!   a forwarded unit on the same line, and the cached reads answered meanwhile (`transparent`);
//! - zenoh: serial frame end to subscriber p99, sustained samples/s (`process`, real binary);
//! - resident memory with 4 lines, 32 devices, 10 000 points (`process`, real binary);
//! - zenoh bounds: log lines and counted refusals of a flood of refused puts, resident memory
//!   growth for an 8 MiB and a 256 MiB put (`zenoh_bounds`, real binary).
//! - `/metrics` with `[http] tag_metrics = true` at 10 000 tags: scrape time and size
//!   (`tag_metrics`, real binary);
//! - the mailbox journal: 3964R telegrams per second at 9600 Bd with and without `journal`, and
//!   the journal's largest size against its bound (`telegram`);
//! - reading the configuration at 10 000 and 100 000 tags: exec to serving, the peak resident
//!   memory of the start, of a SIGHUP re-read and of a REST replace, and the resident memory after
//!   a re-read (`startup`, real binary; `--baseline-gateway` runs a second binary beside it).
//!
//! Run `cargo build --release` first (the zenoh and memory rows start `target/release/gateway`),
//! then `target/release/gateway-bench` (about 7 minutes) or `--quick` (about a minute). Progress
//! goes to stderr, the table to stdout.

mod ceiling;
mod child;
mod closed;
mod dead;
mod device;
mod mbap;
mod poll;
mod process;
mod report;
mod startup;
mod stats;
mod tag_metrics;
mod tap;
mod tcp;
mod telegram;
mod tls;
mod transparent;
mod zenoh_bounds;

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::{Parser, ValueEnum};

use report::Row;

/// Command line.
#[derive(Debug, Parser)]
#[command(
    name = "gateway-bench",
    about = "Measures the gateway against the physical best case and a bare reference server"
)]
struct Args {
    /// A short run (about a minute): fewer cycles, shorter windows, wider noise.
    #[arg(long)]
    quick: bool,
    /// The gateway binary for the zenoh and memory rows (default: next to this executable).
    #[arg(long, value_name = "PATH")]
    gateway: Option<PathBuf>,
    /// A second gateway binary (the previous main, say) measured beside the first in the same
    /// run, for the rows that start the real binary (ceiling, zenoh latency, start-up); its
    /// figures go in the reference column or in rows of their own.
    #[arg(long, value_name = "PATH")]
    baseline_gateway: Option<PathBuf>,
    /// Only these groups of rows (comma separated; default: all).
    #[arg(long, value_enum, value_delimiter = ',')]
    only: Vec<Group>,
    /// Frames each line's frame monitor keeps in the poll and memory rows (0: no monitor; the
    /// gateway's default otherwise), to measure what the monitor costs.
    #[arg(long, value_name = "N")]
    monitor_frames: Option<usize>,
}

/// Frames each line's frame monitor keeps in the poll and memory rows (`--monitor-frames`).
static MONITOR_FRAMES: std::sync::OnceLock<usize> = std::sync::OnceLock::new();

/// The frame monitor's size for the rows' lines: `--monitor-frames`, else the gateway's default.
pub(crate) fn monitor_frames() -> usize {
    *MONITOR_FRAMES.get_or_init(|| gateway::line::DEFAULT_MONITOR_FRAMES)
}

/// Groups of rows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum Group {
    /// Poll rate against the best case (16 rows and the t3.5 row).
    Poll,
    /// One dead device among ten, three among nine.
    Dead,
    /// Cached Modbus TCP reads against the bare server.
    Tcp,
    /// Writes through Modbus TCP.
    Write,
    /// A closed-loop writer and on-demand reader beside a cached reader.
    Closed,
    /// A declared device's poll rate while a client hammers a transparently forwarded unit.
    Transparent,
    /// zenoh latency and throughput.
    Zenoh,
    /// Resident memory.
    Memory,
    /// One gateway's ceiling: 32 lines, 100 000 tags on zenoh (RSS, CPU, samples/s).
    Ceiling,
    /// What a zenoh peer can cost: a flood of refused puts, 8 MiB and 256 MiB puts.
    Bounds,
    /// The mailbox journal's cost and size.
    Journal,
    /// `/metrics` with the process values of 10 000 tags.
    TagMetrics,
    /// Reading the configuration at 10 000 and 100 000 tags: time to serve, peak memory of the
    /// start and of re-reads, memory after a re-read.
    Startup,
}

/// How long each measurement runs.
#[derive(Clone, Debug)]
pub(crate) struct Plan {
    /// Shortest window of a poll-rate run.
    pub(crate) poll_window: Duration,
    /// Poll cycles a poll-rate run lasts at least.
    pub(crate) poll_cycles: u32,
    /// Window of the dead-device rows with none dead.
    pub(crate) alive_window: Duration,
    /// Window of the dead-device rows with one dead, from the moment it was declared offline.
    pub(crate) dead_window: Duration,
    /// How often the dead device answers again in the recovery row.
    pub(crate) recoveries: usize,
    /// Rounds of the cached-read rows (each server once a round).
    pub(crate) tcp_rounds: usize,
    /// Length of one server's turn in a round.
    pub(crate) tcp_slice: Duration,
    /// Writes of the write-latency row.
    pub(crate) writes: usize,
    /// How long the closed-loop clients run.
    pub(crate) closed_window: Duration,
    /// Telegrams of the zenoh latency row.
    pub(crate) telegrams: usize,
    /// Window of the zenoh throughput row.
    pub(crate) zenoh_window: Duration,
    /// How long the memory row samples.
    pub(crate) memory_window: Duration,
    /// Rounds of the journal rows (each with and without a journal).
    pub(crate) journal_rounds: usize,
    /// How long one journal run counts telegrams.
    pub(crate) journal_window: Duration,
}

impl Plan {
    fn full() -> Self {
        Self {
            poll_window: Duration::from_secs(3),
            poll_cycles: 40,
            alive_window: Duration::from_secs(30),
            // One minute: twelve probes at the default back-off, one of them waiting the full
            // reply monitoring time, as in every following minute.
            dead_window: Duration::from_secs(60),
            recoveries: 3,
            // Short slices, many alternations: the rate of either server drifts by 15 % from
            // second to second on a shared machine, and 40 pairs average that out better than 10.
            tcp_rounds: 40,
            tcp_slice: Duration::from_millis(250),
            writes: 500,
            closed_window: Duration::from_secs(20),
            telegrams: 1000,
            zenoh_window: Duration::from_secs(5),
            memory_window: Duration::from_secs(3),
            // Two rounds of 45 s: about 1,700 telegrams each, so the journal is compacted
            // while the line runs.
            journal_rounds: 2,
            journal_window: Duration::from_secs(45),
        }
    }

    fn quick() -> Self {
        Self {
            poll_window: Duration::from_millis(500),
            poll_cycles: 8,
            alive_window: Duration::from_secs(4),
            dead_window: Duration::from_secs(4),
            recoveries: 1,
            tcp_rounds: 2,
            tcp_slice: Duration::from_millis(500),
            writes: 60,
            closed_window: Duration::from_secs(4),
            telegrams: 100,
            zenoh_window: Duration::from_secs(2),
            memory_window: Duration::from_secs(1),
            journal_rounds: 1,
            journal_window: Duration::from_secs(4),
        }
    }
}

fn main() -> ExitCode {
    let args = Args::parse();
    if let Some(n) = args.monitor_frames {
        let _ = MONITOR_FRAMES.set(n);
    }
    let runtime = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("gateway-bench: cannot start the runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    let rows = runtime.block_on(run(&args));
    println!("{}", machine(args.quick));
    print!("{}", report::render(&rows));
    if rows.iter().all(Row::passed) {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    }
}

async fn run(args: &Args) -> Vec<Row> {
    let plan = if args.quick {
        Plan::quick()
    } else {
        Plan::full()
    };
    let wanted = |g: Group| args.only.is_empty() || args.only.contains(&g);
    let bin = child::gateway_bin(args.gateway.as_deref());
    let mut rows = Vec::new();
    let failed = |name: &str, e: std::io::Error| poll::failed(name.to_owned(), &e.to_string());

    if wanted(Group::Poll) {
        eprintln!("poll rate against the best case");
        let (mut violations, mut requests, mut own) = (0, 0, Vec::new());
        for baud in poll::BAUDS {
            for n in poll::REGISTERS {
                match poll::poll_rate(baud, n, &plan).await {
                    Ok(run) => {
                        violations += run.violations;
                        requests += run.requests;
                        own.extend(run.own);
                        push(&mut rows, run.row);
                    }
                    Err(e) => push(&mut rows, failed(&format!("poll rate {baud} Bd, N={n}"), e)),
                }
            }
        }
        push(
            &mut rows,
            Row {
                name: "requests started < t3.5 after the previous frame".into(),
                measured: violations.to_string(),
                reference: format!("of {requests}"),
                score: violations as f64,
                target: report::Target::at_most(0.0),
                note: "every request of the 16 poll-rate runs, as the tap between line and link \
                       saw it (master's write after the answer's last byte reached it)"
                    .into(),
            },
        );
        push(&mut rows, poll::own_time_row(&own));
    }
    if wanted(Group::Dead) {
        eprintln!("one dead device among ten");
        // A reply monitoring time set for the line's devices, and the CP's default (003 6.4.2.1)
        // with the recovery row.
        for (timeout, recover) in [
            (Duration::from_millis(200), false),
            (Duration::from_secs(2), true),
        ] {
            match dead::dead_device(&plan, dead::ONE_OF_TEN, timeout, recover).await {
                Ok(r) => r.into_iter().for_each(|row| push(&mut rows, row)),
                Err(e) => push(&mut rows, failed("1 dead device of 10", e)),
            }
        }
        eprintln!("three dead devices among nine");
        let timeout = gateway::protocols::DEFAULT_REPLY_TIMEOUT;
        match dead::dead_device(&plan, dead::THREE_OF_NINE, timeout, false).await {
            Ok(r) => r.into_iter().for_each(|row| push(&mut rows, row)),
            Err(e) => push(&mut rows, failed("3 dead devices of 9", e)),
        }
    }
    if wanted(Group::Tcp) {
        eprintln!("Modbus TCP cached reads against a bare tokio-modbus server");
        match tcp::cached_reads(&plan).await {
            Ok(r) => r.into_iter().for_each(|row| push(&mut rows, row)),
            Err(e) => push(&mut rows, failed("TCP FC03 x125 cached", e)),
        }
        eprintln!("Modbus TCP cached reads over TLS (Modbus/TCP Security) against plain TCP");
        match tcp::cached_reads_tls(&plan).await {
            Ok(r) => r.into_iter().for_each(|row| push(&mut rows, row)),
            Err(e) => push(&mut rows, failed("TLS FC03 x125 cached", e)),
        }
    }
    if wanted(Group::Write) {
        eprintln!("writes through Modbus TCP");
        match tcp::write_latency(&plan).await {
            Ok(r) => r.into_iter().for_each(|row| push(&mut rows, row)),
            Err(e) => push(&mut rows, failed("TCP write to a device", e)),
        }
    }
    if wanted(Group::Closed) {
        eprintln!("closed-loop writer and on-demand reader beside a cached reader");
        match closed::closed_loop(&plan).await {
            Ok(r) => r.into_iter().for_each(|row| push(&mut rows, row)),
            Err(e) => push(&mut rows, failed("closed loop", e)),
        }
    }
    if wanted(Group::Transparent) {
        eprintln!("a forwarded unit hammered beside a declared device's polls");
        match transparent::transparent(&plan).await {
            Ok(r) => r.into_iter().for_each(|row| push(&mut rows, row)),
            Err(e) => push(&mut rows, failed("transparent", e)),
        }
    }
    if wanted(Group::Zenoh) {
        eprintln!("zenoh (gateway binary {})", bin.display());
        match process::zenoh_latency(&bin, args.baseline_gateway.as_deref(), &plan).await {
            Ok(r) => r.into_iter().for_each(|row| push(&mut rows, row)),
            Err(e) => push(
                &mut rows,
                failed("zenoh: serial frame end -> subscriber", e),
            ),
        }
        let row = process::zenoh_throughput(&bin, &plan)
            .await
            .unwrap_or_else(|e| failed("zenoh: tag samples/s", e));
        push(&mut rows, row);
    }
    if wanted(Group::Memory) {
        eprintln!("resident memory (gateway binary {})", bin.display());
        let row = process::memory(&bin, &plan)
            .await
            .unwrap_or_else(|e| failed("RSS, 4 lines / 32 devices / 10 000 points", e));
        push(&mut rows, row);
    }
    if wanted(Group::Ceiling) {
        eprintln!(
            "ceiling, 32 lines / 100 000 points (gateway binary {})",
            bin.display()
        );
        match ceiling::ceiling(&bin, args.baseline_gateway.as_deref(), &plan).await {
            Ok(r) => r.into_iter().for_each(|row| push(&mut rows, row)),
            Err(e) => ceiling::ROWS.iter().for_each(|name| {
                push(
                    &mut rows,
                    failed(name, std::io::Error::other(e.to_string())),
                )
            }),
        }
    }
    if wanted(Group::Bounds) {
        eprintln!("zenoh bounds (gateway binary {})", bin.display());
        let seconds = if args.quick { 3 } else { 10 };
        match zenoh_bounds::flood(&bin, seconds).await {
            Ok(r) => r.into_iter().for_each(|row| push(&mut rows, row)),
            Err(e) => push(&mut rows, failed("zenoh flood", e)),
        }
        for mib in [8, 256] {
            let row = zenoh_bounds::large_put(&bin, mib)
                .await
                .unwrap_or_else(|e| failed(&format!("zenoh {mib} MiB put"), e));
            push(&mut rows, row);
        }
    }
    if wanted(Group::TagMetrics) {
        eprintln!(
            "/metrics with tag_metrics (gateway binary {})",
            bin.display()
        );
        let row = tag_metrics::scrape(&bin, &plan)
            .await
            .unwrap_or_else(|e| failed("/metrics with tag_metrics, 10000 tags", e));
        push(&mut rows, row);
    }
    if wanted(Group::Startup) {
        eprintln!(
            "reading the configuration (gateway binary {})",
            bin.display()
        );
        let baseline = args.baseline_gateway.as_deref();
        startup::startup(&bin, baseline)
            .await
            .into_iter()
            .for_each(|row| push(&mut rows, row));
    }
    if wanted(Group::Journal) {
        eprintln!("mailbox journal: 3964R telegrams/s with and without");
        match telegram::journal_cost(&plan).await {
            Ok(r) => r.into_iter().for_each(|row| push(&mut rows, row)),
            Err(e) => push(&mut rows, failed("3964R telegrams/s, journal / none", e)),
        }
    }
    rows
}

/// Adds a row and shows it on stderr as progress.
fn push(rows: &mut Vec<Row>, row: Row) {
    eprintln!(
        "  {} {}: {} ({:.3})",
        if row.passed() { "PASS" } else { "FAIL" },
        row.name,
        row.measured,
        row.score
    );
    rows.push(row);
}

/// The run's date and machine: `uname -a`, CPUs, CPU model.
fn machine(quick: bool) -> String {
    let uname = std::process::Command::new("uname")
        .arg("-a")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_owned())
        .unwrap_or_else(|_| "?".into());
    let cpus = std::thread::available_parallelism().map_or(0, std::num::NonZero::get);
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|c| {
            c.lines()
                .find_map(|l| l.strip_prefix("model name"))
                .map(|v| v.trim_start_matches([' ', '\t', ':']).to_owned())
        })
        .unwrap_or_else(|| "?".into());
    format!(
        "gateway-bench {} run, {}\nmachine: {uname}\nCPUs: {cpus}, model: {model}\n",
        if quick { "quick" } else { "full" },
        utc_now(),
    )
}

/// Now as `YYYY-MM-DD HH:MM:SS UTC` (civil date from days since 1970, Howard Hinnant's method).
fn utc_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02} {:02}:{:02}:{:02} UTC",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}
