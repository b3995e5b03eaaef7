//! Fair use of the bus and honest offline, end to end: `gateway run` with a socat pty link to a
//! `gateway sim` Altivar 71, real Modbus TCP clients, `/metrics` read on the `--http` listener.
//!
//! - A closed-loop writer (FC 06 to the drive) and a closed-loop on-demand reader (a word nobody
//!   polls) keep the line busy while a third client reads the polled, cached words: every cached
//!   read succeeds, the image never gets older than the poll group's stated bound, and the
//!   achieved cycle stays within it.
//! - A drive that ignores one request type (FC 08) stays online for cached readers while a
//!   client keeps sending that request: each such request fails for that client alone.
//!
//! Each test prints its figures (cached reads, failures, longest image age, longest cycle).

use std::net::SocketAddr;
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use gateway_tests::{start_sim, temp_dir, ChildGuard, Gateway, SocatLink};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_modbus::client::{tcp, Client, Context, Reader, Writer};
use tokio_modbus::prelude::{Request, Slave};

/// The Altivar simulator's W3102..W3105 (002's example: SFr, tFr, HSP, LSP).
const DRIVE_WORDS: [u16; 4] = [40, 600, 500, 0];
/// ACC (W9001), a drive parameter nobody polls: written and read on demand.
const ACC: u16 = 9001;
/// The poll period of the drive's group.
const PERIOD: Duration = Duration::from_millis(200);
/// How long the clients run.
const RUN: Duration = Duration::from_secs(6);

/// A drive line polling W3102..W3105 every 200 ms with the reply monitoring time `reply_timeout`.
fn config(port: &Path, reply_timeout: &str) -> String {
    format!(
        r#"[gateway]
name = "fairness"

[modbus_tcp]
listen = "127.0.0.1:0"

[lines.drive]
port = "{port}"
protocol = "modbus-master-rtu"
baud = 19200
parity = "even"
reply_timeout = "{reply_timeout}"

[lines.drive.devices.atv71]
profile = "altivar71"
address = 2
unit_id = 2

[[lines.drive.devices.atv71.poll]]
name = "settings"
period = "200ms"
ranges = [{{ table = "holding", start = 3102, count = 4 }}]
"#,
        port = port.display()
    )
}

fn start_gateway(dir: &Path, config: &str) -> Gateway {
    let file = dir.join("gateway.toml");
    std::fs::write(&file, config).expect("write config");
    let gw = Gateway::run(&file);
    assert!(gw.http.is_some(), "no HTTP listener announced");
    gw
}

fn drive_sim(port: &Path, extra: &[&str]) -> ChildGuard {
    let mut args = vec![
        "--device",
        "altivar71",
        "--port",
        port.to_str().expect("utf-8 path"),
    ];
    args.extend_from_slice(extra);
    start_sim(&args)
}

async fn client(gw: &Gateway) -> Context {
    tcp::connect_slave(gw.modbus_tcp, Slave(2))
        .await
        .expect("connect to the gateway")
}

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

/// The value of the first sample of `name` with all `labels`.
fn sample(metrics: &str, name: &str, labels: &[(&str, &str)]) -> Option<f64> {
    metrics
        .lines()
        .filter(|l| l.starts_with(&format!("{name}{{")) || l.starts_with(&format!("{name} ")))
        .filter(|l| {
            labels
                .iter()
                .all(|(k, v)| l.contains(&format!("{k}=\"{v}\"")))
        })
        .find_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
}

