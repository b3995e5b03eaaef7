//! Rows measured on the real `gateway` binary with generated configs: zenoh delivery latency and
//! sustained samples, and resident memory with 4 lines, 32 devices and 10 000 points.
//!
//! The serial lines of the child gateway are plain pty pairs; the benchmark holds the other ends
//! and runs the simulated devices on them, or writes telegrams into them.

use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use gateway::sim::serve_modbus;
use proto_core::modbus::rtu::CharTiming;
use tokio::io::AsyncWriteExt;
use tokio_serial::SerialStream;
use tokio_util::sync::CancellationToken;

use crate::child::{free_port, Gateway};
use crate::device::{Bus, FlatDevice};
use crate::mbap::Client;
use crate::report::{Row, Target};
use crate::stats::{ms, percentile, tail};
use crate::Plan;

/// The baud rate of every generated line (the pty ignores it; the engines time by it).
pub(crate) const BAUD: u32 = 115_200;
/// The unit id of the telegram line's mailbox.
const MAILBOX_UNIT: u8 = 100;
/// The mailbox's acknowledge register (gateway::mailbox::layout::ACK).
const ACK: u16 = gateway::mailbox::layout::ACK;
/// The sequence number of the oldest telegram waiting (gateway::mailbox::layout::RX_SEQ).
const RX_SEQ: u16 = gateway::mailbox::layout::RX_SEQ;

/// Releases every telegram waiting in the mailbox. The mailbox releases only its oldest
/// telegram (an acknowledge of any other is refused), so each is read and acknowledged in turn.
async fn drain_mailbox(mailbox: &mut Client) -> std::io::Result<()> {
    loop {
        let oldest = mailbox.read_one(MAILBOX_UNIT, RX_SEQ).await?;
        if oldest == 0 {
            return Ok(());
        }
        mailbox.write_one(MAILBOX_UNIT, ACK, oldest).await?;
    }
}

/// A plain pty pair: the path for the gateway, the other end for the benchmark. The gateway's end
/// is kept open until `shutdown` so that the benchmark's end never hangs up.
pub(crate) fn pty(shutdown: &CancellationToken) -> std::io::Result<(String, SerialStream)> {
    let (ours, theirs) = SerialStream::pair().map_err(std::io::Error::from)?;
    let path = tokio_serial::SerialPort::name(&theirs)
        .ok_or_else(|| std::io::Error::other("the pty has no path"))?;
    let stop = shutdown.clone();
    tokio::spawn(async move {
        let _keep = theirs;
        stop.cancelled().await;
    });
    Ok((path, ours))
}

/// The gateway's own sections: every listener on loopback, on a port the kernel picks (the
/// REST API would otherwise take its default port 8080 on loopback, which another gateway or
/// bench run on the machine may hold).
pub(crate) fn head(name: &str) -> String {
    format!("[gateway]\nname = \"{name}\"\n\n[modbus_tcp]\nlisten = \"127.0.0.1:0\"\nmax_connections = 64\n\n[http]\nlisten = \"127.0.0.1:0\"\n\n")
}

/// A Modbus master line with generic devices, each with `tags[i]` u16 tags on holding registers
/// from 0, all in one poll group of `period`.
pub(crate) fn master_line(
    name: &str,
    path: &str,
    devices: &[(u8, u8, usize)],
    period: &str,
) -> String {
    let mut s = format!(
        "[lines.{name}]\nport = \"{path}\"\nprotocol = \"modbus-master-rtu\"\nbaud = {BAUD}\n\
         parity = \"even\"\nreply_timeout = \"200ms\"\nmonitor_frames = {}\n\n",
        crate::monitor_frames()
    );
    for &(slave, unit, tags) in devices {
        let device = format!("lines.{name}.devices.d{slave}");
        let _ = writeln!(
            s,
            "[{device}]\nprofile = \"generic\"\naddress = {slave}\nunit_id = {unit}"
        );
        s.push_str("tags = [\n");
        for t in 0..tags {
            let _ = writeln!(
                s,
                "  {{ name = \"t{t}\", table = \"holding\", address = {t} }},"
            );
        }
        s.push_str("]\n\n");
        let _ = writeln!(
            s,
            "[[{device}.poll]]\nname = \"all\"\nperiod = \"{period}\""
        );
        s.push_str("tags = [");
        for t in 0..tags {
            let _ = write!(s, "\"t{t}\",");
        }
        s.push_str("]\n\n");
    }
    s
}

