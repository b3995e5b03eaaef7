//! End to end on the binary: the demo on the zenoh fabric. A second zenoh session in this process
//! and the Python binding in a separate process, both on explicit tcp/127.0.0.1 endpoints with
//! multicast scouting off, receive the demo's telegrams and values, get tags, send a telegram that
//! reaches a simulator, and set a value that reaches a simulator.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use gateway_tests::Gateway;
use serde_json::Value;
use tokio::io::AsyncBufReadExt;
use tokio_modbus::client::{tcp, Reader, Writer};
use tokio_modbus::prelude::Slave;

/// The eclipse-zenoh release of the Python client: the crate's (`zenoh = "=1.10.2"`).
const PYTHON_ZENOH_VERSION: &str = "1.10.2";

/// The r3964 mailbox of the demo (acknowledging keeps its queue from filling).
const R3964_UNIT: u8 = 100;

fn demo_with_zenoh(extra: &[&str]) -> (Gateway, u16) {
    let gw = Gateway::demo(extra);
    let port = gw
        .zenoh_port
        .expect("the harness gives every demo its own zenoh port");
    (gw, port)
}

fn json(sample: &zenoh::sample::Sample) -> Value {
    serde_json::from_slice(&sample.payload().to_bytes()).expect("JSON payload")
}

