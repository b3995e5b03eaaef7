//! The Python binding (PyPI eclipse-zenoh) in a separate process: tests/python/zenoh_client.py.

use super::*;

/// The eclipse-zenoh release the Python client must have: the same as the crate (Cargo.toml
/// pins `zenoh = "=1.10.2"`).
const PYTHON_ZENOH_VERSION: &str = "1.10.2";

/// `<workspace>/.venv/bin/python`, with eclipse-zenoh of the crate's version.
fn python() -> std::path::PathBuf {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_owned();
    let python = root.join(".venv/bin/python");
    let hint = format!(
        "the zenoh Python test needs {} with eclipse-zenoh {PYTHON_ZENOH_VERSION}: run \
         `python3 -m venv .venv && .venv/bin/pip install eclipse-zenoh=={PYTHON_ZENOH_VERSION}` \
         at the workspace root (.ci/run does this)",
        python.display()
    );
    let out = std::process::Command::new(&python)
        .args([
            "-c",
            "import importlib.metadata as m; print(m.version('eclipse-zenoh'))",
        ])
        .output()
        .unwrap_or_else(|e| panic!("{hint} ({e})"));
    let version = String::from_utf8_lossy(&out.stdout).trim().to_owned();
    assert!(out.status.success(), "{hint}");
    assert_eq!(version, PYTHON_ZENOH_VERSION, "{hint}");
    python
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_python_binding_receives_gets_sends_and_writes() {
    use tokio::io::AsyncBufReadExt;

    let python = python();
    let script =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/python/zenoh_client.py");
    let backend = TestBackend::new();
    let (bridge, handle, shutdown, port) = start_listening(backend.clone()).await;
    handle.device_online("drive", "atv", true);
    let mut child = tokio::process::Command::new(python)
        .arg(script)
        .args(["--endpoint", &endpoint(port), "--prefix", "gw/test"])
        .stdout(std::process::Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .expect("python starts");
    let mut lines = tokio::io::BufReader::new(child.stdout.take().unwrap()).lines();

    // Publish until the client has seen a tag value and a telegram, then let it run its steps.
    let mut out: Vec<Value> = Vec::new();
    let mut tick = tokio::time::interval(Duration::from_millis(200));
    let mut seq = 0;
    tokio::time::timeout(Duration::from_secs(90), async {
        loop {
            let samples = out.iter().filter(|v| v["kind"] == "sample").count();
            let ready = out.iter().any(|v| v["kind"] == "ready");
            tokio::select! {
                line = lines.next_line() => {
                    let line = line.unwrap().expect("python ended before \"done\"");
                    let v: Value = serde_json::from_str(&line).unwrap();
                    assert_ne!(v["kind"], "error", "python: {v}");
                    let done = v["kind"] == "done";
                    out.push(v);
                    if done {
                        break;
                    }
                }
                _ = tick.tick(), if ready && samples < 2 => {
                    handle.publish_tag("drive", "atv", "speed", value(json!(1450), Some("rpm")));
                    seq += 1;
                    let _ = handle.publish_telegram("r3964", seq, SystemTime::now(), b"\x02RX\x03".to_vec());
                }
            }
        }
    })
    .await
    .expect("python client done within 90 s");
    assert!(child.wait().await.unwrap().success());

    let find = |kind: &str, key: &str| {
        out.iter()
            .find(|v| v["kind"] == kind && v["key"] == key)
            .unwrap_or_else(|| panic!("no {kind} on {key} in {out:?}"))
            .clone()
    };
    let tag = find("sample", "gw/test/drive/atv/speed");
    assert_eq!(tag["payload"]["value"], 1450);
    assert_eq!(tag["payload"]["unit"], "rpm");
    assert_eq!(tag["encoding"], "application/json");
    let rx = find("sample", "gw/test/r3964/rx");
    assert_eq!(rx["payload_hex"], "02525803");
    let att: Value = serde_json::from_str(rx["attachment"].as_str().unwrap()).unwrap();
    assert!(att["seq"].as_u64().unwrap() >= 1);
    assert!(humantime::parse_rfc3339(att["time"].as_str().unwrap()).is_ok());

    let gets: Vec<&str> = out
        .iter()
        .filter(|v| v["kind"] == "get")
        .map(|v| v["key"].as_str().unwrap())
        .collect();
    assert_eq!(gets.len(), 3, "{gets:?}");
    assert!(gets.contains(&"gw/test/drive/atv/eta"));
    assert_eq!(
        find("get", "gw/test/drive/atv/eta")["payload"]["value"],
        0x0237
    );

    let tx = find("tx_result", "gw/test/r3964/tx/result");
    assert_eq!(tx["payload"]["ok"], true);
    assert_eq!(tx["attachment"], "py-1");
    assert!(backend
        .sent
        .lock()
        .unwrap()
        .contains(&("r3964".to_owned(), b"\x02PY\x03".to_vec())));

    let set = find("set_result", "gw/test/drive/atv/cmd/set/result");
    assert_eq!(set["payload"]["ok"], true);
    assert_eq!(
        *backend.writes.lock().unwrap(),
        [("drive".into(), "atv".into(), "cmd".into(), json!(42))]
    );

    let tokens = out.iter().find(|v| v["kind"] == "tokens").unwrap();
    assert_eq!(tokens["keys"], json!(["gw/test", "gw/test/drive/atv"]));

    shutdown.cancel();
    bridge.join().await;
}
