//! End to end on the binary: a fleet of three gateways, each with its own simulated drive on a
//! pty pair, connected as zenoh clients to one router (the Python binding in router mode on
//! tcp/127.0.0.1, multicast scouting off everywhere).
//!
//! One test, in order, since three gateways and a router are slow to start on a loaded machine: the
//! fleet query returns three; `gateway fleet status` prints all three with their lines; `GET
//! /api/v1/fleet` of one lists the two others, and its status page shows them in Debian's Chromium
//! (tests/page/fleet-test.js), each with a link that opens its page; writes are off by default (two
//! gateways refuse a set) and a set through the router on the one with writes on lands in its drive
//! and in no other; a duplicate name is refused with `--exit-on-duplicate-name` (exit 64, naming
//! the other); the router restarted
//! loses no gateway for good (the time each takes to come back is printed); a gateway frozen
//! (SIGSTOP) leaves the fabric within its configured lease.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use gateway_tests::{device_sim, free_port, temp_dir, ChildGuard, Gateway, SocatLink};
use serde_json::Value;

/// The lease every gateway of the test configures (`[zenoh] lease`).
const LEASE: Duration = Duration::from_secs(3);
const NAMES: [&str; 3] = ["g1", "g2", "g3"];

/// The router: `tests/python/zenoh_router.py PORT`, killed when dropped.
struct Router(ChildGuard);

impl Router {
    /// Starts the router on `port`; `None` when it did not open (the port taken).
    fn start(port: u16) -> Option<Self> {
        let python = gateway_tests::venv_python("zenoh");
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/zenoh_router.py");
        let mut child = Command::new(python)
            .arg(script)
            .arg(port.to_string())
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("python starts");
        let out = child.stdout.take().expect("stdout");
        let mut line = String::new();
        std::io::BufRead::read_line(&mut std::io::BufReader::new(out), &mut line)
            .expect("router output");
        let guard = ChildGuard(child);
        line.contains("listening").then_some(Self(guard))
    }

    /// Starts the router on `port`, retrying while the port is still held (a restart).
    fn start_within(port: u16, limit: Duration) -> Self {
        let deadline = Instant::now() + limit;
        loop {
            if let Some(r) = Self::start(port) {
                return r;
            }
            assert!(
                Instant::now() < deadline,
                "the router did not reopen port {port}"
            );
            std::thread::sleep(Duration::from_millis(200));
        }
    }
}

fn gateway_config(name: &str, port: &Path, router: u16, writes: bool) -> String {
    let writes = if writes { "writes = true\n" } else { "" };
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
lease = "{lease}s"
{writes}
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
        lease = LEASE.as_secs(),
        port = port.display(),
    )
}

/// A client session of the router, multicast scouting off.
async fn client(router: u16) -> zenoh::Session {
    gateway_tests::zenoh_client(router).await
}

/// The gateway status replies on `gw/*/status`, by name.
async fn statuses(s: &zenoh::Session) -> Vec<(String, Value)> {
    let replies = s
        .get("gw/*/status")
        .timeout(Duration::from_secs(2))
        .await
        .expect("get");
    let mut out = Vec::new();
    while let Ok(r) = replies.recv_async().await {
        if let Ok(sample) = r.result() {
            let v: Value = serde_json::from_slice(&sample.payload().to_bytes()).expect("JSON");
            out.push((v["name"].as_str().unwrap_or_default().to_owned(), v));
        }
    }
    out.sort_by(|a, b| a.0.cmp(&b.0));
    out
}

