//! What reading the configuration costs, at 10 000 and 100 000 tags: the gateway started on a
//! generated file (Modbus master lines on plain ptys nobody answers, generic devices of u16 tags
//! in one poll group each, as the ceiling rows write them), then the same file re-read on
//! SIGHUP, then the whole configuration replaced over REST (`PUT /api/v1/config`, TOML, one
//! line's `reply_timeout` changed). Six rows a size:
//!
//! - exec to serving: from the process's start to its `modbus-tcp listening` line (printed
//!   last, when every listener serves);
//! - start-up VmHWM / steady RSS: the process's peak resident memory over its start, against its
//!   VmRSS a second after (target <= 1.5);
//! - SIGHUP and REST replace, VmHWM / RSS before: the peak while the file is read again and
//!   checked (the peak is reset before, `/proc/PID/clear_refs` 5), against VmRSS before it
//!   (target <= 1.5);
//! - SIGHUP and REST replace, RSS after / before: VmRSS a second after it, against before
//!   (target <= 1.1: what the re-read took is given back).
//!
//! With `--baseline-gateway PATH` every size runs that binary too, right after the gateway under
//! test, and its rows follow with `[baseline]` in their names.

use std::path::Path;
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_util::sync::CancellationToken;

use crate::child::Gateway;
use crate::process::{head, master_line, pty};
use crate::report::{Row, Target};

/// Lines, devices a line and tags of the two sizes (the larger is the ceiling rows' gateway).
const SIZES: [(u8, u8, usize); 2] = [(4, 8, 10_000), (32, 7, 100_000)];

/// Longest wait for a re-read to be done.
const REREAD_TIMEOUT: Duration = Duration::from_secs(300);

/// The rows of every size, for `bin` and, after it each time, `baseline`.
pub(crate) async fn startup(bin: &Path, baseline: Option<&Path>) -> Vec<Row> {
    let mut rows = Vec::new();
    for (lines, devices, tags) in SIZES {
        for (bin, tag) in [(Some(bin), ""), (baseline, " [baseline]")] {
            let Some(bin) = bin else { continue };
            eprintln!("  {tags} tags, {}", bin.display());
            let size = format!("{tags} tags{tag}");
            match measure(bin, lines, devices, tags).await {
                Ok(m) => rows.extend(m.rows(&size, bin)),
                Err(e) => rows.extend(
                    NAMES
                        .iter()
                        .map(|name| crate::poll::failed(format!("{name}, {size}"), &e.to_string())),
                ),
            }
        }
    }
    rows
}

/// The rows' names, before their size.
const NAMES: [&str; 6] = [
    "exec to serving",
    "start-up VmHWM / steady RSS",
    "SIGHUP re-read: VmHWM / RSS before",
    "SIGHUP re-read: RSS after / before",
    "REST replace: VmHWM / RSS before",
    "REST replace: RSS after / before",
];

/// What one run measured, memory in KiB.
struct Measured {
    serving: Duration,
    file_bytes: usize,
    start_hwm: u64,
    steady: u64,
    /// (RSS before, VmHWM during, RSS after) of the SIGHUP and of the REST replace.
    rereads: [(u64, u64, u64); 2],
    reread_times: [Duration; 2],
    panicked: bool,
}

impl Measured {
    fn rows(&self, size: &str, bin: &Path) -> Vec<Row> {
        let mib = |kib: u64| kib as f64 / 1024.0;
        let valid = |v: f64| if self.panicked { f64::NAN } else { v };
        let setup = format!(
            "{}; a {:.1} MB file of Modbus master lines on plain ptys nobody answers, generic \
             devices of u16 tags",
            bin.display(),
            self.file_bytes as f64 / 1e6
        );
        let serving = self.serving.as_secs_f64();
        let limit = if size.starts_with("100000") { 5.0 } else { 1.0 };
        let mut rows = vec![
            Row {
                name: format!("{}, {size}", NAMES[0]),
                measured: format!("{serving:.2} s"),
                reference: "-".into(),
                score: valid(serving),
                target: Target::at_most(limit).with_unit(" s"),
                note: format!(
                    "from the process's start to its `modbus-tcp listening` line; {setup}"
                ),
            },
            Row {
                name: format!("{}, {size}", NAMES[1]),
                measured: format!("{:.1} MiB", mib(self.start_hwm)),
                reference: format!("{:.1} MiB", mib(self.steady)),
                score: valid(self.start_hwm as f64 / self.steady.max(1) as f64),
                target: Target::at_most(1.5),
                note: format!("VmHWM over the start, VmRSS a second after; {setup}"),
            },
        ];
        let what = ["SIGHUP of the same file", "PUT /api/v1/config (TOML)"];
        for (i, (before, hwm, after)) in self.rereads.iter().copied().enumerate() {
            let took = self.reread_times[i].as_secs_f64();
            rows.push(Row {
                name: format!("{}, {size}", NAMES[2 + 2 * i]),
                measured: format!("{:.1} MiB", mib(hwm)),
                reference: format!("{:.1} MiB", mib(before)),
                score: valid(hwm as f64 / before.max(1) as f64),
                target: Target::at_most(1.5),
                note: format!(
                    "VmHWM during the {} (reset before; done in {took:.2} s), VmRSS before it; \
                     {setup}",
                    what[i]
                ),
            });
            rows.push(Row {
                name: format!("{}, {size}", NAMES[3 + 2 * i]),
                measured: format!("{:.1} MiB", mib(after)),
                reference: format!("{:.1} MiB", mib(before)),
                score: valid(after as f64 / before.max(1) as f64),
                target: Target::at_most(1.1),
                note: format!(
                    "VmRSS a second after the {}, and before it; {setup}",
                    what[i]
                ),
            });
        }
        rows
    }
}

