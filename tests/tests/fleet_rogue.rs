//! End to end on the binary: a zenoh fabric with someone on it who is not a gateway
//! (tests/python/zenoh_rogue.py, the Python binding, multicast scouting off everywhere, every
//! endpoint on 127.0.0.1).
//!
//! - A rogue peer with 1,000 liveliness tokens `gw/rogue<i>` whose status answers carry 28 KiB
//!   fields: the gateway's resident memory grows by less than [`RSS_GROWTH_BOUND_KIB`], its
//!   `GET /api/v1/fleet` stays under [`FLEET_BODY_BOUND`] and offers no link for the rogue's
//!   addresses (nor does the status page in Chromium, tests/page/fleet-rogue-test.js), and
//!   `gateway fleet status` prints less than [`FLEET_STATUS_BOUND`].
//! - A rogue holding the gateway's own name (`gw/g1`, with a forged host carrying terminal
//!   escapes and a phishing link): the gateway serves its line over Modbus TCP and REST, reports
//!   the conflict (ERROR log, `/readyz` 503 at `zenoh.name`, a problem on the page,
//!   `gateway_zenoh_name_conflict 1`) with the holder's text escaped, publishes nothing on zenoh,
//!   and takes the name and publishes once the rogue leaves.
//! - On the fabric of deploy/zenoh/ (router.json5: mutual TLS and access control by certificate
//!   name; certificates made at test time by deploy/zenoh/make-certs.sh): a rogue without a
//!   certificate cannot connect, and one with the certificate of another gateway (cab2) cannot
//!   declare `gw/cab1`; the real cab1 then takes its name at once.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use gateway_tests::{device_sim, free_port, temp_dir, ChildGuard, Gateway, SocatLink};
use serde_json::Value;

/// The stated bound of the gateway's RSS growth under the 1,000-token rogue (docs/fleet.md).
const RSS_GROWTH_BOUND_KIB: u64 = 16 * 1024;
/// The stated bound of `GET /api/v1/fleet` (256 members of under 1 KiB each).
const FLEET_BODY_BOUND: usize = 256 * 1024;
/// The stated bound of `gateway fleet status`'s output (4096 rows of about 1 KiB).
const FLEET_STATUS_BOUND: usize = 5 * 1024 * 1024;
/// The most gateways the fleet view keeps (`zenoh_bridge::fleet::MEMBER_LIMIT`).
const MEMBER_LIMIT: usize = 256;

fn python() -> PathBuf {
    gateway_tests::venv_python("zenoh")
}

fn script(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("python")
        .join(name)
}

/// A router: `tests/python/zenoh_router.py`, killed when dropped.
struct Router {
    _child: ChildGuard,
}

impl Router {
    /// Starts the router with `args` (a port, or `--config FILE`); `None` when it did not open.
    fn start(args: &[&str]) -> Option<Self> {
        let mut child = Command::new(python())
            .arg(script("zenoh_router.py"))
            .args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("python starts");
        let out = child.stdout.take().expect("stdout");
        let mut line = String::new();
        BufReader::new(out)
            .read_line(&mut line)
            .expect("router output");
        let guard = ChildGuard(child);
        line.contains("listening").then_some(Self { _child: guard })
    }

    /// A plain router on a free port of 127.0.0.1.
    fn plain() -> (u16, Self) {
        for _ in 0..3 {
            let port = free_port();
            if let Some(r) = Self::start(&[&port.to_string()]) {
                return (port, r);
            }
        }
        panic!("the router did not open");
    }
}

/// A rogue: `tests/python/zenoh_rogue.py ARGS`; it leaves when its stdin closes.
struct Rogue {
    child: Child,
    stdin: Option<std::process::ChildStdin>,
    /// The first line it printed (`rogue ready N` or `rogue not connected: ...`).
    first: String,
}

