//! `/api/v1/config...`: read, replace, validate, one line; persistence and what is restarted.

use serde_json::{json, Value};

use super::backend::MISSING_PORT;
use super::support::{start, start_with, test_config, Setup, TOKEN};

/// The configuration in force as JSON.
async fn current(api: &super::support::TestApi) -> Value {
    let r = api.get("/api/v1/config").await;
    assert_eq!(r.status, 200, "{}", r.text);
    r.json
}

#[tokio::test]
async fn get_config_answers_json_with_an_etag_or_toml_on_request() {
    let api = start().await;
    let r = api.get("/api/v1/config").await;
    assert_eq!(r.status, 200);
    assert_eq!(r.json["gateway"]["name"], "demo");
    assert_eq!(r.json["lines"]["drive"]["baud"], 19200);
    assert_eq!(r.json["lines"]["ascii"]["interface"], "rs232");
    let etag = r.header("etag").expect("ETag").to_owned();
    assert!(etag.starts_with('"') && etag.len() > 2, "{etag}");

    let toml_reply = api
        .send(
            api.http
                .get(api.url("/api/v1/config"))
                .header("accept", "application/toml"),
        )
        .await;
    assert_eq!(toml_reply.status, 200);
    assert_eq!(toml_reply.header("content-type"), Some("application/toml"));
    let parsed = gateway::plant::parse(&toml_reply.text).expect("the TOML answer parses");
    assert_eq!(parsed, test_config());
    assert_eq!(toml_reply.header("etag"), Some(etag.as_str()));
}

#[tokio::test]
async fn a_put_of_the_same_config_restarts_nothing() {
    let api = start().await;
    let body = current(&api).await;
    let r = api.put("/api/v1/config", &body).await;
    assert_eq!(r.status, 200, "{}", r.text);
    assert_eq!(r.json["persisted"], true);
    for key in [
        "lines_started",
        "lines_stopped",
        "lines_restarted",
        "devices_restarted",
        "servers_restarted",
    ] {
        assert_eq!(r.json["applied"][key], json!([]), "{key}: {}", r.text);
    }
}

#[tokio::test]
async fn a_baud_rate_change_restarts_only_its_line() {
    let api = start().await;
    // Traffic on the other lines, Modbus TCP clients connected.
    api.gw.receive("ascii", b"before");
    api.gw
        .raise("r3964", proto_core::event::EventId::new(0x08, 0x08));
    api.gw.connect_modbus_clients(3);
    let before = api.get("/api/v1/status").await.json;

    let mut body = current(&api).await;
    body["lines"]["drive"]["baud"] = json!(9600);
    let r = api.put("/api/v1/config", &body).await;
    assert_eq!(r.status, 200, "{}", r.text);
    assert_eq!(r.json["applied"]["lines_restarted"], json!(["drive"]));
    assert_eq!(r.json["applied"]["servers_restarted"], json!([]));
    assert_eq!(r.header("etag"), r.json["etag"].as_str());

    let after = api.get("/api/v1/status").await.json;
    let line = |status: &Value, name: &str| {
        status["lines"]
            .as_array()
            .and_then(|l| l.iter().find(|x| x["name"] == name))
            .cloned()
            .unwrap_or_else(|| panic!("no line {name}"))
    };
    for name in ["ksvario", "r3964", "ascii"] {
        assert_eq!(
            line(&before, name),
            line(&after, name),
            "line {name} was touched"
        );
    }
    assert_ne!(
        line(&before, "drive")["started"],
        line(&after, "drive")["started"]
    );
    assert_eq!(
        after["modbus_tcp"]["connections"], 3,
        "Modbus TCP clients dropped"
    );
    assert_eq!(api.gw.modbus_tcp_starts(), 1);
    // Persisted: the file holds the new rate, the previous file the old one.
    assert_eq!(api.stored().lines["drive"].serial.baud.get(), 9600);
    let prev = gateway::plant::load(&api.store_path.as_ref().unwrap().with_extension("toml.prev"))
        .unwrap();
    assert_eq!(prev.lines["drive"].serial.baud.get(), 19200);
    assert_eq!(current(&api).await["lines"]["drive"]["baud"], 9600);
}