/// Acknowledges every telegram of the r3964 mailbox, so that its partner never gets a NAK.
fn keep_mailbox_empty(gw: &Gateway) -> tokio::task::JoinHandle<()> {
    let addr = gw.modbus_tcp;
    tokio::spawn(async move {
        let mut ctx = tcp::connect_slave(addr, Slave(R3964_UNIT))
            .await
            .expect("connect");
        loop {
            let Ok(Ok(regs)) = ctx.read_holding_registers(0, 2).await else {
                return;
            };
            if regs[1] != 0 {
                let _ = ctx.write_single_register(600, regs[1]).await;
            } else {
                tokio::time::sleep(Duration::from_millis(2)).await;
            }
        }
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_zenoh_session_receives_gets_sends_and_sets() {
    let (gw, port) = demo_with_zenoh(&["--telegram-every", "20ms"]);
    let _acks = keep_mailbox_empty(&gw);
    let s = gateway_tests::zenoh_client(port).await;

    // Tag values on change, as JSON.
    let tags = s
        .declare_subscriber("gw/demo/drive/atv71/*")
        .await
        .expect("subscribe");
    let sample = tokio::time::timeout(Duration::from_secs(30), tags.recv_async())
        .await
        .expect("a tag value within 30 s")
        .expect("sample");
    let value = json(&sample);
    assert!(
        value.get("value").is_some() && value.get("quality").is_some(),
        "{value}"
    );
    assert!(value.get("timestamp").is_some(), "{value}");

    // Received telegrams with their sequence number in the attachment.
    let rx = s
        .declare_subscriber("gw/demo/r3964/rx")
        .await
        .expect("subscribe");
    let sample = tokio::time::timeout(Duration::from_secs(30), rx.recv_async())
        .await
        .expect("a telegram within 30 s")
        .expect("sample");
    assert!(String::from_utf8_lossy(&sample.payload().to_bytes()).contains("3964R"));
    let att: Value =
        serde_json::from_slice(&sample.attachment().expect("attachment").to_bytes()).expect("JSON");
    assert!(att["seq"].as_u64().is_some_and(|n| n > 0), "{att}");

    // Any tag by query, with wildcards.
    let mut got: BTreeMap<String, Value> = BTreeMap::new();
    let replies = s.get("gw/demo/*/*/*").await.expect("get");
    while let Ok(reply) = replies.recv_async().await {
        if let Ok(sample) = reply.result() {
            got.insert(sample.key_expr().to_string(), json(sample));
        }
    }
    assert!(
        got.contains_key("gw/demo/drive/atv71/ETA"),
        "{:?}",
        got.keys()
    );
    assert!(
        got.keys().any(|k| k.starts_with("gw/demo/ksvario/")),
        "{:?}",
        got.keys()
    );

    // A telegram sent through zenoh reaches the simulated partner, which echoes it back.
    let result = s
        .declare_subscriber("gw/demo/r3964/tx/result")
        .await
        .expect("subscribe");
    s.put("gw/demo/r3964/tx", b"ZENOH-PING".to_vec())
        .await
        .expect("put");
    let r = tokio::time::timeout(Duration::from_secs(20), result.recv_async())
        .await
        .expect("a result")
        .expect("sample");
    assert_eq!(json(&r)["ok"], Value::Bool(true), "{}", json(&r));
    let echoed = tokio::time::timeout(Duration::from_secs(20), async {
        loop {
            let sample = rx.recv_async().await.expect("sample");
            if &*sample.payload().to_bytes() == b"ZENOH-PING" {
                return;
            }
        }
    })
    .await;
    assert!(echoed.is_ok(), "the partner's echo never came back");

    // A value set through zenoh is written to the drive: ACC (W9001, 0.1 s) = 4.5 s.
    let result = s
        .declare_subscriber("gw/demo/drive/atv71/ACC/set/result")
        .await
        .expect("subscribe");
    s.put("gw/demo/drive/atv71/ACC/set", "4.5")
        .await
        .expect("put");
    let r = tokio::time::timeout(Duration::from_secs(20), result.recv_async())
        .await
        .expect("a result")
        .expect("sample");
    assert_eq!(json(&r)["ok"], Value::Bool(true), "{}", json(&r));
    let mut drive = tcp::connect_slave(gw.modbus_tcp, Slave(2))
        .await
        .expect("connect");
    // W9001..W9003: W9003 is not polled, so the gateway asks the drive itself.
    let words = drive
        .read_holding_registers(9001, 3)
        .await
        .expect("transport")
        .expect("read");
    assert_eq!(
        words[0], 45,
        "ACC in the drive after the zenoh write: {words:?}"
    );

    // Tag names compare without letter case, as in the config and REST: `acc` is ACC, and
    // the reply comes under the key the query named.
    let replies = s.get("gw/demo/drive/atv71/acc").await.expect("get");
    let reply = tokio::time::timeout(Duration::from_secs(10), replies.recv_async())
        .await
        .expect("a reply")
        .expect("reply");
    let sample = reply.result().expect("ACC");
    assert_eq!(sample.key_expr().as_str(), "gw/demo/drive/atv71/acc");
    assert_eq!(json(sample)["unit"], "s", "{}", json(sample));

    // A value ACC (0.1 s steps) cannot hold exactly is refused with the nearest values.
    let result = s
        .declare_subscriber("gw/demo/drive/atv71/ACC/set/result")
        .await
        .expect("subscribe");
    s.put("gw/demo/drive/atv71/ACC/set", "4.55")
        .await
        .expect("put");
    let r = tokio::time::timeout(Duration::from_secs(20), result.recv_async())
        .await
        .expect("a result")
        .expect("sample");
    assert_eq!(json(&r)["ok"], Value::Bool(false), "{}", json(&r));
    assert!(
        json(&r)["error"]
            .as_str()
            .is_some_and(|e| e.ends_with("nearest: 4.5 or 4.6")),
        "{}",
        json(&r)
    );

    // A read-only tag is refused with the reason, and the drive keeps its value.
    let result = s
        .declare_subscriber("gw/demo/drive/atv71/ETA/set/result")
        .await
        .expect("subscribe");
    s.put("gw/demo/drive/atv71/ETA/set", "1")
        .await
        .expect("put");
    let r = tokio::time::timeout(Duration::from_secs(20), result.recv_async())
        .await
        .expect("a result")
        .expect("sample");
    assert_eq!(json(&r)["ok"], Value::Bool(false), "{}", json(&r));

    // The CP memory of the slave line is tags too (DB 800 word w = register w of unit 50).
    let replies = s.get("gw/demo/hmi/memory/DB800.DBW20").await.expect("get");
    let reply = tokio::time::timeout(Duration::from_secs(10), replies.recv_async())
        .await
        .expect("a reply")
        .expect("reply");
    let value = json(reply.result().expect("the memory word"));
    assert!(value["value"].is_number(), "{value}");
    let result = s
        .declare_subscriber("gw/demo/hmi/memory/DB800.DBW200/set/result")
        .await
        .expect("subscribe");
    s.put("gw/demo/hmi/memory/DB800.DBW200/set", "99")
        .await
        .expect("put");
    let r = tokio::time::timeout(Duration::from_secs(20), result.recv_async())
        .await
        .expect("a result")
        .expect("sample");
    assert_eq!(json(&r)["ok"], Value::Bool(true), "{}", json(&r));
    let mut cp = tcp::connect_slave(gw.modbus_tcp, Slave(50))
        .await
        .expect("connect");
    let words = cp
        .read_holding_registers(100, 1)
        .await
        .expect("transport")
        .expect("read");
    assert_eq!(words, vec![99], "DBW 200 of DB 800 after the zenoh write");

    // Presence: the gateway and its online devices hold liveliness tokens.
    let mut tokens = Vec::new();
    let replies = s
        .liveliness()
        .get("gw/demo/**")
        .await
        .expect("liveliness get");
    while let Ok(reply) = replies.recv_async().await {
        if let Ok(sample) = reply.result() {
            tokens.push(sample.key_expr().to_string());
        }
    }
    assert!(tokens.iter().any(|k| k == "gw/demo"), "{tokens:?}");
    assert!(
        tokens.iter().any(|k| k == "gw/demo/drive/atv71"),
        "{tokens:?}"
    );
    s.close().await.expect("close");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn thousand_telegrams_in_order_each_published_once() {
    let (gw, port) = demo_with_zenoh(&["--telegram-every", "3ms"]);
    let _acks = keep_mailbox_empty(&gw);
    let s = gateway_tests::zenoh_client(port).await;
    let rx = s
        .declare_subscriber("gw/demo/r3964/rx")
        .await
        .expect("subscribe");
    let mut last: Option<u64> = None;
    let mut seen = 0;
    tokio::time::timeout(Duration::from_secs(120), async {
        while seen < 1000 {
            let sample = rx.recv_async().await.expect("sample");
            let att: Value =
                serde_json::from_slice(&sample.attachment().expect("attachment").to_bytes())
                    .expect("JSON attachment");
            let seq = att["seq"].as_u64().expect("seq");
            if let Some(prev) = last {
                // Sequence numbers run 1..=65535; 1000 telegrams from the start never wrap.
                assert_eq!(seq, prev + 1, "each telegram once and in order");
            }
            last = Some(seq);
            seen += 1;
        }
    })
    .await
    .unwrap_or_else(|_| panic!("only {seen} telegrams within 120 s"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_gateway_outlives_its_zenoh_peer_and_publishes_again() {
    let (gw, port) = demo_with_zenoh(&[]);
    let s = gateway_tests::zenoh_client(port).await;
    let sub = s
        .declare_subscriber("gw/demo/drive/atv71/*")
        .await
        .expect("subscribe");
    tokio::time::timeout(Duration::from_secs(30), sub.recv_async())
        .await
        .expect("a value")
        .expect("sample");
    // The peer disappears: Modbus TCP goes on.
    drop(sub);
    s.close().await.expect("close");
    let mut drive = tcp::connect_slave(gw.modbus_tcp, Slave(2))
        .await
        .expect("connect");
    for _ in 0..5 {
        let words = drive
            .read_holding_registers(3102, 4)
            .await
            .expect("transport");
        assert_eq!(words, Ok(vec![40, 600, 500, 0]));
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    // A peer comes back and receives publications again (a write makes a value change).
    let s = gateway_tests::zenoh_client(port).await;
    let sub = s
        .declare_subscriber("gw/demo/drive/atv71/DEC")
        .await
        .expect("subscribe");
    drive
        .write_single_register(9002, 77)
        .await
        .expect("transport")
        .expect("write DEC");
    let sample = tokio::time::timeout(Duration::from_secs(30), sub.recv_async())
        .await
        .expect("publications again after the peer returned")
        .expect("sample");
    assert!(json(&sample)["value"].is_number());
    s.close().await.expect("close");
}

/// The keys of a JSON object, sorted.
fn keys(v: &Value) -> Vec<String> {
    v.as_object()
        .map(|o| o.keys().cloned().collect())
        .unwrap_or_default()
}

/// The single reply to a zenoh query of `key`, as JSON.
async fn get_one(s: &zenoh::Session, key: &str) -> Value {
    let replies = s.get(key).await.expect("get");
    let reply = tokio::time::timeout(Duration::from_secs(10), replies.recv_async())
        .await
        .expect("a reply within 10 s")
        .expect("reply");
    json(reply.result().expect("a status"))
}

/// `<line>/status` over zenoh is the JSON REST answers for the line (`GET /api/v1/lines/<line>`):
/// the same fields with the same names and formats, the STATUS word a number.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_line_status_is_the_same_view_over_zenoh_and_rest() {
    let (gw, port) = demo_with_zenoh(&[]);
    let http = reqwest::Client::new();
    let url = format!(
        "http://{}/api/v1/lines/drive",
        gw.http.expect("the demo serves HTTP")
    );
    // Both drives answer: the view has everything a polled line shows.
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    let rest = loop {
        let rest: Value = http
            .get(&url)
            .send()
            .await
            .expect("GET")
            .json()
            .await
            .expect("JSON");
        // Devices start online; each has answered once it has a `last_answer` (the view leaves
        // the key out before), and only then do the two views have the same keys.
        let answered = rest["devices"]
            .as_array()
            .is_some_and(|d| d.len() == 2 && d.iter().all(|d| !d["last_answer"].is_null()));
        if rest["state"] == "running" && rest["devices_online"] == 2 && answered {
            break rest;
        }
        assert!(std::time::Instant::now() < deadline, "{rest:#}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    let s = gateway_tests::zenoh_client(port).await;
    let zenoh = get_one(&s, "gw/demo/drive/status").await;
    assert_eq!(keys(&zenoh), keys(&rest), "zenoh {zenoh:#}\nREST {rest:#}");
    for field in [
        "name",
        "protocol",
        "port",
        "state",
        "port_open",
        "started",
        "port_opens",
        "devices_total",
    ] {
        assert_eq!(zenoh[field], rest[field], "{field}: {zenoh:#}");
    }
    assert!(zenoh["status_word"].is_u64(), "{zenoh:#}");
    assert_eq!(keys(&zenoh["counters"]), keys(&rest["counters"]));
    let devices = |v: &Value| -> Vec<(Value, Value, Value, Vec<String>)> {
        v["devices"]
            .as_array()
            .expect("devices")
            .iter()
            .map(|d| {
                let key = |k: &str| d[k].clone();
                (key("name"), key("address"), key("unit_id"), keys(d))
            })
            .collect()
    };
    assert_eq!(devices(&zenoh), devices(&rest), "{zenoh:#}");
    let codes: Vec<&Value> = zenoh["event_counts"]
        .as_array()
        .expect("event counts")
        .iter()
        .map(|c| &c["event"]["code"])
        .collect();
    assert!(codes.contains(&&Value::from("0003")), "{codes:?}");

    // The gateway's status carries every line in the same view, with the fleet's two fields
    // added (docs/fleet.md: `online`, `last_event_age_s`).
    let gateway = get_one(&s, "gw/demo/status").await;
    let drive = gateway["lines"]
        .as_array()
        .expect("lines")
        .iter()
        .find(|l| l["name"] == "drive")
        .expect("the drive line");
    let fleet = ["online", "last_event_age_s"];
    let view: Vec<String> = keys(drive)
        .into_iter()
        .filter(|k| !fleet.contains(&k.as_str()))
        .collect();
    assert_eq!(view, keys(&rest), "{drive:#}");
    assert!(fleet.iter().all(|k| drive.get(*k).is_some()), "{drive:#}");
    s.close().await.expect("close");
}

/// `<workspace>/.venv/bin/python` with eclipse-zenoh of the crate's version.
fn python() -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let python = root.join(".venv/bin/python");
    let hint = format!(
        "the Python zenoh test needs {} with eclipse-zenoh {PYTHON_ZENOH_VERSION}: run \
         `python3 -m venv .venv && .venv/bin/pip install eclipse-zenoh=={PYTHON_ZENOH_VERSION}` at \
         the workspace root (.ci/run does this)",
        python.display()
    );
    let out = std::process::Command::new(&python)
        .args([
            "-c",
            "import importlib.metadata as m; print(m.version('eclipse-zenoh'))",
        ])
        .output()
        .unwrap_or_else(|e| panic!("{hint} ({e})"));
    assert!(out.status.success(), "{hint}");
    assert_eq!(
        String::from_utf8_lossy(&out.stdout).trim(),
        PYTHON_ZENOH_VERSION,
        "{hint}"
    );
    python
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_python_binding_receives_gets_sends_and_sets() {
    let python = python();
    let (gw, port) = demo_with_zenoh(&["--telegram-every", "100ms"]);
    let _acks = keep_mailbox_empty(&gw);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/zenoh_client.py");
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let mut child = tokio::process::Command::new(python)
        .arg(script)
        .args([
            "--endpoint",
            &endpoint,
            "--prefix",
            "gw/demo",
            "--timeout",
            "40",
        ])
        .args(["--tag-key", "drive/atv71/ETA", "--get-key", "drive/atv71/*"])
        .args([
            "--set-key",
            "drive/atv71/DEC",
            "--set-value",
            "6.5",
            "--tx-line",
            "r3964",
        ])
        .stdout(std::process::Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .expect("python starts");
    let mut lines = tokio::io::BufReader::new(child.stdout.take().expect("stdout")).lines();
    let mut out: Vec<Value> = Vec::new();
    tokio::time::timeout(Duration::from_secs(150), async {
        while let Some(line) = lines.next_line().await.expect("read") {
            let v: Value =
                serde_json::from_str(&line).unwrap_or_else(|_| panic!("not JSON: {line}"));
            let done = v["kind"] == "done" || v["kind"] == "error";
            out.push(v);
            if done {
                break;
            }
        }
    })
    .await
    .unwrap_or_else(|_| panic!("the Python client did not finish: {out:?}"));
    let status = child.wait().await.expect("python exits");
    assert!(status.success(), "{out:#?}");
    let kinds: Vec<&str> = out.iter().filter_map(|v| v["kind"].as_str()).collect();
    assert!(
        kinds.contains(&"sample") && kinds.contains(&"get"),
        "{out:#?}"
    );
    let tx = out
        .iter()
        .find(|v| v["kind"] == "tx_result")
        .expect("tx result");
    assert_eq!(tx["payload"]["ok"], Value::Bool(true), "{tx}");
    let set = out
        .iter()
        .find(|v| v["kind"] == "set_result")
        .expect("set result");
    assert_eq!(set["payload"]["ok"], Value::Bool(true), "{set}");
    // The value reached the drive: DEC (W9002, 0.1 s) = 6.5 s.
    let mut drive = tcp::connect_slave(gw.modbus_tcp, Slave(2))
        .await
        .expect("connect");
    let words = drive
        .read_holding_registers(9002, 2)
        .await
        .expect("transport")
        .expect("read");
    assert_eq!(words[0], 65, "{words:?}");
}

/// A late subscriber gets the current value of every tag at once: the Python binding's advanced
/// subscriber with history, declared long after the KS vario's values (which never change) were
/// last published, receives each of them from the gateway's history queryable.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_late_advanced_subscriber_gets_the_current_values_at_once() {
    let python = python();
    let (_gw, port) = demo_with_zenoh(&[]);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/zenoh_history.py");
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let out = tokio::process::Command::new(python)
        .arg(script)
        .args(["--endpoint", &endpoint, "--prefix", "gw/demo"])
        .args([
            "--key",
            "ksvario/ksvario/*",
            "--settle",
            "3",
            "--window",
            "3",
        ])
        .args(["--timeout", "60"])
        .kill_on_drop(true)
        .output();
    let out = tokio::time::timeout(Duration::from_secs(120), out)
        .await
        .expect("the Python client finishes")
        .expect("python runs");
    let lines: Vec<Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|_| panic!("not JSON: {l}")))
        .collect();
    assert!(
        out.status.success(),
        "{lines:#?}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let get = lines.iter().find(|v| v["kind"] == "get").expect("get");
    let history = lines
        .iter()
        .find(|v| v["kind"] == "history")
        .expect("history");
    assert!(
        get["keys"].as_array().is_some_and(|k| !k.is_empty()),
        "{get}"
    );
    // Every tag the get names arrived, within a second of the subscription.
    assert_eq!(history["keys"], get["keys"], "{history:#}");
    let first = history["first_after"].as_f64().expect("a first sample");
    assert!(first < 1.0, "the first value came after {first} s");
    // Each value came from the history (a reply: no timestamp), not from a publication that
    // happened to fall in the window (a heartbeat, say), and within a second.
    let samples = history["samples"].as_array().expect("samples");
    for key in get["keys"].as_array().expect("keys") {
        assert!(
            samples.iter().any(|s| {
                s["key"] == *key && s["live"] == false && s["at"].as_f64().is_some_and(|t| t < 1.0)
            }),
            "no history reply for {key} within a second: {history:#}"
        );
    }
    for sample in history["samples"].as_array().expect("samples") {
        let payload = &sample["payload"];
        assert!(payload["value"].is_number(), "{sample}");
        assert_eq!(payload["quality"], "good", "{sample}");
    }
}
