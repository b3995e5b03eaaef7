//! The configuration as the operator wrote it, over REST on the binary: `GET /config` shows the
//! file's keys (no defaults), a `PUT` of what it answered leaves the file byte for byte, a line
//! added over REST is written with the keys the client sent in its order, a value the file
//! already had keeps its spelling (`0x0D`), and the command line's listeners are shown beside
//! the configuration (`overrides`), never baked into it. Bodies that are not what an endpoint
//! takes, and paths and queries that do not fit, are answered with what belongs there.

use std::path::Path;

use gateway_tests::{temp_dir, Gateway, SocatLink};
use reqwest::{Method, StatusCode};
use serde_json::{json, Value};

use super::support::Api;

/// A file with comments, hex values, inline tables and most keys left to their defaults.
fn written_config(term: &Path) -> String {
    format!(
        r#"# The terminal gateway of hall 3.
[gateway]
name = "hall3" # shown in metrics

[modbus_tcp]
listen = "127.0.0.1:0"

[http]
listen = "127.0.0.1:0"
insecure_allow_unauthenticated_changes = true

# The label printer: CR LF ends a telegram.
[lines.term]
port = "{port}"
protocol = "ascii"
baud = 9600 # the printer's
end_criterion = "end-chars"
end_chars = [0x0D, 0x0A]
unit_id = 0x65
"#,
        port = term.display()
    )
}

fn client() -> reqwest::Client {
    reqwest::Client::builder()
        .no_proxy()
        .build()
        .expect("HTTP client")
}

/// `method path` with a raw body and content type; status and JSON body.
async fn raw(api_base: &str, method: Method, path: &str, ctype: &str, body: &str) -> (u16, Value) {
    let r = client()
        .request(method, format!("{api_base}{path}"))
        .header("content-type", ctype)
        .body(body.to_owned())
        .send()
        .await
        .expect("request");
    let status = r.status().as_u16();
    let text = r.text().await.expect("body");
    (
        status,
        serde_json::from_str(&text).unwrap_or(Value::String(text)),
    )
}

