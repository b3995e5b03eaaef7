//! The metric families against real tools: `promtool check metrics` on the exposition, the
//! dashboards' names against [`METRIC_NAMES`], `/metrics` over a real TCP connection, and a real
//! Prometheus server scraping it and evaluating every dashboard query.
//!
//! promtool and prometheus come from the Debian package `prometheus`; the tests fail with that hint
//! when they are missing (CI installs it).

use std::collections::BTreeSet;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

use gateway::app::{Metrics, METRIC_NAMES};
use gateway::metrics::{encode_text, serve_metrics, Direction, RequestResult};
use gateway::modbus_tcp::metrics::TcpConnectionGuard;
use gateway::modbus_tcp::RejectReason;
use gateway::zenoh_bridge::{DropReason, PublicationKind};
use prometheus::proto::MetricType;
use prometheus::Registry;
use proto_core::event::{self, EventId};
use proto_core::modbus::pdu::ExceptionCode;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::process::Command;
use tokio_util::sync::CancellationToken;

#[path = "metrics/support.rs"]
mod support;

use support::{dashboard_exprs, dashboards, grafana_to_promql, metric_identifiers};

/// Records at least one sample through every helper, as the demo's lines would; the returned
/// guard keeps one Modbus TCP connection open.
fn record_samples(metrics: &Metrics) -> TcpConnectionGuard {
    let lines = metrics.line();
    lines.init_line("drive", "modbus-master-rtu");
    lines.line_started("drive", "modbus-master-rtu");
    lines.init_line("r3964", "3964r");
    lines.line_started("r3964", "3964r");
    lines.event("drive", event::ids::PTP_PARAMS_ACCEPTED);
    lines.event("drive", EventId::new(0x08, 0x30));
    lines.event("drive", EventId::new(0x0E, 0x62));
    lines.event("r3964", EventId::new(0x07, 0x03));
    lines.event("r3964", EventId::new(0x1F, 0x01)); // a class the catalog does not list
    lines.telegram("drive", Direction::Tx);
    lines.telegram("drive", Direction::Rx);
    lines.bytes("drive", Direction::Tx, 8);
    lines.bytes("drive", Direction::Rx, 23);
    lines.init_device("drive", "atv71");
    lines.set_device_up("drive", "atv71", true);
    lines.modbus_request("drive", "atv71", 0x03, RequestResult::Ok);
    lines.modbus_request(
        "drive",
        "atv71",
        0x06,
        RequestResult::Exception(ExceptionCode::IllegalDataAddress),
    );
    lines.modbus_request("drive", "atv71", 0x03, RequestResult::Timeout);
    lines.modbus_request("drive", "atv71", 0x17, RequestResult::Error);
    lines.poll_duration("drive", "atv71", Duration::from_millis(18));
    lines.poll_duration("drive", "atv71", Duration::from_secs(2));
    lines.device_image_updated("drive", "atv71", Instant::now());
    let connection = metrics.modbus_tcp().connection_accepted();
    metrics.modbus_tcp().request(0x03, RequestResult::Ok);
    metrics.modbus_tcp().request(
        0x03,
        RequestResult::Exception(ExceptionCode::GatewayTargetFailedToRespond),
    );
    metrics.modbus_tcp().request(
        0x42,
        RequestResult::Exception(ExceptionCode::IllegalFunction),
    );
    metrics
        .modbus_tcp()
        .connection_rejected(RejectReason::Limit);
    drop(connection);
    metrics.zenoh().published(PublicationKind::Tag);
    metrics.zenoh().dropped(DropReason::TagQueueFull, 1);
    metrics.modbus_tcp().connection_accepted()
}

fn fresh() -> (Registry, Metrics) {
    let registry = Registry::new();
    let metrics = Metrics::register(&registry).expect("register every family");
    (registry, metrics)
}

