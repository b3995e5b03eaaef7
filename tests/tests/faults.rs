//! Fault injection end to end, on the real binary: `gateway run` with socat pty links and
//! `gateway sim` processes (`--fault silent|slow|bad-crc|wrong-address|noise`), real Modbus TCP
//! clients, and the counters read from `/metrics` on the `--http` listener.
//!
//! For each fault: the right event is counted on the faulty line, the other lines keep answering
//! with no event of their own, the line recovers without a restart when the fault stops, nothing
//! panics (the harness checks the output when the gateway is dropped), and the resident memory
//! comes back to its level.

use std::net::SocketAddr;
use std::path::Path;
use std::time::{Duration, Instant};

use gateway_tests::{start_sim, temp_dir, ChildGuard, Gateway, SocatLink};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_modbus::client::{tcp, Context, Reader};
use tokio_modbus::prelude::Slave;

/// The Altivar simulator's W3102..W3105 (002's example: SFr, tFr, HSP, LSP).
const DRIVE_WORDS: [u16; 4] = [40, 600, 500, 0];
/// The KS vario simulator's input registers 1004..1006 (001's example).
const KS_WORDS: [u16; 3] = [1066, 140, 4158];
/// Events of the serial faults (003 7.2).
const NO_REPLY: &str = "0830";
const WRONG_SLAVE: &str = "0831";
const CHECKSUM: &str = "0E57";
const BYTE_OVERFLOW: &str = "0E53";
const LINE_BREAK: &str = "080D";
/// How much the resident memory may stay above its level once a fault is over: the allocator
/// keeps some freed pages, the metrics keep a few more label sets.
const RSS_SLACK_KIB: u64 = 4 * 1024;

/// `GET /metrics` on the gateway's HTTP listener.
async fn scrape(http: SocketAddr) -> String {
    let mut stream = TcpStream::connect(http).await.expect("connect to /metrics");
    stream
        .write_all(
            format!("GET /metrics HTTP/1.1\r\nHost: {http}\r\nConnection: close\r\n\r\n")
                .as_bytes(),
        )
        .await
        .expect("request /metrics");
    let mut text = String::new();
    stream
        .read_to_string(&mut text)
        .await
        .expect("read /metrics");
    text.split_once("\r\n\r\n")
        .map(|(_, body)| body.to_owned())
        .unwrap_or_default()
}

/// The value of the sample of `name` with all `labels`, 0 when there is none.
fn sample(metrics: &str, name: &str, labels: &[(&str, &str)]) -> f64 {
    metrics
        .lines()
        .filter(|l| l.starts_with(&format!("{name}{{")) || l.starts_with(&format!("{name} ")))
        .filter(|l| {
            labels
                .iter()
                .all(|(k, v)| l.contains(&format!("{k}=\"{v}\"")))
        })
        .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
        .sum()
}

/// `gateway_events_total` of `event` (four hex digits) on `line`.
fn events(metrics: &str, line: &str, event: &str) -> f64 {
    sample(
        metrics,
        "gateway_events_total",
        &[("line", line), ("event", event)],
    )
}

/// The resident memory of a process (VmRSS) in KiB.
fn rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmRSS:"))
                .and_then(|v| v.split_whitespace().next()?.parse().ok())
        })
        .expect("VmRSS of the gateway")
}

/// The resident memory after the gateway has settled for a moment.
async fn settled_rss(pid: u32) -> u64 {
    tokio::time::sleep(Duration::from_millis(1500)).await;
    rss_kib(pid)
}

/// An Altivar line polled every 100 ms, quick to give up on a silent device and quick to retry.
fn drive_line(name: &str, port: &Path, unit: u8) -> String {
    format!(
        r#"
[lines.{name}]
port = "{port}"
protocol = "modbus-master-rtu"
baud = 19200
parity = "even"
reply_timeout = "300ms"

[lines.{name}.devices.atv71]
profile = "altivar71"
address = 2
unit_id = {unit}
offline_backoff_min = "200ms"
offline_backoff_max = "1s"

[[lines.{name}.devices.atv71.poll]]
name = "settings"
period = "100ms"
ranges = [{{ table = "holding", start = 3102, count = 4 }}]
"#,
        port = port.display()
    )
}

