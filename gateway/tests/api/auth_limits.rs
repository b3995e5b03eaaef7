//! Who may change things, and the limits: body size, time, unknown routes and methods, panics.

use std::time::{Duration, Instant};

use gateway::api::{Auth, Token};
use gateway::config::RestRole;
use reqwest::Method;
use serde_json::{json, Value};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use super::support::{assert_error_shape, start, start_with, test_config, Setup, TestApi, TOKEN};

/// Every change the API offers, with a body it accepts.
async fn changes(api: &TestApi) -> Vec<(Method, &'static str, Option<Value>)> {
    let config = api.get("/api/v1/config").await.json;
    let line = config["lines"]["ascii"].clone();
    api.gw.receive("ascii", b"x");
    vec![
        (Method::PUT, "/api/v1/config", Some(config.clone())),
        (Method::POST, "/api/v1/config/validate", Some(config)),
        (Method::PUT, "/api/v1/config/lines/ascii", Some(line)),
        (Method::DELETE, "/api/v1/lines/drive/diag", None),
        (Method::POST, "/api/v1/lines/ascii/telegrams/1/ack", None),
        (
            Method::POST,
            "/api/v1/lines/ascii/send",
            Some(json!({"text": "x"})),
        ),
        (
            Method::PUT,
            "/api/v1/lines/ascii/signals",
            Some(json!({"rts": true})),
        ),
        (
            Method::PUT,
            "/api/v1/lines/drive/devices/atv71/tags/lfrd",
            Some(json!({"value": 5})),
        ),
        (Method::DELETE, "/api/v1/config/lines/r3964", None),
    ]
}

#[tokio::test]
async fn no_token_401_wrong_token_401_right_token_2xx() {
    let api = start().await;
    for (method, path, body) in changes(&api).await {
        let r = api.request(method.clone(), path, None, body.as_ref()).await;
        assert_eq!(
            (r.status, r.code()),
            (401, "unauthorized"),
            "{method} {path} without a token"
        );
        assert_eq!(
            r.header("www-authenticate"),
            Some("Bearer realm=\"gateway\"")
        );

        let r = api
            .request(
                method.clone(),
                path,
                Some("wrong-token-0123456789"),
                body.as_ref(),
            )
            .await;
        assert_eq!(
            (r.status, r.code()),
            (401, "unauthorized"),
            "{method} {path} with a wrong token"
        );
        assert!(r
            .header("www-authenticate")
            .unwrap()
            .contains("invalid_token"));

        let basic = api
            .http
            .request(method.clone(), api.url(path))
            .basic_auth("admin", Some(TOKEN));
        let r = api.send(basic).await;
        assert_eq!(r.status, 401, "{method} {path} with Basic");

        let r = api
            .request(method.clone(), path, Some(TOKEN), body.as_ref())
            .await;
        assert!(
            (200..300).contains(&r.status),
            "{method} {path} with the token: {} {}",
            r.status,
            r.text
        );
    }
    // Reads need no token.
    assert_eq!(api.get("/api/v1/config").await.status, 200);
}

/// The right each change of [`changes`] needs (in its order).
const RIGHTS: [&str; 9] = [
    "config",
    "config",
    "config",
    "diagnostics",
    "send",
    "send",
    "diagnostics",
    "write",
    "config",
];

