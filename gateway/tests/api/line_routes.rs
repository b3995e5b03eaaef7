//! Status, lines, diagnostic buffer, telegrams, signals, tags, health and readiness.

use proto_core::event::EventId;
use serde_json::json;

use super::support::{start, test_config};

#[tokio::test]
async fn gateway_and_line_status() {
    let api = start().await;
    api.gw.raise("drive", EventId::new(0x08, 0x30));
    let r = api.get("/api/v1/status").await;
    assert_eq!(r.status, 200);
    assert_eq!(r.json["name"], "demo");
    assert_eq!(r.json["ready"], true);
    let config = test_config();
    assert_eq!(
        r.json["lines"].as_array().unwrap().len(),
        config.lines.len()
    );
    // The address in the demo config the test backend reports; nothing listens on it.
    assert_eq!(r.json["modbus_tcp"]["listen"], "127.0.0.1:5020"); // demo config value
    assert_eq!(r.json["zenoh"]["up"], true);

    let r = api.get("/api/v1/lines").await;
    assert_eq!(r.status, 200);
    let names: Vec<&str> = r
        .json
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l["name"].as_str().unwrap())
        .collect();
    let expected: Vec<&str> = config.lines.keys().map(String::as_str).collect();
    assert_eq!(names, expected);

    let r = api.get("/api/v1/lines/drive").await;
    assert_eq!(r.status, 200);
    let l = &r.json;
    assert_eq!(l["protocol"], "modbus-master-rtu");
    assert_eq!(l["state"], "running");
    assert_eq!(l["port"], "pty:drive");
    assert_eq!(l["status_word"], 0x0830);
    assert_eq!(l["last_event"]["code"], "0830");
    assert_eq!(l["last_event"]["class_name"], "receive error");
    // The demo's drive line: two drives on one bus.
    assert_eq!(l["devices_online"], 2);
    assert_eq!(l["devices_total"], 2);
    assert_eq!(l["devices"][0]["name"], "atv71");
    assert_eq!(l["devices"][0]["address"], 2);
    assert_eq!(l["devices"][1]["name"], "atv71b");
    assert_eq!(l["devices"][1]["address"], 3);
    assert_eq!(l["counters"]["events"], 1);
    assert_eq!(l["event_counts"][0]["count"], 1);

    let r = api.get("/api/v1/lines/nope").await;
    assert_eq!((r.status, r.code()), (404, "not_found"));
}

#[tokio::test]
async fn the_diagnostic_buffer_is_newest_first_with_catalog_texts_and_clears() {
    let api = start().await;
    for id in [
        EventId::new(0x07, 0x09),
        EventId::new(0x08, 0x30),
        EventId::new(0x08, 0x30),
    ] {
        api.gw.raise("r3964", id);
    }
    let r = api.get("/api/v1/lines/r3964/diag").await;
    assert_eq!(r.status, 200, "{}", r.text);
    assert_eq!(r.json["line"], "r3964");
    assert_eq!(r.json["depth"], 9);
    let entries = r.json["entries"].as_array().unwrap();
    assert_eq!(
        entries.len(),
        3,
        "every event an entry (003 7.3): {}",
        r.text
    );
    let newest = &entries[0];
    assert_eq!(
        (newest["class"].as_u64(), newest["number"].as_u64()),
        (Some(8), Some(0x30))
    );
    assert_eq!(newest["count"], 1);
    assert_eq!(entries[1]["code"], "0830");
    assert_eq!(newest["class_name"], "receive error");
    for key in ["time", "first_time", "description", "remedy"] {
        assert!(
            newest[key].as_str().is_some_and(|s| !s.is_empty()),
            "{key}: {newest}"
        );
    }
    assert_eq!(entries[2]["code"], "0709");

    let r = api.delete("/api/v1/lines/r3964/diag").await;
    assert_eq!(r.status, 204, "{}", r.text);
    assert_eq!(
        api.get("/api/v1/lines/r3964/diag").await.json["entries"],
        json!([])
    );
    assert_eq!(
        api.delete("/api/v1/lines/nope/diag").await.code(),
        "not_found"
    );
}

