//! Helpers of the metrics tests: a plain HTTP/1.0 client, the text exposition's samples, the
//! dashboards' queries, and a real Prometheus server in a temporary directory.

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use gateway_tests::{temp_dir, ChildGuard};
use serde_json::Value;

/// The repository's root (the tests crate lies one level below it).
pub(crate) fn repo_path(relative: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("repository root")
        .join(relative)
}

/// One `GET target` over HTTP/1.0 (no chunked encoding; the server closes): status and body.
pub(crate) fn get(addr: SocketAddr, target: &str) -> std::io::Result<(u16, String)> {
    let mut stream = TcpStream::connect_timeout(&addr, Duration::from_secs(5))?;
    stream.set_read_timeout(Some(Duration::from_secs(10)))?;
    stream.set_write_timeout(Some(Duration::from_secs(10)))?;
    write!(stream, "GET {target} HTTP/1.0\r\nHost: {addr}\r\n\r\n")?;
    let mut raw = Vec::new();
    stream.read_to_end(&mut raw)?;
    let raw = String::from_utf8_lossy(&raw);
    let (head, body) = raw
        .split_once("\r\n\r\n")
        .ok_or_else(|| std::io::Error::other(format!("no end of head in {raw:?}")))?;
    let status = head
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| std::io::Error::other(format!("bad status line in {head:?}")))?;
    Ok((status, body.to_owned()))
}

/// The gateway's `/metrics` exposition (status 200 required).
pub(crate) fn scrape(http: SocketAddr) -> String {
    let (status, body) = get(http, "/metrics").expect("GET /metrics");
    assert_eq!(status, 200, "GET /metrics: {body}");
    body
}

/// The labels of one sample line `name{a="x",b="y"} value` of the family `name`, and its value.
fn parse_sample<'t>(line: &'t str, name: &str) -> Option<(BTreeMap<&'t str, &'t str>, f64)> {
    let rest = line.strip_prefix(name)?;
    let (labels, value) = match rest.strip_prefix('{') {
        Some(rest) => rest.split_once("} ")?,
        None => ("", rest.strip_prefix(' ')?),
    };
    let mut map = BTreeMap::new();
    // Our label values hold no quotes or commas (names from the config, fixed sets).
    for pair in labels.split(',').filter(|p| !p.is_empty()) {
        let (key, value) = pair.split_once('=')?;
        map.insert(key, value.trim_matches('"'));
    }
    Some((map, value.trim().parse().ok()?))
}

/// Every sample of the family `name` in an exposition: its labels and value.
pub(crate) fn samples<'t>(text: &'t str, name: &str) -> Vec<(BTreeMap<&'t str, &'t str>, f64)> {
    text.lines()
        .filter(|line| !line.starts_with('#'))
        .filter_map(|line| parse_sample(line, name))
        .collect()
}

/// The value of the sample of `name` whose labels include `labels`.
pub(crate) fn value(text: &str, name: &str, labels: &[(&str, &str)]) -> Option<f64> {
    samples(text, name)
        .into_iter()
        .find(|(have, _)| labels.iter().all(|(k, v)| have.get(k) == Some(v)))
        .map(|(_, value)| value)
}

/// The PromQL expressions of every dashboard's panels (`targets[].expr`), with their file.
pub(crate) fn dashboard_exprs() -> Vec<(String, String)> {
    let dir = repo_path("dashboards");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("dashboards directory")
        .map(|entry| entry.expect("entry").path())
        .filter(|path| path.extension().is_some_and(|ext| ext == "json"))
        .collect();
    files.sort();
    let mut exprs = Vec::new();
    for path in files {
        let text = std::fs::read_to_string(&path).expect("readable dashboard");
        let board: Value = serde_json::from_str(&text)
            .unwrap_or_else(|e| panic!("{}: invalid JSON: {e}", path.display()));
        let name = path
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        walk(&board, &mut |v| {
            for target in v
                .get("targets")
                .and_then(Value::as_array)
                .into_iter()
                .flatten()
            {
                if let Some(expr) = target.get("expr").and_then(Value::as_str) {
                    exprs.push((name.clone(), expr.to_owned()));
                }
            }
        });
    }
    exprs
}