#[tokio::test]
async fn a_token_without_the_right_role_gets_403_and_is_audited_by_name() {
    const OPS: &str = "operator-token-0123456789";
    const VIEW: &str = "viewer-token-0123456789ab";
    let auth = || {
        Auth::with_tokens(vec![
            (
                "eng".to_owned(),
                RestRole::Admin,
                Token::new(TOKEN, "test").unwrap(),
            ),
            (
                "ops".to_owned(),
                RestRole::Operator,
                Token::new(OPS, "test").unwrap(),
            ),
            (
                "view".to_owned(),
                RestRole::Viewer,
                Token::new(VIEW, "test").unwrap(),
            ),
        ])
    };
    for (name, token, role) in [
        ("view", VIEW, RestRole::Viewer),
        ("ops", OPS, RestRole::Operator),
        ("eng", TOKEN, RestRole::Admin),
    ] {
        // A fresh gateway per role: the changes of one do not disturb the next (an ack).
        let api = start_with(Setup {
            auth: auth(),
            ..Setup::default()
        })
        .await;
        for ((method, path, body), right) in changes(&api).await.into_iter().zip(RIGHTS) {
            let allowed = match role {
                RestRole::Viewer => false,
                RestRole::Operator => right != "config",
                RestRole::Admin => true,
            };
            let r = api
                .request(method.clone(), path, Some(token), body.as_ref())
                .await;
            if allowed {
                assert!(
                    (200..300).contains(&r.status),
                    "{name} {method} {path}: {} {}",
                    r.status,
                    r.text
                );
            } else {
                assert_eq!(
                    (r.status, r.code()),
                    (403, "forbidden"),
                    "{name} {method} {path}"
                );
                assert!(r.text.contains(right), "{name} {method} {path}: {}", r.text);
            }
            if allowed && path.ends_with("/validate") {
                // A validation changes nothing: not audited when it may run.
                continue;
            }
            // Once, with the client's address and the token's name.
            let audits = api.gw.audits();
            let last = audits.last().expect("audited");
            assert!(
                last.0.starts_with("127.0.0.1:") && last.0.ends_with(&format!("token {name}")),
                "{last:?}"
            );
            let result = if allowed { "accepted" } else { "refused" };
            assert_eq!(last.2, result, "{name} {method} {path}: {last:?}");
        }
        // Every change once (the validation changes nothing and is audited only when the
        // role check refuses it).
        let audited = api.gw.audits().len();
        let expected = if role == RestRole::Admin { 8 } else { 9 };
        assert_eq!(audited, expected, "{name}: {:?}", api.gw.audits());
    }
}

#[tokio::test]
async fn without_a_configured_token_changes_are_forbidden_unless_insecure() {
    let locked = start_with(Setup {
        auth: Auth::locked(),
        ..Setup::default()
    })
    .await;
    for (method, path, body) in changes(&locked).await {
        for token in [None, Some(TOKEN)] {
            let r = locked
                .request(method.clone(), path, token, body.as_ref())
                .await;
            assert_eq!((r.status, r.code()), (403, "forbidden"), "{method} {path}");
        }
    }
    assert_eq!(locked.get("/api/v1/status").await.status, 200);

    let open = start_with(Setup {
        auth: Auth::insecure(),
        ..Setup::default()
    })
    .await;
    for (method, path, body) in changes(&open).await {
        let r = open
            .request(method.clone(), path, None, body.as_ref())
            .await;
        assert!(
            (200..300).contains(&r.status),
            "{method} {path}: {} {}",
            r.status,
            r.text
        );
    }
}

#[tokio::test]
async fn the_token_never_appears_in_a_read() {
    let api = start().await;
    for path in [
        "/api/v1/config",
        "/api/v1/status",
        "/api/v1/lines",
        "/api/v1/lines/drive",
        "/api/v1/tags",
        "/api/v1/openapi.json",
        "/healthz",
        "/readyz",
    ] {
        let r = api.get(path).await;
        assert_eq!(r.status, 200, "{path}");
        assert!(!r.text.contains(TOKEN), "{path} shows the token");
    }
}

#[tokio::test]
async fn a_body_over_the_limit_is_refused_with_413() {
    let api = start_with(Setup {
        body_limit: 2048,
        ..Setup::default()
    })
    .await;
    let mut big = api.get("/api/v1/config").await.json;
    big["gateway"]["padding"] = json!("x".repeat(4096));
    let r = api.put("/api/v1/config", &big).await;
    assert_eq!(
        (r.status, r.code()),
        (413, "payload_too_large"),
        "{}",
        r.text
    );

    // The same without Content-Length, chunked, on a raw connection.
    let addr = api.base.trim_start_matches("http://").to_owned();
    let mut s = TcpStream::connect(&addr).await.unwrap();
    let chunk = "x".repeat(1000);
    let mut req = format!(
        "PUT /api/v1/config HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {TOKEN}\r\n\
         Content-Type: application/json\r\nTransfer-Encoding: chunked\r\nConnection: close\r\n\r\n"
    );
    for _ in 0..4 {
        req.push_str(&format!("{:x}\r\n{chunk}\r\n", chunk.len()));
    }
    req.push_str("0\r\n\r\n");
    s.write_all(req.as_bytes()).await.unwrap();
    let mut answer = Vec::new();
    tokio::time::timeout(Duration::from_secs(10), s.read_to_end(&mut answer))
        .await
        .unwrap()
        .unwrap();
    let answer = String::from_utf8_lossy(&answer);
    assert!(answer.starts_with("HTTP/1.1 413"), "{answer}");
    let body = answer.split("\r\n\r\n").nth(1).unwrap_or_default();
    let json: Value = serde_json::from_str(body).unwrap_or_else(|_| panic!("not JSON: {answer}"));
    assert_error_shape(&json);
    assert_eq!(json["error"]["code"], "payload_too_large");

    // A body within the limit goes through.
    let r = api
        .post("/api/v1/lines/ascii/send", &json!({"text": "small"}))
        .await;
    assert_eq!(r.status, 200);
}

