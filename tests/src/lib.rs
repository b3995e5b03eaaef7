//! Helpers shared by the end-to-end tests: start the real `gateway` binary and wait until it
//! listens.
//!
//! The binary is looked up next to the test executable (`target/<profile>/gateway`); when it is
//! missing it is built with `cargo build -p gateway` first, so `cargo test -p gateway-tests` works on
//! its own too.
//!
//! The outside tools the tests drive (mbpoll, socat, tshark, curl, prometheus, the Python clients
//! in `.venv`) are not mocked: `.ci/test`, the README's test command, installs the missing ones
//! before it runs the tests. A test that finds one missing fails at once with the command that
//! installs it ([`tool`], [`venv_python`]), never skips.

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

/// How long a gateway may take to come up (ptys, simulators, first polls) on a loaded machine.
pub const START_TIMEOUT: Duration = Duration::from_secs(60);

/// The path of the `gateway` binary, built once if needed; `GATEWAY_TESTS_BIN` names another one
/// (to measure an older build with the same test, e.g. the before figures of a change).
pub fn gateway_bin() -> PathBuf {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| {
        if let Some(bin) = std::env::var_os("GATEWAY_TESTS_BIN") {
            return PathBuf::from(bin);
        }
        let exe = std::env::current_exe().expect("test executable path");
        // target/<profile>/deps/<test> -> target/<profile>/gateway
        let profile_dir = exe
            .parent()
            .and_then(Path::parent)
            .expect("target/<profile> directory");
        let bin = profile_dir.join("gateway");
        // Always ask cargo: a no-op when the binary is up to date, a rebuild when only this
        // crate's tests were built (`cargo test -p gateway-tests` does not build other packages'
        // binaries), so a test never runs a stale gateway.
        let target_dir = profile_dir.parent().expect("target directory");
        let mut build = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
        build
            .args(["build", "-p", "gateway", "--bin", "gateway"])
            .env("CARGO_TARGET_DIR", target_dir);
        if profile_dir.file_name().is_some_and(|n| n == "release") {
            build.arg("--release");
        }
        let status = build.status().expect("run cargo build -p gateway");
        assert!(status.success(), "cargo build -p gateway failed");
        assert!(
            bin.exists(),
            "gateway binary not found at {}",
            bin.display()
        );
        bin
    })
    .clone()
}

/// A running gateway process, stopped (SIGTERM, then SIGKILL) when dropped.
#[derive(Debug)]
pub struct Gateway {
    child: Child,
    /// The Modbus TCP address the gateway announced.
    pub modbus_tcp: SocketAddr,
    /// The HTTP address (REST API, `/metrics`) the gateway announced, if it serves HTTP.
    pub http: Option<SocketAddr>,
    /// The zenoh port of a demo (`tcp/127.0.0.1:<port>`).
    pub zenoh_port: Option<u16>,
    /// Every line the process wrote to stdout and stderr so far.
    output: Arc<Mutex<Vec<String>>>,
    lines: mpsc::Receiver<String>,
}

impl Gateway {
    /// Starts `gateway demo` with the given extra arguments, Modbus TCP and HTTP on ephemeral
    /// ports.
    pub fn demo(extra: &[&str]) -> Self {
        // Tests run in parallel: every demo gets its own zenoh port (zenoh cannot be given
        // port 0 and tell the port it took, so the port is chosen free and, should another
        // process take it before the gateway binds it, chosen again).
        Self::on_free_zenoh_port(|zenoh_port| Self::try_demo(zenoh_port, extra))
    }

    /// Starts `gateway demo` (as [`Self::demo`]) with zenoh on `zenoh_port`; the output when it
    /// did not start.
    pub fn try_demo(zenoh_port: u16, extra: &[&str]) -> Result<Self, String> {
        let zenoh = format!("tcp/127.0.0.1:{zenoh_port}");
        let mut args = vec![
            "demo",
            "--modbus-tcp",
            "127.0.0.1:0",
            "--http",
            "127.0.0.1:0",
            "--zenoh-listen",
            &zenoh,
        ];
        args.extend_from_slice(extra);
        Self::try_start(&args)
    }

    /// Starts `gateway run --config FILE` with the config `config` makes for a zenoh port that
    /// was free a moment ago, written to `file`; should another process take the port before the
    /// gateway binds it, with another port (at most three tries). `zenoh_port` is the port used.
    pub fn run_on_free_zenoh_port(file: &Path, config: impl Fn(u16) -> String) -> Self {
        Self::on_free_zenoh_port(|zenoh_port| {
            std::fs::write(file, config(zenoh_port)).expect("write config");
            Self::try_start(&Self::run_args(file))
        })
    }

