//! Starting the API on 127.0.0.1 port 0 over an in-memory gateway, and a real HTTP client.

use std::sync::Arc;
use std::time::Duration;

use gateway::api::model::ScalarValue;
use gateway::api::{self, ApiState, Auth, Token};
use gateway::config::{self, Interface};
use gateway::persist::ConfigStore;
use gateway::plant::Config;
use reqwest::header::HeaderMap;
use reqwest::Method;
use serde_json::Value;
use tokio::net::TcpListener;
use tokio::sync::oneshot;

use super::backend::{MemGateway, TagSpec};

/// The token of the tests' servers.
pub(crate) const TOKEN: &str = "test-token-0123456789abcdef";

/// The demo configuration with the ASCII line on RS232 (so that it has modem signals).
pub(crate) fn test_config() -> Config {
    let mut c = gateway::plant::demo();
    c.lines
        .get_mut("ascii")
        .expect("demo line")
        .serial
        .interface = Interface::Rs232;
    c.check().expect("the test configuration is valid");
    c
}

/// The tags of the test gateway: two per polled device, one of them writable.
pub(crate) fn test_tags() -> Vec<(&'static str, &'static str, &'static str, TagSpec)> {
    let tag = |value, unit, writable, range| TagSpec {
        value: Some(value),
        unit,
        writable,
        range,
    };
    vec![
        (
            "drive",
            "atv71",
            "eta",
            tag(ScalarValue::Int(0x0237), "", false, (0.0, 65535.0)),
        ),
        (
            "drive",
            "atv71",
            "lfrd",
            tag(ScalarValue::Int(0), "rpm", true, (-1500.0, 1500.0)),
        ),
        (
            "ksvario",
            "ksvario",
            "pv",
            tag(ScalarValue::Float(23.5), "°C", false, (-50.0, 500.0)),
        ),
        (
            "ksvario",
            "ksvario",
            "sp",
            tag(ScalarValue::Float(40.0), "°C", true, (0.0, 200.0)),
        ),
    ]
}

/// How a test server is set up.
pub(crate) struct Setup {
    pub(crate) auth: Auth,
    /// Persist changes to a file in a temporary directory.
    pub(crate) store: bool,
    pub(crate) body_limit: u64,
    pub(crate) request_timeout: Duration,
    pub(crate) max_connections: u32,
    pub(crate) header_read_timeout: Duration,
    pub(crate) max_connections_per_client: u32,
    pub(crate) max_streams: u32,
    pub(crate) write_timeout: Duration,
    /// Where the listener counts refusals and connections.
    pub(crate) metrics: Option<gateway::app::Metrics>,
    pub(crate) config: Config,
    /// Client networks served; empty: every client.
    pub(crate) allowed_networks: Vec<ipnet::IpNet>,
    /// The configuration file's text as the operator wrote it (it must read as `config`);
    /// `None`: the file is `config` written out whole.
    pub(crate) file_text: Option<String>,
}

impl Default for Setup {
    fn default() -> Self {
        Self {
            auth: Auth::with_token(Token::new(TOKEN, "test").expect("token")),
            store: true,
            body_limit: config::DEFAULT_BODY_LIMIT,
            request_timeout: Duration::from_secs(10),
            max_connections: api::DEFAULT_MAX_CONNECTIONS,
            header_read_timeout: api::DEFAULT_HEADER_READ_TIMEOUT,
            max_connections_per_client: config::DEFAULT_HTTP_MAX_CONNECTIONS_PER_CLIENT,
            max_streams: config::DEFAULT_HTTP_MAX_STREAMS,
            write_timeout: config::DEFAULT_HTTP_WRITE_TIMEOUT,
            metrics: None,
            config: test_config(),
            allowed_networks: Vec::new(),
            file_text: None,
        }
    }
}

/// A running API.
pub(crate) struct TestApi {
    pub(crate) base: String,
    pub(crate) gw: Arc<MemGateway>,
    pub(crate) http: reqwest::Client,
    /// The configuration file's directory (when persisting).
    _dir: Option<tempfile::TempDir>,
    pub(crate) store_path: Option<std::path::PathBuf>,
    shutdown: Option<oneshot::Sender<()>>,
}

impl Drop for TestApi {
    fn drop(&mut self) {
        if let Some(tx) = self.shutdown.take() {
            let _ = tx.send(());
        }
    }
}

/// A reply: status, headers, body as text and as JSON (`Null` when not JSON).
#[derive(Debug)]
pub(crate) struct Reply {
    pub(crate) status: u16,
    pub(crate) headers: HeaderMap,
    pub(crate) text: String,
    pub(crate) json: Value,
}

impl Reply {
    /// The error code of an error reply, after checking the error shape.
    pub(crate) fn code(&self) -> &str {
        assert_error_shape(&self.json);
        self.json["error"]["code"].as_str().unwrap_or_default()
    }