/// The KS vario line every test keeps healthy.
fn ks_line(port: &Path) -> String {
    format!(
        r#"
[lines.healthy]
port = "{port}"
protocol = "modbus-master-rtu"
baud = 19200
parity = "even"
reply_timeout = "300ms"

[lines.healthy.devices.ks]
profile = "ksvario"
address = 17
unit_id = 17

[[lines.healthy.devices.ks.poll]]
name = "process"
period = "100ms"
ranges = [{{ table = "input", start = 1004, count = 3 }}]
"#,
        port = port.display()
    )
}

fn head(extra: &str) -> String {
    format!("[gateway]\nname = \"faults\"\n\n[modbus_tcp]\nlisten = \"127.0.0.1:0\"\n{extra}\n")
}

/// Starts `gateway run` on `config` with /metrics on an ephemeral port.
fn start_gateway(dir: &Path, config: &str) -> Gateway {
    let file = dir.join("gateway.toml");
    std::fs::write(&file, config).expect("write config");
    let gw = Gateway::start(&[
        "run",
        "--config",
        file.to_str().expect("utf-8 path"),
        "--http",
        "127.0.0.1:0",
    ]);
    assert!(gw.http.is_some(), "no HTTP listener announced");
    gw
}

fn sim(device: &str, port: &Path, fault: Option<&str>) -> ChildGuard {
    let mut args = vec!["--device", device, "--port", port.to_str().expect("path")];
    if let Some(fault) = fault {
        args.extend(["--fault", fault, "--fault-delay", "1s"]);
    }
    start_sim(&args)
}

async fn client(gw: &Gateway, unit: u8) -> Context {
    tcp::connect_slave(gw.modbus_tcp, Slave(unit))
        .await
        .expect("connect to the gateway")
}

/// Whether the drive unit answers the simulator's words.
async fn drive_ok(ctx: &mut Context) -> bool {
    matches!(ctx.read_holding_registers(3102, 4).await, Ok(Ok(w)) if w == DRIVE_WORDS)
}

/// Reads the healthy KS vario unit and fails the test if it does not answer its words.
async fn assert_healthy(ctx: &mut Context, when: &str) {
    let answer = ctx.read_input_registers(1004, 3).await;
    assert!(
        matches!(&answer, Ok(Ok(w)) if *w == KS_WORDS),
        "the healthy line stopped answering {when}: {answer:?}"
    );
}