    /// Runs `start` with a free zenoh port until the gateway did not fail to bind it.
    fn on_free_zenoh_port(start: impl Fn(u16) -> Result<Self, String>) -> Self {
        Self::on_zenoh_ports(free_port, start)
    }

    /// Runs `start` with the ports `next` gives until the gateway did not fail to bind one (at
    /// most three tries).
    pub fn on_zenoh_ports(
        mut next: impl FnMut() -> u16,
        start: impl Fn(u16) -> Result<Self, String>,
    ) -> Self {
        const TRIES: usize = 3;
        let mut failed = String::new();
        for _ in 0..TRIES {
            let port = next();
            match start(port) {
                Ok(mut gw) => {
                    gw.zenoh_port = Some(port);
                    return gw;
                }
                Err(output) if output.contains("Address already in use") => failed = output,
                Err(output) => panic!("the gateway did not start; output:\n{output}"),
            }
        }
        panic!("the zenoh port was taken {TRIES} times; last output:\n{failed}")
    }

    /// Starts `gateway run --config FILE`, HTTP (REST API, `/metrics`) on an ephemeral port
    /// (never the config's `[http] listen`, which tests running in parallel would share).
    pub fn run(config: &Path) -> Self {
        Self::start(&Self::run_args(config))
    }

    /// The arguments of `gateway run --config FILE --http 127.0.0.1:0`.
    pub fn run_args(config: &Path) -> [&str; 5] {
        [
            "run",
            "--config",
            config.to_str().expect("utf-8 path"),
            "--http",
            "127.0.0.1:0",
        ]
    }

    /// Starts the binary with `args` and waits for its Modbus TCP announcement (printed last,
    /// after the HTTP one when it serves HTTP).
    pub fn start(args: &[&str]) -> Self {
        Self::try_start(args).unwrap_or_else(|output| {
            panic!("no line containing \"modbus-tcp listening on \" within {START_TIMEOUT:?}; output:\n{output}")
        })
    }

    /// [`Self::start`], or the process's output when it did not announce its Modbus TCP address
    /// in time (it exited, or it hangs: then it is killed).
    pub fn try_start(args: &[&str]) -> Result<Self, String> {
        let log = std::env::var("RUST_LOG").unwrap_or_else(|_| "info".into());
        Self::try_start_logging(args, &log)
    }

    /// [`Self::start`] with `RUST_LOG=filter` (e.g. `info,gateway::line=debug`).
    pub fn start_logging(args: &[&str], filter: &str) -> Self {
        Self::try_start_logging(args, filter).unwrap_or_else(|output| {
            panic!("no line containing \"modbus-tcp listening on \" within {START_TIMEOUT:?}; output:\n{output}")
        })
    }

    /// [`Self::try_start`] with `RUST_LOG=filter`.
    pub fn try_start_logging(args: &[&str], filter: &str) -> Result<Self, String> {
        let mut command = Command::new(gateway_bin());
        command.args(args).env("RUST_LOG", filter);
        Self::try_start_command(command)
    }

    /// [`Self::try_start`] with the gateway started by `command` (the binary and its arguments,
    /// or a program that ends in `exec` of it in the same process, such as `unshare`).
    pub fn try_start_command(mut command: Command) -> Result<Self, String> {
        let mut child = command
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start gateway");
        let output = Arc::new(Mutex::new(Vec::new()));
        let (tx, lines) = mpsc::channel();
        for stream in [
            Box::new(child.stdout.take().expect("stdout")) as Box<dyn std::io::Read + Send>,
            Box::new(child.stderr.take().expect("stderr")),
        ] {
            let tx = tx.clone();
            let output = Arc::clone(&output);
            std::thread::spawn(move || {
                for line in BufReader::new(stream).lines().map_while(Result::ok) {
                    output.lock().expect("output lock").push(line.clone());
                    let _ = tx.send(line);
                }
            });
        }
        // Only the reader threads hold senders now: when the process exits, waiting ends at once.
        drop(tx);
        let mut gw = Self {
            child,
            modbus_tcp: "0.0.0.0:0".parse().expect("addr"),
            http: None,
            zenoh_port: None,
            output,
            lines,
        };
        let Some(line) = gw.try_wait_for("modbus-tcp listening on ", START_TIMEOUT) else {
            gw.kill();
            // The reader threads end with the pipes: the output is complete.
            while gw.lines.recv_timeout(Duration::from_secs(5)).is_ok() {}
            return Err(gw.output());
        };
        let addr = line
            .rsplit("modbus-tcp listening on ")
            .next()
            .expect("address")
            .trim();
        gw.modbus_tcp = addr
            .parse()
            .unwrap_or_else(|e| panic!("bad address {addr:?}: {e}"));
        // Both lines go to stdout, read in order by one thread: the HTTP line, if any, is already
        // in the output.
        gw.http = gw
            .output
            .lock()
            .expect("output lock")
            .iter()
            .find_map(|line| line.split_once("http listening on ").map(|(_, a)| a.trim()))
            .map(|addr| {
                addr.parse()
                    .unwrap_or_else(|e| panic!("bad address {addr:?}: {e}"))
            });
        Ok(gw)
    }