/// Waits until the names answering `gw/*/status` are `want`; how long it took.
async fn until_names(s: &zenoh::Session, want: &[&str], limit: Duration) -> Duration {
    let start = Instant::now();
    loop {
        let got: Vec<String> = statuses(s).await.into_iter().map(|(n, _)| n).collect();
        if got == want {
            return start.elapsed();
        }
        assert!(
            start.elapsed() < limit,
            "gw/*/status answered by {got:?}, expected {want:?} within {limit:?}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// Whether a liveliness token `key` is live.
async fn token_live(s: &zenoh::Session, key: &str) -> bool {
    let replies = s
        .liveliness()
        .get(key)
        .timeout(Duration::from_secs(1))
        .await
        .expect("liveliness get");
    let mut live = false;
    while let Ok(r) = replies.recv_async().await {
        live |= r.result().is_ok();
    }
    live
}

/// HSP of a gateway's drive as its zenoh tag query answers it.
async fn hsp(s: &zenoh::Session, gw: &str) -> Option<f64> {
    let replies = s
        .get(format!("gw/{gw}/drive/atv71/HSP"))
        .timeout(Duration::from_secs(2))
        .await
        .expect("get");
    let mut value = None;
    while let Ok(r) = replies.recv_async().await {
        if let Ok(sample) = r.result() {
            let v: Value = serde_json::from_slice(&sample.payload().to_bytes()).expect("JSON");
            value = v["value"].as_f64();
        }
    }
    value
}

/// A set through the router, and its result.
async fn set_hsp(s: &zenoh::Session, gw: &str, value: &str) -> Value {
    let replies = s
        .get(format!("gw/{gw}/drive/atv71/HSP/set"))
        .payload(value)
        .timeout(Duration::from_secs(10))
        .await
        .expect("get");
    let reply = replies.recv_async().await.expect("a reply");
    let sample = reply.result().expect("a sample");
    serde_json::from_slice(&sample.payload().to_bytes()).expect("JSON")
}

fn fleet_status(router: u16) -> std::process::Output {
    Command::new(gateway_tests::gateway_bin())
        .args([
            "fleet",
            "status",
            "--connect",
            &format!("tcp/127.0.0.1:{router}"),
        ])
        .output()
        .expect("gateway fleet status")
}

/// Runs `gateway run ... extra` until it exits (at most `limit`): its exit code and output.
fn run_to_exit(config: &Path, extra: &[&str], limit: Duration) -> (Option<i32>, String) {
    let mut child: Child = Command::new(gateway_tests::gateway_bin())
        .args(Gateway::run_args(config))
        .args(extra)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("gateway starts");
    let deadline = Instant::now() + limit;
    let code = loop {
        if let Some(status) = child.try_wait().expect("wait") {
            break status.code();
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let out = child.wait_with_output().expect("output");
    (
        code,
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_gateways_through_one_router() {
    let dir = temp_dir("fleet");
    let (router_port, mut router) = {
        let mut tries = 0;
        loop {
            let port = free_port();
            if let Some(r) = Router::start(port) {
                break (port, r);
            }
            tries += 1;
            assert!(tries < 3, "the router did not open");
        }
    };
    let mut links = Vec::new();
    let mut sims = Vec::new();
    let mut gateways = Vec::new();
    for (i, name) in NAMES.iter().enumerate() {
        let link = SocatLink::new(&dir, name);
        sims.push(device_sim("altivar71", &link.b));
        let file = dir.join(format!("{name}.toml"));
        // Writes on only on g1: every other gateway keeps the default (off).
        std::fs::write(&file, gateway_config(name, &link.a, router_port, i == 0))
            .expect("write config");
        gateways.push(Gateway::run(&file));
        links.push(link);
    }
    let s = client(router_port).await;

    // The fleet query returns three, each with its line and device.
    until_names(&s, &NAMES, Duration::from_secs(30)).await;
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let all = statuses(&s).await;
        let online = all
            .iter()
            .filter(|(_, v)| v["lines"][0]["devices"][0]["online"] == Value::Bool(true))
            .count();
        if online == 3 {
            for (name, v) in &all {
                assert_eq!(v["lines"][0]["name"], "drive", "{name}: {v}");
                assert!(v["zenoh"]["zid"].is_string(), "{name}: {v}");
                assert!(
                    v["http"]
                        .as_str()
                        .is_some_and(|u| u.starts_with("http://127.0.0.1:")),
                    "{v}"
                );
            }
            break;
        }
        assert!(Instant::now() < deadline, "drives not online: {all:?}");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    // Liveliness: a token per gateway, line and device.
    for name in NAMES {
        for key in [
            format!("gw/{name}"),
            format!("gw/{name}/drive"),
            format!("gw/{name}/drive/atv71"),
        ] {
            let deadline = Instant::now() + Duration::from_secs(10);
            while !token_live(&s, &key).await {
                assert!(Instant::now() < deadline, "no liveliness token {key}");
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
        }
    }

    // What passes through the router with three gateways (every sample under gw/**, 3 s), and
    // the router's resident memory: printed for the fleet's arithmetic (docs/fleet.md).
    let (count, bytes) = (
        std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0)),
        std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0)),
    );
    let sub = {
        let (count, bytes) = (count.clone(), bytes.clone());
        s.declare_subscriber("gw/**")
            .callback(move |sample| {
                count.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let len = sample.payload().len() + sample.key_expr().as_str().len();
                bytes.fetch_add(len as u64, std::sync::atomic::Ordering::Relaxed);
            })
            .await
            .expect("subscribe")
    };
    tokio::time::sleep(Duration::from_secs(3)).await;
    drop(sub);
    let rss = std::fs::read_to_string(format!("/proc/{}/status", router.0 .0.id()))
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmRSS:"))
                .map(|v| v.trim().to_owned())
        })
        .unwrap_or_default();
    println!(
        "through the router, three gateways: {:.0} samples/s, {:.0} bytes/s (payload + key); router VmRSS {rss} (Python binding, interpreter included)",
        count.load(std::sync::atomic::Ordering::Relaxed) as f64 / 3.0,
        bytes.load(std::sync::atomic::Ordering::Relaxed) as f64 / 3.0,
    );

    // `gateway fleet status` prints all three with their lines and devices.
    let out = fleet_status(router_port);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for name in NAMES {
        assert!(
            text.lines()
                .any(|l| l.starts_with(name) && l.contains("drive") && l.contains("atv71")),
            "{name} missing in:\n{text}"
        );
    }
    println!("fleet status:\n{text}");

    // GET /api/v1/fleet of g1 lists g2 and g3 with a link to their pages.
    let http = gateways[0].http.expect("http");
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let fleet: Value = reqwest::get(format!("http://{http}/api/v1/fleet"))
            .await
            .expect("GET /fleet")
            .json()
            .await
            .expect("JSON");
        let list = fleet["gateways"].as_array().cloned().unwrap_or_default();
        let described = list
            .iter()
            .filter(|g| {
                g["online"] == Value::Bool(true) && g["link"].is_string() && g["zid"].is_string()
            })
            .count();
        if list.len() == 2 && described == 2 {
            let names: Vec<&str> = list.iter().filter_map(|g| g["name"].as_str()).collect();
            assert_eq!(names, ["g2", "g3"], "{fleet}");
            break;
        }
        assert!(Instant::now() < deadline, "GET /api/v1/fleet: {fleet}");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }

    // The status page of g1 shows the same in a real browser: g2 and g3 online, each with a
    // link that opens its own page.
    let others = format!(
        "g2=http://{},g3=http://{}",
        gateways[1].http.expect("http"),
        gateways[2].http.expect("http")
    );
    let page = tokio::task::spawn_blocking(move || fleet_page(&format!("http://{http}"), &others))
        .await
        .expect("the browser task");
    println!("{page}");

    // Writes stay off by default: g2 and g3 refuse a set; on g1 it lands in g1's drive only.
    for name in ["g2", "g3"] {
        let r = set_hsp(&s, name, "42.5").await;
        assert_eq!(r["ok"], Value::Bool(false), "{name}: {r}");
        assert!(
            r["error"]
                .as_str()
                .is_some_and(|e| e.contains("writes over zenoh are off")),
            "{r}"
        );
    }
    // `gateway fleet watch` prints the new value as it comes, one line with the time.
    let mut watch = Command::new(gateway_tests::gateway_bin())
        .args([
            "fleet",
            "watch",
            "gw/*/drive/atv71/HSP",
            "--connect",
            &format!("tcp/127.0.0.1:{router_port}"),
        ])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("gateway fleet watch");
    let watched = {
        let out = watch.stdout.take().expect("stdout");
        let (tx, rx) = std::sync::mpsc::channel::<String>();
        std::thread::spawn(move || {
            for line in std::io::BufRead::lines(std::io::BufReader::new(out)).map_while(Result::ok)
            {
                if tx.send(line).is_err() {
                    return;
                }
            }
        });
        rx
    };
    let mut watch_err = watch.stderr.take().expect("stderr");
    let mut watch = ChildGuard(watch);
    // It says when it watches (its subscriber declared).
    let mut first = [0u8; 1];
    std::io::Read::read_exact(&mut watch_err, &mut first).expect("fleet watch started");
    tokio::time::sleep(Duration::from_millis(500)).await;
    let r = set_hsp(&s, "g1", "42.5").await;
    assert_eq!(r["ok"], Value::Bool(true), "{r}");
    let line = watched
        .recv_timeout(Duration::from_secs(10))
        .expect("fleet watch printed the new value");
    assert!(
        line.starts_with("20")
            && line.contains(" gw/g1/drive/atv71/HSP {")
            && line.contains("42.5"),
        "{line}"
    );
    assert!(
        watched
            .try_recv()
            .map_or(true, |l| !l.contains("gw/g2") && !l.contains("gw/g3")),
        "only g1's drive changed"
    );
    watch.kill();
    println!("fleet watch: {line}");
    let deadline = Instant::now() + Duration::from_secs(10);
    while hsp(&s, "g1").await != Some(42.5) {
        assert!(Instant::now() < deadline, "HSP of g1 never read 42.5");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // g1's drive itself holds it (read over g1's Modbus TCP, from the drive), the others not.
    for (gw, want) in gateways.iter().zip([425u16, 500, 500]) {
        let mut ctx = tokio_modbus::client::tcp::connect_slave(
            gw.modbus_tcp,
            tokio_modbus::prelude::Slave(2),
        )
        .await
        .expect("connect");
        let words = tokio_modbus::client::Reader::read_holding_registers(&mut ctx, 3104, 1)
            .await
            .expect("transport")
            .expect("read");
        assert_eq!(words, [want], "HSP in the drive of {:?}", gw.modbus_tcp);
    }
    assert_eq!(hsp(&s, "g2").await, Some(50.0));
    assert_eq!(hsp(&s, "g3").await, Some(50.0));

    // A second gateway named g2 started with --exit-on-duplicate-name is refused: exit 64,
    // naming the name and the other gateway (without the flag it would serve its lines and
    // wait for the name: tests/tests/fleet_rogue.rs).
    let dup_link = SocatLink::new(&dir, "dup");
    let dup = dir.join("dup.toml");
    std::fs::write(&dup, gateway_config("g2", &dup_link.a, router_port, false)).expect("write");
    let (code, out) = run_to_exit(&dup, &["--exit-on-duplicate-name"], Duration::from_secs(60));
    assert_eq!(code, Some(64), "{out}");
    let g2_zid = statuses(&s)
        .await
        .into_iter()
        .find(|(n, _)| n == "g2")
        .and_then(|(_, v)| v["zenoh"]["zid"].as_str().map(str::to_owned))
        .expect("g2 answers");
    assert!(
        out.contains("\"g2\" is already live") && out.contains(&g2_zid),
        "the refusal names the name and the other: {out}"
    );
    // ... and the first g2 is still there, alone.
    until_names(&s, &NAMES, Duration::from_secs(5)).await;

    // The router restarts: every gateway comes back.
    s.close().await.expect("close");
    router.0.kill();
    let down = Instant::now();
    router = Router::start_within(router_port, Duration::from_secs(30));
    let restarted = down.elapsed();
    let s = client(router_port).await;
    let mut back = Vec::new();
    for name in NAMES {
        let start = Instant::now();
        loop {
            let got = statuses(&s).await;
            if got.iter().any(|(n, _)| n == name) {
                back.push((name, down.elapsed(), start.elapsed()));
                break;
            }
            assert!(
                start.elapsed() < Duration::from_secs(60),
                "{name} did not come back"
            );
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }
    until_names(&s, &NAMES, Duration::from_secs(10)).await;
    println!("router restart: listening again {restarted:?} after the kill");
    for (name, since_kill, since_router) in &back {
        println!(
            "router restart: {name} answers again {since_kill:?} after the kill, {since_router:?} after the router listened"
        );
    }

    // A gateway frozen (SIGSTOP: no close, no undeclare) leaves the fabric within its lease.
    let g3 = gateways[2].pid();
    let stopped = Command::new("kill")
        .args(["-STOP", &g3.to_string()])
        .status()
        .expect("kill -STOP");
    assert!(stopped.success());
    let frozen = Instant::now();
    while token_live(&s, "gw/g3").await {
        assert!(
            frozen.elapsed() < LEASE + Duration::from_secs(3),
            "g3's token still live {:?} after it froze (lease {LEASE:?})",
            frozen.elapsed()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let gone = frozen.elapsed();
    println!("a frozen gateway's token went {gone:?} after it froze (lease {LEASE:?})");
    until_names(&s, &["g1", "g2"], Duration::from_secs(5)).await;
    let _ = Command::new("kill")
        .args(["-CONT", &g3.to_string()])
        .status();
    gateways[2].kill();
    s.close().await.expect("close");
    drop(router);
    drop((sims, links));
    let _ = std::fs::remove_dir_all(PathBuf::from(&dir));
}

/// Runs tests/page/fleet-test.js (Debian's Chromium through the pinned playwright-core, as the
/// page test does) against the page at `base`; `others` is `name=url,...`. Its output.
fn fleet_page(base: &str, others: &str) -> String {
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
        .arg(page_dir.join("fleet-test.js"))
        .current_dir(&page_dir)
        .env("GATEWAY_URL", base)
        .env("FLEET", others)
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
        status.success() && text.contains("fleet-test: all checks passed"),
        "the fleet page script failed:\n{text}"
    );
    text
}
