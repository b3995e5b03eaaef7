//! Every read and device route of the API on `gateway run`.

use std::time::Duration;

use reqwest::{Method, StatusCode};
use serde_json::json;
use tokio_modbus::client::{tcp, Reader, Writer};
use tokio_modbus::prelude::Slave;

use super::support::Plant;

/// The paths of the API that the OpenAPI document must describe.
const DOCUMENTED: &[&str] = &[
    "/healthz",
    "/readyz",
    "/api/v1/openapi.json",
    "/api/v1/status",
    "/api/v1/config",
    "/api/v1/config/validate",
    "/api/v1/config/lines/{line}",
    "/api/v1/lines",
    "/api/v1/lines/{line}",
    "/api/v1/lines/{line}/diag",
    "/api/v1/lines/{line}/telegrams",
    "/api/v1/lines/{line}/telegrams/{seq}/ack",
    "/api/v1/lines/{line}/send",
    "/api/v1/lines/{line}/signals",
    "/api/v1/tags",
    "/api/v1/lines/{line}/devices/{device}/tags",
    "/api/v1/lines/{line}/devices/{device}/tags/{tag}",
];

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_line_route_answers_on_a_running_gateway() {
    let plant = Plant::start("rest-routes").await;
    let api = plant.api.clone();

    // Health, readiness, the document, the metrics on the same listener.
    assert_eq!(api.get_ok("/healthz").await["status"], "alive");
    assert_eq!(api.get_ok("/readyz").await["status"], "ready");
    let doc = api.get_ok("/api/v1/openapi.json").await;
    assert!(doc["openapi"].as_str().is_some_and(|v| v.starts_with("3.")));
    for p in DOCUMENTED {
        assert!(
            doc["paths"].get(*p).is_some(),
            "{p} is not in the OpenAPI document"
        );
    }
    let metrics = api.metrics().await;
    assert!(
        metrics.contains("gateway_line_up{line=\"ascii\",protocol=\"ascii\"} 1"),
        "{metrics}"
    );

    // Status of the gateway and of each line.
    let status = api.get_ok("/api/v1/status").await;
    assert_eq!(status["name"], "rest-e2e");
    assert_eq!(status["ready"], true);
    assert_eq!(status["modbus_tcp"]["up"], true);
    assert!(status.get("zenoh").is_none(), "no [zenoh]: {status:#}");
    let lines = api.get_ok("/api/v1/lines").await;
    let names: Vec<&str> = lines
        .as_array()
        .expect("lines")
        .iter()
        .filter_map(|l| l["name"].as_str())
        .collect();
    assert_eq!(names, ["ascii", "drive", "ksvario"]);
    let ks = api
        .wait_for(
            "/api/v1/lines/ksvario",
            Duration::from_secs(20),
            "KS vario polled",
            |l| l["devices"][0]["polls_ok"].as_u64().unwrap_or(0) > 0,
        )
        .await;
    assert_eq!(ks["protocol"], "modbus-master-rtu");
    assert_eq!(ks["state"], "running");
    assert_eq!(ks["devices_online"], 1);
    assert_eq!(ks["devices_total"], 1);
    assert_eq!(ks["devices"][0]["unit_id"], 17);
    // Start-up: 00 03h "PtP parameters accepted" is the newest event.
    assert_eq!(ks["status_word"], 3);
    assert_eq!(ks["last_event"]["code"], "0003");
    assert!(
        ks["counters"]["frames_sent"].as_u64().unwrap_or(0) > 0,
        "{ks:#}"
    );
    assert_eq!(
        api.get("/api/v1/lines/nope").await.status,
        StatusCode::NOT_FOUND
    );

    // The diagnostic buffer: entries with the catalog's texts; cleared, it is empty.
    let diag = api.get_ok("/api/v1/lines/ksvario/diag").await;
    assert_eq!(diag["depth"], 9);
    let first = &diag["entries"][0];
    assert_eq!(first["code"], "0003", "{diag:#}");
    assert_eq!(first["class_name"], "cp start-up");
    assert!(first["description"].as_str().is_some_and(|d| !d.is_empty()));
    assert!(first["time"].as_str().is_some_and(|t| t.ends_with('Z')));
    let cleared = api
        .change(Method::DELETE, "/api/v1/lines/ksvario/diag", None)
        .await;
    assert_eq!(cleared.status, StatusCode::NO_CONTENT);
    assert_eq!(
        api.get_ok("/api/v1/lines/ksvario/diag").await["entries"],
        json!([])
    );
    // A line's own events stay: the drive's buffer is untouched.
    assert_eq!(
        api.get_ok("/api/v1/lines/drive/diag").await["entries"][0]["code"],
        "0003"
    );

    // Telegrams: the ASCII partner sends one every 300 ms; they queue until acknowledged.
    let queue = api
        .wait_for(
            "/api/v1/lines/ascii/telegrams",
            Duration::from_secs(20),
            "two telegrams",
            |q| q["telegrams"].as_array().is_some_and(|t| t.len() >= 2),
        )
        .await;
    let oldest = queue["telegrams"][0]["seq"].as_u64().expect("seq");
    let second = queue["telegrams"][1]["seq"].as_u64().expect("seq");
    assert!(queue["telegrams"][0]["hex"]
        .as_str()
        .is_some_and(|h| h.ends_with("03")));
    let not_oldest = api
        .change(
            Method::POST,
            &format!("/api/v1/lines/ascii/telegrams/{second}/ack"),
            None,
        )
        .await;
    assert_eq!(
        not_oldest.status,
        StatusCode::CONFLICT,
        "{:#}",
        not_oldest.body
    );
    assert_eq!(not_oldest.body["error"]["code"], "conflict");
    let acked = api
        .change(
            Method::POST,
            &format!("/api/v1/lines/ascii/telegrams/{oldest}/ack"),
            None,
        )
        .await;
    assert_eq!(acked.status, StatusCode::NO_CONTENT, "{:#}", acked.body);
    let unknown = api
        .change(
            Method::POST,
            "/api/v1/lines/ascii/telegrams/65000/ack",
            None,
        )
        .await;
    assert_eq!(unknown.status, StatusCode::NOT_FOUND);
    let queue = api.get_ok("/api/v1/lines/ascii/telegrams").await;
    assert_ne!(queue["telegrams"][0]["seq"], json!(oldest));
    assert_eq!(
        api.get("/api/v1/lines/drive/telegrams").await.status,
        StatusCode::CONFLICT,
        "a Modbus line has no telegrams"
    );

    // Sending: the partner echoes the telegram, which arrives in the queue ("REST-PING" ETX; not
    // all printable, so shown as hex only).
    let sent = api
        .change(
            Method::POST,
            "/api/v1/lines/ascii/send",
            Some(&json!({ "text": "REST-PING\u{3}" })),
        )
        .await;
    assert_eq!(sent.status, StatusCode::OK, "{:#}", sent.body);
    assert_eq!(sent.body["done"], true);
    assert_eq!(sent.body["len"], 10);
    api.wait_for(
        "/api/v1/lines/ascii/telegrams",
        Duration::from_secs(10),
        "the echo",
        |q| {
            q["telegrams"]
                .as_array()
                .is_some_and(|t| t.iter().any(|t| t["hex"] == "524553542d50494e4703"))
        },
    )
    .await;
    let line = api.get_ok("/api/v1/lines/ascii").await;
    assert!(
        line["counters"]["frames_sent"].as_u64().unwrap_or(0) >= 1,
        "{line:#}"
    );
    let bad = api
        .change(
            Method::POST,
            "/api/v1/lines/ascii/send",
            Some(&json!({ "hex": "0" })),
        )
        .await;
    assert_eq!(bad.status, StatusCode::UNPROCESSABLE_ENTITY);

    // RS232 signals: a pseudo-terminal has none, and the answer says which port refused.
    let signals = api.get("/api/v1/lines/ascii/signals").await;
    assert_eq!(signals.status, StatusCode::CONFLICT, "{:#}", signals.body);
    let message = signals.body["error"]["message"]
        .as_str()
        .unwrap_or_default();
    // The port's driver refuses the modem-status ioctl (ENOTTY on a pty behind a socat link).
    assert!(
        message.contains("ascii-a") && message.contains("cannot read"),
        "{message}"
    );
    let set = api
        .change(
            Method::PUT,
            "/api/v1/lines/ascii/signals",
            Some(&json!({ "dtr": true })),
        )
        .await;
    assert_eq!(set.status, StatusCode::CONFLICT, "{:#}", set.body);
    assert_eq!(
        api.get("/api/v1/lines/drive/signals").await.status,
        StatusCode::CONFLICT
    );

    // Tags: all, one device's, one; a write goes through to the device.
    let tags = api.get_ok("/api/v1/tags?line=drive").await;
    let hsp = tags
        .as_array()
        .and_then(|t| t.iter().find(|t| t["tag"] == "HSP"))
        .cloned()
        .unwrap_or_else(|| panic!("no HSP in {tags:#}"));
    assert_eq!(hsp["value"], 50.0);
    assert_eq!(hsp["unit"], "Hz");
    assert_eq!(hsp["quality"], "good");
    assert_eq!(hsp["writable"], true);
    // ACC is not polled: the list has no value for it, one GET reads it from the device.
    let acc = tags
        .as_array()
        .and_then(|t| t.iter().find(|t| t["tag"] == "ACC"))
        .cloned()
        .unwrap_or_else(|| panic!("no ACC in {tags:#}"));
    assert_eq!(acc["quality"], "unknown", "{acc:#}");
    assert_eq!(acc["value"], json!(null));
    let acc = api
        .get_ok("/api/v1/lines/drive/devices/atv71/tags/ACC")
        .await;
    assert_eq!(acc["value"], 3.0, "the simulator's 3.0 s ramp: {acc:#}");
    assert_eq!(acc["unit"], "s");
    assert_eq!(acc["quality"], "good");
    let device = api.get_ok("/api/v1/lines/ksvario/devices/ks/tags").await;
    assert!(device
        .as_array()
        .is_some_and(|t| !t.is_empty() && t.iter().all(|t| t["device"] == "ks")));
    assert_eq!(
        api.get_ok("/api/v1/lines/drive/devices/atv71/tags/hsp")
            .await["tag"],
        "HSP"
    );
    // A value the tag cannot hold exactly is refused with the nearest values it holds: HSP in
    // steps of 0.1 Hz from 0.0 to 1600.0 Hz.
    for (value, nearest) in [(45.55, "nearest: 45.5 or 45.6"), (-1.0, "nearest: 0.0")] {
        let refused = api
            .change(
                Method::PUT,
                "/api/v1/lines/drive/devices/atv71/tags/hsp",
                Some(&json!({ "value": value })),
            )
            .await;
        assert_eq!(
            refused.status,
            StatusCode::UNPROCESSABLE_ENTITY,
            "{value}: {:#}",
            refused.body
        );
        let message = refused.body["error"]["message"]
            .as_str()
            .unwrap_or_default();
        assert!(message.ends_with(nearest), "{value}: {message}");
    }
    assert_eq!(
        api.get("/api/v1/lines/drive/devices/atv71/tags/nope")
            .await
            .status,
        StatusCode::NOT_FOUND
    );
    let written = api
        .change(
            Method::PUT,
            "/api/v1/lines/drive/devices/atv71/tags/HSP",
            Some(&json!({ "value": 45.5 })),
        )
        .await;
    assert_eq!(written.status, StatusCode::OK, "{:#}", written.body);
    assert_eq!(written.body["value"], 45.5);
    let mut atv = tcp::connect_slave(plant.gw.modbus_tcp, Slave(2))
        .await
        .expect("connect");
    let hsp_register = atv
        .read_holding_registers(3104, 1)
        .await
        .expect("transport");
    assert_eq!(hsp_register, Ok(vec![455]), "HSP in 0.1 Hz on the device");
    let read_only = api
        .change(
            Method::PUT,
            "/api/v1/lines/drive/devices/atv71/tags/ETA",
            Some(&json!({ "value": 1 })),
        )
        .await;
    assert_eq!(
        read_only.status,
        StatusCode::CONFLICT,
        "{:#}",
        read_only.body
    );
    let error_keys: Vec<&String> = read_only
        .body
        .as_object()
        .map(|o| o.keys().collect())
        .unwrap_or_default();
    assert_eq!(
        error_keys,
        ["error"],
        "one error shape: {:#}",
        read_only.body
    );

    // A changed [modbus_tcp] limit is put in force in the running server, which keeps its
    // address and its clients (no restart); read-only now, a tag write is refused with the
    // Modbus TCP server's check.
    let mut config = api.get_ok("/api/v1/config").await;
    config["modbus_tcp"]["read_only"] = json!(true);
    let a = api
        .change(Method::PUT, "/api/v1/config", Some(&config))
        .await;
    assert_eq!(a.status, StatusCode::OK, "{:#}", a.body);
    assert_eq!(a.body["applied"]["servers_restarted"], json!([]));
    assert_eq!(a.body["applied"]["lines_restarted"], json!([]));
    let status = api.get_ok("/api/v1/status").await;
    assert_eq!(
        status["modbus_tcp"]["listen"],
        plant.gw.modbus_tcp.to_string()
    );
    assert_eq!(status["modbus_tcp"]["up"], true);
    assert_eq!(api.get_ok("/readyz").await["status"], "ready");
    let mut again = tcp::connect_slave(plant.gw.modbus_tcp, Slave(2))
        .await
        .expect("the server accepts");
    assert_eq!(
        again
            .read_holding_registers(3104, 1)
            .await
            .expect("transport"),
        Ok(vec![455])
    );
    assert_eq!(
        again
            .write_single_register(3104, 400)
            .await
            .expect("transport"),
        Err(tokio_modbus::prelude::ExceptionCode::IllegalFunction)
    );
    let refused = api
        .change(
            Method::PUT,
            "/api/v1/lines/drive/devices/atv71/tags/HSP",
            Some(&json!({ "value": 40 })),
        )
        .await;
    assert_eq!(refused.status, StatusCode::CONFLICT, "{:#}", refused.body);
    assert!(refused.body["error"]["message"]
        .as_str()
        .is_some_and(|m| m.contains("read-only")));

    // A line removed stops, its unit goes; added again, it starts and receives again.
    let ascii = api.get_ok("/api/v1/config/lines/ascii").await;
    let removed = api
        .change(Method::DELETE, "/api/v1/config/lines/ascii", None)
        .await;
    assert_eq!(removed.status, StatusCode::OK, "{:#}", removed.body);
    assert_eq!(removed.body["applied"]["lines_stopped"], json!(["ascii"]));
    assert_eq!(removed.body["applied"]["lines_restarted"], json!([]));
    assert_eq!(
        api.get("/api/v1/lines/ascii").await.status,
        StatusCode::NOT_FOUND
    );
    let mut mailbox = tcp::connect_slave(plant.gw.modbus_tcp, Slave(101))
        .await
        .expect("connect");
    assert_eq!(
        mailbox
            .read_holding_registers(0, 1)
            .await
            .expect("transport"),
        Err(tokio_modbus::prelude::ExceptionCode::GatewayPathUnavailable),
        "unit 101 is gone with its line"
    );
    let added = api
        .change(Method::PUT, "/api/v1/config/lines/ascii", Some(&ascii))
        .await;
    assert_eq!(added.status, StatusCode::OK, "{:#}", added.body);
    assert_eq!(added.body["applied"]["lines_started"], json!(["ascii"]));
    api.wait_for(
        "/api/v1/lines/ascii/telegrams",
        Duration::from_secs(20),
        "telegrams on the added line",
        |q| q["telegrams"].as_array().is_some_and(|t| !t.is_empty()),
    )
    .await;
    assert!(mailbox
        .read_holding_registers(0, 1)
        .await
        .expect("transport")
        .is_ok());
    assert_eq!(
        api.change(Method::DELETE, "/api/v1/config/lines/nope", None)
            .await
            .status,
        StatusCode::NOT_FOUND
    );

    // Unknown routes and methods answer in the same shape.
    let none = api.get("/api/v1/nothing").await;
    assert_eq!(none.status, StatusCode::NOT_FOUND);
    assert!(none.body["error"]["code"].is_string(), "{:#}", none.body);
}
