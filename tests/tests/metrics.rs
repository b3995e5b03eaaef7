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
    // SPEC.md: the demo polls the drive and the KS vario; the other lines count when served.
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