#[tokio::test]
async fn queued_telegrams_are_read_and_acknowledged_oldest_first() {
    let api = start().await;
    api.gw.receive("ascii", b"first\r\n");
    api.gw.receive("ascii", &[0x02, 0xFF, 0x03]);
    let r = api.get("/api/v1/lines/ascii/telegrams").await;
    assert_eq!(r.status, 200, "{}", r.text);
    let t = r.json["telegrams"].as_array().unwrap();
    assert_eq!(t.len(), 2);
    assert_eq!(t[0]["seq"], 1);
    assert_eq!(t[0]["text"], "first\r\n");
    assert_eq!(t[1]["hex"], "02ff03");
    assert!(t[1].get("text").is_none());
    assert!(t[0]["received"].is_string());

    assert_eq!(
        api.post("/api/v1/lines/ascii/telegrams/2/ack", &json!({}))
            .await
            .code(),
        "conflict"
    );
    assert_eq!(
        api.post("/api/v1/lines/ascii/telegrams/9/ack", &json!({}))
            .await
            .code(),
        "not_found"
    );
    let r = api
        .post("/api/v1/lines/ascii/telegrams/x/ack", &json!({}))
        .await;
    assert_eq!((r.status, r.code()), (400, "bad_request"));
    assert_eq!(
        api.post("/api/v1/lines/ascii/telegrams/1/ack", &json!({}))
            .await
            .status,
        204
    );
    let r = api.get("/api/v1/lines/ascii/telegrams").await;
    assert_eq!(r.json["telegrams"][0]["seq"], 2);

    let r = api.get("/api/v1/lines/drive/telegrams").await;
    assert_eq!((r.status, r.code()), (409, "conflict"));
}

#[tokio::test]
async fn a_telegram_is_sent_as_hex_or_text() {
    let api = start().await;
    let r = api
        .post("/api/v1/lines/r3964/send", &json!({"hex": "02 41 42 03"}))
        .await;
    assert_eq!(r.status, 200, "{}", r.text);
    assert_eq!(r.json, json!({"done": true, "status_word": 0, "len": 4}));
    let r = api
        .post("/api/v1/lines/r3964/send", &json!({"text": "hello"}))
        .await;
    assert_eq!(r.status, 200, "{}", r.text);
    // The partner echoes: both telegrams are queued, the counters moved.
    let q = api.get("/api/v1/lines/r3964/telegrams").await.json;
    assert_eq!(q["telegrams"][1]["text"], "hello");
    assert_eq!(
        api.get("/api/v1/lines/r3964").await.json["counters"]["frames_sent"],
        2
    );

    for bad in [
        json!({"hex": "0"}),
        json!({}),
        json!({"hex": "00", "text": "a"}),
        json!({"data": "a"}),
    ] {
        let r = api.post("/api/v1/lines/r3964/send", &bad).await;
        assert_eq!(
            (r.status, r.code()),
            (422, "invalid_body"),
            "{bad}: {}",
            r.text
        );
    }
    let r = api
        .post("/api/v1/lines/drive/send", &json!({"text": "x"}))
        .await;
    assert_eq!((r.status, r.code()), (409, "conflict"));
    let r = api
        .post("/api/v1/lines/nope/send", &json!({"text": "x"}))
        .await;
    assert_eq!((r.status, r.code()), (404, "not_found"));
}

#[tokio::test]
async fn rs232_signals_are_read_and_set() {
    let api = start().await;
    let r = api.get("/api/v1/lines/ascii/signals").await;
    assert_eq!(r.status, 200, "{}", r.text);
    assert_eq!(
        r.json,
        json!({"dtr": true, "rts": false, "dsr": true, "cts": true, "dcd": false, "ri": false})
    );
    let r = api
        .put("/api/v1/lines/ascii/signals", &json!({"rts": true}))
        .await;
    assert_eq!(r.status, 200, "{}", r.text);
    assert_eq!(
        (r.json["rts"].as_bool(), r.json["dtr"].as_bool()),
        (Some(true), Some(true))
    );
    let r = api
        .put("/api/v1/lines/ascii/signals", &json!({"dtr": false}))
        .await;
    assert_eq!(
        (r.json["rts"].as_bool(), r.json["dtr"].as_bool()),
        (Some(true), Some(false))
    );
    assert_eq!(
        api.get("/api/v1/lines/ascii/signals").await.json["dtr"],
        false
    );

    let r = api
        .put("/api/v1/lines/ascii/signals", &json!({"dsr": true}))
        .await;
    assert_eq!(
        (r.status, r.code()),
        (422, "invalid_body"),
        "an input cannot be set"
    );
    let r = api.get("/api/v1/lines/drive/signals").await;
    assert_eq!(
        (r.status, r.code()),
        (409, "conflict"),
        "RS422 has no modem signals"
    );
}

