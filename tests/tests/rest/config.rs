//! Configuration changes: the token, validation with every mistake at once, SIGKILL during a
//! series of PUTs, and the demo's insecure mode.

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use gateway_tests::{temp_dir, Gateway};
use reqwest::{Method, StatusCode};
use serde_json::{json, Value};

use super::support::{check, Api, TOKEN};

/// A gateway without serial lines: `[http]` with the token file, when given.
fn light_config(dir: &Path, token: Option<&str>) -> std::path::PathBuf {
    let mut text = String::from(
        "[gateway]\nname = \"rest-light\"\n\n[modbus_tcp]\nlisten = \"127.0.0.1:0\"\n\n[http]\nlisten = \"127.0.0.1:0\"\n",
    );
    if let Some(token) = token {
        let file = dir.join("api-token");
        std::fs::write(&file, format!("{token}\n")).expect("token file");
        text.push_str(&format!("token_file = \"{}\"\n", file.display()));
    }
    let config = dir.join("gateway.toml");
    std::fs::write(&config, text).expect("config");
    config
}

async fn start(config: &Path) -> (Gateway, Api) {
    let gw = Gateway::run(config);
    let api = Api::new(gw.http.expect("HTTP address"));
    api.wait_ready().await;
    (gw, api)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn changes_need_the_token_which_is_never_shown() {
    let dir = temp_dir("rest-auth");
    let (_gw, api) = start(&light_config(&dir, Some(TOKEN))).await;

    // Reading needs no token, and never shows it.
    let config = api.get("/api/v1/config").await;
    assert_eq!(config.status, StatusCode::OK);
    assert!(config.headers.contains_key("etag"));
    assert!(config.body["http"]["token_file"]
        .as_str()
        .is_some_and(|f| f.ends_with("api-token")));
    assert!(
        !config.body.to_string().contains(TOKEN),
        "the token is returned: {:#}",
        config.body
    );

    let mut changed = config.body.clone();
    changed["gateway"]["diag_buffer_depth"] = json!(20);
    let put = |token: Option<&'static str>| {
        let (api, body) = (api.clone(), changed.clone());
        async move {
            api.call(Method::PUT, "/api/v1/config", Some(&body), token)
                .await
        }
    };
    // No token: 401 with the challenge.
    let none = put(None).await;
    assert_eq!(none.status, StatusCode::UNAUTHORIZED, "{:#}", none.body);
    let challenge = none
        .headers
        .get("www-authenticate")
        .and_then(|v| v.to_str().ok());
    assert!(
        challenge.is_some_and(|c| c.starts_with("Bearer")),
        "{challenge:?}"
    );
    assert_eq!(none.body["error"]["code"], "unauthorized");
    // A wrong token: 401 (RFC 6750: an invalid token) or 403.
    let wrong = put(Some("e2e-token-0000000000000000")).await;
    assert!(
        matches!(
            wrong.status,
            StatusCode::UNAUTHORIZED | StatusCode::FORBIDDEN
        ),
        "{:?} {:#}",
        wrong.status,
        wrong.body
    );
    // Every changing method is guarded, also on routes that do not exist.
    for (method, path) in [
        (Method::POST, "/api/v1/config/validate"),
        (Method::DELETE, "/api/v1/lines/x/diag"),
        (Method::POST, "/api/v1/lines/x/send"),
    ] {
        let a = api.call(method.clone(), path, Some(&json!({})), None).await;
        assert_eq!(a.status, StatusCode::UNAUTHORIZED, "{method} {path}");
    }
    assert_eq!(
        api.get_ok("/api/v1/config").await["gateway"]["diag_buffer_depth"],
        Value::Null,
        "nothing changed without the token (the file leaves the key out)"
    );
    // The right token: 200, saved, in force.
    let right = put(Some(TOKEN)).await;
    assert_eq!(right.status, StatusCode::OK, "{:#}", right.body);
    assert_eq!(right.body["persisted"], true);
    assert_eq!(
        api.get_ok("/api/v1/config").await["gateway"]["diag_buffer_depth"],
        20
    );
    assert!(std::fs::read_to_string(dir.join("gateway.toml"))
        .expect("file")
        .contains("diag_buffer_depth = 20"));

    // No token configured (and not insecure): every change is refused, whatever is presented.
    let locked_dir = temp_dir("rest-locked");
    let (_locked, locked) = start(&light_config(&locked_dir, None)).await;
    assert_eq!(locked.get("/api/v1/status").await.status, StatusCode::OK);
    for token in [None, Some(TOKEN)] {
        let a = locked
            .call(Method::PUT, "/api/v1/config", Some(&changed), token)
            .await;
        assert_eq!(a.status, StatusCode::FORBIDDEN, "{:#}", a.body);
        assert_eq!(a.body["error"]["code"], "forbidden");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_config_with_three_mistakes_gets_all_three() {
    let dir = temp_dir("rest-mistakes");
    let file = light_config(&dir, Some(TOKEN));
    let (_gw, api) = start(&file).await;
    let before = api.get("/api/v1/config").await;
    let text_before = std::fs::read_to_string(&file).expect("file");

    let mut wrong = before.body.clone();
    wrong["gateway"]["diag_buffer_depth"] = json!(0);
    wrong["modbus_tcp"]["max_connections"] = json!(0);
    wrong["lines"] = json!({
        "x": { "port": "/dev/ttyS0", "protocol": "modbus-master-rtu", "baud": 19201 }
    });
    for (method, path) in [
        (Method::POST, "/api/v1/config/validate"),
        (Method::PUT, "/api/v1/config"),
    ] {
        let a = api.change(method.clone(), path, Some(&wrong)).await;
        assert_eq!(
            a.status,
            StatusCode::UNPROCESSABLE_ENTITY,
            "{method} {path}: {:#}",
            a.body
        );
        assert_eq!(a.body["error"]["code"], "validation_failed", "{:#}", a.body);
        let mut paths: Vec<&str> = a.body["error"]["issues"]
            .as_array()
            .expect("issues")
            .iter()
            .filter_map(|i| i["path"].as_str())
            .collect();
        paths.sort_unstable();
        assert_eq!(
            paths,
            [
                "gateway.diag_buffer_depth",
                "lines.x.baud",
                "modbus_tcp.max_connections"
            ],
            "{method} {path}: {:#}",
            a.body
        );
    }
    // Nothing was saved or applied.
    let after = api.get("/api/v1/config").await;
    assert_eq!(after.headers.get("etag"), before.headers.get("etag"));
    assert_eq!(std::fs::read_to_string(&file).expect("file"), text_before);

    // A line the parser accepts on a port that does not exist: refused with its path.
    let missing = api
        .change(
            Method::PUT,
            "/api/v1/config/lines/x",
            Some(&json!({ "port": "/dev/no-such-port-e2e", "protocol": "modbus-master-rtu" })),
        )
        .await;
    assert_eq!(
        missing.status,
        StatusCode::UNPROCESSABLE_ENTITY,
        "{:#}",
        missing.body
    );
    assert_eq!(missing.body["error"]["issues"][0]["path"], "lines.x.port");
    // A body over `[http] body_limit` (1 MiB by default) is refused before it is read whole.
    let big = json!({ "gateway": { "name": "x".repeat(2 * 1024 * 1024) } });
    let too_big = api
        .change(Method::POST, "/api/v1/config/validate", Some(&big))
        .await;
    assert_eq!(
        too_big.status,
        StatusCode::PAYLOAD_TOO_LARGE,
        "{:#}",
        too_big.body
    );
    assert_eq!(too_big.body["error"]["code"], "payload_too_large");
    // The unread rest of the body ends the connection, and the answer says so.
    assert_eq!(
        too_big.headers.get("connection").map(|v| v.as_bytes()),
        Some(&b"close"[..])
    );

    // A valid configuration validates.
    let ok = api
        .change(Method::POST, "/api/v1/config/validate", Some(&before.body))
        .await;
    assert_eq!(ok.status, StatusCode::OK, "{:#}", ok.body);
    assert_eq!(ok.body["valid"], true);
}

/// The `body_limit` of `[http]` in a saved configuration.
fn body_limit(text: &str) -> Option<u64> {
    let http = text.split("[http]").nth(1)?;
    http.lines()
        .find_map(|l| l.trim().strip_prefix("body_limit = ")?.trim().parse().ok())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigkill_during_a_series_of_puts_leaves_a_config_that_loads() {
    let dir = temp_dir("rest-sigkill");
    let file = light_config(&dir, Some(TOKEN));
    let mut written: Vec<u64> = vec![1_048_576];
    for round in 0u64..3 {
        let (mut gw, api) = start(&file).await;
        let base = api.get_ok("/api/v1/config").await;
        let sent: Arc<Mutex<Vec<u64>>> = Arc::default();
        let done: Arc<Mutex<u64>> = Arc::default();
        let writer = {
            let (api, sent, done) = (api.clone(), Arc::clone(&sent), Arc::clone(&done));
            tokio::spawn(async move {
                for i in 0u64.. {
                    let limit = 100_000 + round * 10_000 + i;
                    let mut body = base.clone();
                    body["http"]["body_limit"] = json!(limit);
                    sent.lock().expect("sent").push(limit);
                    let req = api.try_call(Method::PUT, "/api/v1/config", Some(&body), Some(TOKEN));
                    // The process dies under the client: the last request fails; stop there.
                    match tokio::time::timeout(Duration::from_secs(10), req).await {
                        Ok(Some(StatusCode::OK)) => *done.lock().expect("done") += 1,
                        _ => return,
                    }
                }
            })
        };
        // Let a few PUTs complete, then kill in the middle of the series.
        let started = Instant::now();
        while *done.lock().expect("done") < 3 + round * 2 {
            assert!(
                started.elapsed() < Duration::from_secs(30),
                "the PUTs do not complete"
            );
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        tokio::time::sleep(Duration::from_millis(7 * round + 3)).await;
        gw.kill();
        let elapsed = started.elapsed();
        // The client's request in flight fails now (the handler would end otherwise).
        let _ = writer.await;
        let completed = *done.lock().expect("done");
        eprintln!(
            "round {round}: {completed} PUTs saved in {elapsed:?} ({:.0}/s), then SIGKILL",
            completed as f64 / elapsed.as_secs_f64()
        );
        written.extend(sent.lock().expect("sent").iter());

        let (ok, report) = check(&file);
        assert!(
            ok,
            "the configuration does not load after SIGKILL: {report}"
        );
        let text = std::fs::read_to_string(&file).expect("file");
        let limit = body_limit(&text).unwrap_or_else(|| panic!("no body_limit in\n{text}"));
        assert!(written.contains(&limit), "{limit} was never written");
        let prev = dir.join("gateway.toml.prev");
        let (ok, report) = check(&prev);
        assert!(ok, "the previous configuration does not load: {report}");
    }
    // And the gateway starts on it again.
    let (_gw, api) = start(&file).await;
    assert_eq!(api.get_ok("/readyz").await["status"], "ready");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_demo_accepts_changes_without_a_token_and_says_so() {
    let gw = Gateway::demo(&[]);
    // Said before anything listens (the start waited for the Modbus TCP line, printed last).
    let log = gw.output();
    assert!(
        log.lines()
            .any(|l| l.contains("WARN") && l.contains("INSECURE") && l.contains("without a token")),
        "{log}"
    );
    let api = Api::new(gw.http.expect("HTTP address"));
    api.wait_ready().await;
    let status = api.get_ok("/api/v1/status").await;
    assert_eq!(status["zenoh"]["up"], true, "{status:#}");

    // The slave line's CP memory words are tags too; the simulated HMI counts in DB 800 DBW 20.
    let memory = api
        .wait_for(
            "/api/v1/lines/hmi/devices/memory/tags",
            Duration::from_secs(20),
            "the HMI's counter",
            |t| {
                t.as_array().is_some_and(|t| {
                    t.iter()
                        .any(|t| t["tag"] == "DB800.DBW20" && t["quality"] == "good")
                })
            },
        )
        .await;
    assert!(memory
        .as_array()
        .is_some_and(|t| t.iter().all(|t| t["device"] == "memory")));

    let mut ks = api.get_ok("/api/v1/config/lines/ksvario").await;
    ks["baud"] = json!(9600);
    let a = api
        .call(Method::PUT, "/api/v1/config/lines/ksvario", Some(&ks), None)
        .await;
    assert_eq!(a.status, StatusCode::OK, "{:#}", a.body);
    assert_eq!(
        a.body["persisted"], false,
        "the demo has no configuration file"
    );
    assert_eq!(a.body["applied"]["lines_restarted"], json!(["ksvario"]));
    assert!(gw.output().contains("kept in memory"), "{}", gw.output());
    api.wait_for(
        "/api/v1/lines/ksvario",
        Duration::from_secs(20),
        "ksvario reopened",
        |l| l["port_opens"] == 1 && l["state"] == "running",
    )
    .await;
    assert_eq!(
        api.get_ok("/api/v1/config/lines/ksvario").await["baud"],
        9600
    );
}