async fn measure(bin: &Path, lines: u8, devices: u8, tags: usize) -> std::io::Result<Measured> {
    let shutdown = CancellationToken::new();
    let _stop = shutdown.clone().drop_guard();
    let mut config = head("bench").replace(
        "[http]\n",
        "[http]\nbody_limit = 67108864\nrequest_timeout = \"600s\"\n\
         insecure_allow_unauthenticated_changes = true\n",
    );
    let total = usize::from(lines) * usize::from(devices);
    // The ports stay open (nobody answers on them) until the run ends.
    let mut ports = Vec::new();
    for line in 0..lines {
        let (path, port) = pty(&shutdown)?;
        ports.push(port);
        let list: Vec<(u8, u8, usize)> = (1..=devices)
            .map(|d| {
                let i = usize::from(line) * usize::from(devices) + usize::from(d) - 1;
                let n = tags / total + usize::from(i < tags % total);
                (d, line * devices + d, n)
            })
            .collect();
        config.push_str(&master_line(&format!("l{line}"), &path, &list, "1s"));
    }
    let dir = std::env::temp_dir().join(format!("gateway-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let file = dir.join(format!("startup-{tags}.toml"));
    std::fs::write(&file, &config)?;
    let args = [
        "run".to_owned(),
        "--config".to_owned(),
        file.display().to_string(),
    ];
    let started = Instant::now();
    let owned = bin.to_owned();
    let gw = tokio::task::spawn_blocking(move || Gateway::start(&owned, &args))
        .await
        .map_err(std::io::Error::other)??;
    let serving = started.elapsed();
    let memory = || {
        gw.memory_kib()
            .ok_or_else(|| std::io::Error::other("no /proc status"))
    };
    tokio::time::sleep(Duration::from_secs(1)).await;
    let m = memory()?;
    let (start_hwm, steady) = (m.hwm, m.rss);

    // The same file again on SIGHUP.
    let t = Instant::now();
    let sighup = reread(&gw).await?;
    let sighup_time = t.elapsed();
    // The whole configuration over REST, one line's reply timeout changed.
    let http = gw
        .output()
        .lines()
        .find_map(|l| l.split("http listening on ").nth(1).map(str::trim))
        .and_then(|a| a.parse::<std::net::SocketAddr>().ok())
        .ok_or_else(|| std::io::Error::other("the gateway did not announce its HTTP listener"))?;
    let body = config.replacen("reply_timeout = \"200ms\"", "reply_timeout = \"300ms\"", 1);
    let t = Instant::now();
    let rest = reread_async(&gw, put_config(http, body)).await?;
    let rest_time = t.elapsed();
    Ok(Measured {
        serving,
        file_bytes: config.len(),
        start_hwm,
        steady,
        rereads: [sighup, rest],
        reread_times: [sighup_time, rest_time],
        panicked: gw.panicked(),
    })
    .inspect(|_| drop(ports))
}

/// Resets the peak resident memory of `pid` (VmHWM) to its current resident memory.
fn reset_peak(pid: u32) -> std::io::Result<()> {
    std::fs::write(format!("/proc/{pid}/clear_refs"), "5")
}

/// (RSS before, VmHWM during, RSS a second after) of a SIGHUP: done when the gateway logs its
/// SIGHUP line.
async fn reread(gw: &Gateway) -> std::io::Result<(u64, u64, u64)> {
    let logged = gw.output().matches("SIGHUP:").count();
    let done = async {
        let pid = gw.pid().to_string();
        std::process::Command::new("kill")
            .args(["-HUP", &pid])
            .status()?;
        let deadline = Instant::now() + REREAD_TIMEOUT;
        while gw.output().matches("SIGHUP:").count() == logged {
            if Instant::now() > deadline {
                return Err(std::io::Error::other("no SIGHUP line in time"));
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        Ok(())
    };
    reread_async(gw, done).await
}

/// (RSS before, VmHWM during, RSS a second after) of `step`.
async fn reread_async(
    gw: &Gateway,
    step: impl std::future::Future<Output = std::io::Result<()>>,
) -> std::io::Result<(u64, u64, u64)> {
    let memory = || {
        gw.memory_kib()
            .ok_or_else(|| std::io::Error::other("no /proc status"))
    };
    let before = memory()?.rss;
    reset_peak(gw.pid())?;
    step.await?;
    // The SIGHUP line comes before the re-read's memory is given back.
    tokio::time::sleep(Duration::from_secs(1)).await;
    let after = memory()?;
    Ok((before, after.hwm, after.rss))
}

/// `PUT /api/v1/config` of `text` as TOML over HTTP/1.0: an error unless 200.
async fn put_config(http: std::net::SocketAddr, text: String) -> std::io::Result<()> {
    let mut stream = tokio::net::TcpStream::connect(http).await?;
    let head = format!(
        "PUT /api/v1/config HTTP/1.0\r\nHost: {http}\r\nContent-Type: application/toml\r\n\
         Content-Length: {}\r\n\r\n",
        text.len()
    );
    stream.write_all(head.as_bytes()).await?;
    stream.write_all(text.as_bytes()).await?;
    let mut answer = Vec::new();
    tokio::time::timeout(REREAD_TIMEOUT, stream.read_to_end(&mut answer))
        .await
        .map_err(|_| std::io::Error::other("PUT /api/v1/config did not answer in time"))??;
    let answer = String::from_utf8_lossy(&answer);
    if answer.starts_with("HTTP/1.1 200") || answer.starts_with("HTTP/1.0 200") {
        Ok(())
    } else {
        Err(std::io::Error::other(format!(
            "PUT /api/v1/config: {}",
            answer.chars().take(300).collect::<String>()
        )))
    }
}