#[tokio::test]
async fn a_config_with_three_mistakes_answers_all_three_and_changes_nothing() {
    let api = start().await;
    let before = current(&api).await;
    let mut body = before.clone();
    body["lines"]["drive"]["baud"] = json!(12345);
    body["modbus_tcp"]["listen"] = json!("nowhere");
    body["gateway"]["colour"] = json!("blue");

    for path in ["/api/v1/config/validate", "/api/v1/config"] {
        let method = if path.ends_with("validate") {
            reqwest::Method::POST
        } else {
            reqwest::Method::PUT
        };
        let r = api.request(method, path, Some(TOKEN), Some(&body)).await;
        assert_eq!(r.status, 422, "{path}: {}", r.text);
        assert_eq!(r.code(), "validation_failed");
        let mut paths = r.issue_paths();
        paths.sort();
        assert_eq!(
            paths,
            ["gateway.colour", "lines.drive.baud", "modbus_tcp.listen"],
            "{}",
            r.text
        );
    }
    assert_eq!(current(&api).await, before);
    assert_eq!(api.stored(), test_config());
}

#[tokio::test]
async fn validate_accepts_a_valid_config_without_applying_it() {
    let api = start().await;
    let mut body = current(&api).await;
    body["lines"]["drive"]["baud"] = json!(9600);
    let r = api.post("/api/v1/config/validate", &body).await;
    assert_eq!(r.status, 200, "{}", r.text);
    let config = test_config();
    let expected =
        json!({"valid": true, "lines": config.lines.len(), "devices": config.device_count()});
    assert_eq!(r.json, expected);
    assert_eq!(current(&api).await["lines"]["drive"]["baud"], 19200);
}

#[tokio::test]
async fn the_backend_checks_run_after_the_parser_and_report_with_paths() {
    let api = start().await;
    let mut body = current(&api).await;
    body["lines"]["drive"]["port"] = json!(MISSING_PORT);
    let r = api.put("/api/v1/config", &body).await;
    assert_eq!(r.status, 422, "{}", r.text);
    assert_eq!(r.issue_paths(), ["lines.drive.port"]);
}

#[tokio::test]
async fn one_line_is_read_replaced_added_and_removed() {
    let api = start().await;
    let r = api.get("/api/v1/config/lines/ascii").await;
    assert_eq!(r.status, 200);
    assert_eq!(r.json["protocol"], "ascii");
    assert!(r.header("etag").is_some());
    assert_eq!(
        api.get("/api/v1/config/lines/nope").await.code(),
        "not_found"
    );

    // Replace: a new baud rate on one line.
    let mut line = r.json.clone();
    line["baud"] = json!(19200);
    let r = api.put("/api/v1/config/lines/ascii", &line).await;
    assert_eq!(r.status, 200, "{}", r.text);
    assert_eq!(r.json["applied"]["lines_restarted"], json!(["ascii"]));
    assert_eq!(api.stored().lines["ascii"].serial.baud.get(), 19200);

    // A mistake in a line is reported under the line's path.
    let mut bad = line.clone();
    bad["colour"] = json!("blue");
    bad["baud"] = json!(7);
    let r = api.put("/api/v1/config/lines/ascii", &bad).await;
    assert_eq!(r.status, 422, "{}", r.text);
    let mut paths = r.issue_paths();
    paths.sort();
    assert_eq!(paths, ["lines.ascii.baud", "lines.ascii.colour"]);

    // Add a line, then remove it.
    let mut spare = line.clone();
    spare["port"] = json!("/dev/ttyS7");
    spare["unit_id"] = json!(102);
    let r = api.put("/api/v1/config/lines/spare", &spare).await;
    assert_eq!(r.status, 200, "{}", r.text);
    assert_eq!(r.json["applied"]["lines_started"], json!(["spare"]));
    assert_eq!(api.get("/api/v1/lines/spare").await.status, 200);
    let r = api.delete("/api/v1/config/lines/spare").await;
    assert_eq!(r.status, 200, "{}", r.text);
    assert_eq!(r.json["applied"]["lines_stopped"], json!(["spare"]));
    assert_eq!(api.get("/api/v1/lines/spare").await.code(), "not_found");
    assert_eq!(
        api.delete("/api/v1/config/lines/spare").await.code(),
        "not_found"
    );
    assert!(!api.stored().lines.contains_key("spare"));
}