#[tokio::test]
async fn exposition_passes_promtool_check_metrics() {
    let (registry, metrics) = fresh();
    let _open = record_samples(&metrics);
    let text = encode_text(&registry);

    let mut child = Command::new("promtool")
        .args(["check", "metrics"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .expect("promtool not found: apt-get install prometheus (it ships promtool)");
    let mut stdin = child.stdin.take().expect("stdin");
    stdin.write_all(text.as_bytes()).await.expect("write");
    drop(stdin);
    let out = child.wait_with_output().await.expect("promtool ran");
    assert!(
        out.status.success(),
        "promtool check metrics: {}\n{}{}\n--- exposition ---\n{text}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );

    for line in [
        r#"gateway_events_total{class="08",class_name="receive error",event="0830",line="drive"} 1"#,
        r#"gateway_events_total{class="00",class_name="cp start-up",event="0003",line="drive"} 2"#,
        r#"gateway_events_total{class="1F",class_name="unknown",event="1F01",line="r3964"} 1"#,
        r#"gateway_modbus_requests_total{device="atv71",function="06",line="drive",result="exception_02"} 1"#,
        r#"gateway_modbus_requests_total{device="atv71",function="03",line="drive",result="timeout"} 1"#,
        r#"gateway_modbus_tcp_requests_total{function="03",result="exception_0B"} 1"#,
        r#"gateway_modbus_tcp_requests_total{function="other",result="exception_01"} 1"#,
        r#"gateway_poll_duration_seconds_bucket{device="atv71",line="drive",le="0.02"} 1"#,
        r#"gateway_poll_duration_seconds_count{device="atv71",line="drive"} 2"#,
        r#"gateway_bytes_total{direction="rx",line="drive"} 23"#,
        r#"gateway_line_up{line="drive",protocol="modbus-master-rtu"} 1"#,
        r#"gateway_modbus_tcp_connections 1"#,
        r#"gateway_modbus_tcp_connections_accepted_total 2"#,
        r#"gateway_modbus_tcp_connections_rejected_total{reason="limit"} 1"#,
        r#"gateway_modbus_tcp_connections_rejected_total{reason="accept_error"} 0"#,
        r#"gateway_zenoh_publications_total{kind="tag"} 1"#,
        r#"gateway_dropped_updates_total{reason="queue_full"} 1"#,
    ] {
        assert!(
            text.lines().any(|l| l == line),
            "missing {line}\n--- exposition ---\n{text}"
        );
    }
    let version = format!(
        r#"gateway_build_info{{version="{}"}} 1"#,
        env!("CARGO_PKG_VERSION")
    );
    assert!(text.lines().any(|l| l == version), "{text}");
    assert!(
        text.lines()
            .any(|l| l
                .starts_with(r#"gateway_device_image_age_seconds{device="atv71",line="drive"} "#)),
        "{text}"
    );
}

/// The histogram families, whose `_bucket`, `_sum` and `_count` series dashboards may use.
fn histogram_families() -> BTreeSet<String> {
    let (registry, metrics) = fresh();
    let _open = record_samples(&metrics);
    registry
        .gather()
        .iter()
        .filter(|f| f.get_field_type() == MetricType::HISTOGRAM)
        .map(|f| f.name().to_owned())
        .collect()
}

fn repo_path(relative: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(relative)
}

#[test]
fn dashboards_and_alerts_use_only_exported_names() {
    let histograms = histogram_families();
    let known: BTreeSet<&str> = METRIC_NAMES.iter().copied().collect();
    let resolve = |name: &str| -> Option<String> {
        if known.contains(name) {
            return Some(name.to_owned());
        }
        ["_bucket", "_sum", "_count"].iter().find_map(|suffix| {
            let base = name.strip_suffix(suffix)?;
            histograms.contains(base).then(|| base.to_owned())
        })
    };

    let mut used = BTreeSet::new();
    let mut unknown = Vec::new();
    let boards = dashboards(&repo_path("dashboards"));
    assert!(
        boards.len() >= 3,
        "overview, line and Modbus TCP dashboards"
    );
    for (path, board) in &boards {
        let mut names = BTreeSet::new();
        support::walk_strings(board, &mut |s| names.extend(metric_identifiers(s)));
        assert!(
            !names.is_empty(),
            "{} uses no gateway metric",
            path.display()
        );
        for name in names {
            match resolve(&name) {
                Some(family) => {
                    used.insert(family);
                }
                None => unknown.push(format!("{}: {name}", path.display())),
            }
        }
    }
    let alerts = std::fs::read_to_string(repo_path("deploy/alerts.yml")).expect("alerts.yml");
    for name in metric_identifiers(&alerts) {
        if resolve(&name).is_none() {
            unknown.push(format!("deploy/alerts.yml: {name}"));
        }
    }
    assert!(
        unknown.is_empty(),
        "names not in METRIC_NAMES: {unknown:#?}"
    );
    // Every family is shown somewhere.
    let unused: Vec<_> = known.iter().filter(|n| !used.contains(**n)).collect();
    assert!(unused.is_empty(), "families on no dashboard: {unused:?}");
}

#[test]
fn line_dashboard_describes_every_catalog_event() {
    let boards = dashboards(&repo_path("dashboards"));
    let (_, line) = boards
        .iter()
        .find(|(_, b)| b["uid"] == "cp341-gateway-line")
        .expect("the line dashboard");
    let variables = line["templating"]["list"].as_array().expect("variables");
    assert!(
        variables
            .iter()
            .any(|v| v["name"] == "line" && v["type"] == "query"),
        "a `line` template variable"
    );
    // The value mapping of the events table: event code -> the manual's description.
    let mut mapping = None;
    support::walk_values(line, &mut |v| {
        if v["type"] == "value" && v["options"].get("0830").is_some() {
            mapping = Some(v["options"].clone());
        }
    });
    let mapping = mapping.expect("a value mapping of event codes");
    let mut missing = Vec::new();
    for info in event::all() {
        let code = format!("{:02X}{:02X}", info.id.class, info.id.number);
        if mapping[&code]["text"].as_str() != Some(info.description) {
            missing.push(format!("{code}: {:?}", info.description));
        }
    }
    assert!(
        missing.is_empty(),
        "events whose mapping differs from the catalog (set these texts): {missing:#?}"
    );
    assert_eq!(
        mapping.as_object().map(serde_json::Map::len),
        Some(event::all().len()),
        "no codes beyond the catalog"
    );
}

/// One HTTP/1.1 GET over a fresh connection: status code, head and body.
async fn http_get(addr: SocketAddr, target: &str) -> (u16, String, String) {
    let mut stream = TcpStream::connect(addr).await.expect("connect");
    let request = format!("GET {target} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n");
    stream.write_all(request.as_bytes()).await.expect("send");
    let mut raw = Vec::new();
    tokio::time::timeout(Duration::from_secs(10), stream.read_to_end(&mut raw))
        .await
        .expect("response within 10 s")
        .expect("read");
    let raw = String::from_utf8(raw).expect("utf-8 response");
    let (head, body) = raw.split_once("\r\n\r\n").expect("head and body");
    let status = head
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
        .expect("status code");
    (status, head.to_owned(), body.to_owned())
}

/// Starts `serve_metrics` on 127.0.0.1 port 0.
async fn start_endpoint(
    registry: &Registry,
) -> (SocketAddr, CancellationToken, tokio::task::JoinHandle<()>) {
    let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
    let addr = listener.local_addr().expect("addr");
    let shutdown = CancellationToken::new();
    let task = tokio::spawn(serve_metrics(listener, registry.clone(), shutdown.clone()));
    (addr, shutdown, task)
}

#[tokio::test]
async fn metrics_endpoint_answers_over_tcp() {
    let (registry, metrics) = fresh();
    let _open = record_samples(&metrics);
    let (addr, shutdown, task) = start_endpoint(&registry).await;

    let (status, head, body) = http_get(addr, "/metrics").await;
    assert_eq!(status, 200, "{head}");
    assert!(
        head.contains("\r\nContent-Type: text/plain; version=0.0.4; charset=utf-8\r\n"),
        "{head}"
    );
    assert!(head.contains(&format!("\r\nContent-Length: {}\r\n", body.len())));
    assert!(
        body.contains("# TYPE gateway_events_total counter"),
        "{body}"
    );
    assert!(body.contains(r#"gateway_line_up{line="drive",protocol="modbus-master-rtu"} 1"#));

    // The counters move between scrapes.
    metrics.line().telegram("drive", Direction::Rx);
    let (_, _, body) = http_get(addr, "/metrics?x=1").await;
    assert!(body.contains(r#"gateway_telegrams_total{direction="rx",line="drive"} 2"#));

    let (status, _, _) = http_get(addr, "/").await;
    assert_eq!(status, 404);

    // A bad request line gets 400, and the listener keeps serving.
    let mut stream = TcpStream::connect(addr).await.expect("connect");
    stream.write_all(b"NONSENSE\r\n\r\n").await.expect("send");
    let mut raw = Vec::new();
    stream.read_to_end(&mut raw).await.expect("read");
    assert!(raw.starts_with(b"HTTP/1.1 400 "), "{raw:?}");
    let (status, _, _) = http_get(addr, "/metrics").await;
    assert_eq!(status, 200);

    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(10), task)
        .await
        .expect("serve_metrics returns after shutdown")
        .expect("no panic");
    assert!(TcpStream::connect(addr).await.is_err(), "listener closed");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn prometheus_scrapes_the_endpoint_and_evaluates_every_dashboard_query() {
    let (registry, metrics) = fresh();
    let _open = record_samples(&metrics);
    let (target, shutdown, task) = start_endpoint(&registry).await;

    // Traffic while Prometheus scrapes, so that rate() and histogram_quantile() have data.
    let traffic = {
        let metrics = metrics.clone();
        let stop = shutdown.clone();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_millis(100));
            while !stop.is_cancelled() {
                tick.tick().await;
                let lines = metrics.line();
                lines.event("drive", EventId::new(0x08, 0x30));
                lines.telegram("drive", Direction::Tx);
                lines.bytes("drive", Direction::Tx, 8);
                lines.modbus_request("drive", "atv71", 0x03, RequestResult::Ok);
                lines.poll_duration("drive", "atv71", Duration::from_millis(18));
                lines.device_image_updated("drive", "atv71", Instant::now());
                metrics.modbus_tcp().request(0x03, RequestResult::Ok);
                metrics.zenoh().published(PublicationKind::Tag);
            }
        })
    };

    let server = support::Prometheus::start(&repo_path("deploy/prometheus-test.yml"), target).await;
    let api = server.addr;

    // Up, and at least three scrapes in, so that rates over 1m have points.
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let result = support::query(api, "count_over_time(up{job=\"gateway\"}[1m])").await;
        let scrapes = result
            .as_ref()
            .ok()
            .and_then(|r| r.first())
            .and_then(|s| s["value"][1].as_str())
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(0.0);
        let up = support::query(api, "up{job=\"gateway\"}").await;
        let is_up = up
            .as_ref()
            .ok()
            .and_then(|r| r.first())
            .is_some_and(|s| s["value"][1] == "1");
        if scrapes >= 3.0 && is_up {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "Prometheus did not scrape {target} 3 times within 60 s (up: {up:?}); log:\n{}",
            server.log()
        );
        tokio::time::sleep(Duration::from_millis(250)).await;
    }

    let mut failures = Vec::new();
    let mut empty = Vec::new();
    let mut evaluated = 0;
    for (path, board) in dashboards(&repo_path("dashboards")) {
        for expr in dashboard_exprs(&board) {
            evaluated += 1;
            let promql = grafana_to_promql(&expr, "drive");
            match support::query(api, &promql).await {
                Ok(result) if result.is_empty() => empty.push(promql),
                Ok(_) => {}
                Err(error) => failures.push(format!("{}: {promql}: {error}", path.display())),
            }
        }
    }
    assert!(evaluated >= 30, "only {evaluated} dashboard queries found");
    assert!(
        failures.is_empty(),
        "queries Prometheus refused: {failures:#?}"
    );
    // Queries that must show the traffic above.
    for must in [
        "histogram_quantile(0.95",
        "sum by (class_name) (rate(gateway_events_total",
        "label_replace(sum by (event, class_name)",
        "sum by (function, result) (rate(gateway_modbus_tcp_requests_total",
        "gateway_device_image_age_seconds{",
    ] {
        assert!(
            !empty.iter().any(|q| q.contains(must)),
            "a query with `{must}` returned nothing: {empty:#?}"
        );
    }

    shutdown.cancel();
    traffic.await.expect("traffic task");
    task.await.expect("serve_metrics");
    server.stop().await;
}
