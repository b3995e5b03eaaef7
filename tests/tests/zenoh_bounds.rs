//! End to end on the binary: what a zenoh peer sends is bounded. A flood of refused puts leaves
//! a few log lines and is counted put by put in `gateway_writes_total`; a put far larger than
//! `[zenoh] max_payload` is dropped while zenoh reassembles it, so the gateway does not grow by
//! its size; a tag without a unit reads the same over zenoh as over REST.

use std::net::SocketAddr;
use std::path::Path;
use std::time::{Duration, Instant};

use gateway_tests::{temp_dir, Gateway, SocatLink};
use zenoh::qos::CongestionControl;

/// The flood of the issue: 2 000 puts a second for 10 s.
const FLOOD_RATE: u32 = 2_000;
/// Puts sent back to back in one burst of the flood (the command queue holds 64 by default).
const BURST: u32 = 200;
const FLOOD_SECONDS: u32 = 10;

/// A gateway named `bounds` with one ASCII line and zenoh writes off (the default).
fn writes_off_gateway(dir: &Path, link: &SocatLink) -> Gateway {
    let config = |zenoh_port: u16| {
        format!(
            r#"
[gateway]
name = "bounds"

[modbus_tcp]
listen = "127.0.0.1:0"

[zenoh]
listen = ["tcp/127.0.0.1:{zenoh_port}"]
multicast_scouting = false

[lines.ascii]
port = "{port}"
protocol = "ascii"
end_criterion = "end-chars"
end_chars = [0x03]
"#,
            port = link.a.display(),
        )
    };
    Gateway::run_on_free_zenoh_port(&dir.join("gateway.toml"), config)
}

fn scrape(http: SocketAddr) -> String {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(http).expect("connect /metrics");
    s.write_all(
        format!("GET /metrics HTTP/1.1\r\nHost: {http}\r\nConnection: close\r\n\r\n").as_bytes(),
    )
    .expect("request");
    let mut text = String::new();
    s.read_to_string(&mut text).expect("read");
    text
}

/// The value of one series of `/metrics` (0 when it is not there).
fn series(metrics: &str, name: &str) -> u64 {
    metrics
        .lines()
        .find_map(|l| l.strip_prefix(name)?.trim().parse().ok())
        .unwrap_or(0)
}

/// `gateway_writes_total` of zenoh refusals for `reason`.
fn refused(http: SocketAddr, reason: &str) -> u64 {
    let name =
        format!("gateway_writes_total{{path=\"zenoh\",reason=\"{reason}\",result=\"refused\"}}");
    series(&scrape(http), &name)
}