#[tokio::test]
async fn if_match_makes_a_change_conditional() {
    let api = start().await;
    let r = api.get("/api/v1/config").await;
    let etag = r.header("etag").unwrap().to_owned();
    let mut body = r.json.clone();
    body["lines"]["drive"]["baud"] = json!(9600);
    let put = |tag: &str| {
        api.http
            .put(api.url("/api/v1/config"))
            .bearer_auth(TOKEN)
            .header("if-match", tag)
            .json(&body)
    };
    let r = api.send(put(&etag)).await;
    assert_eq!(r.status, 200, "{}", r.text);
    // The same tag again: the configuration moved on since.
    let r = api.send(put(&etag)).await;
    assert_eq!(r.status, 412, "{}", r.text);
    assert_eq!(r.code(), "precondition_failed");
}

#[tokio::test]
async fn toml_bodies_are_accepted_and_bad_bodies_refused() {
    let api = start().await;
    let mut config = test_config();
    config.lines.get_mut("r3964").unwrap().serial.baud =
        gateway::config::Baud::try_new(19200).unwrap();
    let text = toml::to_string(&config).unwrap();
    let put = |body: String, ct: &str| {
        api.http
            .put(api.url("/api/v1/config"))
            .bearer_auth(TOKEN)
            .header("content-type", ct)
            .body(body)
    };
    let r = api.send(put(text, "application/toml")).await;
    assert_eq!(r.status, 200, "{}", r.text);
    assert_eq!(r.json["applied"]["lines_restarted"], json!(["r3964"]));

    let r = api
        .send(put("{\"gateway\": ".into(), "application/json"))
        .await;
    assert_eq!((r.status, r.code()), (400, "bad_request"));
    let r = api.send(put("[gateway\n".into(), "application/toml")).await;
    assert_eq!((r.status, r.code()), (400, "bad_request"));
    let r = api.send(put("{}".into(), "text/plain")).await;
    assert_eq!((r.status, r.code()), (415, "unsupported_media_type"));
    let r = api
        .send(put(
            "{\"gateway\": {\"name\": null}}".into(),
            "application/json",
        ))
        .await;
    assert_eq!((r.status, r.code()), (422, "validation_failed"));
    assert_eq!(r.issue_paths(), ["gateway.name"]);
}

/// The operator's file: comments, order and the keys left out survive REST changes; only the
/// changed keys are written.
#[tokio::test]
async fn a_change_edits_the_operators_file_in_place() {
    let file = gateway::plant::demo_toml().replace(
        "[lines.ascii]\n",
        "[lines.ascii]\ninterface = \"rs232\" # the partner has modem signals\n",
    );
    let api = start_with(Setup {
        file_text: Some(file.clone()),
        ..Setup::default()
    })
    .await;
    let path = api.store_path.clone().expect("a store");

    // One key of one line.
    let mut line = api.get("/api/v1/config/lines/drive").await.json;
    line["baud"] = json!(9600);
    let r = api.put("/api/v1/config/lines/drive", &line).await;
    assert_eq!(r.status, 200, "{}", r.text);
    let expected = file.replacen(
        "port = \"pty:drive\"\nprotocol = \"modbus-master-rtu\"\nbaud = 19200\n",
        "port = \"pty:drive\"\nprotocol = \"modbus-master-rtu\"\nbaud = 9600\n",
        1,
    );
    assert_ne!(expected, file);
    let saved = std::fs::read_to_string(&path).expect("the file");
    assert_eq!(saved, expected);

    // The whole configuration, with a key the file left out (its default) now set.
    let mut body = current(&api).await;
    body["lines"]["ksvario"]["devices"]["ksvario"]["poll"][0]["period"] = json!("2s");
    body["gateway"]["diag_buffer_depth"] = json!(20);
    let r = api.put("/api/v1/config", &body).await;
    assert_eq!(r.status, 200, "{}", r.text);
    let saved = std::fs::read_to_string(&path).expect("the file");
    let expected = expected
        .replacen(
            "period = \"1s\"\nranges = [{ table = \"input\"",
            "period = \"2s\"\nranges = [{ table = \"input\"",
            1,
        )
        .replacen(
            "name = \"demo\"\n",
            "name = \"demo\"\ndiag_buffer_depth = 20\n",
            1,
        );
    assert_eq!(saved, expected);
    assert_eq!(api.stored().gateway.diag_buffer_depth, 20);
    // The previous version is the file as the first change left it.
    assert!(path.with_extension("toml.prev").exists());
}
