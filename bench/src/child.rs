//! The real `gateway` binary as a child process: started with a generated config, its Modbus TCP
//! address read from its announcement, its resident memory read from `/proc`, stopped when
//! dropped.

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant};

use crate::tap::lock;

/// How long the gateway may take to announce its Modbus TCP listener.
const START_TIMEOUT: Duration = Duration::from_secs(60);

/// The gateway binary: `--gateway PATH`, else next to this executable (`cargo build --release`
/// builds both into `target/release/`).
pub(crate) fn gateway_bin(given: Option<&Path>) -> PathBuf {
    if let Some(path) = given {
        return path.to_owned();
    }
    std::env::current_exe()
        .ok()
        .and_then(|exe| exe.parent().map(|dir| dir.join("gateway")))
        .unwrap_or_else(|| PathBuf::from("gateway"))
}

/// Memory figures of a process, in KiB.
#[derive(Clone, Copy, Debug)]
pub(crate) struct MemoryKib {
    pub(crate) rss: u64,
    pub(crate) anon: u64,
    pub(crate) hwm: u64,
}

/// A running gateway process.
pub(crate) struct Gateway {
    child: std::process::Child,
    /// Where it serves Modbus TCP.
    pub(crate) modbus_tcp: SocketAddr,
    output: Arc<Mutex<Vec<String>>>,
    /// The threads reading its stdout and stderr, ending with them.
    readers: Vec<std::thread::JoinHandle<()>>,
}

// === impl Gateway ===

impl Gateway {
    /// Starts `bin` with `args` and waits for `modbus-tcp listening on ADDR` (blocking).
    pub(crate) fn start(bin: &Path, args: &[String]) -> std::io::Result<Self> {
        let mut child = Command::new(bin)
            .args(args)
            .env(
                "RUST_LOG",
                std::env::var("RUST_LOG").unwrap_or_else(|_| "info".into()),
            )
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| std::io::Error::other(format!("cannot start {}: {e}", bin.display())))?;
        let output = Arc::new(Mutex::new(Vec::new()));
        let (tx, lines) = mpsc::channel::<String>();
        let streams: [Box<dyn std::io::Read + Send>; 2] = [
            Box::new(
                child
                    .stdout
                    .take()
                    .ok_or_else(|| std::io::Error::other("no stdout"))?,
            ),
            Box::new(
                child
                    .stderr
                    .take()
                    .ok_or_else(|| std::io::Error::other("no stderr"))?,
            ),
        ];
        let readers = streams
            .into_iter()
            .map(|stream| {
                let tx = tx.clone();
                let output = Arc::clone(&output);
                std::thread::spawn(move || {
                    for line in BufReader::new(stream).lines().map_while(Result::ok) {
                        lock(&output).push(line.clone());
                        let _ = tx.send(line);
                    }
                })
            })
            .collect();
        drop(tx);
        let mut gateway = Self {
            child,
            modbus_tcp: SocketAddr::from(([127, 0, 0, 1], 0)),
            output,
            readers,
        };
        let deadline = Instant::now() + START_TIMEOUT;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match lines.recv_timeout(left) {
                Ok(line) => {
                    if let Some(addr) = line.split("modbus-tcp listening on ").nth(1) {
                        gateway.modbus_tcp = addr.trim().parse().map_err(|e| {
                            std::io::Error::other(format!("bad address {addr:?}: {e}"))
                        })?;
                        return Ok(gateway);
                    }
                }
                Err(_) => {
                    return Err(std::io::Error::other(format!(
                        "the gateway did not announce its Modbus TCP listener:\n{}",
                        gateway.output()
                    )))
                }
            }
        }
    }

    /// The process id.
    pub(crate) fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Resident memory (VmRSS), its anonymous part (RssAnon) and its peak (VmHWM), in KiB.
    pub(crate) fn memory_kib(&self) -> Option<MemoryKib> {
        let status = std::fs::read_to_string(format!("/proc/{}/status", self.child.id())).ok()?;
        let field = |name: &str| {
            status
                .lines()
                .find_map(|l| l.strip_prefix(name))
                .and_then(|v| v.split_whitespace().next())
                .and_then(|v| v.parse::<u64>().ok())
        };
        Some(MemoryKib {
            rss: field("VmRSS:")?,
            anon: field("RssAnon:")?,
            hwm: field("VmHWM:")?,
        })
    }

    /// Everything it printed so far.
    pub(crate) fn output(&self) -> String {
        lock(&self.output).join("\n")
    }

    /// Whether it printed a panic.
    pub(crate) fn panicked(&self) -> bool {
        lock(&self.output).iter().any(|l| l.contains("panicked at"))
    }

    /// Stops it (SIGTERM) and returns the table of stalls it printed when it ended, then the
    /// first 20 stalls it logged (with their time, to tell the start from the run): `None` from a
    /// gateway built without the `stall-watch` feature.
    pub(crate) fn stalls(mut self) -> Option<String> {
        self.terminate();
        self.readers.drain(..).for_each(|r| drop(r.join()));
        let output = lock(&self.output);
        let table: Vec<&str> = output
            .iter()
            .map(String::as_str)
            .skip_while(|l| !l.starts_with("stall-watch: "))
            .filter(|l| l.starts_with("stall"))
            .collect();
        let logged = output
            .iter()
            .map(String::as_str)
            .filter(|l| l.contains("gateway::task") && l.contains("stall: a "))
            .take(20);
        (!table.is_empty()).then(|| {
            table
                .into_iter()
                .chain(logged)
                .collect::<Vec<_>>()
                .join("\n")
        })
    }

    /// SIGTERM, then SIGKILL after 15 s; nothing once it has ended.
    fn terminate(&mut self) {
        if let Ok(Some(_)) = self.child.try_wait() {
            return;
        }
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        let deadline = Instant::now() + Duration::from_secs(15);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Gateway {
    fn drop(&mut self) {
        self.terminate();
    }
}

/// A TCP port that was free on 127.0.0.1 a moment ago (for the gateway's zenoh endpoint).
pub(crate) fn free_port() -> std::io::Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port())
}