/// GET with `Accept: application/toml`: the text.
async fn get_toml(api_base: &str) -> String {
    client()
        .get(format!("{api_base}/api/v1/config"))
        .header("accept", "application/toml")
        .send()
        .await
        .expect("GET TOML")
        .text()
        .await
        .expect("text")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_get_then_put_leaves_the_file_byte_for_byte_and_lines_are_written_as_sent() {
    let dir = temp_dir("rest-as-written");
    let term = SocatLink::new(&dir, "term");
    let spare = SocatLink::new(&dir, "spare");
    let file = dir.join("gateway.toml");
    let text = written_config(&term.a);
    std::fs::write(&file, &text).expect("write config");
    let gw = Gateway::run(&file);
    let http = gw.http.expect("HTTP address");
    let base = format!("http://{http}");
    let api = Api::new(http);
    api.wait_ready().await;

    // The keys as the file gives them, in its order; no defaults written back.
    let config = api.get_ok("/api/v1/config").await;
    let answer = client()
        .get(format!("{base}/api/v1/config"))
        .send()
        .await
        .expect("GET")
        .text()
        .await
        .expect("text");
    let expected = format!(
        "{{\"gateway\":{{\"name\":\"hall3\"}},\"modbus_tcp\":{{\"listen\":\"127.0.0.1:0\"}},\
         \"http\":{{\"listen\":\"127.0.0.1:0\",\"insecure_allow_unauthenticated_changes\":true}},\
         \"lines\":{{\"term\":{{\"port\":\"{}\",\"protocol\":\"ascii\",\"baud\":9600,\
         \"end_criterion\":\"end-chars\",\"end_chars\":[13,10],\"unit_id\":101}}}},\"overrides\":",
        term.a.display()
    );
    assert!(
        answer.starts_with(&expected),
        "{answer}\nexpected to start with\n{expected}"
    );
    assert_eq!(config["lines"]["term"]["end_chars"], json!([13, 10]));
    // What runs: `--http 127.0.0.1:0` of the command line, with the port it bound; the file's
    // own listen stays what the file says.
    assert_eq!(config["http"]["listen"], "127.0.0.1:0");
    assert_eq!(
        config["overrides"],
        json!([{"key": "http.listen", "option": "--http", "given": "127.0.0.1:0",
                "in_force": http.to_string()}])
    );

    // GET then PUT, as JSON and as TOML: nothing on disk changes, nothing restarts.
    let put = api
        .change(Method::PUT, "/api/v1/config", Some(&config))
        .await;
    assert_eq!(put.status, StatusCode::OK, "{:#}", put.body);
    assert_eq!(put.body["applied"]["lines_restarted"], json!([]));
    assert_eq!(put.body["applied"]["servers_restarted"], json!([]));
    assert_eq!(std::fs::read_to_string(&file).expect("file"), text);
    let toml = get_toml(&base).await;
    assert!(
        toml.starts_with("# In force from the command line"),
        "{toml}"
    );
    assert!(toml.ends_with(&text), "the file as written:\n{toml}");
    let (status, body) = raw(
        &base,
        Method::PUT,
        "/api/v1/config",
        "application/toml",
        &toml,
    )
    .await;
    assert_eq!(status, 200, "{body:#}");
    assert_eq!(std::fs::read_to_string(&file).expect("file"), text);
    assert!(!dir.join("gateway.toml.prev").exists(), "nothing was saved");

    // One key changed over JSON: only that value is rewritten; the hex spellings, the comments
    // and the keys left out stay.
    let mut line = api.get_ok("/api/v1/config/lines/term").await;
    assert_eq!(line["end_chars"], json!([13, 10]));
    line["baud"] = json!(19200);
    let put = api
        .change(Method::PUT, "/api/v1/config/lines/term", Some(&line))
        .await;
    assert_eq!(put.status, StatusCode::OK, "{:#}", put.body);
    assert_eq!(put.body["applied"]["lines_restarted"], json!(["term"]));
    let after = std::fs::read_to_string(&file).expect("file");
    assert_eq!(
        after,
        text.replace(
            "baud = 9600 # the printer's",
            "baud = 19200 # the printer's"
        )
    );

    // A line added over JSON: the keys the client sent, in its order, nothing else (the body is
    // sent as text: serde_json's own objects would sort the keys).
    let added = format!(
        r#"{{"protocol": "ascii", "port": "{}", "end_chars": [13, 10], "end_criterion": "end-chars"}}"#,
        spare.a.display()
    );
    let (status, body) = raw(
        &base,
        Method::PUT,
        "/api/v1/config/lines/spare",
        "application/json",
        &added,
    )
    .await;
    assert_eq!(status, 200, "{body:#}");
    assert_eq!(body["applied"]["lines_started"], json!(["spare"]));
    let with_spare = std::fs::read_to_string(&file).expect("file");
    assert_eq!(
        with_spare,
        format!(
            "{after}\n[lines.spare]\nprotocol = \"ascii\"\nport = \"{}\"\nend_chars = [13, 10]\n\
             end_criterion = \"end-chars\"\n",
            spare.a.display()
        )
    );

    // The same line sent as TOML with hex after a change of baud rate: the file keeps its own
    // spelling of the values that did not change (13, 10), takes the new rate.
    let toml_line = format!(
        "protocol = \"ascii\"\nport = \"{}\"\nend_chars = [0x0D, 0x0A] # CR LF\n\
         end_criterion = \"end-chars\"\nbaud = 4800\n",
        spare.a.display()
    );
    let (status, body) = raw(
        &base,
        Method::PUT,
        "/api/v1/config/lines/spare",
        "application/toml",
        &toml_line,
    )
    .await;
    assert_eq!(status, 200, "{body:#}");
    assert_eq!(
        std::fs::read_to_string(&file).expect("file"),
        format!("{with_spare}baud = 4800\n")
    );

    // Removed, and added again as TOML with hex: the client's spelling and comment are written.
    let removed = api
        .change(Method::DELETE, "/api/v1/config/lines/spare", None)
        .await;
    assert_eq!(removed.status, StatusCode::OK, "{:#}", removed.body);
    assert_eq!(std::fs::read_to_string(&file).expect("file"), after);
    let toml_line = format!(
        "protocol = \"ascii\"\nport = \"{}\"\nend_chars = [0x0D, 0x0A] # CR LF\n\
         end_criterion = \"end-chars\"\nbaud = 4800\n",
        spare.a.display()
    );
    let (status, body) = raw(
        &base,
        Method::PUT,
        "/api/v1/config/lines/spare",
        "application/toml",
        &toml_line,
    )
    .await;
    assert_eq!(status, 200, "{body:#}");
    let spare_text = std::fs::read_to_string(&file).expect("file");
    assert!(
        spare_text.ends_with(&format!(
            "[lines.spare]\nprotocol = \"ascii\"\nport = \"{}\"\nend_chars = [0x0D, 0x0A] # CR LF\n\
             end_criterion = \"end-chars\"\nbaud = 4800\n",
            spare.a.display()
        )),
        "{spare_text}"
    );
    // And what the gateway reads from the file is what runs.
    let (ok, report) = super::support::check(&file);
    assert!(ok, "{report}");
    assert_eq!(api.get_ok("/api/v1/config/lines/spare").await["baud"], 4800);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_demo_shows_its_command_line_listeners_and_bad_bodies_hear_what_to_send() {
    let gw = Gateway::demo(&[]);
    let http = gw.http.expect("HTTP address");
    let base = format!("http://{http}");
    let api = Api::new(http);
    api.wait_ready().await;
    let zenoh = format!("tcp/127.0.0.1:{}", gw.zenoh_port.expect("zenoh port"));

    let config = api.get_ok("/api/v1/config").await;
    // The demo's own text: its listen addresses, not the command line's.
    assert_eq!(config["modbus_tcp"]["listen"], "127.0.0.1:5020");
    assert_eq!(config["http"]["listen"], "127.0.0.1:8080");
    // What runs, marked as the command line's, with the ports the system chose.
    let overrides = config["overrides"].as_array().expect("overrides");
    let find = |key: &str| {
        overrides
            .iter()
            .find(|o| o["key"] == key)
            .unwrap_or_else(|| panic!("no override {key}: {overrides:#?}"))
            .clone()
    };
    let modbus = find("modbus_tcp.listen");
    assert_eq!(modbus["option"], "--modbus-tcp");
    assert_eq!(modbus["given"], "127.0.0.1:0");
    assert_eq!(modbus["in_force"], gw.modbus_tcp.to_string());
    let listen = find("http.listen");
    assert_eq!(listen["given"], "127.0.0.1:0");
    assert_eq!(listen["in_force"], http.to_string());
    assert_eq!(find("zenoh.listen")["in_force"], zenoh);
    let status = api.get_ok("/api/v1/status").await;
    assert_eq!(status["modbus_tcp"]["listen"], gw.modbus_tcp.to_string());

    // A PUT of what GET answered changes nothing: the listeners stay the command line's.
    let put = api
        .call(Method::PUT, "/api/v1/config", Some(&config), None)
        .await;
    assert_eq!(put.status, StatusCode::OK, "{:#}", put.body);
    assert_eq!(put.body["applied"]["servers_restarted"], json!([]));
    assert_eq!(put.body["applied"]["lines_restarted"], json!([]));
    let again = api.get_ok("/api/v1/config").await;
    assert_eq!(again, config);

    // Bodies that are not what an endpoint takes: each answer names what it takes.
    let tag = "/api/v1/lines/drive/devices/atv71/tags/ACC";
    for (method, path, ctype, body, status, says) in [
        (
            Method::PUT,
            tag,
            "application/json",
            "30.5",
            422,
            r#"expected a JSON object like {"value": 30.5}, not the bare number 30.5"#,
        ),
        (
            Method::PUT,
            tag,
            "application/json",
            "{\"value\": 30.5",
            400,
            r#"send a JSON object like {"value": 30.5}"#,
        ),
        (
            Method::PUT,
            tag,
            "text/plain",
            "30.5",
            415,
            r#"expected Content-Type: application/json and a JSON object like {"value": 30.5}"#,
        ),
        (
            Method::POST,
            "/api/v1/lines/r3964/send",
            "application/json",
            "\"HELLO\"",
            422,
            r#"expected a JSON object like {"text": "HELLO"} or {"hex": "02 41 42 03"}, not a bare string"#,
        ),
        (
            Method::PUT,
            "/api/v1/lines/ascii/signals",
            "application/json",
            "{\"dtr\": \"on\"}",
            422,
            "dtr: invalid type: string \"on\", expected a boolean",
        ),
        (
            Method::PUT,
            "/api/v1/config",
            "application/json",
            "30.5",
            422,
            "expected a JSON object with the configuration's tables",
        ),
        (
            Method::PUT,
            "/api/v1/config/lines/drive",
            "application/json",
            "",
            400,
            "the body is empty: send a JSON object with the line's keys",
        ),
        // Paths and queries that do not fit: which part, and what belongs there.
        (
            Method::POST,
            "/api/v1/lines/r3964/telegrams/abc/ack",
            "application/json",
            "",
            400,
            "\"abc\" in the path: expected a whole number, 0 or more there",
        ),
        (
            Method::GET,
            "/api/v1/tags?lien=drive",
            "application/json",
            "",
            400,
            "unknown query parameter \"lien\": this path takes `line` or `device`",
        ),
        (
            Method::GET,
            "/api/v1/lines/drive/frames?since=soon",
            "application/json",
            "",
            400,
            "query parameter since: expected a whole number, 0 or more",
        ),
    ] {
        let (got, answer) = raw(&base, method.clone(), path, ctype, body).await;
        assert_eq!(got, status, "{method} {path} {body:?}: {answer:#}");
        let text = answer["error"].to_string();
        assert!(
            text.contains(&says.replace('"', "\\\"")),
            "{method} {path} {body:?}: {answer:#}"
        );
        for raw_word in ["Failed to", "Invalid URL", "struct ", "untagged enum"] {
            assert!(!text.contains(raw_word), "{method} {path}: {answer:#}");
        }
    }
}