#[tokio::test]
async fn tags_are_listed_read_and_written_through() {
    let api = start().await;
    let all = api.get("/api/v1/tags").await;
    assert_eq!(all.status, 200);
    assert_eq!(all.json.as_array().unwrap().len(), 4);
    let drive = api.get("/api/v1/tags?line=drive").await;
    assert_eq!(drive.json.as_array().unwrap().len(), 2);
    let ks = api.get("/api/v1/tags?device=ksvario").await;
    assert!(ks
        .json
        .as_array()
        .unwrap()
        .iter()
        .all(|t| t["device"] == "ksvario"));
    assert_eq!(api.get("/api/v1/tags?line=nope").await.code(), "not_found");
    let r = api.get("/api/v1/tags?colour=blue").await;
    assert_eq!((r.status, r.code()), (400, "bad_request"));

    let r = api.get("/api/v1/lines/ksvario/devices/ksvario/tags").await;
    assert_eq!(r.json.as_array().unwrap().len(), 2);
    assert_eq!(
        api.get("/api/v1/lines/ksvario/devices/nope/tags")
            .await
            .code(),
        "not_found"
    );
    assert_eq!(
        api.get("/api/v1/lines/nope/devices/x/tags").await.code(),
        "not_found"
    );

    let r = api
        .get("/api/v1/lines/ksvario/devices/ksvario/tags/pv")
        .await;
    assert_eq!(r.status, 200);
    assert_eq!(r.json["value"], 23.5);
    assert_eq!(r.json["unit"], "°C");
    assert_eq!(r.json["quality"], "good");
    assert_eq!(r.json["writable"], false);
    assert_eq!(
        api.get("/api/v1/lines/ksvario/devices/ksvario/tags/nope")
            .await
            .code(),
        "not_found"
    );

    let path = "/api/v1/lines/drive/devices/atv71/tags/lfrd";
    let r = api.put(path, &json!({"value": 750})).await;
    assert_eq!(r.status, 200, "{}", r.text);
    assert_eq!(r.json["value"], 750);
    assert_eq!(api.get(path).await.json["value"], 750);
    let r = api.put(path, &json!({"value": 9999})).await;
    assert_eq!(
        (r.status, r.code()),
        (502, "device_exception"),
        "{}",
        r.text
    );
    let r = api.put(path, &json!({"value": "fast"})).await;
    assert_eq!((r.status, r.code()), (422, "invalid_body"));
    let r = api
        .put(
            "/api/v1/lines/drive/devices/atv71/tags/eta",
            &json!({"value": 1}),
        )
        .await;
    assert_eq!((r.status, r.code()), (409, "conflict"));

    api.gw.set_device_online("drive", "atv71", false);
    let r = api.put(path, &json!({"value": 10})).await;
    assert_eq!((r.status, r.code()), (504, "device_timeout"));
    assert_eq!(api.get(path).await.json["quality"], "comm_failure");
}

#[tokio::test]
async fn healthz_is_alive_and_readyz_waits_for_lines_and_zenoh() {
    let api = start().await;
    let r = api.get("/healthz").await;
    assert_eq!(
        (r.status, r.json.clone()),
        (200, json!({"status": "alive"}))
    );
    assert_eq!(api.get("/readyz").await.json, json!({"status": "ready"}));

    api.gw.set_port_opened("ksvario", false);
    api.gw.set_zenoh(Some(false));
    let r = api.get("/readyz").await;
    assert_eq!((r.status, r.code()), (503, "not_ready"));
    assert_eq!(r.issue_paths(), ["lines.ksvario", "zenoh"]);
    assert_eq!(r.header("retry-after"), Some("1"));
    assert_eq!(api.get("/api/v1/status").await.json["ready"], false);
    assert_eq!(api.get("/healthz").await.status, 200);

    api.gw.set_port_opened("ksvario", true);
    api.gw.set_zenoh(None);
    assert_eq!(api.get("/readyz").await.status, 200);
}