#[tokio::test]
async fn a_request_over_the_time_limit_answers_504() {
    let api = start_with(Setup {
        request_timeout: Duration::from_millis(300),
        ..Setup::default()
    })
    .await;
    let started = Instant::now();
    let r = api.get("/api/v1/lines/drive/devices/slow/tags/x").await;
    assert_eq!((r.status, r.code()), (504, "timeout"), "{}", r.text);
    assert!(started.elapsed() < Duration::from_secs(10));
    // The server still answers.
    assert_eq!(api.get("/healthz").await.status, 200);
}

#[tokio::test]
async fn unknown_routes_wrong_methods_and_panics_answer_in_the_error_shape() {
    let api = start().await;
    let r = api.get("/api/v1/nothing").await;
    assert_eq!((r.status, r.code()), (404, "not_found"));
    let r = api.get("/api/v2/config").await;
    assert_eq!((r.status, r.code()), (404, "not_found"));

    let r = api
        .request(Method::PATCH, "/api/v1/status", Some(TOKEN), None)
        .await;
    assert_eq!(
        (r.status, r.code()),
        (405, "method_not_allowed"),
        "{}",
        r.text
    );
    assert!(
        r.header("allow").is_some_and(|a| a.contains("GET")),
        "{:?}",
        r.headers
    );
    let r = api
        .request(Method::DELETE, "/api/v1/config", Some(TOKEN), None)
        .await;
    assert_eq!((r.status, r.code()), (405, "method_not_allowed"));

    let r = api.get("/api/v1/lines/panic").await;
    assert_eq!((r.status, r.code()), (500, "internal"));
    assert!(
        !r.text.contains("a handler panic"),
        "panic text leaked: {}",
        r.text
    );
    assert_eq!(api.get("/api/v1/lines/drive").await.status, 200);
}

#[tokio::test]
async fn a_change_runs_to_the_end_even_when_the_client_gives_up() {
    let api = start().await;
    let mut body = api.get("/api/v1/config").await.json;
    body["lines"]["drive"]["baud"] = json!(9600);
    // A client that sends the whole request and hangs up at once, before the answer.
    let text = body.to_string();
    let addr = api.base.trim_start_matches("http://").to_owned();
    let mut s = TcpStream::connect(&addr).await.unwrap();
    let req = format!(
        "PUT /api/v1/config HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {TOKEN}\r\n\
         Content-Type: application/json\r\nContent-Length: {}\r\n\r\n{text}",
        text.len()
    );
    s.write_all(req.as_bytes()).await.unwrap();
    drop(s);
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        if api.get("/api/v1/config").await.json["lines"]["drive"]["baud"] == 9600 {
            break;
        }
        assert!(Instant::now() < deadline, "the change did not complete");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert_eq!(api.stored().lines["drive"].serial.baud.get(), 9600);
    assert_eq!(api.stored().lines, {
        let mut c = test_config();
        c.lines.get_mut("drive").unwrap().serial.baud =
            gateway::config::Baud::try_new(9600).unwrap();
        c.lines
    });
}

/// Reads from `s` until the peer closes; the bytes read.
async fn read_until_closed(s: &mut TcpStream, within: Duration) -> Option<Vec<u8>> {
    let mut out = Vec::new();
    match tokio::time::timeout(within, s.read_to_end(&mut out)).await {
        Ok(Ok(_)) => Some(out),
        Ok(Err(_)) => Some(out), // reset by the server: closed too
        Err(_) => None,
    }
}

