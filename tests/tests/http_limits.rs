//! The HTTP listener under clients that try to monopolize it, against the real `gateway demo`:
//! non-reading SSE followers, slowloris connections (request heads trickled a byte a second) and
//! timed captures, each from addresses of their own (every 127/8 address reaches lo, so a test
//! can be many clients), while a probe on 127.0.0.1 scrapes `/metrics` over a kept-alive
//! connection and asks `/healthz` on a new connection every 250 ms. Every probe must answer
//! within a second. The report (stderr) gives the probes' latencies, the refusals counted and the
//! gateway's resident memory; `GATEWAY_TESTS_BIN=<older gateway>` measures an older build with the
//! same attack (its assertions then fail after the report).

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::time::Duration;

use gateway_tests::Gateway;
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpSocket, TcpStream};
use tokio::time::Instant;

/// How long the attack holds.
const HOLD: Duration = Duration::from_secs(20);
/// Every probe answers within this.
const BOUND: Duration = Duration::from_secs(1);
/// Between two probes.
const PROBE_EVERY: Duration = Duration::from_millis(250);

fn rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmRSS:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        })
        .unwrap_or(0)
}

/// A connection from `src` (any 127/8 address) with a small receive buffer.
async fn connect_from(src: Ipv4Addr, to: SocketAddr) -> std::io::Result<TcpStream> {
    let socket = TcpSocket::new_v4()?;
    socket.set_recv_buffer_size(4096)?;
    socket.bind(SocketAddr::new(IpAddr::V4(src), 0))?;
    socket.connect(to).await
}

/// A client that sends `GET path` and never reads, holding its connection until `until`.
async fn never_reads(src: Ipv4Addr, to: SocketAddr, path: String, until: Instant) {
    if let Ok(mut s) = connect_from(src, to).await {
        let _ = s
            .write_all(format!("GET {path} HTTP/1.1\r\nHost: {to}\r\n\r\n").as_bytes())
            .await;
        tokio::time::sleep_until(until).await;
    }
}

/// A slowloris client: a request line, then one byte of a header a second, never the end of the
/// head; when the server closes, again on a new connection; until `until`.
async fn slowloris(src: Ipv4Addr, to: SocketAddr, until: Instant) {
    while Instant::now() < until {
        let Ok(mut s) = connect_from(src, to).await else {
            tokio::time::sleep(Duration::from_millis(100)).await;
            continue;
        };
        if s.write_all(b"GET /api/v1/status HTTP/1.1\r\nX-Slow: ")
            .await
            .is_err()
        {
            continue;
        }
        while Instant::now() < until {
            tokio::time::sleep(Duration::from_secs(1)).await;
            if s.write_all(b"a").await.is_err() {
                break;
            }
        }
    }
}

/// What the probes saw.
#[derive(Debug, Default)]
struct Probes {
    /// (path, latency, status or error) of every probe.
    seen: Vec<(&'static str, Duration, Result<u16, String>)>,
}

impl Probes {
    fn summary(&self, path: &str) -> String {
        let mine: Vec<_> = self.seen.iter().filter(|(p, ..)| *p == path).collect();
        let ok = mine
            .iter()
            .filter(|(_, d, r)| *r == Ok(200) && *d <= BOUND)
            .count();
        let max = mine.iter().map(|(_, d, _)| *d).max().unwrap_or_default();
        let mut sorted: Vec<Duration> = mine.iter().map(|(_, d, _)| *d).collect();
        sorted.sort();
        let median = sorted.get(sorted.len() / 2).copied().unwrap_or_default();
        let failed: Vec<String> = mine
            .iter()
            .filter(|(_, d, r)| *r != Ok(200) || *d > BOUND)
            .take(3)
            .map(|(_, d, r)| format!("{r:?} after {d:?}"))
            .collect();
        format!(
            "{path}: {ok}/{} answered 200 within {BOUND:?}, median {median:?}, max {max:?}{}",
            mine.len(),
            if failed.is_empty() {
                String::new()
            } else {
                format!(", e.g. {}", failed.join("; "))
            }
        )
    }