    /// The issue paths of an error reply.
    pub(crate) fn issue_paths(&self) -> Vec<String> {
        assert_error_shape(&self.json);
        self.json["error"]["issues"]
            .as_array()
            .map(|a| {
                a.iter()
                    .map(|i| i["path"].as_str().unwrap_or_default().to_owned())
                    .collect()
            })
            .unwrap_or_default()
    }

    pub(crate) fn header(&self, name: &str) -> Option<&str> {
        self.headers.get(name).and_then(|v| v.to_str().ok())
    }
}

/// `{"error": {"code": str, "message": str, "issues"?: [{"path": str, "message": str}]}}` and
/// nothing else.
pub(crate) fn assert_error_shape(v: &Value) {
    let obj = v
        .as_object()
        .unwrap_or_else(|| panic!("not an error body: {v}"));
    assert_eq!(obj.len(), 1, "{v}");
    let e = v["error"]
        .as_object()
        .unwrap_or_else(|| panic!("no error object: {v}"));
    assert!(e["code"].is_string() && e["message"].is_string(), "{v}");
    for key in e.keys() {
        assert!(
            ["code", "message", "issues"].contains(&key.as_str()),
            "unexpected key {key}: {v}"
        );
    }
    if let Some(issues) = e.get("issues") {
        for i in issues
            .as_array()
            .unwrap_or_else(|| panic!("issues not a list: {v}"))
        {
            assert!(i["path"].is_string() && i["message"].is_string(), "{v}");
        }
    }
}

pub(crate) async fn start() -> TestApi {
    start_with(Setup::default()).await
}

pub(crate) async fn start_with(setup: Setup) -> TestApi {
    let gw = Arc::new(MemGateway::new(setup.config.clone(), test_tags()));
    let mut state = ApiState::new(gw.clone(), setup.auth)
        .with_limits(setup.body_limit, setup.request_timeout)
        .with_connections(setup.max_connections, setup.header_read_timeout)
        .with_client_limits(
            setup.max_connections_per_client,
            setup.max_streams,
            setup.write_timeout,
        )
        .with_allowed_networks(setup.allowed_networks.clone());
    if let Some(metrics) = setup.metrics.clone() {
        state = state.with_metrics(metrics.http().clone());
    }
    let (dir, store_path) = if setup.store {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("gateway.toml");
        let store = ConfigStore::new(&path);
        match &setup.file_text {
            Some(text) => {
                assert_eq!(
                    gateway::plant::parse(text).expect("the test file is valid"),
                    setup.config
                );
                store.save_atomic(text).expect("initial save");
            }
            None => store.save(&setup.config).expect("initial save"),
        }
        state = state.with_store(store);
        (Some(dir), Some(path))
    } else {
        (None, None)
    };
    let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
    let addr = listener.local_addr().expect("addr");
    let (tx, rx) = oneshot::channel();
    tokio::spawn(api::serve(listener, state, async {
        let _ = rx.await;
    }));
    TestApi {
        base: format!("http://{addr}"),
        gw,
        http: reqwest::Client::builder()
            .timeout(Duration::from_secs(20))
            .build()
            .expect("client"),
        _dir: dir,
        store_path,
        shutdown: Some(tx),
    }
}

impl TestApi {
    /// `method path` with the token when `token` is given, a JSON body when `body` is given.
    pub(crate) async fn request(
        &self,
        method: Method,
        path: &str,
        token: Option<&str>,
        body: Option<&Value>,
    ) -> Reply {
        let mut req = self.http.request(method, format!("{}{path}", self.base));
        if let Some(t) = token {
            req = req.bearer_auth(t);
        }
        if let Some(b) = body {
            req = req.json(b);
        }
        into_reply(req.send().await.expect("HTTP request")).await
    }

    /// A request built by the caller (headers, raw bodies).
    pub(crate) async fn send(&self, req: reqwest::RequestBuilder) -> Reply {
        into_reply(req.send().await.expect("HTTP request")).await
    }

    pub(crate) fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    pub(crate) async fn get(&self, path: &str) -> Reply {
        self.request(Method::GET, path, None, None).await
    }

    pub(crate) async fn put(&self, path: &str, body: &Value) -> Reply {
        self.request(Method::PUT, path, Some(TOKEN), Some(body))
            .await
    }

    pub(crate) async fn post(&self, path: &str, body: &Value) -> Reply {
        self.request(Method::POST, path, Some(TOKEN), Some(body))
            .await
    }

    pub(crate) async fn delete(&self, path: &str) -> Reply {
        self.request(Method::DELETE, path, Some(TOKEN), None).await
    }

    /// The configuration file's contents, parsed.
    pub(crate) fn stored(&self) -> Config {
        let path = self.store_path.as_ref().expect("a store");
        gateway::plant::load(path).expect("the stored configuration loads")
    }
}

async fn into_reply(r: reqwest::Response) -> Reply {
    let status = r.status().as_u16();
    let headers = r.headers().clone();
    let text = r.text().await.expect("body");
    let json = serde_json::from_str(&text).unwrap_or(Value::Null);
    Reply {
        status,
        headers,
        text,
        json,
    }
}
