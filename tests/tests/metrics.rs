//! End to end on the binary: `/metrics` of the running gateway scraped by a real Prometheus server
//! (Debian `prometheus`), every dashboard query evaluated against it, the exposition checked with
//! `promtool check metrics`, and a device that stops answering shown as down.

use std::collections::BTreeSet;
use std::io::Write;
use std::net::SocketAddr;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use gateway_tests::{device_sim, temp_dir, two_device_lines, Gateway, SocatLink};
use tokio_modbus::client::{tcp, Reader};
use tokio_modbus::prelude::{ExceptionCode, Slave};

#[path = "metrics/support.rs"]
mod support;

use support::{dashboard_exprs, grafana_to_promql, samples, scrape, value, Prometheus};

/// How long Prometheus may take to start, scrape and answer on a loaded machine.
const PROMETHEUS_TIMEOUT: Duration = Duration::from_secs(90);

/// The lines the gateway serves, as its `/metrics` lists them (`gateway_line_up`).
fn served_lines(exposition: &str) -> BTreeSet<String> {
    samples(exposition, "gateway_line_up")
        .into_iter()
        .filter_map(|(labels, _)| labels.get("line").map(|l| (*l).to_owned()))
        .collect()
}

/// Modbus TCP requests from a real client: the two polled devices (until their first poll has
/// filled the image) and a unit nobody serves (0x0A, three times).
fn modbus_tcp_traffic(addr: SocketAddr) {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    runtime.block_on(async {
        let deadline = Instant::now() + Duration::from_secs(20);
        for (unit, input) in [(2, false), (17, true)] {
            let mut ctx = tcp::connect_slave(addr, Slave(unit))
                .await
                .expect("connect to the gateway");
            loop {
                let answer = if input {
                    ctx.read_input_registers(1004, 3).await
                } else {
                    ctx.read_holding_registers(3201, 2).await
                };
                match answer.expect("transport") {
                    Ok(_) => break,
                    Err(e) => assert!(Instant::now() < deadline, "unit {unit}: {e:?}"),
                }
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
        }
        let mut ctx = tcp::connect_slave(addr, Slave(99))
            .await
            .expect("connect to the gateway");
        for _ in 0..3 {
            let answer = ctx.read_holding_registers(0, 1).await.expect("transport");
            assert_eq!(answer, Err(ExceptionCode::GatewayPathUnavailable));
        }
    });
}

/// `promtool check metrics` on `exposition`: its complaints, if any.
fn promtool_check(exposition: &str) -> Result<(), String> {
    let mut child = Command::new("promtool")
        .args(["check", "metrics"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("promtool not found: apt-get install prometheus (.ci/run does)");
    child
        .stdin
        .take()
        .expect("stdin")
        .write_all(exposition.as_bytes())
        .expect("write to promtool");
    let out = child.wait_with_output().expect("promtool ran");
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ))
    }
}

