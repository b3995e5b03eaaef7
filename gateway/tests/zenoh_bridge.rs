//! The zenoh bridge against a second zenoh session in this process (and the Python binding in
//! another), all on explicit tcp/127.0.0.1 endpoints with multicast scouting off.

#[path = "zenoh_bridge/support.rs"]
mod support;

use std::collections::BTreeMap;
use std::time::{Duration, SystemTime};

use gateway::zenoh_bridge::{DropReason, Mode, PublicationKind, ZenohConfig};
use serde_json::{json, Value};
use zenoh::sample::SampleKind;

use support::*;

const LIMIT: Duration = Duration::from_secs(10);

async fn get_json(session: &zenoh::Session, selector: &str) -> BTreeMap<String, Value> {
    let replies = session
        .get(selector)
        .timeout(LIMIT)
        .await
        .expect("get is sent");
    let mut out = BTreeMap::new();
    while let Ok(reply) = replies.recv_async().await {
        let sample = reply.into_result().expect("no error reply");
        out.insert(sample.key_expr().as_str().to_owned(), json_of(&sample));
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn publications_queries_and_presence() {
    let backend = TestBackend::new();
    let (bridge, handle, shutdown, port) = start_listening(backend.clone()).await;
    let session = peer(&[endpoint(port)], &[]).await;
    let (_sub, mut rx) = subscribe(&session, "gw/test/**").await;

    // Tag values as JSON.
    let s = publish_until_seen(&handle, &mut rx, 1500).await;
    let body = json_of(&s);
    assert_eq!(body["value"], 1500);
    assert_eq!(body["unit"], "rpm");
    assert_eq!(body["quality"], "good");
    assert!(humantime::parse_rfc3339(body["timestamp"].as_str().unwrap()).is_ok());
    assert_eq!(s.encoding().to_string(), "application/json");
    assert!(s.timestamp().is_some());

    // A received telegram: raw bytes, sequence number and time in the attachment.
    let received = SystemTime::UNIX_EPOCH + Duration::from_micros(1_700_000_000_000_001);
    handle
        .publish_telegram("r3964", 7, received, b"\x02HELLO\x03".to_vec())
        .unwrap();
    let s = recv_until(&mut rx, LIMIT, |s| {
        s.key_expr().as_str() == "gw/test/r3964/rx"
    })
    .await;
    assert_eq!(&*s.payload().to_bytes(), b"\x02HELLO\x03");
    let att: Value = serde_json::from_slice(&s.attachment().unwrap().to_bytes()).unwrap();
    assert_eq!(
        att,
        json!({"seq": 7, "time": "2023-11-14T22:13:20.000001Z"})
    );

    // An event.
    handle
        .publish_event(
            "r3964",
            0x08,
            0x0A,
            "receive buffer full",
            "telegram discarded",
        )
        .unwrap();
    let s = recv_until(&mut rx, LIMIT, |s| {
        s.key_expr().as_str() == "gw/test/r3964/events"
    })
    .await;
    let ev = json_of(&s);
    assert_eq!(
        (ev["class"].clone(), ev["number"].clone()),
        (json!(8), json!(10))
    );
    assert_eq!(ev["event"], "080A");
    assert_eq!(ev["name"], "receive buffer full");
    assert_eq!(ev["text"], "telegram discarded");

    // Queries: one tag, wildcards, status.
    let one = get_json(&session, "gw/test/drive/atv/speed").await;
    assert_eq!(one.len(), 1);
    assert_eq!(one["gw/test/drive/atv/speed"]["unit"], "rpm");
    let drive = get_json(&session, "gw/test/drive/**").await;
    let drive_keys: Vec<&str> = drive.keys().map(String::as_str).collect();
    assert_eq!(
        drive_keys,
        [
            "gw/test/drive/atv/cmd",
            "gw/test/drive/atv/eta",
            "gw/test/drive/atv/speed",
            "gw/test/drive/status"
        ]
    );
    let x1 = get_json(&session, "gw/*/*/*/x1").await;
    assert_eq!(x1.len(), 1);
    assert_eq!(x1["gw/test/ksvario/ks/x1"]["value"], 106.6);
    let all_tags = get_json(&session, "gw/test/*/*/*").await;
    assert_eq!(all_tags.len(), 5);
    let status = get_json(&session, "gw/test/status").await;
    let gw = &status["gw/test/status"];
    assert_eq!(gw["name"], "test");
    assert_eq!(gw["zenoh"]["prefix"], "gw/test");
    assert_eq!(gw["zenoh"]["mode"], "peer");
    assert!(
        gw["zenoh"]["stats"]["publications"]["telegram"]
            .as_u64()
            .unwrap()
            >= 1
    );
    let lines = get_json(&session, "gw/test/*/status").await;
    assert_eq!(lines.len(), 3);
    assert_eq!(lines["gw/test/r3964/status"]["state"], "running");
    assert!(get_json(&session, "gw/test/nosuchline/status")
        .await
        .is_empty());

    // Presence: the gateway's token, a device's while it is online.
    let (live_tx, mut live) = tokio::sync::mpsc::unbounded_channel();
    let _live_sub = session
        .liveliness()
        .declare_subscriber("gw/test/**")
        .history(true)
        .callback(move |s| {
            let _ = live_tx.send(s);
        })
        .await
        .unwrap();
    let s = recv_until(&mut live, LIMIT, |s| s.key_expr().as_str() == "gw/test").await;
    assert_eq!(s.kind(), SampleKind::Put);
    handle.device_online("drive", "atv", true);
    let s = recv_until(&mut live, LIMIT, |s| {
        s.key_expr().as_str() == "gw/test/drive/atv"
    })
    .await;
    assert_eq!(s.kind(), SampleKind::Put);
    let tokens = session.liveliness().get("gw/test/**").await.unwrap();
    let mut alive = Vec::new();
    while let Ok(r) = tokens.recv_async().await {
        alive.push(r.into_result().unwrap().key_expr().as_str().to_owned());
    }
    alive.sort();
    assert_eq!(alive, ["gw/test", "gw/test/drive/atv"]);
    handle.device_online("drive", "atv", false);
    let s = recv_until(&mut live, LIMIT, |s| {
        s.key_expr().as_str() == "gw/test/drive/atv"
    })
    .await;
    assert_eq!(s.kind(), SampleKind::Delete);

    // Shutdown takes the gateway's token away.
    shutdown.cancel();
    bridge.join().await;
    let s = recv_until(&mut live, LIMIT, |s| s.key_expr().as_str() == "gw/test").await;
    assert_eq!(s.kind(), SampleKind::Delete);
    assert_eq!(handle.stats().drops(DropReason::PublishError), 0);
    session.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn commands_reach_the_backend_and_results_come_back() {
    let backend = TestBackend::new();
    let (bridge, handle, shutdown, port) = start_listening(backend.clone()).await;
    let session = peer(&[endpoint(port)], &[]).await;
    let (_sub, mut rx) = subscribe(&session, "gw/test/**").await;
    publish_until_seen(&handle, &mut rx, 1).await;

    // A telegram to send, correlated by its attachment.
    session
        .put("gw/test/r3964/tx", b"\x02PING\x03".to_vec())
        .attachment("req-1")
        .await
        .unwrap();
    let s = recv_until(&mut rx, LIMIT, |s| {
        s.key_expr().as_str() == "gw/test/r3964/tx/result"
    })
    .await;
    let r = json_of(&s);
    assert_eq!(
        r,
        json!({"ok": true, "line": "r3964", "len": 6, "result": {"sent": 6}})
    );
    assert_eq!(&*s.attachment().unwrap().to_bytes(), b"req-1");
    assert_eq!(
        *backend.sent.lock().unwrap(),
        [("r3964".to_owned(), b"\x02PING\x03".to_vec())]
    );

    // A write goes through; the new value is published by the image (here: the backend).
    session
        .put("gw/test/drive/atv/cmd/set", "15")
        .await
        .unwrap();
    let s = recv_until(&mut rx, LIMIT, |s| {
        s.key_expr().as_str() == "gw/test/drive/atv/cmd/set/result"
    })
    .await;
    let r = json_of(&s);
    assert_eq!(r["ok"], true);
    assert_eq!(r["value"], 15);
    assert_eq!(r["result"], json!({"written": 15}));
    let s = recv_until(&mut rx, LIMIT, |s| {
        s.key_expr().as_str() == "gw/test/drive/atv/cmd"
    })
    .await;
    assert_eq!(json_of(&s)["value"], 15);
    assert_eq!(
        *backend.writes.lock().unwrap(),
        [("drive".into(), "atv".into(), "cmd".into(), json!(15))]
    );

    // Refusals: the device's (read-only), the bridge's (payload, line).
    for (key, payload, want) in [
        ("gw/test/drive/atv/eta/set", "1", "exception 04"),
        ("gw/test/drive/atv/cmd/set", "fast", "not a JSON value"),
        ("gw/test/nosuchline/tx", "x", "unknown line"),
        ("gw/test/drive/atv/nosuchtag/set", "1", "no tag"),
    ] {
        session.put(key, payload).await.unwrap();
        let result_key = format!("{key}/result");
        let s = recv_until(&mut rx, LIMIT, |s| s.key_expr().as_str() == result_key).await;
        let r = json_of(&s);
        assert_eq!(r["ok"], false, "{key}");
        assert!(r["error"].as_str().unwrap().contains(want), "{key}: {r}");
    }
    assert_eq!(backend.writes.lock().unwrap().len(), 1);

    // The query form: the result is the reply.
    let replies = session
        .get("gw/test/r3964/tx")
        .payload(b"\x02Q\x03".to_vec())
        .timeout(LIMIT)
        .await
        .unwrap();
    let reply = replies.recv_async().await.unwrap().into_result().unwrap();
    assert_eq!(json_of(&reply)["result"], json!({"sent": 3}));
    let replies = session
        .get("gw/test/drive/atv/speed/set")
        .payload("1200")
        .timeout(LIMIT)
        .await
        .unwrap();
    let reply = replies.recv_async().await.unwrap().into_result().unwrap();
    assert_eq!(json_of(&reply)["ok"], true);
    assert_eq!(backend.sent.lock().unwrap().len(), 2);

    shutdown.cancel();
    bridge.join().await;
    session.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_thousand_telegrams_in_order_each_once() {
    const N: u64 = 1000;
    let backend = TestBackend::new();
    let (bridge, handle, shutdown, port) = start_listening(backend).await;
    let session = peer(&[endpoint(port)], &[]).await;
    let (_sub, mut rx) = subscribe(&session, "gw/test/*/rx").await;
    let (_tags, mut tag_rx) = subscribe(&session, "gw/test/*/*/*").await;
    publish_until_seen(&handle, &mut tag_rx, 2).await;

    for seq in 0..N {
        let line = if seq % 3 == 0 { "ascii" } else { "r3964" };
        let bytes = format!("telegram {seq}").into_bytes();
        handle
            .publish_telegram(line, seq, SystemTime::now(), bytes)
            .unwrap();
    }
    let mut seen: BTreeMap<String, Vec<u64>> = BTreeMap::new();
    for _ in 0..N {
        let s = tokio::time::timeout(LIMIT, rx.recv())
            .await
            .unwrap()
            .unwrap();
        let att: Value = serde_json::from_slice(&s.attachment().unwrap().to_bytes()).unwrap();
        let seq = att["seq"].as_u64().unwrap();
        assert_eq!(
            &*s.payload().to_bytes(),
            format!("telegram {seq}").as_bytes()
        );
        let line = s.key_expr().as_str().split('/').nth(2).unwrap().to_owned();
        seen.entry(line).or_default().push(seq);
    }
    let want_ascii: Vec<u64> = (0..N).filter(|s| s % 3 == 0).collect();
    let want_r3964: Vec<u64> = (0..N).filter(|s| s % 3 != 0).collect();
    assert_eq!(seen["ascii"], want_ascii);
    assert_eq!(seen["r3964"], want_r3964);
    // Nothing more arrives: each telegram was published once.
    assert!(tokio::time::timeout(Duration::from_millis(500), rx.recv())
        .await
        .is_err());
    assert_eq!(handle.stats().publications(PublicationKind::Telegram), N);
    assert_eq!(handle.stats().drops(DropReason::TelegramQueueFull), 0);

    shutdown.cancel();
    bridge.join().await;
    session.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_telegram_queue_drops_and_counts_the_new_ones() {
    // No session can publish before it is open: a client with nowhere to connect keeps
    // everything in the outbox.
    let port = free_port();
    let cfg = ZenohConfig {
        mode: Some(Mode::Client),
        connect: Some(vec![endpoint(port).try_into().unwrap()]),
        listen: Some(Vec::new()),
        multicast_scouting: Some(false),
        telegram_queue: 4.try_into().unwrap(),
        ..ZenohConfig::default()
    };
    let (bridge, handle, shutdown) = start(cfg, TestBackend::new()).await;
    for seq in 0..4 {
        assert!(handle
            .publish_telegram("r3964", seq, SystemTime::now(), vec![1])
            .is_ok());
    }
    assert_eq!(
        handle.publish_telegram("r3964", 4, SystemTime::now(), vec![1]),
        Err(DropReason::TelegramQueueFull)
    );
    assert_eq!(handle.stats().drops(DropReason::TelegramQueueFull), 1);
    assert_eq!(
        handle.publish_telegram("a/b", 5, SystemTime::now(), vec![1]),
        Err(DropReason::BadKey)
    );
    shutdown.cancel();
    bridge.join().await;
}

/// Waits for the `gw/test` liveliness token to appear (`true`) or go (`false`).
async fn gateway_token(
    live: &mut tokio::sync::mpsc::UnboundedReceiver<zenoh::sample::Sample>,
    kind: SampleKind,
) {
    recv_until(live, Duration::from_secs(20), |s| {
        s.key_expr().as_str() == "gw/test" && s.kind() == kind
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn peers_leave_and_return_the_bridge_publishes_again() {
    // The bridge listens; peers come and go.
    let backend = TestBackend::new();
    let (bridge, handle, shutdown, port) = start_listening(backend).await;
    for round in 0..2 {
        let session = peer(&[endpoint(port)], &[]).await;
        let (_sub, mut rx) = subscribe(&session, "gw/test/**").await;
        publish_until_seen(&handle, &mut rx, 100 + round).await;
        session.close().await.unwrap();
        // Publishing into the void neither fails nor blocks.
        for seq in 0..50 {
            handle
                .publish_telegram("r3964", seq, SystemTime::now(), vec![0x02, 0x03])
                .unwrap();
        }
    }
    assert_eq!(handle.stats().drops(DropReason::PublishError), 0);
    shutdown.cancel();
    bridge.join().await;

    // The bridge connects to a peer that disappears and comes back on the same endpoint.
    let peer_port = free_port();
    let cfg = ZenohConfig {
        mode: Some(Mode::Peer),
        connect: Some(vec![endpoint(peer_port).try_into().unwrap()]),
        listen: Some(Vec::new()),
        multicast_scouting: Some(false),
        ..ZenohConfig::default()
    };
    let remote = peer(&[], &[endpoint(peer_port)]).await;
    let (bridge, handle, shutdown) = start(cfg, TestBackend::new()).await;
    let (_sub, mut rx) = subscribe(&remote, "gw/test/**").await;
    publish_until_seen(&handle, &mut rx, 200).await;
    remote.close().await.unwrap();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let remote = peer(&[], &[endpoint(peer_port)]).await;
    let (_sub, mut rx) = subscribe(&remote, "gw/test/**").await;
    publish_until_seen(&handle, &mut rx, 201).await;
    shutdown.cancel();
    bridge.join().await;
    remote.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_retries_until_its_router_appears() {
    let port = free_port();
    let cfg = ZenohConfig {
        mode: Some(Mode::Client),
        connect: Some(vec![endpoint(port).try_into().unwrap()]),
        listen: Some(Vec::new()),
        multicast_scouting: Some(false),
        ..ZenohConfig::default()
    };
    let (bridge, handle, shutdown) = start(cfg, TestBackend::new()).await;
    assert!(!handle.stats().session_open());
    // Queued before the session exists, published once it does.
    handle
        .publish_telegram("r3964", 1, SystemTime::now(), b"early".to_vec())
        .unwrap();
    tokio::time::sleep(Duration::from_millis(1500)).await;

    let remote = peer(&[], &[endpoint(port)]).await;
    let (live_tx, mut live) = tokio::sync::mpsc::unbounded_channel();
    let _live_sub = remote
        .liveliness()
        .declare_subscriber("gw/test/**")
        .history(true)
        .callback(move |s| {
            let _ = live_tx.send(s);
        })
        .await
        .unwrap();
    gateway_token(&mut live, SampleKind::Put).await;
    assert!(handle.stats().session_open());
    let (_sub, mut rx) = subscribe(&remote, "gw/test/**").await;
    publish_until_seen(&handle, &mut rx, 300).await;
    // The early telegram was published (to nobody yet) and counted.
    assert!(handle.stats().publications(PublicationKind::Telegram) >= 1);
    shutdown.cancel();
    bridge.join().await;
    gateway_token(&mut live, SampleKind::Delete).await;
    remote.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_peer_bridge_fails_to_start_on_a_busy_port() {
    let busy = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = busy.local_addr().unwrap().port();
    let cfg = ZenohConfig::loopback_peer(&endpoint(port)).unwrap();
    let result = gateway::zenoh_bridge::Bridge::start(
        cfg,
        NAME,
        TestBackend::new(),
        tokio_util::sync::CancellationToken::new(),
    )
    .await;
    assert!(matches!(
        result,
        Err(gateway::zenoh_bridge::BridgeError::Open(_))
    ));
    drop(busy);
}

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

/// A gate a subscriber callback waits at while it is closed.
#[derive(Default)]
struct Gate {
    closed: std::sync::Mutex<bool>,
    changed: std::sync::Condvar,
}

impl Gate {
    fn set_closed(&self, closed: bool) {
        *self.closed.lock().unwrap() = closed;
        self.changed.notify_all();
    }

    fn pass(&self) {
        let mut closed = self.closed.lock().unwrap();
        while *closed {
            closed = self.changed.wait(closed).unwrap();
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stuck_subscriber_never_makes_the_producer_wait() {
    const N: u64 = 2000;
    let port = free_port();
    let mut cfg = ZenohConfig::loopback_peer(&endpoint(port)).unwrap();
    cfg.telegram_queue = 8.try_into().unwrap();
    let (bridge, handle, shutdown) = start(cfg, TestBackend::new()).await;
    let session = peer(&[endpoint(port)], &[]).await;
    let gate = std::sync::Arc::new(Gate::default());
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let _stuck = {
        let gate = gate.clone();
        session
            .declare_subscriber("gw/test/**")
            .callback(move |s| {
                gate.pass();
                let _ = tx.send(s);
            })
            .await
            .unwrap()
    };
    publish_until_seen(&handle, &mut rx, 3).await;

    // The subscriber stops reading: zenoh's reader stalls, TCP pushes back, and the publisher
    // thread waits in its put (telegrams use CongestionControl::Block). 128 MB cannot fit in
    // the socket buffers and queues in between.
    gate.set_closed(true);
    let (mut queued, mut dropped) = (0u64, 0u64);
    for seq in 0..N {
        let bytes = vec![0x55; 64 * 1024];
        match handle.publish_telegram("r3964", seq, SystemTime::now(), bytes) {
            Ok(()) => queued += 1,
            Err(DropReason::TelegramQueueFull) => dropped += 1,
            Err(other) => panic!("unexpected drop reason {other:?}"),
        }
    }
    // The loop ended while the subscriber was still stuck: no call waited for the network.
    gate.set_closed(false);
    assert_eq!(queued + dropped, N);
    assert!(dropped > 0, "the queue never filled: nothing pushed back");
    assert_eq!(handle.stats().drops(DropReason::TelegramQueueFull), dropped);

    // What was queued arrives once the subscriber reads again: in order, each once.
    let mut last = None;
    for _ in 0..queued {
        let s = recv_until(&mut rx, Duration::from_secs(30), |s| {
            s.key_expr().as_str() == "gw/test/r3964/rx"
        })
        .await;
        let att: Value = serde_json::from_slice(&s.attachment().unwrap().to_bytes()).unwrap();
        let seq = att["seq"].as_u64().unwrap();
        assert!(last.is_none_or(|l| seq > l), "{seq} after {last:?}");
        last = Some(seq);
    }
    assert_eq!(
        handle.stats().publications(PublicationKind::Telegram),
        queued
    );

    shutdown.cancel();
    bridge.join().await;
    session.close().await.unwrap();
}
