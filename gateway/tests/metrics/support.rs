//! Helpers of the metrics tests: reading the dashboards, a raw HTTP client, and a real Prometheus
//! server in a temporary directory.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use serde_json::Value;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::process::{Child, Command};

/// Every `*.json` dashboard in `dir`, parsed.
pub(crate) fn dashboards(dir: &Path) -> Vec<(PathBuf, Value)> {
    let mut boards: Vec<_> = std::fs::read_dir(dir)
        .expect("dashboards directory")
        .map(|entry| entry.expect("entry").path())
        .filter(|path| path.extension().is_some_and(|ext| ext == "json"))
        .map(|path| {
            let text = std::fs::read_to_string(&path).expect("readable dashboard");
            let board = serde_json::from_str(&text)
                .unwrap_or_else(|e| panic!("{}: invalid JSON: {e}", path.display()));
            (path, board)
        })
        .collect();
    boards.sort_by(|a, b| a.0.cmp(&b.0));
    boards
}

/// Calls `f` on every value of a JSON document, depth first.
pub(crate) fn walk_values(value: &Value, f: &mut dyn FnMut(&Value)) {
    f(value);
    match value {
        Value::Array(items) => items.iter().for_each(|v| walk_values(v, f)),
        Value::Object(map) => map.values().for_each(|v| walk_values(v, f)),
        _ => {}
    }
}

/// Calls `f` on every string of a JSON document.
pub(crate) fn walk_strings(value: &Value, f: &mut dyn FnMut(&str)) {
    walk_values(value, &mut |v| {
        if let Value::String(s) = v {
            f(s);
        }
    });
}

/// The metric names in a text: identifiers that start with `gateway_`.
pub(crate) fn metric_identifiers(text: &str) -> Vec<String> {
    let is_ident = |c: char| c.is_ascii_alphanumeric() || c == '_' || c == ':';
    let mut names = Vec::new();
    let mut rest = text;
    let mut before: Option<char> = None;
    while let Some(at) = rest.find("gateway_") {
        let preceding = rest[..at].chars().next_back().or(before);
        let tail = &rest[at..];
        let len = tail.find(|c: char| !is_ident(c)).unwrap_or(tail.len());
        if !preceding.is_some_and(is_ident) {
            // A colon may be part of a name (recording rules), but not at its end ("name: text").
            names.push(tail[..len].trim_end_matches(':').to_owned());
        }
        before = tail[..len].chars().next_back();
        rest = &tail[len..];
    }
    names
}

/// The PromQL expressions of a dashboard's panels (`targets[].expr`).
pub(crate) fn dashboard_exprs(board: &Value) -> Vec<String> {
    let mut exprs = Vec::new();
    walk_values(board, &mut |v| {
        if let Some(targets) = v.get("targets").and_then(Value::as_array) {
            for target in targets {
                if let Some(expr) = target.get("expr").and_then(Value::as_str) {
                    exprs.push(expr.to_owned());
                }
            }
        }
    });
    exprs
}

/// A panel expression with Grafana's variables replaced as Grafana would for `line`.
pub(crate) fn grafana_to_promql(expr: &str, line: &str) -> String {
    expr.replace("$__rate_interval", "1m")
        .replace("$__range", "1m")
        .replace("$instance", ".*")
        .replace("$line", line)
}

/// Percent-encoding of a query parameter value (RFC 3986 unreserved characters kept).
pub(crate) fn percent_encode(value: &str) -> String {
    let mut out = String::with_capacity(value.len() * 3);
    for byte in value.bytes() {
        if byte.is_ascii_alphanumeric() || b"-._~".contains(&byte) {
            out.push(char::from(byte));
        } else {
            out.push_str(&format!("%{byte:02X}"));
        }
    }
    out
}

/// One HTTP/1.0 GET (no chunked encoding, the server closes): status and body.
pub(crate) async fn get(addr: SocketAddr, target: &str) -> std::io::Result<(u16, String)> {
    let mut stream = TcpStream::connect(addr).await?;
    let request = format!("GET {target} HTTP/1.0\r\nHost: {addr}\r\n\r\n");
    stream.write_all(request.as_bytes()).await?;
    let mut raw = Vec::new();
    tokio::time::timeout(Duration::from_secs(10), stream.read_to_end(&mut raw))
        .await
        .map_err(|_| std::io::Error::other("no response within 10 s"))??;
    let raw = String::from_utf8_lossy(&raw);
    let (head, body) = raw
        .split_once("\r\n\r\n")
        .ok_or_else(|| std::io::Error::other("no end of head"))?;
    let status = head
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| std::io::Error::other(format!("bad status line in {head:?}")))?;
    Ok((status, body.to_owned()))
}