#[test]
fn prometheus_scrapes_the_demo_sees_every_line_start_and_evaluates_every_dashboard_query() {
    let gw = Gateway::demo(&[]);
    let http = gw.http.expect("the demo announces its HTTP address");

    let exposition = scrape(http);
    let lines = served_lines(&exposition);
    // The demo polls the drive and the KS vario; the other lines count when served.
    for required in ["drive", "ksvario"] {
        assert!(
            lines.contains(required),
            "line {required} missing from /metrics: {lines:?}\n{exposition}"
        );
    }
    modbus_tcp_traffic(gw.modbus_tcp);

    let prometheus = Prometheus::start(http);
    let deadline = Instant::now() + PROMETHEUS_TIMEOUT;
    // Every line's start-up event 00 03h, and at least three scrapes so that rates have points.
    loop {
        let started: BTreeSet<String> = prometheus
            .query(r#"gateway_events_total{job="gateway", event="0003", class_name="cp start-up"} >= 1"#)
            .unwrap_or_default()
            .iter()
            .filter_map(|s| s["metric"]["line"].as_str().map(str::to_owned))
            .collect();
        let scrapes = prometheus
            .query(r#"count_over_time(up{job="gateway"}[1m])"#)
            .ok()
            .and_then(|r| {
                r.first()
                    .and_then(|s| s["value"][1].as_str()?.parse::<f64>().ok())
            })
            .unwrap_or(0.0);
        if started == lines && scrapes >= 3.0 {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "Prometheus has 00 03h for {started:?} of {lines:?} after {scrapes} scrapes; log:\n{}",
            prometheus.log()
        );
        std::thread::sleep(Duration::from_millis(250));
    }

    let exprs = dashboard_exprs();
    assert!(exprs.len() >= 30, "only {} dashboard queries", exprs.len());
    let mut failures = Vec::new();
    let mut empty = Vec::new();
    let mut evaluated = 0;
    for (file, expr) in &exprs {
        // A query of the line dashboard, once per line; the others once.
        let variants: Vec<String> = if expr.contains("$line") {
            lines.iter().map(|l| grafana_to_promql(expr, l)).collect()
        } else {
            vec![grafana_to_promql(expr, "")]
        };
        for promql in variants {
            evaluated += 1;
            match prometheus.query(&promql) {
                Ok(result) if result.is_empty() => empty.push(promql),
                Ok(_) => {}
                Err(error) => failures.push(format!("{file}: {promql}: {error}")),
            }
        }
    }
    eprintln!(
        "{evaluated} dashboard queries evaluated, {} empty (no such traffic in the demo)",
        empty.len()
    );
    assert!(
        failures.is_empty(),
        "queries Prometheus refused: {failures:#?}"
    );
    // Queries the demo's traffic must fill.
    for must in [
        r#"histogram_quantile(0.95, sum by (line, device, le)"#,
        r#"gateway_line_up{instance=~".*", line="drive"}"#,
        r#"gateway_device_image_age_seconds{instance=~".*", line="ksvario"}"#,
        "sum by (function, result) (rate(gateway_modbus_tcp_requests_total",
        "sum by (line, direction) (rate(gateway_telegrams_total",
    ] {
        assert!(
            !empty.iter().any(|q| q.contains(must)),
            "a query with `{must}` returned nothing: {empty:#?}"
        );
    }

    let exposition = scrape(http);
    if let Err(complaints) = promtool_check(&exposition) {
        panic!("promtool check metrics: {complaints}\n--- /metrics ---\n{exposition}");
    }
    // A Modbus slave line counts the requests its serial master sent (the demo's hmi line).
    if lines.contains("hmi") {
        let served: f64 = samples(&exposition, "gateway_modbus_requests_total")
            .iter()
            .filter(|(l, _)| l.get("line") == Some(&"hmi") && l.get("device") == Some(&"master"))
            .map(|(_, v)| v)
            .sum();
        assert!(served >= 1.0, "{exposition}");
    }
    // The 0x0A answers of unit 99 were counted.
    assert!(
        value(
            &exposition,
            "gateway_modbus_tcp_requests_total",
            &[("function", "03"), ("result", "exception_0A")]
        )
        .is_some_and(|v| v >= 3.0),
        "{exposition}"
    );
}

fn offline_config(drive: &std::path::Path, ks: &std::path::Path) -> String {
    let lines = two_device_lines(drive, ks, "300ms", Some(("500ms", "1s")));
    format!(
        r#"
[gateway]
name = "e2e-metrics"

[modbus_tcp]
listen = "127.0.0.1:0"
{lines}"#
    )
}

/// Scrapes `http` until `check` holds on the exposition; panics with it after `timeout`.
fn scrape_until(http: SocketAddr, timeout: Duration, what: &str, check: impl Fn(&str) -> bool) {
    let deadline = Instant::now() + timeout;
    loop {
        let text = scrape(http);
        if check(&text) {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "{what} within {timeout:?}:\n{text}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

#[test]
fn a_device_that_stops_answering_is_down_in_the_metrics_and_up_again_when_it_is_back() {
    let dir = temp_dir("metrics-offline");
    let drive = SocatLink::new(&dir, "drive");
    let ks = SocatLink::new(&dir, "ks");
    let mut drive_sim = device_sim("altivar71", &drive.b);
    let _ks_sim = device_sim("ksvario", &ks.b);
    let cfg = dir.join("gateway.toml");
    std::fs::write(&cfg, offline_config(&drive.a, &ks.a)).expect("write config");
    let gw = Gateway::start(&[
        "run",
        "--config",
        cfg.to_str().expect("path"),
        "--http",
        "127.0.0.1:0",
    ]);
    let http = gw.http.expect("the gateway announces its HTTP address");

    let drive_up = |text: &str| value(text, "gateway_device_up", &[("device", "atv71")]);
    let ks_up = |text: &str| value(text, "gateway_device_up", &[("device", "ks")]);
    scrape_until(http, Duration::from_secs(20), "both devices up", |t| {
        drive_up(t) == Some(1.0) && ks_up(t) == Some(1.0)
    });

    drive_sim.kill();
    let killed = Instant::now();
    scrape_until(http, Duration::from_secs(10), "the drive down", |t| {
        drive_up(t) == Some(0.0)
    });
    eprintln!(
        "gateway_device_up 0 {:?} after the simulator was killed",
        killed.elapsed()
    );
    let text = scrape(http);
    assert_eq!(
        ks_up(&text),
        Some(1.0),
        "the other line is not disturbed:\n{text}"
    );
    // The reason is on the line: polls timed out (08 30h, no reply within the reply monitoring
    // time), the line itself stays up.
    let timeouts = value(
        &text,
        "gateway_modbus_requests_total",
        &[
            ("device", "atv71"),
            ("function", "03"),
            ("result", "timeout"),
        ],
    );
    assert!(timeouts.is_some_and(|v| v >= 1.0), "{text}");
    let no_reply = value(
        &text,
        "gateway_events_total",
        &[("line", "drive"), ("event", "0830")],
    );
    assert!(no_reply.is_some_and(|v| v >= 1.0), "{text}");
    assert_eq!(
        value(&text, "gateway_line_up", &[("line", "drive")]),
        Some(1.0),
        "{text}"
    );

    let _drive_sim = device_sim("altivar71", &drive.b);
    scrape_until(http, Duration::from_secs(15), "the drive up again", |t| {
        drive_up(t) == Some(1.0)
    });
}

/// The metric names (`gateway_` and lower-case letters and underscores) in a PromQL expression.
fn gateway_names(expr: &str) -> BTreeSet<String> {
    const PREFIX: &str = "gateway_";
    let mut names = BTreeSet::new();
    let bytes = expr.as_bytes();
    let mut at = 0;
    while let Some(found) = expr.get(at..).and_then(|rest| rest.find(PREFIX)) {
        let start = at + found;
        // Part of a longer word (a label value like `my_gateway_x`) is no metric name.
        let inside_word = start > 0
            && bytes
                .get(start - 1)
                .is_some_and(|b| b.is_ascii_alphanumeric() || *b == b'_' || *b == b'-');
        let end = start
            + PREFIX.len()
            + expr[start + PREFIX.len()..]
                .bytes()
                .take_while(|b| b.is_ascii_lowercase() || *b == b'_')
                .count();
        if !inside_word && end > start + PREFIX.len() {
            names.insert(expr[start..end].to_owned());
        }
        at = end.max(start + 1);
    }
    names
}

/// Every string under an `expr`, `query` or `definition` key of a dashboard (panel targets and
/// template variables).
fn dashboard_queries(value: &serde_json::Value, out: &mut Vec<String>) {
    match value {
        serde_json::Value::Object(map) => {
            for (key, v) in map {
                match (key.as_str(), v) {
                    ("expr" | "query" | "definition", serde_json::Value::String(s)) => {
                        out.push(s.clone());
                    }
                    _ => dashboard_queries(v, out),
                }
            }
        }
        serde_json::Value::Array(items) => items.iter().for_each(|v| dashboard_queries(v, out)),
        _ => {}
    }
}

/// The `expr:` values of an alerting rules file (one line, or a `|` / `>` block below it).
fn alert_exprs(yaml: &str) -> Vec<String> {
    let mut exprs = Vec::new();
    let lines: Vec<&str> = yaml.lines().collect();
    for (i, line) in lines.iter().enumerate() {
        let Some((indent, rest)) = line.split_once("expr:") else {
            continue;
        };
        if !indent.trim().is_empty() && indent.trim() != "-" {
            continue;
        }
        let rest = rest.trim();
        if rest.is_empty() || rest.starts_with('|') || rest.starts_with('>') {
            let block = lines
                .iter()
                .skip(i + 1)
                .take_while(|l| l.len() - l.trim_start().len() > indent.len())
                .map(|l| l.trim())
                .collect::<Vec<_>>()
                .join(" ");
            exprs.push(block);
        } else {
            exprs.push(rest.to_owned());
        }
    }
    exprs
}

/// Every metric family the dashboards and the alerting rules query, with where it is queried.
/// Histogram series (`_bucket`, `_sum`, `_count`) name their family.
fn queried_families() -> std::collections::BTreeMap<String, String> {
    let mut exprs: Vec<(String, String)> = Vec::new();
    let dir = support::repo_path("dashboards");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .expect("dashboards directory")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    files.sort();
    for path in files {
        let board: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).expect("readable dashboard"))
                .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let mut queries = Vec::new();
        dashboard_queries(&board, &mut queries);
        let file = path.display().to_string();
        exprs.extend(queries.into_iter().map(|q| (file.clone(), q)));
    }
    let alerts = support::repo_path("deploy/alerts.yml");
    let yaml = std::fs::read_to_string(&alerts).expect("deploy/alerts.yml");
    let file = alerts.display().to_string();
    exprs.extend(alert_exprs(&yaml).into_iter().map(|e| (file.clone(), e)));

    let mut families = std::collections::BTreeMap::new();
    for (file, expr) in exprs {
        for name in gateway_names(&expr) {
            let family = ["_bucket", "_sum", "_count"]
                .iter()
                .find_map(|s| name.strip_suffix(s))
                .filter(|f| f.ends_with("_seconds"))
                .map_or_else(|| name.clone(), str::to_owned);
            families.entry(family).or_insert_with(|| file.clone());
        }
    }
    families
}

/// The sum of every sample of a family (a histogram by its `_count`).
fn family_total(exposition: &str, family: &str) -> Option<f64> {
    let mut found = samples(exposition, family);
    if found.is_empty() {
        found = samples(exposition, &format!("{family}_count"));
    }
    (!found.is_empty()).then(|| found.iter().map(|(_, v)| v).sum())
}

#[test]
fn every_family_the_dashboards_and_alerts_query_counts_in_the_running_demo() {
    let families = queried_families();
    // The extraction itself: the families the alerts and the overview are built on.
    for known in [
        "gateway_line_up",
        "gateway_dropped_updates_total",
        "gateway_zenoh_publications_total",
        "gateway_poll_duration_seconds",
    ] {
        assert!(
            families.contains_key(known),
            "{known} not found among {families:?}"
        );
    }

    let gw = Gateway::demo(&[]);
    let http = gw.http.expect("the demo announces its HTTP address");
    modbus_tcp_traffic(gw.modbus_tcp);

    // What the demo's traffic moves within a few seconds: its polls, its telegram partners, the
    // Modbus TCP requests just made, and the zenoh publications of tags, events and telegrams.
    let must_move = [
        "gateway_build_info",
        "gateway_events_total",
        "gateway_telegrams_total",
        "gateway_bytes_total",
        "gateway_line_up",
        "gateway_modbus_requests_total",
        "gateway_poll_duration_seconds",
        "gateway_device_up",
        "gateway_device_image_age_seconds",
        "gateway_modbus_tcp_connections_accepted_total",
        "gateway_modbus_tcp_connections_closed_total",
        "gateway_modbus_tcp_requests_total",
        "gateway_zenoh_publications_total",
    ];
    let deadline = Instant::now() + Duration::from_secs(30);
    let exposition = loop {
        let text = scrape(http);
        let still: Vec<&str> = must_move
            .iter()
            .copied()
            .filter(|f| family_total(&text, f).is_none_or(|v| v <= 0.0))
            .collect();
        if still.is_empty() {
            break text;
        }
        assert!(
            Instant::now() < deadline,
            "families still at 0 or missing after 30 s: {still:?}\n{text}"
        );
        std::thread::sleep(Duration::from_millis(250));
    };
    let mut report = Vec::new();
    for (family, file) in &families {
        let total = family_total(&exposition, family);
        assert!(
            total.is_some(),
            "{family} (queried in {file}) is not in /metrics of the running demo:\n{exposition}"
        );
        report.push(format!("{family} = {}", total.unwrap_or_default()));
    }
    for family in must_move {
        assert!(
            families.contains_key(family),
            "{family} must move in the demo but no dashboard or alert queries it: {families:?}"
        );
    }
    eprintln!(
        "{} queried families in /metrics:\n  {}",
        families.len(),
        report.join("\n  ")
    );
}