impl Rogue {
    fn start(args: &[&str]) -> Self {
        let mut child = Command::new(python())
            .arg(script("zenoh_rogue.py"))
            .args(args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("python starts");
        let stdin = child.stdin.take();
        let out = child.stdout.take().expect("stdout");
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut line = String::new();
            let _ = BufReader::new(out).read_line(&mut line);
            let _ = tx.send(line);
        });
        let first = rx.recv_timeout(Duration::from_secs(60)).unwrap_or_default();
        Self {
            child,
            stdin,
            first,
        }
    }

    fn ready(&self) -> bool {
        self.first.starts_with("rogue ready")
    }

    /// Closes its stdin (it undeclares everything and closes its session) and waits for it.
    fn leave(&mut self) {
        if let Some(mut stdin) = self.stdin.take() {
            let _ = stdin.flush();
        }
        let deadline = Instant::now() + Duration::from_secs(20);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Runs the script to its end (`--probe`): its first line and exit code.
    fn run(args: &[&str]) -> (String, Option<i32>) {
        let mut r = Self::start(args);
        r.leave();
        let code = r.child.wait().ok().and_then(|s| s.code());
        (r.first.trim().to_owned(), code)
    }
}

impl Drop for Rogue {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// VmRSS of `pid` in KiB.
fn rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmRSS:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        })
        .expect("VmRSS")
}

fn http_client() -> reqwest::Client {
    reqwest::Client::builder()
        .timeout(Duration::from_secs(10))
        .build()
        .expect("client")
}

/// `/readyz`: its status code and body.
async fn readyz(c: &reqwest::Client, http: std::net::SocketAddr) -> (u16, String) {
    let r = c
        .get(format!("http://{http}/readyz"))
        .send()
        .await
        .expect("GET /readyz");
    let code = r.status().as_u16();
    (code, r.text().await.unwrap_or_default())
}

/// The value of the metric `name` (no labels) in `/metrics`.
async fn metric(c: &reqwest::Client, http: std::net::SocketAddr, name: &str) -> Option<f64> {
    let text = c
        .get(format!("http://{http}/metrics"))
        .send()
        .await
        .expect("GET /metrics")
        .text()
        .await
        .expect("text");
    text.lines()
        .find_map(|l| l.strip_prefix(&format!("{name} ")))
        .and_then(|v| v.trim().parse().ok())
}