/// Waits until the drive's cached words read back.
async fn until_polled(ctx: &mut Context) {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        if matches!(ctx.read_holding_registers(3102, 4).await, Ok(Ok(w)) if w == DRIVE_WORDS) {
            return;
        }
        assert!(Instant::now() < deadline, "the drive is never polled");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// What the cached reader and the image age watcher saw.
#[derive(Debug, Default)]
struct Cached {
    reads: u64,
    failed: u64,
    /// The oldest image age `/metrics` showed.
    oldest: Duration,
}

/// Reads the cached words in a closed loop until `stop`, and watches the image age on
/// `/metrics` every 20 ms meanwhile.
async fn cached_reader(gw: &Gateway, stop: Arc<AtomicBool>) -> Cached {
    let http = gw.http.expect("HTTP listener");
    let watch_stop = Arc::clone(&stop);
    let watcher = tokio::spawn(async move {
        let mut oldest = Duration::ZERO;
        while !watch_stop.load(Ordering::Relaxed) {
            let metrics = scrape(http).await;
            if let Some(age) = sample(
                &metrics,
                "gateway_device_image_age_seconds",
                &[("device", "atv71")],
            ) {
                oldest = oldest.max(Duration::from_secs_f64(age));
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        oldest
    });
    let mut ctx = client(gw).await;
    let mut cached = Cached::default();
    while !stop.load(Ordering::Relaxed) {
        cached.reads += 1;
        match ctx.read_holding_registers(3102, 4).await {
            Ok(Ok(w)) if w == DRIVE_WORDS => {}
            _ => cached.failed += 1,
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    cached.oldest = watcher.await.expect("image age watcher");
    cached
}

/// The poll cycle of kind `kind` of the drive's 200 ms group, from `/metrics`.
async fn cycle(gw: &Gateway, kind: &str) -> Duration {
    let metrics = scrape(gw.http.expect("HTTP listener")).await;
    let seconds = sample(
        &metrics,
        "gateway_poll_cycle_seconds",
        &[("device", "atv71"), ("period", "200ms"), ("kind", kind)],
    )
    .unwrap_or_else(|| panic!("no {kind} poll cycle in /metrics:\n{metrics}"));
    Duration::from_secs_f64(seconds)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_closed_loop_writer_and_on_demand_reader_leave_the_cached_values_fresh() {
    let dir = temp_dir("fairness-writer");
    let link = SocatLink::new(&dir, "drive");
    let _sim = drive_sim(&link.b, &[]);
    let gw = start_gateway(&dir, &config(&link.a, "300ms"));
    until_polled(&mut client(&gw).await).await;

    let stop = Arc::new(AtomicBool::new(false));
    let (writes, on_demand) = (Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0)));
    let mut writer = client(&gw).await;
    let (w_stop, w_count) = (Arc::clone(&stop), Arc::clone(&writes));
    let writer = tokio::spawn(async move {
        let mut value = 10;
        while !w_stop.load(Ordering::Relaxed) {
            value = if value == 10 { 20 } else { 10 };
            if matches!(writer.write_single_register(ACC, value).await, Ok(Ok(()))) {
                w_count.fetch_add(1, Ordering::Relaxed);
            }
        }
    });
    let mut reader = client(&gw).await;
    let (r_stop, r_count) = (Arc::clone(&stop), Arc::clone(&on_demand));
    let reader = tokio::spawn(async move {
        while !r_stop.load(Ordering::Relaxed) {
            if matches!(reader.read_holding_registers(ACC, 1).await, Ok(Ok(_))) {
                r_count.fetch_add(1, Ordering::Relaxed);
            }
        }
    });
    let timer_stop = Arc::clone(&stop);
    tokio::spawn(async move {
        tokio::time::sleep(RUN).await;
        timer_stop.store(true, Ordering::Relaxed);
    });
    let cached = cached_reader(&gw, Arc::clone(&stop)).await;
    writer.await.expect("writer");
    reader.await.expect("on-demand reader");

    let (bound, achieved_max) = (cycle(&gw, "bound").await, cycle(&gw, "achieved_max").await);
    let (writes, on_demand) = (
        writes.load(Ordering::Relaxed),
        on_demand.load(Ordering::Relaxed),
    );
    eprintln!(
        "closed-loop writer and on-demand reader, {RUN:?}: {writes} writes, {on_demand} on-demand \
         reads; cached reads {} of which {} failed; oldest image {:?}; poll cycle: planned \
         {PERIOD:?}, achieved max {achieved_max:?}, bound {bound:?}",
        cached.reads, cached.failed, cached.oldest
    );
    // The clients were served, and so were the polls.
    assert!(writes > 20, "only {writes} writes");
    assert!(on_demand > 20, "only {on_demand} on-demand reads");
    assert!(cached.reads > 100, "only {} cached reads", cached.reads);
    assert_eq!(cached.failed, 0, "cached reads failed: {cached:?}");
    assert!(
        cached.oldest <= bound,
        "image {:?} older than the bound {bound:?}",
        cached.oldest
    );
    assert!(
        achieved_max <= bound,
        "cycle {achieved_max:?} beyond its bound {bound:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_drive_that_ignores_one_request_type_stays_online_for_cached_readers() {
    let dir = temp_dir("fairness-ignored");
    let link = SocatLink::new(&dir, "drive");
    let _sim = drive_sim(&link.b, &["--ignore-function", "8"]);
    let gw = start_gateway(&dir, &config(&link.a, "200ms"));
    until_polled(&mut client(&gw).await).await;

    let stop = Arc::new(AtomicBool::new(false));
    let (echoes, echoes_failed) = (Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0)));
    let mut echo = client(&gw).await;
    let (e_stop, e_count, e_failed) = (
        Arc::clone(&stop),
        Arc::clone(&echoes),
        Arc::clone(&echoes_failed),
    );
    let echoer = tokio::spawn(async move {
        // FC 08 sub-function 00 "return query data" with 16 bytes: the drive never answers.
        let mut data = vec![0x00, 0x00];
        data.extend(0..16u8);
        while !e_stop.load(Ordering::Relaxed) {
            e_count.fetch_add(1, Ordering::Relaxed);
            let answer = echo.call(Request::Custom(0x08, data.clone().into())).await;
            if !matches!(answer, Ok(Ok(_))) {
                e_failed.fetch_add(1, Ordering::Relaxed);
            }
        }
    });
    let timer_stop = Arc::clone(&stop);
    tokio::spawn(async move {
        tokio::time::sleep(RUN).await;
        timer_stop.store(true, Ordering::Relaxed);
    });
    let cached = cached_reader(&gw, Arc::clone(&stop)).await;
    echoer.await.expect("echo client");

    let metrics = scrape(gw.http.expect("HTTP listener")).await;
    let up = sample(&metrics, "gateway_device_up", &[("device", "atv71")]);
    let (echoes, echoes_failed) = (
        echoes.load(Ordering::Relaxed),
        echoes_failed.load(Ordering::Relaxed),
    );
    let success = 100.0 * (cached.reads - cached.failed) as f64 / cached.reads.max(1) as f64;
    eprintln!(
        "drive ignoring FC 08, {RUN:?}: {echoes} echoes sent, {echoes_failed} failed; cached \
         reads {} of which {} failed ({success:.1} % success); oldest image {:?}",
        cached.reads, cached.failed, cached.oldest
    );
    assert!(echoes > 5, "only {echoes} echoes sent");
    assert_eq!(echoes_failed, echoes, "an ignored request was answered");
    assert!(cached.reads > 100, "only {} cached reads", cached.reads);
    assert_eq!(cached.failed, 0, "cached reads failed: {cached:?}");
    assert_eq!(up, Some(1.0), "the drive went offline");
}
