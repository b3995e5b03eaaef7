//! `/metrics` with `[http] tag_metrics = true` at 10 000 tags: the size of one scrape and how long
//! it takes, on the real binary (4 Modbus master lines on plain ptys, 8 generic devices each,
//! every tag polled every second and good).
//!
//! The scrape is timed as Prometheus sees it: connect, `GET /metrics`, the last byte read.

use std::path::Path;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use gateway::sim::serve_modbus;
use proto_core::modbus::rtu::CharTiming;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_util::sync::CancellationToken;

use crate::device::{Bus, FlatDevice};
use crate::process::{head, master_line, pty, start, BAUD};
use crate::report::{Row, Target};
use crate::stats::percentile;
use crate::Plan;

const LINES: u8 = 4;
const DEVICES: u8 = 8;
const TAGS: usize = 10_000;

/// The row: scrape time (p50 measured, p99 held against 100 ms) and size at 10 000 tags.
pub(crate) async fn scrape(bin: &Path, plan: &Plan) -> std::io::Result<Row> {
    let name = format!("/metrics with tag_metrics, {TAGS} tags: scrape p99");
    let shutdown = CancellationToken::new();
    let _stop = shutdown.clone().drop_guard();
    let mut config = head("bench").replace("[http]\n", "[http]\ntag_metrics = true\n");
    let mut reads = Vec::new();
    let devices_total = usize::from(LINES * DEVICES);
    let per_device = TAGS / devices_total;
    let mut extra = TAGS % devices_total;
    for line in 0..LINES {
        let (path, port) = pty(&shutdown)?;
        let mut bus = Vec::new();
        let mut devices = Vec::new();
        for slave in 1..=DEVICES {
            let device = FlatDevice::new(slave).changing();
            reads.push(device.reads());
            bus.push(device);
            let tags = per_device + usize::from(extra > 0);
            extra = extra.saturating_sub(1);
            devices.push((slave, line * DEVICES + slave, tags));
        }
        tokio::spawn(serve_modbus(
            port,
            Bus(bus),
            CharTiming::new(BAUD, 11),
            shutdown.clone(),
        ));
        config.push_str(&master_line(&format!("l{line}"), &path, &devices, "1s"));
    }
    let gw = start(bin, "tag-metrics", config, &[]).await?;
    let blocks = (per_device + 1).div_ceil(125) as u64;
    let deadline = Instant::now() + Duration::from_secs(60);
    while reads.iter().any(|r| r.load(Ordering::Relaxed) < 2 * blocks) {
        if Instant::now() > deadline {
            return Err(std::io::Error::other("not every device was polled"));
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let http = gw
        .output()
        .lines()
        .find_map(|l| l.split("http listening on ").nth(1).map(str::trim))
        .and_then(|a| a.parse::<std::net::SocketAddr>().ok())
        .ok_or_else(|| std::io::Error::other("the gateway did not announce its HTTP listener"))?;

    let scrapes = if plan.memory_window < Duration::from_secs(2) {
        10
    } else {
        50
    };
    let mut times = Vec::with_capacity(scrapes);
    let mut body = String::new();
    for _ in 0..scrapes {
        let started = Instant::now();
        body = get_metrics(http).await?;
        times.push(started.elapsed());
        // Prometheus scrapes every few seconds; a pause keeps the scrapes apart.
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    times.sort_unstable();
    let values = count(&body, "gateway_tag_value{");
    let qualities = count(&body, "gateway_tag_quality{");
    let tag_bytes: usize = body
        .lines()
        .filter(|l| l.starts_with("gateway_tag_") || l.starts_with("# HELP gateway_tag_"))
        .map(|l| l.len() + 1)
        .sum();
    let p99 = percentile(&times, 99.0);
    Ok(Row {
        name,
        measured: format!("{:.1} ms", ms(p99)),
        reference: format!("p50 {:.1} ms", ms(percentile(&times, 50.0))),
        score: if values == 0 || gw.panicked() {
            f64::NAN
        } else {
            ms(p99)
        },
        target: Target::at_most(100.0).with_unit(" ms"),
        note: format!(
            "{scrapes} scrapes (connect, GET /metrics over HTTP/1.0, last byte) of a gateway with \
             {LINES} Modbus master lines on plain ptys, {DEVICES} generic devices each, {TAGS} u16 \
             tags polled every second; /metrics {:.2} MB, of it the tag families {:.2} MB \
             ({values} gateway_tag_value and {qualities} gateway_tag_quality samples, {:.0} \
             bytes a tag); slowest {:.1} ms",
            body.len() as f64 / 1e6,
            tag_bytes as f64 / 1e6,
            tag_bytes as f64 / values.max(1) as f64,
            ms(times.last().copied().unwrap_or_default()),
        ),
    })
}

/// Milliseconds as a number.
fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

fn count(text: &str, prefix: &str) -> usize {
    text.lines().filter(|l| l.starts_with(prefix)).count()
}

/// One `GET /metrics` over HTTP/1.0 (the server closes): the body.
async fn get_metrics(http: std::net::SocketAddr) -> std::io::Result<String> {
    let mut stream = tokio::net::TcpStream::connect(http).await?;
    stream
        .write_all(format!("GET /metrics HTTP/1.0\r\nHost: {http}\r\n\r\n").as_bytes())
        .await?;
    let mut raw = Vec::with_capacity(4 << 20);
    tokio::time::timeout(Duration::from_secs(10), stream.read_to_end(&mut raw))
        .await
        .map_err(|_| std::io::Error::other("/metrics did not answer within 10 s"))??;
    let raw = String::from_utf8_lossy(&raw);
    match raw.split_once("\r\n\r\n") {
        Some((head, body))
            if head.starts_with("HTTP/1.1 200") || head.starts_with("HTTP/1.0 200") =>
        {
            Ok(body.to_owned())
        }
        _ => Err(std::io::Error::other(format!(
            "GET /metrics: {}",
            raw.lines().next().unwrap_or_default()
        ))),
    }
}