    fn all_within_bound(&self) -> bool {
        !self.seen.is_empty()
            && self
                .seen
                .iter()
                .all(|(_, d, r)| *r == Ok(200) && *d <= BOUND)
    }
}

/// Probes `/metrics` (kept-alive connection) and `/healthz` (a new connection each time) from
/// 127.0.0.1 until `until`, and a REST read (`/api/v1/status`) from 127.0.4.1, an address no
/// attacker uses (reported, not asserted); samples the gateway's resident memory; the probes and
/// the largest resident memory seen (KiB).
async fn probe(http: SocketAddr, pid: u32, until: Instant) -> (Probes, u64) {
    let pooled = reqwest::Client::builder()
        .timeout(Duration::from_secs(5))
        .build()
        .expect("client");
    let fresh = reqwest::Client::builder()
        .timeout(Duration::from_secs(5))
        .pool_max_idle_per_host(0)
        .build()
        .expect("client");
    let rest = reqwest::Client::builder()
        .timeout(Duration::from_secs(5))
        .local_address(IpAddr::V4(addr(4, 1)))
        .build()
        .expect("client");
    let mut probes = Probes::default();
    let mut rss_max = 0;
    while Instant::now() < until {
        for (path, client) in [
            ("/metrics", &pooled),
            ("/healthz", &fresh),
            ("/api/v1/status", &rest),
        ] {
            let started = Instant::now();
            let result = match client.get(format!("http://{http}{path}")).send().await {
                Ok(r) => {
                    let status = r.status().as_u16();
                    r.bytes().await.map(|_| status).map_err(|e| e.to_string())
                }
                Err(e) => Err(e.to_string()),
            };
            probes.seen.push((path, started.elapsed(), result));
        }
        rss_max = rss_max.max(rss_kib(pid));
        tokio::time::sleep(PROBE_EVERY).await;
    }
    (probes, rss_max)
}

/// The `gateway_http_rejected_total` series of the gateway's `/metrics`, one per line.
async fn rejections(http: SocketAddr) -> String {
    let text = reqwest::get(format!("http://{http}/metrics"))
        .await
        .expect("metrics")
        .text()
        .await
        .expect("text");
    text.lines()
        .filter(|l| l.starts_with("gateway_http_rejected_total{"))
        .collect::<Vec<_>>()
        .join("\n")
}

fn count_of(rejected: &str, reason: &str) -> f64 {
    rejected
        .lines()
        .find(|l| l.contains(&format!("reason=\"{reason}\"")))
        .and_then(|l| l.rsplit(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or(0.0)
}

fn addr(c: u8, d: u8) -> Ipv4Addr {
    Ipv4Addr::new(127, 0, c, d)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn followers_and_slowloris_do_not_shut_out_metrics_and_health() {
    let gw = Gateway::demo(&[]);
    let http = gw.http.expect("http");
    let rss_before = rss_kib(gw.pid());
    let until = Instant::now() + HOLD;
    let mut attack = Vec::new();
    // 64 followers of the drive line's frames that never read: eight addresses, eight each.
    for n in 0..64u8 {
        let path = "/api/v1/lines/drive/frames?follow=true".to_owned();
        attack.push(tokio::spawn(never_reads(
            addr(1, 1 + n / 8),
            http,
            path,
            until,
        )));
    }
    tokio::time::sleep(Duration::from_millis(500)).await;
    // 50 slowloris connections: eight from the probe's own address, the rest from 42 others.
    for n in 0..50u8 {
        let src = if n < 8 {
            Ipv4Addr::LOCALHOST
        } else {
            addr(2, n)
        };
        attack.push(tokio::spawn(slowloris(src, http, until)));
    }
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let (probes, rss_max) = probe(http, gw.pid(), until).await;
    for task in attack {
        let _ = task.await;
    }
    let rejected = rejections(http).await;
    eprintln!(
        "64 non-reading followers + 50 slowloris for {HOLD:?}:\n  {}\n  {}\n  {}\n  RSS {} KiB before, {} KiB at most during\n{rejected}",
        probes.summary("/metrics"),
        probes.summary("/healthz"),
        probes.summary("/api/v1/status"),
        rss_before,
        rss_max,
    );
    assert!(probes.all_within_bound(), "a probe was late or failed");
    assert!(count_of(&rejected, "stream_limit") >= 56.0, "{rejected}");
    assert!(count_of(&rejected, "header_timeout") >= 1.0, "{rejected}");
    let out = gw.output();
    assert!(
        out.contains("every stream place is taken") && out.contains("client=127.0.1."),
        "the refusals are not logged with the client's address:\n{out}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn timed_captures_are_bounded_and_do_not_shut_out_metrics_and_health() {
    let gw = Gateway::demo(&[]);
    let http = gw.http.expect("http");
    let busiest = busiest_line(http).await;
    let rss_before = rss_kib(gw.pid());
    let until = Instant::now() + HOLD;
    let mut attack = Vec::new();
    // 100 timed captures of 300 s that are never read: thirteen addresses, eight each at most.
    for n in 0..100u8 {
        let path = format!("/api/v1/lines/{busiest}/capture?seconds=300");
        attack.push(tokio::spawn(never_reads(
            addr(3, 1 + n / 8),
            http,
            path,
            until,
        )));
    }
    tokio::time::sleep(Duration::from_millis(1500)).await;
    let (probes, rss_max) = probe(http, gw.pid(), until).await;
    for task in attack {
        let _ = task.await;
    }
    let rejected = rejections(http).await;
    eprintln!(
        "100 non-reading timed captures of {busiest} for {HOLD:?}:\n  {}\n  {}\n  {}\n  RSS {} KiB before, {} KiB at most during\n{rejected}",
        probes.summary("/metrics"),
        probes.summary("/healthz"),
        probes.summary("/api/v1/status"),
        rss_before,
        rss_max,
    );
    assert!(probes.all_within_bound(), "a probe was late or failed");
    let refused: f64 = ["stream_limit", "connection_limit", "client_limit"]
        .iter()
        .map(|r| count_of(&rejected, r))
        .sum();
    assert!(refused >= 92.0, "{rejected}");

    // Eight captures that are read (every stream place), of the busiest line: what one costs.
    tokio::time::sleep(Duration::from_secs(1)).await;
    let rss_idle = rss_kib(gw.pid());
    let seconds = 15;
    let client = reqwest::Client::new();
    let mut captures = Vec::new();
    for _ in 0..8 {
        let url = format!("http://{http}/api/v1/lines/{busiest}/capture?seconds={seconds}");
        let client = client.clone();
        captures.push(tokio::spawn(async move {
            let r = client.get(url).send().await.expect("capture");
            assert_eq!(r.status(), 200);
            r.bytes().await.expect("body").len()
        }));
    }
    let deadline = Instant::now() + Duration::from_secs(seconds);
    let mut rss_peak = 0;
    while Instant::now() < deadline {
        rss_peak = rss_peak.max(rss_kib(gw.pid()));
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let mut sizes = Vec::new();
    for c in captures {
        sizes.push(c.await.expect("capture task"));
    }
    let per_second = sizes.iter().max().copied().unwrap_or(0) / usize::try_from(seconds).unwrap();
    eprintln!(
        "8 read captures of {busiest} for {seconds} s: {sizes:?} bytes ({per_second} B/s, {} KiB in 300 s); \
         RSS {rss_idle} KiB before, {rss_peak} KiB at most during (+{} KiB)",
        per_second * 300 / 1024,
        rss_peak.saturating_sub(rss_idle)
    );
    assert!(sizes.iter().all(|&n| n > 100), "empty captures: {sizes:?}");
}

/// The demo line with the most bytes on the wire in two seconds.
async fn busiest_line(http: SocketAddr) -> String {
    let bytes = || async {
        let lines: serde_json::Value = reqwest::get(format!("http://{http}/api/v1/lines"))
            .await
            .expect("lines")
            .json()
            .await
            .expect("json");
        lines
            .as_array()
            .expect("list")
            .iter()
            .map(|l| {
                let c = &l["counters"];
                let n = c["bytes_sent"].as_u64().unwrap_or(0)
                    + c["bytes_received"].as_u64().unwrap_or(0);
                (l["name"].as_str().unwrap_or_default().to_owned(), n)
            })
            .collect::<std::collections::BTreeMap<_, _>>()
    };
    let before = bytes().await;
    tokio::time::sleep(Duration::from_secs(2)).await;
    let after = bytes().await;
    let (name, delta) = after
        .iter()
        .map(|(name, n)| (name.clone(), n - before.get(name).copied().unwrap_or(0)))
        .max_by_key(|(_, d)| *d)
        .expect("a line");
    eprintln!("busiest demo line: {name} ({} B/s on the wire)", delta / 2);
    name
}