#[tokio::test]
async fn a_trickled_request_head_and_an_idle_connection_are_closed() {
    let api = start_with(Setup {
        header_read_timeout: Duration::from_millis(300),
        ..Setup::default()
    })
    .await;
    let addr = api.base.trim_start_matches("http://").to_owned();

    let mut trickle = TcpStream::connect(&addr).await.unwrap();
    trickle
        .write_all(b"GET /healthz HTTP/1.1\r\nHo")
        .await
        .unwrap();
    let closed = read_until_closed(&mut trickle, Duration::from_secs(10)).await;
    assert!(
        closed.is_some(),
        "a connection that never completes its head stays open"
    );

    // A kept-alive connection: one answer, then closed when no next request comes.
    let mut idle = TcpStream::connect(&addr).await.unwrap();
    idle.write_all(format!("GET /healthz HTTP/1.1\r\nHost: {addr}\r\n\r\n").as_bytes())
        .await
        .unwrap();
    let answer = read_until_closed(&mut idle, Duration::from_secs(10))
        .await
        .expect("closed when idle");
    assert!(String::from_utf8_lossy(&answer).starts_with("HTTP/1.1 200"));
}

/// Sends `GET path` on a new connection and reads the answer until the server closes it (or
/// `within` is over): the answer's head and body as text.
async fn one_request(addr: &str, path: &str, close: bool, within: Duration) -> (TcpStream, String) {
    let mut s = TcpStream::connect(addr).await.unwrap();
    let connection = if close { "Connection: close\r\n" } else { "" };
    s.write_all(format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\n{connection}\r\n").as_bytes())
        .await
        .unwrap();
    let mut buf = vec![0u8; 64 * 1024];
    let mut got = Vec::new();
    let deadline = Instant::now() + within;
    // Read until the head and the whole body (Content-Length) are in.
    loop {
        let text = String::from_utf8_lossy(&got).into_owned();
        if let Some((head, body)) = text.split_once("\r\n\r\n") {
            let len = head
                .lines()
                .find_map(|l| {
                    l.to_ascii_lowercase()
                        .strip_prefix("content-length: ")
                        .map(str::to_owned)
                })
                .and_then(|n| n.trim().parse::<usize>().ok());
            if len.is_some_and(|n| body.len() >= n) {
                return (s, text);
            }
        }
        let left = deadline.saturating_duration_since(Instant::now());
        match tokio::time::timeout(left, s.read(&mut buf)).await {
            Ok(Ok(0)) | Ok(Err(_)) | Err(_) => {
                return (s, String::from_utf8_lossy(&got).into_owned())
            }
            Ok(Ok(n)) => got.extend_from_slice(&buf[..n]),
        }
    }
}

#[tokio::test]
async fn beyond_the_limit_only_the_health_paths_are_served_until_a_place_frees() {
    let api = start_with(Setup {
        max_connections: 1,
        ..Setup::default()
    })
    .await;
    let addr = api.base.trim_start_matches("http://").to_owned();
    let within = Duration::from_secs(10);

    // The only general place, taken by a request in progress (its body comes slowly).
    let busy = busy_request(&addr).await;

    // Beyond it: the health paths answer, anything else is 503 with Retry-After, and closed.
    for path in ["/healthz", "/readyz"] {
        let (_, answer) = one_request(&addr, path, false, within).await;
        assert!(
            answer.starts_with("HTTP/1.1 200")
                || path == "/readyz" && answer.starts_with("HTTP/1.1 503"),
            "{path}: {answer}"
        );
    }
    let (mut refused, answer) = one_request(&addr, "/api/v1/lines", false, within).await;
    assert!(answer.starts_with("HTTP/1.1 503"), "{answer}");
    assert!(
        answer.to_ascii_lowercase().contains("retry-after: 5"),
        "{answer}"
    );
    assert!(answer.contains("\"busy\""), "{answer}");
    assert!(
        read_until_closed(&mut refused, within).await.is_some(),
        "a refused connection stays open"
    );

    drop(busy);
    // A connection that only waits (kept alive, idle after its answer) gives its place to a new
    // one after a second.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (mut idle, answer) = one_request(&addr, "/api/v1/lines", false, within).await;
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    tokio::time::sleep(Duration::from_millis(1200)).await;
    let (_, answer) = one_request(&addr, "/api/v1/lines", false, within).await;
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    assert!(
        read_until_closed(&mut idle, Duration::from_secs(5))
            .await
            .is_some(),
        "the idle one was kept"
    );
}

/// A connection with a request in progress: a change whose body never comes in full.
async fn busy_request(addr: &str) -> TcpStream {
    let mut s = TcpStream::connect(addr).await.unwrap();
    s.write_all(
        format!(
            "PUT /api/v1/config HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {TOKEN}\r\n\
             Content-Type: application/json\r\nContent-Length: 100\r\n\r\n{{"
        )
        .as_bytes(),
    )
    .await
    .unwrap();
    // Its head is read and the handler waits for the body.
    tokio::time::sleep(Duration::from_millis(200)).await;
    s
}

#[tokio::test]
async fn a_client_beyond_its_own_places_is_refused_while_another_is_served() {
    let api = start_with(Setup {
        max_connections_per_client: 2,
        ..Setup::default()
    })
    .await;
    let addr = api.base.trim_start_matches("http://").to_owned();
    // 127.0.0.1 holds its two places with requests in progress.
    let mut held = Vec::new();
    for _ in 0..2 {
        held.push(busy_request(&addr).await);
    }
    let (_, answer) = one_request(&addr, "/api/v1/lines", false, Duration::from_secs(10)).await;
    assert!(answer.starts_with("HTTP/1.1 503"), "{answer}");
    assert!(answer.contains("max_connections_per_client"), "{answer}");
    let (_, answer) = one_request(&addr, "/healthz", false, Duration::from_secs(10)).await;
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    // Another address of the host (every 127/8 address reaches lo) has places of its own.
    let other = tokio::net::TcpSocket::new_v4().unwrap();
    other.bind("127.0.1.7:0".parse().unwrap()).unwrap();
    let mut s = other.connect(addr.parse().unwrap()).await.unwrap();
    s.write_all(
        format!("GET /api/v1/lines HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n")
            .as_bytes(),
    )
    .await
    .unwrap();
    let answer = read_until_closed(&mut s, Duration::from_secs(10))
        .await
        .unwrap();
    assert!(String::from_utf8_lossy(&answer).starts_with("HTTP/1.1 200"));
}

#[tokio::test]
async fn an_answer_the_client_does_not_read_is_closed_after_the_write_timeout() {
    let api = start_with(Setup {
        write_timeout: Duration::from_millis(500),
        ..Setup::default()
    })
    .await;
    let addr = api.base.trim_start_matches("http://").to_owned();
    // A small receive window and a large answer (the OpenAPI document, asked for 400 times in a
    // pipeline) that the client never reads.
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(4096).unwrap();
    let mut s = socket.connect(addr.parse().unwrap()).await.unwrap();
    let one = format!("GET /api/v1/openapi.json HTTP/1.1\r\nHost: {addr}\r\n\r\n");
    let started = Instant::now();
    let _ = s.write_all(one.repeat(400).as_bytes()).await;
    tokio::time::sleep(Duration::from_secs(3)).await;
    // Now read: what the server wrote before it gave up, then the end of the connection.
    let closed = read_until_closed(&mut s, Duration::from_secs(20)).await;
    assert!(closed.is_some(), "the unread answer was not closed");
    assert!(started.elapsed() < Duration::from_secs(20));
    let answered = String::from_utf8_lossy(closed.as_deref().unwrap_or_default())
        .matches("HTTP/1.1 200")
        .count();
    assert!(answered < 400, "every answer was written: {answered}");
}

#[tokio::test]
async fn clients_outside_the_allowed_networks_are_closed_at_accept() {
    let registry = prometheus::Registry::new();
    let metrics = gateway::app::Metrics::register(&registry).expect("metrics");
    let outside = start_with(Setup {
        allowed_networks: vec!["192.0.2.0/24".parse().expect("net")],
        metrics: Some(metrics),
        ..Setup::default()
    })
    .await;
    let addr = outside.base.trim_start_matches("http://").to_owned();
    let mut stream = TcpStream::connect(&addr).await.expect("connect");
    let _ = stream
        .write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n")
        .await;
    let mut answer = Vec::new();
    let read = tokio::time::timeout(Duration::from_secs(5), stream.read_to_end(&mut answer))
        .await
        .expect("closed, not left waiting");
    assert!(
        read.is_err() || answer.is_empty(),
        "answered: {}",
        String::from_utf8_lossy(&answer)
    );
    // Counted (and logged, rate-limited, with the client's address).
    let text = gateway::metrics::encode_text(&registry);
    assert!(
        text.contains("gateway_http_rejected_total{reason=\"network\"} 1"),
        "{text}"
    );
    let inside = start_with(Setup {
        allowed_networks: vec!["127.0.0.0/8".parse().expect("net")],
        ..Setup::default()
    })
    .await;
    assert_eq!(inside.get("/healthz").await.status, 200);
}