/// Waits until `/readyz` answers `code`; its body.
async fn until_ready_is(
    c: &reqwest::Client,
    http: std::net::SocketAddr,
    code: u16,
    limit: Duration,
) -> String {
    let start = Instant::now();
    loop {
        let (got, body) = readyz(c, http).await;
        if got == code {
            return body;
        }
        assert!(
            start.elapsed() < limit,
            "/readyz still {got} after {limit:?}, expected {code}: {body}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

/// `gateway check --config FILE`: whether it passed, and what it printed (stdout and stderr).
fn check(config: &Path) -> (bool, String) {
    let out = Command::new(gateway_tests::gateway_bin())
        .args(["check", "--config", config.to_str().expect("utf-8 path")])
        .output()
        .expect("gateway check");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr),
    )
}

fn peer_config(name: &str, zenoh_port: u16) -> String {
    format!(
        r#"
[gateway]
name = "{name}"

[modbus_tcp]
listen = "127.0.0.1:0"

[zenoh]
listen = ["tcp/127.0.0.1:{zenoh_port}"]
multicast_scouting = false
"#
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rogue_peer_cannot_inflate_the_fleet_view() {
    let dir = temp_dir("fleet-rogue-flood");
    let file = dir.join("victim.toml");
    let gw = Gateway::run_on_free_zenoh_port(&file, |port| peer_config("victim", port));
    let (http, port) = (gw.http.expect("http"), gw.zenoh_port.expect("zenoh port"));
    let c = http_client();
    until_ready_is(&c, http, 200, Duration::from_secs(30)).await;
    tokio::time::sleep(Duration::from_secs(2)).await;
    let before = rss_kib(gw.pid());

    let endpoint = format!("tcp/127.0.0.1:{port}");
    let mut rogue = Rogue::start(&[
        "--connect",
        &endpoint,
        "--tokens",
        "1000",
        "--field-kb",
        "28",
        "--answer-all",
        "50",
    ]);
    assert!(rogue.ready(), "the rogue did not start: {}", rogue.first);
    let attacked = Instant::now();
    let mut peak = before;

    // The view fills to its limit, every member described (name cut, no link).
    let fleet = loop {
        peak = peak.max(rss_kib(gw.pid()));
        let body = c
            .get(format!("http://{http}/api/v1/fleet"))
            .send()
            .await
            .expect("GET /fleet")
            .bytes()
            .await
            .expect("body");
        assert!(
            body.len() <= FLEET_BODY_BOUND,
            "GET /api/v1/fleet answered {} bytes",
            body.len()
        );
        let v: Value = serde_json::from_slice(&body).expect("JSON");
        let list = v["gateways"].as_array().cloned().unwrap_or_default();
        assert!(list.len() <= MEMBER_LIMIT, "{} members", list.len());
        let described = list.iter().filter(|g| g["http"].is_string()).count();
        if list.len() == MEMBER_LIMIT && described == MEMBER_LIMIT {
            break (v, body.len());
        }
        assert!(
            attacked.elapsed() < Duration::from_secs(90),
            "the view did not fill: {} members, {described} described",
            list.len()
        );
        tokio::time::sleep(Duration::from_millis(500)).await;
    };
    let filled = attacked.elapsed();
    for g in fleet.0["gateways"].as_array().expect("list") {
        let name = g["name"].as_str().expect("name");
        assert!(name.len() <= 64 + 3 && name.starts_with("rogue"), "{name}");
        assert!(
            g["host"].as_str().is_some_and(|h| h.len() <= 253 + 3),
            "{g}"
        );
        assert!(
            g["http"].as_str().is_some_and(|h| h.len() <= 256 + 3),
            "{g}"
        );
        assert!(g["link"].is_null(), "a rogue's address is no link: {g}");
        assert!(g["zid"].is_null(), "28 KiB of A is no zenoh id: {g}");
    }

    // Eight readers of the fleet at once, and `gateway fleet status`, while the rogue stays.
    let readers: Vec<_> = (0..8)
        .map(|_| {
            let c = c.clone();
            tokio::spawn(async move {
                c.get(format!("http://{http}/api/v1/fleet"))
                    .send()
                    .await
                    .expect("GET /fleet")
                    .bytes()
                    .await
                    .expect("body")
                    .len()
            })
        })
        .collect();
    for r in readers {
        let len = r.await.expect("reader");
        assert!(len <= FLEET_BODY_BOUND, "{len}");
    }
    let status = tokio::task::spawn_blocking(move || {
        Command::new(gateway_tests::gateway_bin())
            .args(["fleet", "status", "--connect", &endpoint, "--timeout", "5s"])
            .output()
            .expect("gateway fleet status")
    })
    .await
    .expect("fleet status task");
    let (out, err) = (
        String::from_utf8_lossy(&status.stdout).into_owned(),
        String::from_utf8_lossy(&status.stderr).into_owned(),
    );
    assert!(status.status.success(), "{err}");
    assert!(
        out.len() <= FLEET_STATUS_BOUND,
        "fleet status printed {} bytes",
        out.len()
    );
    assert!(
        out.lines().any(|l| l.starts_with("victim")),
        "the real gateway is listed:\n{}",
        &out[..out.len().min(2000)]
    );
    assert!(err.contains("answers left out"), "{err}");
    // The page shows every rogue address as text, none as a link.
    let base = format!("http://{http}");
    let page = tokio::task::spawn_blocking(move || fleet_rogue_page(&base))
        .await
        .expect("the browser task");
    println!("{page}");
    // Ten more seconds under the attack (the view asks nobody again: all are described).
    let until = Instant::now() + Duration::from_secs(10);
    while Instant::now() < until {
        peak = peak.max(rss_kib(gw.pid()));
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
    let growth = peak.saturating_sub(before);
    println!(
        "rogue with 1000 tokens and 28 KiB fields: view full ({MEMBER_LIMIT} members) {filled:?} \
         after it joined; GET /api/v1/fleet {} bytes; fleet status {} bytes; gateway VmRSS {before} \
         KiB before, peak {peak} KiB ({growth} KiB growth, bound {RSS_GROWTH_BOUND_KIB} KiB)",
        fleet.1,
        out.len()
    );
    assert!(
        growth <= RSS_GROWTH_BOUND_KIB,
        "RSS grew by {growth} KiB (bound {RSS_GROWTH_BOUND_KIB} KiB)"
    );

    // The rogue leaves: its members are listed as gone (dropped after 10 minutes).
    rogue.leave();
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let v: Value = c
            .get(format!("http://{http}/api/v1/fleet"))
            .send()
            .await
            .expect("GET /fleet")
            .json()
            .await
            .expect("JSON");
        let list = v["gateways"].as_array().cloned().unwrap_or_default();
        if list.iter().all(|g| g["online"] == Value::Bool(false)) {
            break;
        }
        assert!(Instant::now() < deadline, "the rogue's members stay online");
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    drop(gw);
    let _ = std::fs::remove_dir_all(&dir);
}

fn client_config(name: &str, port: &Path, router: u16) -> String {
    format!(
        r#"
[gateway]
name = "{name}"

[modbus_tcp]
listen = "127.0.0.1:0"

[zenoh]
mode = "client"
connect = ["tcp/127.0.0.1:{router}"]
multicast_scouting = false
lease = "3s"

[lines.drive]
port = "{port}"
protocol = "modbus-master-rtu"
baud = 19200
parity = "even"
reply_timeout = "300ms"

[lines.drive.devices.atv71]
profile = "altivar71"
address = 2
unit_id = 2

[[lines.drive.devices.atv71.poll]]
name = "settings"
period = "200ms"
ranges = [{{ table = "holding", start = 3102, count = 4 }}]
"#,
        port = port.display(),
    )
}

/// Samples a subscriber of `key` receives within `window`.
async fn samples_within(s: &zenoh::Session, key: &str, window: Duration) -> usize {
    let sub = s.declare_subscriber(key).await.expect("subscribe");
    let deadline = tokio::time::Instant::now() + window;
    let mut n = 0;
    while let Ok(Ok(_)) = tokio::time::timeout_at(deadline, sub.recv_async()).await {
        n += 1;
    }
    n
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rogue_holding_the_name_does_not_stop_the_gateway() {
    let dir = temp_dir("fleet-rogue-name");
    let (router_port, router) = Router::plain();
    let endpoint = format!("tcp/127.0.0.1:{router_port}");
    // The rogue holds gw/g1 before g1 starts, with a host that would clear a terminal.
    let forged_host = "forged\u{1b}[2Jhost";
    let mut rogue = Rogue::start(&[
        "--connect",
        &endpoint,
        "--hold",
        "g1",
        "--host",
        forged_host,
        "--link",
        "http://evil.example/phish",
    ]);
    assert!(rogue.ready(), "the rogue did not start: {}", rogue.first);

    let link = SocatLink::new(&dir, "g1");
    let _sim = device_sim("altivar71", &link.b);
    let file = dir.join("g1.toml");
    std::fs::write(&file, client_config("g1", &link.a, router_port)).expect("write config");
    let mut gw = Gateway::run(&file);
    let http = gw.http.expect("http");
    let c = http_client();

    // The conflict is reported: /readyz 503 at zenoh.name naming the holder, escaped.
    let body = until_ready_is(&c, http, 503, Duration::from_secs(30)).await;
    let deadline = Instant::now() + Duration::from_secs(30);
    let body = if body.contains("zenoh.name") {
        body
    } else {
        loop {
            let (_, body) = readyz(&c, http).await;
            if body.contains("zenoh.name") {
                break body;
            }
            assert!(Instant::now() < deadline, "no zenoh.name issue: {body}");
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    };
    let readyz_json: Value = serde_json::from_str(&body).expect("JSON");
    let issue = readyz_json.to_string();
    assert!(
        issue.contains("forged\\\\u{1b}[2Jhost") && issue.contains("\\\"g1\\\""),
        "the holder named, escaped: {issue}"
    );
    assert!(!body.contains('\u{1b}'), "no raw escape: {body}");
    let log = gw.wait_for("held by another session", Duration::from_secs(30));
    assert!(log.contains("ERROR"), "{log}");
    assert!(!gw.output().contains('\u{1b}'), "no raw escape in the log");
    assert_eq!(
        metric(&c, http, "gateway_zenoh_name_conflict").await,
        Some(1.0)
    );
    // ... in the status and on the page's snapshot, escaped.
    let status: Value = c
        .get(format!("http://{http}/api/v1/status"))
        .send()
        .await
        .expect("GET /status")
        .json()
        .await
        .expect("JSON");
    assert!(
        status["zenoh"]["name_conflict"]
            .as_str()
            .is_some_and(|t| t.contains("forged\\u{1b}[2Jhost")),
        "{status}"
    );
    let page = c
        .get(format!("http://{http}/"))
        .send()
        .await
        .expect("GET /")
        .text()
        .await
        .expect("page");
    assert!(
        page.contains("held by another session") && !page.contains('\u{1b}'),
        "the page shows the problem"
    );

    // The line and Modbus TCP serve meanwhile: the drive's HSP (W3104, 500 = 50.0 Hz).
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let read = async {
            let mut ctx = tokio_modbus::client::tcp::connect_slave(
                gw.modbus_tcp,
                tokio_modbus::prelude::Slave(2),
            )
            .await
            .ok()?;
            tokio_modbus::client::Reader::read_holding_registers(&mut ctx, 3104, 1)
                .await
                .ok()?
                .ok()
        }
        .await;
        if read.as_deref() == Some(&[500]) {
            break;
        }
        assert!(Instant::now() < deadline, "Modbus TCP read: {read:?}");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let line: Value = c
        .get(format!("http://{http}/api/v1/lines/drive"))
        .send()
        .await
        .expect("GET /lines/drive")
        .json()
        .await
        .expect("JSON");
    assert_eq!(line["state"], "running", "{line}");

    // Nothing of g1 on zenoh while the name is held (its frame monitor would publish 10/s).
    let s = gateway_tests::zenoh_client(router_port).await;
    let held = samples_within(&s, "gw/g1/**", Duration::from_secs(2)).await;
    assert_eq!(held, 0, "g1 published while its name was held");

    // The rogue leaves: g1 takes the name and publishes.
    rogue.leave();
    let left = Instant::now();
    until_ready_is(&c, http, 200, Duration::from_secs(30)).await;
    let took = left.elapsed();
    assert_eq!(
        metric(&c, http, "gateway_zenoh_name_conflict").await,
        Some(0.0)
    );
    gw.wait_for("the gateway name is free now", Duration::from_secs(5));
    let deadline = Instant::now() + Duration::from_secs(20);
    while samples_within(&s, "gw/g1/drive/frames", Duration::from_secs(1)).await == 0 {
        assert!(Instant::now() < deadline, "g1 does not publish");
    }
    let replies = s
        .get("gw/g1/status")
        .timeout(Duration::from_secs(2))
        .await
        .expect("get");
    let reply = replies.recv_async().await.expect("g1 answers");
    let v: Value = serde_json::from_slice(&reply.result().expect("sample").payload().to_bytes())
        .expect("JSON");
    assert_eq!(v["name"], "g1");
    assert_ne!(v["host"].as_str(), Some(forged_host), "{v}");
    println!("a rogue held g1: g1 served Modbus TCP and REST meanwhile; it took its name {took:?} after the rogue left");
    s.close().await.expect("close");
    drop(gw);
    drop(router);
    let _ = std::fs::remove_dir_all(&dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_authenticated_fabric_keeps_rogues_off_a_gateway_name() {
    let dir = temp_dir("fleet-rogue-mtls");
    let certs = dir.join("certs");
    let deploy = gateway_tests::repo_root().join("deploy/zenoh");
    let made = Command::new("sh")
        .arg(deploy.join("make-certs.sh"))
        .arg(&certs)
        .args(["router=IP:127.0.0.1", "cab1", "cab2", "historian"])
        .output()
        .expect("make-certs.sh (openssl)");
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );
    let from_deploy = |file: &str, port: u16| {
        std::fs::read_to_string(deploy.join(file))
            .expect("deploy file")
            .replace("/etc/gateway/zenoh/", &format!("{}/", certs.display()))
            .replace("tls/0.0.0.0:7448", &format!("tls/127.0.0.1:{port}"))
            .replace(
                "tls/zenoh-router.hall1:7448",
                &format!("tls/127.0.0.1:{port}"),
            )
    };
    let (port, router) = {
        let mut started = None;
        for _ in 0..3 {
            let port = free_port();
            let file = dir.join("router.json5");
            std::fs::write(&file, from_deploy("router.json5", port)).expect("write");
            if let Some(r) = Router::start(&["--config", file.to_str().expect("utf-8")]) {
                started = Some((port, r));
                break;
            }
        }
        started.expect("the router did not open")
    };
    let endpoint = format!("tls/127.0.0.1:{port}");
    let cert = |name: &str| -> [String; 3] {
        [
            certs.join("ca.crt").display().to_string(),
            certs.join(format!("{name}.crt")).display().to_string(),
            certs.join(format!("{name}.key")).display().to_string(),
        ]
    };
    let probe = |args: &[&str]| Rogue::run(args);

    // Without a certificate: not even connected (TLS, and plain TCP on the same port).
    let (first, code) = probe(&["--connect", &endpoint, "--probe", "gw/cab1"]);
    assert!(
        first.starts_with("rogue not connected") && code == Some(2),
        "{first} {code:?}"
    );
    let (first, _) = probe(&[
        "--connect",
        &format!("tcp/127.0.0.1:{port}"),
        "--probe",
        "gw/cab1",
    ]);
    assert!(first.starts_with("rogue not connected"), "{first}");

    // With cab2's certificate it connects, but its token gw/cab1 is dropped by the router.
    let [ca, crt, key] = cert("cab2");
    let mut rogue = Rogue::start(&[
        "--connect",
        &endpoint,
        "--tls",
        &ca,
        &crt,
        &key,
        "--hold",
        "cab1",
    ]);
    assert!(
        rogue.ready(),
        "cab2's certificate connects: {}",
        rogue.first
    );
    let [hca, hcrt, hkey] = cert("historian");
    let reader = [
        "--connect",
        endpoint.as_str(),
        "--tls",
        &hca,
        &hcrt,
        &hkey,
        "--probe",
        "gw/cab1",
    ];
    let (live, _) = probe(&reader);
    assert_eq!(live, "live 0", "the router let cab2 declare gw/cab1");

    // The real cab1, with its own certificate, takes its name at once.
    let zenoh_file = dir.join("cab1.json5");
    std::fs::write(&zenoh_file, from_deploy("gateway-cab1.json5", port)).expect("write");
    let file = dir.join("cab1.toml");
    std::fs::write(
        &file,
        format!(
            r#"
[gateway]
name = "cab1"

[modbus_tcp]
listen = "127.0.0.1:0"

[zenoh]
mode = "client"
connect = ["{endpoint}"]
config_file = "{}"
"#,
            zenoh_file.display()
        ),
    )
    .expect("write config");
    let (ok, checked) = check(&file);
    assert!(ok && !checked.contains("any peer may join"), "{checked}");
    let gw = Gateway::run(&file);
    let http = gw.http.expect("http");
    let c = http_client();
    until_ready_is(&c, http, 200, Duration::from_secs(30)).await;
    assert_eq!(
        metric(&c, http, "gateway_zenoh_name_conflict").await,
        Some(0.0)
    );
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let (live, _) = probe(&reader);
        if live == "live 1" {
            break;
        }
        assert!(Instant::now() < deadline, "cab1's own token: {live}");
    }
    // The same configuration over plain TCP would be warned about.
    let open = dir.join("open.toml");
    std::fs::write(
        &open,
        "[gateway]\nname = \"cab1\"\n[zenoh]\nmode = \"client\"\nconnect = [\"tcp/10.1.0.1:7447\"]\n",
    )
    .expect("write");
    let (_, checked) = check(&open);
    assert!(checked.contains("any peer may join the fleet"), "{checked}");
    rogue.leave();
    drop(gw);
    drop(router);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Runs tests/page/fleet-rogue-test.js (Debian's Chromium through the pinned playwright-core, as
/// the fleet and page tests do) against the page at `base`; its output.
fn fleet_rogue_page(base: &str) -> String {
    let page_dir = gateway_tests::repo_root().join("tests/page");
    assert!(
        Path::new("/usr/bin/chromium").exists()
            && page_dir
                .join("node_modules/playwright-core/package.json")
                .exists(),
        "chromium or tests/page/node_modules is missing: run the tests with `.ci/test`, which \
         installs Debian's chromium and runs `npm ci` in tests/page"
    );
    let mut child = Command::new("node")
        .arg(page_dir.join("fleet-rogue-test.js"))
        .current_dir(&page_dir)
        .env("GATEWAY_URL", base)
        .env("CHROMIUM", "/usr/bin/chromium")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start node (Debian package nodejs)");
    let started = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait for node") {
            break status;
        }
        if started.elapsed() > Duration::from_secs(120) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("the fleet page script did not finish within 120 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let output = child.wait_with_output().expect("node output");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(
        status.success() && text.contains("fleet-rogue-test: all checks passed"),
        "the fleet page script failed:\n{text}"
    );
    text
}
