//! The zenoh bridge against a second zenoh session in this process (and the Python binding in
//! another), all on explicit tcp/127.0.0.1 endpoints with multicast scouting off.

#[path = "zenoh_bridge/flow.rs"]
mod flow;
#[path = "zenoh_bridge/policy.rs"]
mod policy;
#[path = "zenoh_bridge/python.rs"]
mod python;
#[path = "zenoh_bridge/reconnect.rs"]
mod reconnect;
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

    // A write goes through; the new value is published by the image (here: the backend). The
    // value and the result are two keys, and the bridge keeps no order between keys: the value,
    // queued first, is often published before the result. Both must come, once each.
    session
        .put("gw/test/drive/atv/cmd/set", "15")
        .await
        .unwrap();
    let got = recv_keys(
        &mut rx,
        LIMIT,
        &["gw/test/drive/atv/cmd/set/result", "gw/test/drive/atv/cmd"],
    )
    .await;
    let r = json_of(&got["gw/test/drive/atv/cmd/set/result"]);
    assert_eq!(r["ok"], true);
    assert_eq!(r["value"], 15);
    assert_eq!(r["result"], json!({"written": 15}));
    assert_eq!(json_of(&got["gw/test/drive/atv/cmd"])["value"], 15);
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
    // The refusals wrote nothing.
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
async fn the_zenoh_config_file_is_passed_through_with_access_control() {
    // Endpoints, scouting and an access control list come from the zenoh file alone: writes
    // from the fabric are denied at the gateway's ingress, telegrams to send are allowed.
    let port = free_port();
    let dir = std::env::temp_dir().join(format!("zenoh-acl-{}-{port}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("zenoh.json5");
    std::fs::write(
        &file,
        format!(
            r#"{{
  mode: "peer",
  listen: {{ endpoints: ["{}"] }},
  scouting: {{ multicast: {{ enabled: false }} }},
  access_control: {{
    enabled: true,
    default_permission: "allow",
    rules: [{{ id: "no_writes", messages: ["put"], flows: ["ingress"], permission: "deny",
               key_exprs: ["gw/test/*/*/*/set"] }}],
    subjects: [{{ id: "tcp_peers", link_protocols: ["tcp"] }}],
    policies: [{{ rules: ["no_writes"], subjects: ["tcp_peers"] }}],
  }},
}}"#,
            endpoint(port)
        ),
    )
    .unwrap();
    let cfg = ZenohConfig {
        config_file: Some(file),
        ..ZenohConfig::default()
    };
    let backend = TestBackend::new();
    // A tag on the telegram line: its commands and the telegram's share one worker, in order.
    backend.tags.lock().unwrap().insert(
        ("r3964".into(), "partner".into(), "word".into()),
        value(json!(0), None),
    );
    let (bridge, handle, shutdown) = start(cfg, backend.clone()).await;
    let session = peer(&[endpoint(port)], &[]).await;
    let (_sub, mut rx) = subscribe(&session, "gw/test/**").await;
    publish_until_seen(&handle, &mut rx, 4).await;

    session
        .put("gw/test/r3964/partner/word/set", "7")
        .await
        .unwrap();
    session.put("gw/test/r3964/tx", "T").await.unwrap();
    let s = recv_until(&mut rx, LIMIT, |s| {
        s.key_expr().as_str().ends_with("/result")
    })
    .await;
    // Had the write passed, its result would have come first (same line, same order).
    assert_eq!(s.key_expr().as_str(), "gw/test/r3964/tx/result");
    assert_eq!(json_of(&s)["ok"], true);
    assert!(backend.writes.lock().unwrap().is_empty());

    shutdown.cancel();
    bridge.join().await;
    session.close().await.unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}