    /// Waits until a line containing `needle` appears and returns it; panics with the whole
    /// output after `timeout`.
    pub fn wait_for(&mut self, needle: &str, timeout: Duration) -> String {
        self.try_wait_for(needle, timeout).unwrap_or_else(|| {
            panic!(
                "no line containing {needle:?} within {timeout:?}; output:\n{}",
                self.output()
            )
        })
    }

    /// Waits until a line containing `needle` appears and returns it; `None` after `timeout`, or
    /// at once when the process has ended.
    pub fn try_wait_for(&mut self, needle: &str, timeout: Duration) -> Option<String> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(line) if line.contains(needle) => return Some(line),
                Ok(_) => {}
                Err(_) => return None,
            }
        }
    }

    /// Everything the process printed so far.
    pub fn output(&self) -> String {
        self.output.lock().expect("output lock").join("\n")
    }

    /// The process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Kills the process with SIGKILL (no chance to clean up) and waits for it.
    pub fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Sends SIGTERM, waits up to `timeout` for the exit status and then for the last lines the
    /// process wrote (its output is complete when this returns with a status).
    pub fn stop(&mut self, timeout: Duration) -> Option<std::process::ExitStatus> {
        let status = self.terminate(timeout)?;
        let deadline = Instant::now() + timeout;
        // The reader threads drop their senders at the end of the pipes: disconnected then.
        while self
            .lines
            .recv_timeout(deadline.saturating_duration_since(Instant::now()))
            .is_ok()
        {}
        Some(status)
    }

    /// Sends SIGTERM and waits up to `timeout` for the exit status.
    pub fn terminate(&mut self, timeout: Duration) -> Option<std::process::ExitStatus> {
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        let deadline = Instant::now() + timeout;
        while Instant::now() < deadline {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Some(status);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        None
    }
}

impl Drop for Gateway {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            if self.terminate(Duration::from_secs(5)).is_none() {
                let _ = self.child.kill();
                let _ = self.child.wait();
            }
        }
        let out = self.output();
        if !std::thread::panicking() {
            assert!(!out.contains("panicked at"), "the gateway panicked:\n{out}");
        }
    }
}

/// A TCP port that was free on 127.0.0.1 a moment ago (for listeners of other programs that
/// cannot be given port 0, such as a zenoh endpoint).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("bind 127.0.0.1:0")
        .port()
}

/// The repository's root (deploy/, docs/ and the Python clients are found from it).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// `name`, an outside command the tests drive, after checking that it runs (`--version`, or
/// `-V` for mbpoll); panics with what installs it when it does not.
pub fn tool(name: &'static str) -> &'static str {
    let version = if name == "mbpoll" { "-V" } else { "--version" };
    let runs = Command::new(name)
        .arg(version)
        .stdin(Stdio::null())
        .output()
        .is_ok_and(|o| o.status.success());
    let package = if name == "promtool" {
        "prometheus"
    } else {
        name
    };
    assert!(
        runs,
        "{name} is missing: run the tests with `.ci/test`, which installs what is missing, or \
         `apt-get install -y {package}` yourself"
    );
    name
}

/// The `tshark` command, after checking that it runs (a clear message when it is missing).
pub fn tshark() -> &'static str {
    tool("tshark")
}

/// The Python of the repository's `.venv` after checking that it imports `module` (`zenoh`,
/// `pymodbus`); panics with what installs it when it does not.
pub fn venv_python(module: &str) -> PathBuf {
    let python = repo_root().join(".venv/bin/python");
    let imports = Command::new(&python)
        .args(["-c", &format!("import {module}")])
        .stdin(Stdio::null())
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        imports,
        "{} cannot import {module}: run the tests with `.ci/test`, which makes .venv and installs \
         the pinned eclipse-zenoh and pymodbus into it",
        python.display()
    );
    python
}

/// tshark's `-X` argument that loads the project's 3964(R) dissector.
pub fn lua_3964_dissector() -> String {
    format!(
        "lua_script:{}",
        repo_root()
            .join("deploy/wireshark/cp341_3964r.lua")
            .display()
    )
}