/// Waits until every drive unit of `units` answers its words, reading the healthy unit between.
async fn until_drives_answer(units: &mut [(u8, Context)], ks: &mut Context, limit: Duration) {
    let deadline = Instant::now() + limit;
    for (unit, ctx) in units.iter_mut() {
        while !drive_ok(ctx).await {
            assert!(
                Instant::now() < deadline,
                "unit {unit} does not answer its words within {limit:?}"
            );
            assert_healthy(ks, "while another line recovered").await;
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }
}

/// The faults of `gateway sim`, the line each runs on and the event it must raise.
const FAULTS: [(&str, &str, u8, &str); 5] = [
    ("silent", "silent", 2, NO_REPLY),
    ("slow", "slow", 3, NO_REPLY),
    ("bad-crc", "badcrc", 4, CHECKSUM),
    ("wrong-address", "wrong", 5, WRONG_SLAVE),
    ("noise", "noise", 6, BYTE_OVERFLOW),
];

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn serial_faults_are_counted_kept_apart_and_recovered_from() {
    let dir = temp_dir("serial-faults");
    let ks_link = SocatLink::new(&dir, "healthy");
    let _ks_sim = sim("ksvario", &ks_link.b, None);
    let mut config = head("") + &ks_line(&ks_link.a);
    let mut links = Vec::new();
    let mut sims = Vec::new();
    for (_, line, unit, _) in FAULTS {
        let link = SocatLink::new(&dir, line);
        config += &drive_line(line, &link.a, unit);
        sims.push(sim("altivar71", &link.b, None));
        links.push(link);
    }
    let gw = start_gateway(&dir, &config);
    let http = gw.http.expect("http");
    let mut ks = client(&gw, 17).await;
    let mut drives = Vec::new();
    for (_, _, unit, _) in FAULTS {
        drives.push((unit, client(&gw, unit).await));
    }
    until_drives_answer(&mut drives, &mut ks, Duration::from_secs(30)).await;
    assert_healthy(&mut ks, "at start").await;
    let rss_before = settled_rss(gw.pid()).await;
    let before = scrape(http).await;

    // Every device turns faulty at once.
    for ((fault, _, _, _), (link, guard)) in FAULTS.iter().zip(links.iter().zip(sims.iter_mut())) {
        guard.kill();
        *guard = sim("altivar71", &link.b, Some(fault));
    }
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        assert_healthy(&mut ks, "during the faults").await;
        let now = scrape(http).await;
        let missing: Vec<_> = FAULTS
            .iter()
            .filter(|(_, line, _, event)| events(&now, line, event) <= events(&before, line, event))
            .map(|(fault, line, _, event)| format!("{fault} on {line}: {event}"))
            .collect();
        if missing.is_empty() {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "events not counted within 20 s: {missing:?}\n{now}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    // A device that does not answer usably is offline: its unit answers 0x0B. Noise after a good
    // answer leaves the answer good.
    for ((fault, _, _, _), (unit, ctx)) in FAULTS.iter().zip(drives.iter_mut()) {
        let answer = ctx
            .read_holding_registers(3102, 4)
            .await
            .expect("transport");
        if *fault == "noise" {
            assert_eq!(answer.as_deref(), Ok(&DRIVE_WORDS[..]), "unit {unit}");
        } else {
            assert!(answer.is_err(), "unit {unit} ({fault}) answered {answer:?}");
        }
    }
    let during = scrape(http).await;
    for event in [NO_REPLY, WRONG_SLAVE, CHECKSUM, BYTE_OVERFLOW, LINE_BREAK] {
        assert_eq!(
            events(&during, "healthy", event),
            events(&before, "healthy", event),
            "the healthy line counted {event}"
        );
    }

    // The faults stop: the same gateway answers for every device again.
    for (link, guard) in links.iter().zip(sims.iter_mut()) {
        guard.kill();
        *guard = sim("altivar71", &link.b, None);
    }
    until_drives_answer(&mut drives, &mut ks, Duration::from_secs(20)).await;
    assert_healthy(&mut ks, "after the faults").await;
    let rss_after = settled_rss(gw.pid()).await;
    eprintln!("resident memory: {rss_before} KiB before the faults, {rss_after} KiB after");
    assert!(
        rss_after <= rss_before + RSS_SLACK_KIB,
        "memory did not come back: {rss_before} KiB before, {rss_after} KiB after"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_port_that_vanishes_and_returns_is_reopened() {
    let dir = temp_dir("port-vanishes");
    let ks_link = SocatLink::new(&dir, "healthy");
    let _ks_sim = sim("ksvario", &ks_link.b, None);
    let link = SocatLink::new(&dir, "flaky");
    let mut drive_sim = sim("altivar71", &link.b, None);
    let config = head("") + &ks_line(&ks_link.a) + &drive_line("flaky", &link.a, 2);
    let gw = start_gateway(&dir, &config);
    let http = gw.http.expect("http");
    let mut ks = client(&gw, 17).await;
    let mut drives = vec![(2, client(&gw, 2).await)];
    until_drives_answer(&mut drives, &mut ks, Duration::from_secs(30)).await;
    let rss_before = settled_rss(gw.pid()).await;
    let before = scrape(http).await;

    // The cable is pulled: the pty pair and the device are gone.
    let (a, b) = (link.a.clone(), link.b.clone());
    drop(link);
    drive_sim.kill();
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        assert_healthy(&mut ks, "while the other port was gone").await;
        let now = scrape(http).await;
        if events(&now, "flaky", LINE_BREAK) > events(&before, "flaky", LINE_BREAK) {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "no {LINE_BREAK} on the line whose port vanished:\n{now}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let answer = drives[0].1.read_holding_registers(3102, 4).await;
    assert!(
        matches!(answer, Ok(Err(_))),
        "unit 2 answered {answer:?} without a port"
    );
    for _ in 0..10 {
        assert_healthy(&mut ks, "while the other port was gone").await;
        tokio::time::sleep(Duration::from_millis(100)).await;
    }

    // The cable is back on the same paths.
    let link = SocatLink::new(&dir, "flaky");
    assert_eq!((&link.a, &link.b), (&a, &b));
    let _drive_sim = sim("altivar71", &link.b, None);
    until_drives_answer(&mut drives, &mut ks, Duration::from_secs(30)).await;
    let after = scrape(http).await;
    for event in [NO_REPLY, LINE_BREAK] {
        assert_eq!(
            events(&after, "healthy", event),
            events(&before, "healthy", event),
            "the healthy line counted {event}"
        );
    }
    let rss_after = settled_rss(gw.pid()).await;
    eprintln!("resident memory: {rss_before} KiB before, {rss_after} KiB after the port returned");
    assert!(
        rss_after <= rss_before + RSS_SLACK_KIB,
        "memory did not come back: {rss_before} KiB before, {rss_after} KiB after"
    );
}

/// What became of one connection of the burst.
#[derive(Debug, PartialEq, Eq)]
enum Outcome {
    Answered,
    Closed,
}

/// Connects, asks unit 17 for its three input registers, and waits for the answer or the close.
async fn one_of_the_burst(addr: SocketAddr, id: u16) -> (Outcome, Option<TcpStream>) {
    let mut stream = TcpStream::connect(addr).await.expect("connect");
    let [t0, t1] = id.to_be_bytes();
    let request = [t0, t1, 0, 0, 0, 6, 17, 0x04, 0x03, 0xEC, 0x00, 0x03];
    if stream.write_all(&request).await.is_err() {
        return (Outcome::Closed, None);
    }
    let mut answer = [0u8; 15];
    let read = tokio::time::timeout(Duration::from_secs(20), stream.read_exact(&mut answer)).await;
    match read {
        Ok(Ok(_)) => {
            assert_eq!(
                answer.get(7..),
                Some(&[0x04, 6, 0x04, 0x2A, 0x00, 0x8C, 0x10, 0x3E][..])
            );
            (Outcome::Answered, Some(stream))
        }
        Ok(Err(_)) => (Outcome::Closed, None),
        Err(_) => panic!("connection {id} neither answered nor closed within 20 s"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_of_1000_connections_and_stalled_headers_leave_the_server_serving() {
    const BURST: u16 = 1000;
    const MAX_CONNECTIONS: usize = 200;
    const STALLED: usize = 50;
    let dir = temp_dir("tcp-faults");
    let ks_link = SocatLink::new(&dir, "healthy");
    let _ks_sim = sim("ksvario", &ks_link.b, None);
    let limits = format!("max_connections = {MAX_CONNECTIONS}\nidle_timeout = \"2s\"\n");
    let gw = start_gateway(&dir, &(head(&limits) + &ks_line(&ks_link.a)));
    let http = gw.http.expect("http");
    let mut ks = client(&gw, 17).await;
    let deadline = Instant::now() + Duration::from_secs(30);
    while !matches!(ks.read_input_registers(1004, 3).await, Ok(Ok(w)) if w == KS_WORDS) {
        assert!(Instant::now() < deadline, "unit 17 never answered");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    drop(ks);
    let rss_before = settled_rss(gw.pid()).await;
    let before = scrape(http).await;
    let rejected = |m: &str| {
        sample(
            m,
            "gateway_modbus_tcp_connections_rejected_total",
            &[("reason", "limit")],
        )
    };

    // 1000 clients at once: each is served or closed at once, none hangs.
    let addr = gw.modbus_tcp;
    let burst_started = Instant::now();
    let tasks: Vec<_> = (0..BURST)
        .map(|id| tokio::spawn(one_of_the_burst(addr, id)))
        .collect();
    let mut answered = 0usize;
    let mut open = Vec::new();
    for task in tasks {
        let (outcome, stream) = task.await.expect("burst task");
        if outcome == Outcome::Answered {
            answered += 1;
        }
        open.extend(stream);
    }
    let burst_took = burst_started.elapsed();
    let closed = usize::from(BURST) - answered;
    let during = scrape(http).await;
    eprintln!("burst: {answered} answered, {closed} closed at the limit, in {burst_took:?}");
    assert!(answered > 0, "no connection of the burst was served");
    // Served connections are held open; only the idle timeout frees their places.
    if burst_took < Duration::from_secs(2) {
        assert!(
            answered <= MAX_CONNECTIONS,
            "{answered} served, more than max_connections {MAX_CONNECTIONS}"
        );
    }
    assert_eq!(
        rejected(&during) - rejected(&before),
        closed as f64,
        "every connection closed at the limit is counted"
    );
    drop(open);
    // The places of the clients that left are free once the server has read their FIN: wait for
    // that (the gauge at 0) before taking one, else the new client races the burst's closes and
    // may find the server still full.
    let left = Instant::now();
    loop {
        let open_now = sample(&scrape(http).await, "gateway_modbus_tcp_connections", &[]);
        if open_now == 0.0 {
            break;
        }
        assert!(
            left.elapsed() < Duration::from_millis(1500),
            "{open_now} connections still open {:?} after their clients left",
            left.elapsed()
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    eprintln!(
        "the burst's places were free {:?} after its clients left",
        left.elapsed()
    );

    // The server keeps serving.
    let mut ks = client(&gw, 17).await;
    assert_healthy(&mut ks, "after the burst").await;

    // Clients that never finish their MBAP header: closed by the idle timeout, while others are
    // served.
    let mut stalled = Vec::new();
    for _ in 0..STALLED {
        let mut s = TcpStream::connect(addr).await.expect("connect");
        s.write_all(&[0x00, 0x01, 0x00])
            .await
            .expect("half a header");
        stalled.push(s);
    }
    let started = Instant::now();
    tokio::time::sleep(Duration::from_millis(300)).await;
    let with_stalled = scrape(http).await;
    let gauge = sample(&with_stalled, "gateway_modbus_tcp_connections", &[]);
    assert!(
        gauge >= STALLED as f64,
        "{gauge} connections open with {STALLED} stalled ones"
    );
    assert_healthy(&mut ks, "while clients stalled").await;
    for mut s in stalled {
        let mut buf = [0u8; 16];
        let read = tokio::time::timeout(Duration::from_secs(10), s.read(&mut buf)).await;
        assert!(
            matches!(read, Ok(Ok(0)) | Ok(Err(_))),
            "a stalled client was not closed: {read:?}"
        );
    }
    let closed_after = started.elapsed();
    eprintln!("{STALLED} stalled clients closed after {closed_after:?}");
    assert!(
        closed_after >= Duration::from_secs(2),
        "closed before the idle timeout"
    );
    drop(ks);
    let mut ks = client(&gw, 17).await;
    assert_healthy(&mut ks, "after the stalled clients").await;
    drop(ks);

    let rss_after = settled_rss(gw.pid()).await;
    let after = scrape(http).await;
    assert!(
        sample(&after, "gateway_modbus_tcp_connections", &[]) <= 1.0,
        "connections still open:\n{after}"
    );
    eprintln!("resident memory: {rss_before} KiB before, {rss_after} KiB after");
    assert!(
        rss_after <= rss_before + RSS_SLACK_KIB,
        "memory did not come back: {rss_before} KiB before, {rss_after} KiB after"
    );
}