/// An instant query: the result series, or Prometheus' error.
pub(crate) async fn query(api: SocketAddr, promql: &str) -> Result<Vec<Value>, String> {
    let target = format!("/api/v1/query?query={}", percent_encode(promql));
    let (status, body) = get(api, &target).await.map_err(|e| e.to_string())?;
    let answer: Value =
        serde_json::from_str(&body).map_err(|e| format!("HTTP {status}: {e}: {body}"))?;
    if answer["status"] != "success" {
        return Err(format!(
            "HTTP {status}: {} {}",
            answer["errorType"], answer["error"]
        ));
    }
    match &answer["data"]["result"] {
        Value::Array(series) if answer["data"]["resultType"] != "scalar" => Ok(series.clone()),
        other => Ok(vec![other.clone()]),
    }
}

/// A Prometheus server on 127.0.0.1 scraping one target, with its data in a temporary directory.
pub(crate) struct Prometheus {
    /// Its HTTP API.
    pub(crate) addr: SocketAddr,
    child: Child,
    dir: PathBuf,
}

impl Prometheus {
    /// Starts `prometheus` with the config `template` (deploy/prometheus-test.yml) aimed at
    /// `target`, and waits until it is ready.
    pub(crate) async fn start(template: &Path, target: SocketAddr) -> Self {
        let nanos = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        let dir = std::env::temp_dir().join(format!(
            "gateway-metrics-test-{}-{nanos}",
            std::process::id()
        ));
        std::fs::create_dir_all(dir.join("data")).expect("temporary directory");
        let config = std::fs::read_to_string(template)
            .expect("deploy/prometheus-test.yml")
            .replace("__TARGET__", &target.to_string());
        std::fs::write(dir.join("prometheus.yml"), config).expect("write config");

        // A free port: bound to 0 and released; if another process takes it first, Prometheus
        // exits and the next attempt takes another.
        for _attempt in 0..3 {
            let addr = std::net::TcpListener::bind("127.0.0.1:0")
                .and_then(|l| l.local_addr())
                .expect("a free port");
            let log = std::fs::File::create(dir.join("prometheus.log")).expect("log file");
            let mut child = Command::new("prometheus")
                .arg(format!(
                    "--config.file={}",
                    dir.join("prometheus.yml").display()
                ))
                .arg(format!(
                    "--storage.tsdb.path={}",
                    dir.join("data").display()
                ))
                .arg(format!("--web.listen-address={addr}"))
                .arg("--log.level=warn")
                .stdout(Stdio::null())
                .stderr(log)
                .kill_on_drop(true)
                .spawn()
                .expect("prometheus not found: apt-get install prometheus");
            let deadline = Instant::now() + Duration::from_secs(30);
            loop {
                if let Ok(Some(status)) = child.try_wait() {
                    eprintln!("prometheus exited with {status}, trying another port");
                    break;
                }
                if matches!(get(addr, "/-/ready").await, Ok((200, _))) {
                    return Self { addr, child, dir };
                }
                if Instant::now() > deadline {
                    let _ = child.kill().await;
                    break;
                }
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
        }
        let log = std::fs::read_to_string(dir.join("prometheus.log")).unwrap_or_default();
        panic!("prometheus did not become ready; log:\n{log}");
    }

    /// Its log so far.
    pub(crate) fn log(&self) -> String {
        std::fs::read_to_string(self.dir.join("prometheus.log")).unwrap_or_default()
    }

    /// Stops it and removes its directory.
    pub(crate) async fn stop(mut self) {
        let _ = self.child.kill().await;
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

impl Drop for Prometheus {
    fn drop(&mut self) {
        // After a failed assertion: the child is killed on drop, the directory removed here.
        let _ = self.child.start_kill();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

#[test]
fn identifiers_are_found_at_word_starts_only() {
    assert_eq!(
        metric_identifiers(
            r#"sum(rate(gateway_events_total{a="b"}[1m])) / my_gateway_x + gateway_poll_duration_seconds_bucket"#
        ),
        [
            "gateway_events_total",
            "gateway_poll_duration_seconds_bucket"
        ]
    );
    assert_eq!(
        metric_identifiers("gateway_line_up: 1 while the port is open"),
        ["gateway_line_up"]
    );
    assert!(metric_identifiers("cp341-gateway-line").is_empty());
}