/// A fresh directory under the system temp dir for one test.
pub fn temp_dir(test: &str) -> PathBuf {
    static COUNTER: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let n = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = std::env::temp_dir().join(format!("gateway-e2e-{}-{test}-{n}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("create temp dir");
    dir
}

/// A child process killed (by its PID, SIGKILL) and reaped when dropped.
#[derive(Debug)]
pub struct ChildGuard(pub Child);

impl ChildGuard {
    /// Kills the process now and waits for it.
    pub fn kill(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Drop for ChildGuard {
    fn drop(&mut self) {
        self.kill();
    }
}

/// A virtual null-modem cable: two pseudo-terminals joined by socat, reachable at `a` and `b`.
#[derive(Debug)]
pub struct SocatLink {
    /// One end (give it to the gateway).
    pub a: PathBuf,
    /// The other end (give it to the device).
    pub b: PathBuf,
    _socat: ChildGuard,
}

impl SocatLink {
    /// Creates the link in `dir` as `<name>-a` and `<name>-b`.
    pub fn new(dir: &Path, name: &str) -> Self {
        let a = dir.join(format!("{name}-a"));
        let b = dir.join(format!("{name}-b"));
        let child = Command::new("socat")
            .arg("-d")
            .arg(format!("pty,raw,echo=0,link={}", a.display()))
            .arg(format!("pty,raw,echo=0,link={}", b.display()))
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| {
                panic!("socat is needed (`.ci/test` installs it, or apt-get install -y socat): {e}")
            });
        let guard = ChildGuard(child);
        let deadline = Instant::now() + Duration::from_secs(10);
        while !(a.exists() && b.exists()) {
            assert!(
                Instant::now() < deadline,
                "socat did not create {} and {}",
                a.display(),
                b.display()
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        Self {
            a,
            b,
            _socat: guard,
        }
    }
}

/// Starts `gateway sim` with `args` (stdout and stderr discarded).
pub fn start_sim(args: &[&str]) -> ChildGuard {
    let child = Command::new(gateway_bin())
        .arg("sim")
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start gateway sim");
    ChildGuard(child)
}

/// Starts `gateway sim --device DEVICE --port PORT` with the simulator's defaults.
pub fn device_sim(device: &str, port: &Path) -> ChildGuard {
    start_sim(&[
        "--device",
        device,
        "--port",
        port.to_str().expect("utf-8 path"),
    ])
}

/// The two Modbus master lines several end-to-end tests share, as configuration sections:
/// `drive` on `drive` (the Altivar 71 at address 2, unit 2, holding 3102..3105 polled every 200 ms)
/// and `ksvario` on `ks` (the KS vario at address 17, unit 17, input 1004..1006 every 200 ms), both
/// 19200 Bd 8E1 with the reply monitoring time `reply_timeout`, and the drive's offline back-off
/// `(min, max)` when given.
pub fn two_device_lines(
    drive: &Path,
    ks: &Path,
    reply_timeout: &str,
    drive_backoff: Option<(&str, &str)>,
) -> String {
    let backoff = drive_backoff
        .map(|(min, max)| {
            format!("offline_backoff_min = \"{min}\"\noffline_backoff_max = \"{max}\"\n")
        })
        .unwrap_or_default();
    format!(
        r#"
[lines.drive]
port = "{drive}"
protocol = "modbus-master-rtu"
baud = 19200
parity = "even"
reply_timeout = "{reply_timeout}"

[lines.drive.devices.atv71]
profile = "altivar71"
address = 2
unit_id = 2
{backoff}
[[lines.drive.devices.atv71.poll]]
name = "settings"
period = "200ms"
ranges = [{{ table = "holding", start = 3102, count = 4 }}]

[lines.ksvario]
port = "{ks}"
protocol = "modbus-master-rtu"
baud = 19200
parity = "even"
reply_timeout = "{reply_timeout}"

[lines.ksvario.devices.ks]
profile = "ksvario"
address = 17
unit_id = 17

[[lines.ksvario.devices.ks.poll]]
name = "process"
period = "200ms"
ranges = [{{ table = "input", start = 1004, count = 3 }}]
"#,
        drive = drive.display(),
        ks = ks.display()
    )
}

/// `gateway check --config FILE`: whether it passed, and what it printed on stdout.
pub fn check_config(config: &Path) -> (bool, String) {
    let out = Command::new(gateway_bin())
        .args(["check", "--config", config.to_str().expect("utf-8 path")])
        .output()
        .expect("gateway check");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    )
}

/// A zenoh client session connected to the gateway's zenoh port on loopback, multicast scouting
/// off.
pub async fn zenoh_client(port: u16) -> zenoh::Session {
    let mut c = zenoh::Config::default();
    c.insert_json5("mode", r#""client""#).expect("mode");
    c.insert_json5("connect/endpoints", &format!(r#"["tcp/127.0.0.1:{port}"]"#))
        .expect("connect");
    c.insert_json5("scouting/multicast/enabled", "false")
        .expect("scouting");
    zenoh::open(c)
        .await
        .expect("a zenoh session to the gateway")
}
