//! Browser-safe REST, end to end on the binary: in no-token mode (the demo's
//! `insecure_allow_unauthenticated_changes`) a cross-site form POST that would acknowledge (and so
//! remove) a 3964R telegram, and any request with a foreign `Host` (DNS rebinding), are refused
//! with 403, counted and audited; the same change from the listener's own origin, or without
//! `Origin` as curl sends it, still works; `[http] hosts` lets `/metrics` be scraped by name.

use std::net::SocketAddr;
use std::time::Duration;

use gateway_tests::{temp_dir, Gateway};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// Sends `head` (request line and headers, without the blank line) and `body` on a new
/// connection; the status and the answer's body.
async fn raw(http: SocketAddr, head: &str, body: &str) -> (u16, String) {
    let mut s = TcpStream::connect(http).await.expect("connect");
    let request = format!(
        "{head}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    s.write_all(request.as_bytes()).await.expect("write");
    let mut answer = Vec::new();
    tokio::time::timeout(Duration::from_secs(10), s.read_to_end(&mut answer))
        .await
        .expect("answer within 10 s")
        .expect("read");
    let text = String::from_utf8_lossy(&answer).into_owned();
    let status = text
        .split(' ')
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or_else(|| panic!("no status line: {text:?}"));
    let body = text
        .split_once("\r\n\r\n")
        .map(|(_, b)| b.to_owned())
        .unwrap_or_default();
    (status, body)
}

/// The sequence numbers of the telegrams waiting on `line`, oldest first.
async fn waiting(http: SocketAddr, line: &str) -> Vec<u64> {
    let q: serde_json::Value = reqwest::get(format!("http://{http}/api/v1/lines/{line}/telegrams"))
        .await
        .expect("telegrams")
        .json()
        .await
        .expect("json");
    q["telegrams"]
        .as_array()
        .expect("list")
        .iter()
        .filter_map(|t| t["seq"].as_u64())
        .collect()
}

/// At least `n` telegrams waiting on `line` (the demo's partner sends one a second).
async fn at_least(http: SocketAddr, line: &str, n: usize) -> Vec<u64> {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(30);
    loop {
        let seqs = waiting(http, line).await;
        if seqs.len() >= n {
            return seqs;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "fewer than {n} telegrams on {line} within 30 s: {seqs:?}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

fn rejected(metrics: &str, reason: &str) -> u64 {
    metrics
        .lines()
        .find_map(|l| {
            l.strip_prefix(&format!(
                "gateway_http_rejected_total{{reason=\"{reason}\"}} "
            ))
        })
        .and_then(|v| v.trim().parse().ok())
        .unwrap_or(0)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cross_site_changes_and_foreign_hosts_are_refused_without_a_token_too() {
    let gw = Gateway::demo(&["--no-mailbox-consumer"]);
    let http = gw.http.expect("http");
    let own = format!("Host: {http}");
    let seqs = at_least(http, "r3964", 3).await;
    let oldest = seqs[0];
    let ack = format!("POST /api/v1/lines/r3964/telegrams/{oldest}/ack HTTP/1.1");

    // A cross-site form POST (what any web page can make a browser send): refused, the telegram
    // stays.
    let (status, body) = raw(
        http,
        &format!(
            "{ack}\r\n{own}\r\nOrigin: http://evil.example\r\n\
             Content-Type: application/x-www-form-urlencoded"
        ),
        "seq=1",
    )
    .await;
    assert_eq!(status, 403, "{body}");
    let problem: serde_json::Value = serde_json::from_str(&body).expect("a JSON problem body");
    assert_eq!(problem["error"]["code"], "forbidden", "{body}");
    assert!(
        problem["error"]["message"]
            .as_str()
            .unwrap_or_default()
            .contains("evil.example"),
        "{body}"
    );
    // `Origin: null` (a sandboxed frame, a file: page) is no better.
    let (status, _) = raw(http, &format!("{ack}\r\n{own}\r\nOrigin: null"), "").await;
    assert_eq!(status, 403);
    // DNS rebinding: the page's own origin, under a name that now points at the gateway.
    let (status, body) = raw(
        http,
        &format!(
            "{ack}\r\nHost: evil.example:{}\r\nOrigin: http://evil.example:{}",
            http.port(),
            http.port()
        ),
        "",
    )
    .await;
    assert_eq!(status, 403, "{body}");
    assert_eq!(
        waiting(http, "r3964").await[0],
        oldest,
        "a refused ack removed a telegram"
    );
    // Reads too, on every path: nothing reaches a rebound page.
    for path in ["/api/v1/status", "/metrics", "/", "/healthz"] {
        let (status, body) = raw(
            http,
            &format!("GET {path} HTTP/1.1\r\nHost: evil.example"),
            "",
        )
        .await;
        assert_eq!(status, 403, "GET {path}: {body}");
    }

    // The page's own origin (a same-origin fetch) and curl (no Origin) still change things, and
    // the listener's other names (localhost on loopback, the gateway's name) are its own.
    let (status, body) = raw(
        http,
        &format!("{ack}\r\n{own}\r\nOrigin: http://{http}\r\nContent-Type: application/json"),
        "",
    )
    .await;
    assert_eq!(status, 204, "same origin: {body}");
    let (status, body) = raw(
        http,
        &format!(
            "POST /api/v1/lines/r3964/telegrams/{}/ack HTTP/1.1\r\nHost: localhost:{}",
            seqs[1],
            http.port()
        ),
        "",
    )
    .await;
    assert_eq!(status, 204, "curl-like: {body}");
    let (status, body) = raw(
        http,
        &format!("GET /api/v1/status HTTP/1.1\r\nHost: demo:{}", http.port()),
        "",
    )
    .await;
    assert_eq!(status, 200, "the gateway's name: {body}");
    let left = waiting(http, "r3964").await;
    assert!(
        !left.contains(&oldest) && !left.contains(&seqs[1]),
        "{left:?}"
    );
    // The page itself still loads.
    let (status, _) = raw(http, &format!("GET / HTTP/1.1\r\n{own}"), "").await;
    assert_eq!(status, 200);

    // Counted by reason, and the refused changes audited with the client and the escaped origin.
    let metrics = reqwest::get(format!("http://{http}/metrics"))
        .await
        .expect("metrics")
        .text()
        .await
        .expect("text");
    assert_eq!(rejected(&metrics, "origin"), 2, "{metrics}");
    assert_eq!(rejected(&metrics, "host"), 5, "{metrics}");
    let out = gw.output();
    let audited = out
        .lines()
        .filter(|l| {
            l.contains("audit")
                && l.contains("refused")
                && l.contains(&format!("/api/v1/lines/r3964/telegrams/{oldest}/ack"))
        })
        .count();
    assert_eq!(
        audited, 3,
        "the refused changes are not all audited:\n{out}"
    );
    assert!(
        out.contains("no token (insecure_allow_unauthenticated_changes)")
            && out.contains("the origin \"http://evil.example\""),
        "{out}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metrics_are_scraped_by_a_name_of_http_hosts() {
    let dir = temp_dir("rest-origin-hosts");
    let file = dir.join("gateway.toml");
    std::fs::write(
        &file,
        "[gateway]\nname = \"gw1\"\n\n[modbus_tcp]\nlisten = \"127.0.0.1:0\"\n\n[http]\n\
         hosts = [\"gw1.plant.test\", \"prometheus-target\"]\n",
    )
    .expect("config");
    let gw = Gateway::run(&file);
    let http = gw.http.expect("http");
    let port = http.port();
    for (host, expected) in [
        (format!("gw1.plant.test:{port}"), 200),
        (format!("GW1.Plant.Test.:{port}"), 200),
        ("prometheus-target".to_owned(), 200),
        (format!("gw1:{port}"), 200),
        (format!("127.0.0.1:{port}"), 200),
        (format!("other.plant.test:{port}"), 403),
        (format!("gw1.plant.test.evil.example:{port}"), 403),
    ] {
        let (status, body) = raw(http, &format!("GET /metrics HTTP/1.1\r\nHost: {host}"), "").await;
        assert_eq!(status, expected, "Host: {host}: {body}");
        if expected == 200 {
            assert!(body.contains("gateway_http_rejected_total"), "{body}");
        }
    }
    // Without a token changes are locked (403 anyway); the Origin check comes first, before the
    // token is looked at, and its answer names the origin.
    let (status, body) = raw(
        http,
        &format!(
            "PUT /api/v1/config HTTP/1.1\r\nHost: gw1.plant.test:{port}\r\nOrigin: http://evil.example"
        ),
        "",
    )
    .await;
    assert_eq!(status, 403, "{body}");
    assert!(body.contains("evil.example"), "{body}");
}