/// Waits until the zenoh refusals for `reason` reach `n` (within `timeout`); the last count.
fn wait_refused(http: SocketAddr, reason: &str, n: u64, timeout: Duration) -> u64 {
    let deadline = Instant::now() + timeout;
    loop {
        let now = refused(http, reason);
        if now >= n || Instant::now() > deadline {
            return now;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The resident set of a process, in bytes (`VmRSS` of /proc/<pid>/status).
fn rss(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("proc status");
    let kib: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .expect("VmRSS");
    kib * 1024
}

/// A put every zenoh delivers (blocking under congestion instead of dropping it).
async fn put(session: &zenoh::Session, key: &str, payload: Vec<u8>) {
    session
        .put(key, payload)
        .congestion_control(CongestionControl::Block)
        .await
        .expect("put");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flood_of_refused_puts_is_counted_one_by_one_and_logs_little() {
    let dir = temp_dir("zenoh-flood");
    let link = SocatLink::new(&dir, "ascii");
    let gw = writes_off_gateway(&dir, &link);
    let http = gw.http.expect("http");
    let session = gateway_tests::zenoh_client(gw.zenoh_port.expect("zenoh port")).await;
    // The subscriber is declared once the session is up; a first put tells when it is.
    let key = "gw/bounds/ascii/dev/value/set";
    let deadline = Instant::now() + Duration::from_secs(20);
    while refused(http, "writes_off") == 0 {
        assert!(Instant::now() < deadline, "the first put was never counted");
        put(&session, key, b"1".to_vec()).await;
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let before = refused(http, "writes_off");
    let lines_before = gw.output().lines().count();

    let total = FLOOD_RATE * FLOOD_SECONDS;
    let start = tokio::time::Instant::now();
    // Bursts of BURST puts back to back, BURST / FLOOD_RATE seconds apart: the rate of the
    // issue, arriving as a client that sends in batches does (more than a command queue holds).
    let step = Duration::from_secs(1) * BURST / FLOOD_RATE;
    for i in 0..total / BURST {
        tokio::time::sleep_until(start + step * i).await;
        for _ in 0..BURST {
            put(&session, key, b"1500".to_vec()).await;
        }
    }
    let took = start.elapsed();
    let expected = before + u64::from(total);
    let counted = wait_refused(http, "writes_off", expected, Duration::from_secs(60));
    let lines = gw.output().lines().count() - lines_before;
    let output = gw.output();
    eprintln!(
        "{total} puts in {took:?}: {} counted, {lines} log lines",
        counted - before
    );
    assert_eq!(counted, expected, "every refused put is counted");
    assert!(
        lines < 100,
        "{lines} log lines for {total} refused puts:\n{output}"
    );
    // The audit still says what happened, with how many were left out.
    assert!(
        output.lines().any(|l| l.contains("audit")
            && l.contains("writes_off")
            && l.contains("writes over zenoh are off")),
        "no audit line of the refusals:\n{output}"
    );
    session.close().await.expect("close");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_put_far_over_max_payload_is_dropped_before_it_grows_the_gateway() {
    let dir = temp_dir("zenoh-large");
    let link = SocatLink::new(&dir, "ascii");
    let gw = writes_off_gateway(&dir, &link);
    let http = gw.http.expect("http");
    let session = gateway_tests::zenoh_client(gw.zenoh_port.expect("zenoh port")).await;
    let key = "gw/bounds/ascii/dev/value/set";
    let deadline = Instant::now() + Duration::from_secs(20);
    while refused(http, "writes_off") == 0 {
        assert!(Instant::now() < deadline, "the first put was never counted");
        put(&session, key, b"1".to_vec()).await;
        tokio::time::sleep(Duration::from_millis(200)).await;
    }

    // Over max_payload (64 KiB) but within zenoh's limit (max_payload + 64 KiB): the bridge
    // refuses it by its size, before writes are looked at.
    put(&session, key, vec![b'7'; 100 * 1024]).await;
    assert_eq!(
        wait_refused(http, "too_large", 1, Duration::from_secs(20)),
        1,
        "the 100 KiB put is refused as too large"
    );

    // 8 MiB: zenoh drops it while the fragments arrive. A small put after it (same priority,
    // same reliability, so delivered after it) tells when the gateway has seen all of it.
    tokio::time::sleep(Duration::from_millis(500)).await;
    let pid = gw.pid();
    let before = rss(pid);
    let size: u64 = 8 * 1024 * 1024;
    put(&session, key, vec![b'7'; 8 * 1024 * 1024]).await;
    let small = refused(http, "writes_off");
    put(&session, key, b"2".to_vec()).await;
    assert_eq!(
        wait_refused(http, "writes_off", small + 1, Duration::from_secs(30)),
        small + 1,
        "the link outlives the large put"
    );
    tokio::time::sleep(Duration::from_millis(500)).await;
    let after = rss(pid);
    let grown = after.saturating_sub(before);
    eprintln!("8 MiB put: VmRSS {before} -> {after} bytes (+{grown})");
    assert!(
        grown < size,
        "the gateway grew by {grown} bytes for an 8 MiB put"
    );
    assert_eq!(
        refused(http, "too_large"),
        1,
        "the 8 MiB put never reached the bridge"
    );
    session.close().await.expect("close");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tag_without_a_unit_reads_the_same_over_zenoh_as_over_rest() {
    let gw = Gateway::demo(&[]);
    let http = gw.http.expect("http");
    let session = gateway_tests::zenoh_client(gw.zenoh_port.expect("zenoh port")).await;
    // The demo meter's `preset` has no unit; `energy` has one.
    for (tag, unit) in [("preset", ""), ("energy", "Wh")] {
        let url = format!("http://{http}/api/v1/lines/ksvario/devices/meter/tags/{tag}");
        let deadline = Instant::now() + Duration::from_secs(30);
        let rest = loop {
            let r = reqwest::get(&url).await.expect("REST get");
            if r.status().is_success() {
                break r.json::<serde_json::Value>().await.expect("REST JSON");
            }
            assert!(Instant::now() < deadline, "{url}: {}", r.status());
            tokio::time::sleep(Duration::from_millis(200)).await;
        };
        let replies = session
            .get(format!("gw/demo/ksvario/meter/{tag}"))
            .await
            .expect("get");
        let reply = tokio::time::timeout(Duration::from_secs(10), replies.recv_async())
            .await
            .expect("a reply")
            .expect("reply");
        let sample = reply.result().expect("a tag value");
        let zenoh: serde_json::Value =
            serde_json::from_slice(&sample.payload().to_bytes()).expect("JSON");
        assert_eq!(zenoh["unit"], unit, "zenoh: {zenoh}");
        assert_eq!(zenoh["unit"], rest["unit"], "zenoh {zenoh}, REST {rest}");
    }
    session.close().await.expect("close");
}