fn walk(value: &Value, f: &mut dyn FnMut(&Value)) {
    f(value);
    match value {
        Value::Array(items) => items.iter().for_each(|v| walk(v, f)),
        Value::Object(map) => map.values().for_each(|v| walk(v, f)),
        _ => {}
    }
}

/// A panel expression with Grafana's variables replaced as Grafana would for `line`.
pub(crate) fn grafana_to_promql(expr: &str, line: &str) -> String {
    expr.replace("$__rate_interval", "1m")
        .replace("$__range", "1m")
        .replace("$instance", ".*")
        .replace("$line", line)
}

/// Percent-encoding of a query parameter value (RFC 3986 unreserved characters kept).
fn percent_encode(value: &str) -> String {
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

/// A Prometheus server on 127.0.0.1 scraping one target every second; killed by its PID and its
/// directory removed when dropped.
pub(crate) struct Prometheus {
    /// Its HTTP API.
    pub(crate) addr: SocketAddr,
    dir: PathBuf,
    child: ChildGuard,
}

impl Prometheus {
    /// Starts `prometheus` with deploy/prometheus-test.yml aimed at `target` and waits until it
    /// is ready.
    pub(crate) fn start(target: SocketAddr) -> Self {
        let dir = temp_dir("prometheus");
        let config = std::fs::read_to_string(repo_path("deploy/prometheus-test.yml"))
            .expect("deploy/prometheus-test.yml")
            .replace("__TARGET__", &target.to_string());
        std::fs::write(dir.join("prometheus.yml"), config).expect("write prometheus.yml");
        // A free port: bound to 0 and released; if another process takes it first, Prometheus
        // exits and the next attempt takes another.
        for _attempt in 0..3 {
            let addr = std::net::TcpListener::bind("127.0.0.1:0")
                .and_then(|l| l.local_addr())
                .expect("a free port");
            let log = std::fs::File::create(dir.join("prometheus.log")).expect("log file");
            let child = Command::new("prometheus")
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
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(log)
                .spawn()
                .expect("prometheus not found: apt-get install prometheus (.ci/run does)");
            let mut child = ChildGuard(child);
            let deadline = Instant::now() + Duration::from_secs(30);
            loop {
                if let Ok(Some(status)) = child.0.try_wait() {
                    eprintln!("prometheus exited with {status}, trying another port");
                    break;
                }
                if matches!(get(addr, "/-/ready"), Ok((200, _))) {
                    return Self { addr, dir, child };
                }
                if Instant::now() > deadline {
                    child.kill();
                    break;
                }
                std::thread::sleep(Duration::from_millis(100));
            }
        }
        panic!("prometheus did not become ready; log:\n{}", log(&dir));
    }

    /// Its log so far.
    pub(crate) fn log(&self) -> String {
        log(&self.dir)
    }

    /// An instant query: the result series, or Prometheus' error.
    pub(crate) fn query(&self, promql: &str) -> Result<Vec<Value>, String> {
        let target = format!("/api/v1/query?query={}", percent_encode(promql));
        let (status, body) = get(self.addr, &target).map_err(|e| e.to_string())?;
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
}

impl Drop for Prometheus {
    fn drop(&mut self) {
        self.child.kill();
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn log(dir: &Path) -> String {
    std::fs::read_to_string(dir.join("prometheus.log")).unwrap_or_default()
}

#[test]
fn samples_are_parsed_with_their_labels() {
    let text = "# HELP x y\n\
                gateway_device_up{device=\"atv71\",line=\"drive\"} 1\n\
                gateway_device_up{device=\"ks\",line=\"ksvario\"} 0\n\
                gateway_modbus_tcp_connections 2\n";
    assert_eq!(
        value(text, "gateway_device_up", &[("line", "ksvario")]),
        Some(0.0)
    );
    assert_eq!(
        value(text, "gateway_modbus_tcp_connections", &[]),
        Some(2.0)
    );
    assert_eq!(value(text, "gateway_device", &[]), None);
    assert_eq!(samples(text, "gateway_device_up").len(), 2);
}
