//! End to end on the binary: `[http] tag_metrics = true` puts the process values on `/metrics`.
//! A real Prometheus server (Debian `prometheus`) scrapes two simulated devices through the
//! gateway: a tag in good quality is in `gateway_tag_value` with the value REST shows; once its
//! device stops answering, its tags leave `gateway_tag_value` and their quality word shows in
//! `gateway_tag_quality`; `promtool check metrics` accepts the exposition.

use std::collections::BTreeMap;
use std::io::Write;
use std::net::SocketAddr;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use gateway_tests::{device_sim, temp_dir, two_device_lines, Gateway, SocatLink};

// The dashboard helpers of the module are not used here.
#[allow(dead_code)]
#[path = "metrics/support.rs"]
mod support;

use support::{get, samples, scrape, Prometheus};

/// How long Prometheus may take to start, scrape and answer on a loaded machine.
const PROMETHEUS_TIMEOUT: Duration = Duration::from_secs(90);

fn config(drive: &std::path::Path, ks: &std::path::Path, http_extra: &str) -> String {
    let lines = two_device_lines(drive, ks, "300ms", Some(("500ms", "1s")));
    format!(
        r#"
[gateway]
name = "e2e-tag-metrics"

[modbus_tcp]
listen = "127.0.0.1:0"

[http]
listen = "127.0.0.1:0"
{http_extra}
{lines}"#
    )
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

/// REST's good numeric tags of `line`: tag name -> value.
fn rest_good_values(http: SocketAddr, line: &str) -> BTreeMap<String, f64> {
    let (status, body) = get(http, &format!("/api/v1/tags?line={line}")).expect("GET /tags");
    assert_eq!(status, 200, "{body}");
    let tags: serde_json::Value = serde_json::from_str(&body).expect("JSON");
    tags.as_array()
        .expect("a list of tags")
        .iter()
        .filter(|t| t["quality"] == "good")
        .filter_map(|t| {
            let value = match &t["value"] {
                serde_json::Value::Bool(b) => f64::from(u8::from(*b)),
                v => v.as_f64()?,
            };
            Some((t["tag"].as_str()?.to_owned(), value))
        })
        .collect()
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

/// The series of an instant query, as (labels, value), once `check` holds on them.
fn query_until(
    prometheus: &Prometheus,
    promql: &str,
    what: &str,
    check: impl Fn(&[serde_json::Value]) -> bool,
) -> Vec<serde_json::Value> {
    let deadline = Instant::now() + PROMETHEUS_TIMEOUT;
    loop {
        let result = prometheus.query(promql).unwrap_or_default();
        if check(&result) {
            return result;
        }
        assert!(
            Instant::now() < deadline,
            "{what}: `{promql}` answered {result:?}; log:\n{}",
            prometheus.log()
        );
        std::thread::sleep(Duration::from_millis(250));
    }
}

#[test]
fn prometheus_reads_good_tags_and_the_quality_of_a_device_that_stopped_answering() {
    let dir = temp_dir("tag-metrics");
    let drive = SocatLink::new(&dir, "drive");
    let ks = SocatLink::new(&dir, "ks");
    let _drive_sim = device_sim("altivar71", &drive.b);
    let mut ks_sim = device_sim("ksvario", &ks.b);
    let cfg = dir.join("gateway.toml");
    let http_extra = "tag_metrics = true\ntag_metrics_filter = [\"drive/**\", \"ksvario/ks/*\"]\n";
    std::fs::write(&cfg, config(&drive.a, &ks.a, http_extra)).expect("write config");
    let gw = Gateway::start(&["run", "--config", cfg.to_str().expect("path")]);
    let http = gw.http.expect("the gateway announces its HTTP address");

    let good = |text: &str, line: &str| {
        samples(text, "gateway_tag_value")
            .iter()
            .filter(|(l, _)| l.get("line") == Some(&line))
            .count()
    };
    scrape_until(
        http,
        Duration::from_secs(30),
        "good tags of both lines",
        |t| good(t, "drive") > 0 && good(t, "ksvario") > 0,
    );
    let exposition = scrape(http);
    if let Err(complaints) = promtool_check(&exposition) {
        panic!("promtool check metrics: {complaints}\n--- /metrics ---\n{exposition}");
    }
    // Every exported value is a good tag REST shows with the same value and unit; every tag
    // with a value has the quality `good`.
    let rest = rest_good_values(http, "drive");
    for (labels, value) in samples(&exposition, "gateway_tag_value") {
        if labels.get("line") != Some(&"drive") {
            continue;
        }
        let tag = labels["tag"];
        let quality = support::value(
            &exposition,
            "gateway_tag_quality",
            &[("line", "drive"), ("tag", tag), ("quality", "good")],
        );
        assert_eq!(quality, Some(1.0), "{tag}:\n{exposition}");
        if let Some(expected) = rest.get(tag) {
            assert!(
                (expected - value).abs() < 1e-9,
                "{tag}: {value} vs REST {expected}"
            );
        }
    }

    let prometheus = Prometheus::start(http);
    let drive_values = query_until(
        &prometheus,
        r#"gateway_tag_value{job="gateway", line="drive", device="atv71"}"#,
        "the drive's good tags in Prometheus",
        |r| !r.is_empty(),
    );
    let first = &drive_values[0];
    let tag = first["metric"]["tag"]
        .as_str()
        .expect("tag label")
        .to_owned();
    assert!(first["metric"]["unit"].is_string(), "{first}");
    let scraped: f64 = first["value"][1]
        .as_str()
        .and_then(|v| v.parse().ok())
        .expect("a number");
    let rest = rest_good_values(http, "drive");
    assert_eq!(rest.get(&tag), Some(&scraped), "{tag}: {rest:?}");
    query_until(
        &prometheus,
        r#"gateway_tag_value{job="gateway", line="ksvario"}"#,
        "the KS vario's good tags in Prometheus",
        |r| !r.is_empty(),
    );

    // The KS vario stops answering: its tags leave gateway_tag_value, their quality shows.
    ks_sim.kill();
    let killed = Instant::now();
    let bad = query_until(
        &prometheus,
        r#"gateway_tag_quality{job="gateway", line="ksvario", quality!~"good|unknown"} == 1"#,
        "a bad quality word for the KS vario's tags",
        |r| !r.is_empty(),
    );
    query_until(
        &prometheus,
        r#"gateway_tag_value{job="gateway", line="ksvario"}"#,
        "the KS vario's tags gone from gateway_tag_value",
        <[serde_json::Value]>::is_empty,
    );
    eprintln!(
        "KS vario tags out of gateway_tag_value {:?} after the simulator was killed, quality {}",
        killed.elapsed(),
        bad[0]["metric"]["quality"]
    );
    // The other line still has its values.
    query_until(
        &prometheus,
        r#"gateway_tag_value{job="gateway", line="drive"}"#,
        "the drive's tags still in Prometheus",
        |r| !r.is_empty(),
    );
    let text = scrape(http);
    assert_eq!(good(&text, "ksvario"), 0, "{text}");
    for (labels, value) in samples(&text, "gateway_tag_quality") {
        if labels.get("line") == Some(&"ksvario") {
            assert_eq!(value, 1.0);
            assert_ne!(labels["quality"], "good", "{text}");
        }
    }
    if let Err(complaints) = promtool_check(&text) {
        panic!("promtool check metrics: {complaints}\n--- /metrics ---\n{text}");
    }
}

#[test]
fn without_tag_metrics_no_tag_is_on_metrics() {
    let dir = temp_dir("tag-metrics-off");
    let drive = SocatLink::new(&dir, "drive");
    let ks = SocatLink::new(&dir, "ks");
    let _drive_sim = device_sim("altivar71", &drive.b);
    let _ks_sim = device_sim("ksvario", &ks.b);
    let cfg = dir.join("gateway.toml");
    std::fs::write(&cfg, config(&drive.a, &ks.a, "")).expect("write config");
    let gw = Gateway::start(&["run", "--config", cfg.to_str().expect("path")]);
    let http = gw.http.expect("the gateway announces its HTTP address");
    // Once the drive's tags are good in REST, /metrics still has none of them.
    let deadline = Instant::now() + Duration::from_secs(30);
    while rest_good_values(http, "drive").is_empty() {
        assert!(
            Instant::now() < deadline,
            "no good tag of the drive in REST"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let text = scrape(http);
    assert!(!text.contains("gateway_tag_value"), "{text}");
    assert!(!text.contains("gateway_tag_quality"), "{text}");
}