/// Starts the gateway on a written config with zenoh on `endpoint` (blocking start on a worker
/// that may block).
pub(crate) async fn start(
    bin: &Path,
    name: &str,
    config: String,
    extra: &[String],
) -> std::io::Result<Gateway> {
    let dir = std::env::temp_dir().join(format!("gateway-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let file = dir.join(format!("{name}.toml"));
    std::fs::write(&file, config)?;
    let mut args = vec![
        "run".to_owned(),
        "--config".to_owned(),
        file.display().to_string(),
    ];
    args.extend_from_slice(extra);
    let bin = bin.to_owned();
    tokio::task::spawn_blocking(move || Gateway::start(&bin, &args))
        .await
        .map_err(std::io::Error::other)?
}

/// A zenoh client session connected to `endpoint`, multicast scouting off.
pub(crate) async fn zenoh_client(endpoint: &str) -> std::io::Result<zenoh::Session> {
    let err = |e: zenoh::Error| std::io::Error::other(e.to_string());
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", "\"client\"").map_err(err)?;
    config
        .insert_json5("connect/endpoints", &format!("[\"{endpoint}\"]"))
        .map_err(err)?;
    config
        .insert_json5("scouting/multicast/enabled", "false")
        .map_err(err)?;
    zenoh::open(config).await.map_err(err)
}

/// A received telegram: when, and its bytes.
type Received = (Instant, Vec<u8>);

/// Serial frame end (the telegram's end character written into the pty) to the subscriber's
/// callback: p99 and max, for `bin` and, beside it in the same run, for `baseline` (the previous
/// gateway). Both gateways run at once and take the telegrams in turn, one each, so that the
/// machine's load of the moment hits both alike.
pub(crate) async fn zenoh_latency(
    bin: &Path,
    baseline: Option<&Path>,
    plan: &Plan,
) -> std::io::Result<Vec<Row>> {
    let shutdown = CancellationToken::new();
    let _stop = shutdown.clone().drop_guard();
    let mut ours = Probe::start(bin, &shutdown).await?;
    let mut base = match baseline {
        Some(path) => Some(Probe::start(path, &shutdown).await),
        None => None,
    };
    for i in 0..plan.telegrams {
        ours.send(i).await?;
        if let Some(Ok(b)) = &mut base {
            if let Err(e) = b.send(i).await {
                base = Some(Err(e));
            }
        }
    }
    let ours = ours.finish().await?;
    let base = match base {
        Some(Ok(b)) => Some(b.finish().await),
        Some(Err(e)) => Some(Err(e)),
        None => None,
    };
    let mut note = format!(
        "{} telegrams of 8 bytes on an ASCII line (end character ETX), one at a time, each \
         acknowledged in the mailbox; {}; lost {}; subscriber: zenoh client on tcp/127.0.0.1, \
         scouting off",
        plan.telegrams,
        tail(&ours.latencies),
        ours.lost,
    );
    if let Some(stalls) = &ours.stalls {
        let _ = write!(note, "; {}", stalls.lines().next().unwrap_or_default());
    }
    match &base {
        Some(Ok(b)) => {
            let _ = write!(
                note,
                "; previous gateway, telegrams in turn with this one: {}; lost {}",
                tail(&b.latencies),
                b.lost
            );
        }
        Some(Err(e)) => {
            let _ = write!(note, "; previous gateway failed: {e}");
        }
        None => {}
    }
    let row = |what: &str, p: f64, limit: f64, note: String| {
        let value = percentile(&ours.latencies, p);
        Row {
            name: format!("zenoh: serial frame end -> subscriber, {what}"),
            measured: ms(value),
            reference: match &base {
                Some(Ok(b)) => format!("{} previous", ms(percentile(&b.latencies, p))),
                _ => "-".into(),
            },
            score: if ours.lost == 0 && !ours.panicked {
                value.as_secs_f64() * 1e3
            } else {
                f64::NAN
            },
            target: Target::at_most(limit).with_unit(" ms"),
            note,
        }
    };
    Ok(vec![
        row("p99", 99.0, 0.5, note),
        row("max", 100.0, 2.0, String::new()),
    ])
}

/// What one gateway binary delivered in the zenoh latency run.
struct Deliveries {
    latencies: Vec<Duration>,
    lost: usize,
    panicked: bool,
    /// Its stall table (a gateway built with `stall-watch`).
    stalls: Option<String>,
}

/// One gateway of the zenoh latency run: its telegram line's pty, a subscriber of the line's
/// telegrams, a Modbus TCP client of its mailbox.
struct Probe {
    bin: std::path::PathBuf,
    gw: Gateway,
    port: SerialStream,
    rx: tokio::sync::mpsc::UnboundedReceiver<Received>,
    mailbox: Client,
    _session: zenoh::Session,
    _subscriber: zenoh::pubsub::Subscriber<()>,
    latencies: Vec<Duration>,
    lost: usize,
}

// === impl Probe ===

impl Probe {
    /// Starts the gateway `bin` and waits until its telegrams reach the subscriber.
    async fn start(bin: &Path, shutdown: &CancellationToken) -> std::io::Result<Self> {
        let (path, mut port) = pty(shutdown)?;
        let config = format!(
            "{}[lines.tg]\nport = \"{path}\"\nprotocol = \"ascii\"\nbaud = {BAUD}\n\
             data_bits = 8\nparity = \"none\"\nstop_bits = 1\nend_criterion = \"end-chars\"\n\
             end_chars = [0x03]\nunit_id = {MAILBOX_UNIT}\n",
            head("bench")
        );
        let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
        let gw = start(
            bin,
            "zenoh-latency",
            config,
            &["--zenoh-listen".to_owned(), endpoint.clone()],
        )
        .await?;
        let session = zenoh_client(&endpoint).await?;
        let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<Received>();
        let subscriber = session
            .declare_subscriber("gw/bench/tg/rx")
            .callback(move |sample| {
                let at = Instant::now();
                let _ = tx.send((at, sample.payload().to_bytes().into_owned()));
            })
            .await
            .map_err(|e| std::io::Error::other(e.to_string()))?;
        let mut mailbox = Client::connect(gw.modbus_tcp).await?;

        // Until the subscription has reached the gateway.
        let deadline = Instant::now() + Duration::from_secs(20);
        loop {
            port.write_all(b"W\x03").await?;
            if let Ok(Some(_)) = tokio::time::timeout(Duration::from_millis(200), rx.recv()).await {
                break;
            }
            if Instant::now() > deadline {
                return Err(std::io::Error::other(format!(
                    "no telegram reached the subscriber:\n{}",
                    gw.output()
                )));
            }
        }
        // Warm-up telegrams sent before the subscription was in place are waiting in the
        // mailbox without having reached the subscriber: release them all.
        tokio::time::sleep(Duration::from_millis(300)).await;
        while rx.try_recv().is_ok() {}
        drain_mailbox(&mut mailbox).await?;
        Ok(Self {
            bin: bin.to_owned(),
            gw,
            port,
            rx,
            mailbox,
            _session: session,
            _subscriber: subscriber,
            latencies: Vec::new(),
            lost: 0,
        })
    }

    /// Telegram `i`: written, waited for at the subscriber, released in the mailbox.
    async fn send(&mut self, i: usize) -> std::io::Result<()> {
        let telegram = format!("T{i:06}\x03");
        self.port.write_all(telegram.as_bytes()).await?;
        let sent = Instant::now();
        let wanted = format!("T{i:06}");
        let got = loop {
            match tokio::time::timeout(Duration::from_secs(2), self.rx.recv()).await {
                Ok(Some(r)) if r.1.starts_with(wanted.as_bytes()) => break Some(r),
                Ok(Some(_)) => continue,
                _ => break None,
            }
        };
        match got {
            Some((at, _)) => {
                self.latencies.push(at.saturating_duration_since(sent));
                // Release the telegram (and any before it) so that the mailbox never fills up.
                drain_mailbox(&mut self.mailbox).await?;
            }
            None => self.lost += 1,
        }
        tokio::time::sleep(Duration::from_millis(2)).await;
        Ok(())
    }

    /// Stops the gateway: what it delivered, and its stall table.
    async fn finish(self) -> std::io::Result<Deliveries> {
        let panicked = self.gw.panicked();
        let gw = self.gw;
        let stalls = tokio::task::spawn_blocking(move || gw.stalls())
            .await
            .map_err(std::io::Error::other)?;
        if let Some(table) = &stalls {
            eprintln!("  stalls of {}:\n{table}", self.bin.display());
        }
        Ok(Deliveries {
            latencies: self.latencies,
            lost: self.lost,
            panicked,
            stalls,
        })
    }
}

/// Tag samples per second a subscriber receives while two lines poll 125 changing registers as
/// fast as they can.
pub(crate) async fn zenoh_throughput(bin: &Path, plan: &Plan) -> std::io::Result<Row> {
    const LINES: u8 = 2;
    const TAGS: usize = 125;
    let name = "zenoh: tag samples/s sustained".to_owned();
    let shutdown = CancellationToken::new();
    let _stop = shutdown.clone().drop_guard();
    let mut config = head("bench");
    let mut reads = Vec::new();
    for line in 0..LINES {
        let (path, port) = pty(&shutdown)?;
        let device = FlatDevice::new(1).changing();
        reads.push(device.reads());
        tokio::spawn(serve_modbus(
            port,
            device,
            CharTiming::new(BAUD, 11),
            shutdown.clone(),
        ));
        config.push_str(&master_line(
            &format!("m{line}"),
            &path,
            &[(1, line + 1, TAGS)],
            "10ms",
        ));
    }
    let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
    let gw = start(
        bin,
        "zenoh-throughput",
        config,
        &["--zenoh-listen".to_owned(), endpoint.clone()],
    )
    .await?;
    let session = zenoh_client(&endpoint).await?;
    let count = Arc::new(AtomicU64::new(0));
    let counter = Arc::clone(&count);
    let _subscriber = session
        .declare_subscriber("gw/bench/*/d1/*")
        .callback(move |_| {
            counter.fetch_add(1, Ordering::Relaxed);
        })
        .await
        .map_err(|e| std::io::Error::other(e.to_string()))?;
    tokio::time::sleep(Duration::from_secs(2)).await;
    let offered = || reads.iter().map(|r| r.load(Ordering::Relaxed)).sum::<u64>();
    let (c0, r0, t0) = (count.load(Ordering::Relaxed), offered(), Instant::now());
    tokio::time::sleep(plan.zenoh_window).await;
    let (c1, r1, t1) = (count.load(Ordering::Relaxed), offered(), Instant::now());
    let elapsed = t1.saturating_duration_since(t0).as_secs_f64();
    let rate = (c1 - c0) as f64 / elapsed;
    let changes = (r1 - r0) as f64 * TAGS as f64 / elapsed;
    let panicked = gw.panicked();
    drop(gw);
    Ok(Row {
        name,
        measured: format!("{rate:.0}/s"),
        reference: "-".into(),
        score: if panicked { f64::NAN } else { rate },
        target: Target::at_least(10_000.0).with_unit("/s"),
        note: format!(
            "{LINES} lines x 1 device x {TAGS} u16 tags polled every 10 ms on plain ptys, every \
             poll changing every tag: {changes:.0} tag changes/s offered in {elapsed:.1} s, \
             {:.1} % of them received (a newer value replaces one not yet published, so the \
             figure is what the bridge sustained at this offer)",
            100.0 * rate / changes.max(1.0)
        ),
    })
}

/// Resident memory of the gateway with 4 lines, 32 devices and 10 000 tags, all polled; once
/// with the zenoh bridge (the row) and once without (the note), back to back.
pub(crate) async fn memory(bin: &Path, plan: &Plan) -> std::io::Result<Row> {
    let name = "RSS, 4 lines / 32 devices / 10 000 points".to_owned();
    let with = measure_memory(bin, plan, true).await?;
    let without = measure_memory(bin, plan, false).await?;
    let mib = |kib: u64| kib as f64 / 1024.0;
    Ok(Row {
        name,
        measured: format!("{:.1} MiB", mib(with.rss)),
        reference: "-".into(),
        score: if with.panicked || without.panicked || with.rss == 0 {
            f64::NAN
        } else {
            mib(with.rss)
        },
        target: Target::at_most(32.0).with_unit(" MiB"),
        note: format!(
            "VmRSS of the gateway process, largest of the samples over {:.1} s once every device \
             was polled twice; {MEMORY_LINES} Modbus master lines on plain ptys, {MEMORY_DEVICES} \
             generic devices each, {MEMORY_POINTS} u16 tags polled every second, values changing, \
             published on zenoh (peer on loopback), /metrics served. Of it: anonymous {:.1} MiB, \
             file-backed (the binary's code) {:.1} MiB, peak {:.1} MiB. The same without zenoh \
             and HTTP: {:.1} MiB (anonymous {:.1} MiB)",
            plan.memory_window.as_secs_f64(),
            mib(with.anon),
            mib(with.rss.saturating_sub(with.anon)),
            mib(with.hwm),
            mib(without.rss),
            mib(without.anon),
        ),
    })
}

const MEMORY_LINES: u8 = 4;
const MEMORY_DEVICES: u8 = 8;
const MEMORY_POINTS: usize = 10_000;

/// What the memory row read from `/proc/PID/status`, in KiB.
struct Memory {
    rss: u64,
    anon: u64,
    hwm: u64,
    panicked: bool,
}

async fn measure_memory(bin: &Path, plan: &Plan, zenoh: bool) -> std::io::Result<Memory> {
    let shutdown = CancellationToken::new();
    let _stop = shutdown.clone().drop_guard();
    let mut config = head("bench");
    let mut reads = Vec::new();
    let devices_total = usize::from(MEMORY_LINES * MEMORY_DEVICES);
    let per_device = MEMORY_POINTS / devices_total;
    let mut extra = MEMORY_POINTS % devices_total;
    for line in 0..MEMORY_LINES {
        let (path, port) = pty(&shutdown)?;
        let mut bus = Vec::new();
        let mut devices = Vec::new();
        for slave in 1..=MEMORY_DEVICES {
            let device = FlatDevice::new(slave).changing();
            reads.push(device.reads());
            bus.push(device);
            let tags = per_device + usize::from(extra > 0);
            extra = extra.saturating_sub(1);
            devices.push((slave, line * MEMORY_DEVICES + slave, tags));
        }
        tokio::spawn(serve_modbus(
            port,
            Bus(bus),
            CharTiming::new(BAUD, 11),
            shutdown.clone(),
        ));
        config.push_str(&master_line(&format!("l{line}"), &path, &devices, "1s"));
    }
    let extra_args = if zenoh {
        vec![
            "--zenoh-listen".to_owned(),
            format!("tcp/127.0.0.1:{}", free_port()?),
            "--http".to_owned(),
            "127.0.0.1:0".to_owned(),
        ]
    } else {
        Vec::new()
    };
    let gw = start(bin, "memory", config, &extra_args).await?;
    // Every device read completely at least twice (at most 125 registers a read).
    let blocks = (per_device + 1).div_ceil(125) as u64;
    let deadline = Instant::now() + Duration::from_secs(60);
    while reads.iter().any(|r| r.load(Ordering::Relaxed) < 2 * blocks) {
        if Instant::now() > deadline {
            return Err(std::io::Error::other("not every device was polled"));
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let mut memory = Memory {
        rss: 0,
        anon: 0,
        hwm: 0,
        panicked: false,
    };
    let samples = (plan.memory_window.as_millis() / 200).max(1);
    for _ in 0..samples {
        if let Some(now) = gw.memory_kib() {
            if now.rss > memory.rss {
                memory.rss = now.rss;
                memory.anon = now.anon;
            }
            memory.hwm = memory.hwm.max(now.hwm);
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    memory.panicked = gw.panicked();
    Ok(memory)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gateways_listeners_are_loopback_ports_the_kernel_picks() {
        let config = gateway::plant::parse(&head("bench")).expect("the head is a valid config");
        for addr in [config.modbus_tcp.listen, config.http.listen] {
            assert!(addr.ip().is_loopback(), "{addr}");
            assert_eq!(addr.port(), 0, "{addr}");
        }
        assert!(config.zenoh.is_none(), "zenoh only on the command line");
    }
}
