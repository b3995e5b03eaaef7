//! A plant for the REST tests: `gateway run` on socat links with simulator processes (an
//! Altivar 71, a KS vario, an ASCII partner on an RS232 line), a token file, and an HTTP client.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use gateway_tests::{
    check_config, device_sim, start_sim, temp_dir, two_device_lines, ChildGuard, Gateway, SocatLink,
};
use reqwest::{Method, StatusCode};
use serde_json::Value;

/// The bearer token the plant's gateway reads from its token file.
pub(crate) const TOKEN: &str = "e2e-token-7f3a9c01d2b4e5f6";

/// How long the gateway may take to open its ports and answer on a loaded machine.
pub(crate) const READY_TIMEOUT: Duration = Duration::from_secs(60);

/// A JSON answer.
#[derive(Debug)]
pub(crate) struct Answer {
    pub(crate) status: StatusCode,
    pub(crate) headers: reqwest::header::HeaderMap,
    pub(crate) body: Value,
}

/// The REST API of one gateway.
#[derive(Clone, Debug)]
pub(crate) struct Api {
    base: String,
    client: reqwest::Client,
}

impl Api {
    pub(crate) fn new(http: SocketAddr) -> Self {
        let client = reqwest::Client::builder()
            .no_proxy()
            .timeout(Duration::from_secs(60))
            .build()
            .expect("HTTP client");
        Self {
            base: format!("http://{http}"),
            client,
        }
    }

    /// `method path` with an optional JSON body and bearer token.
    pub(crate) async fn call(
        &self,
        method: Method,
        path: &str,
        body: Option<&Value>,
        token: Option<&str>,
    ) -> Answer {
        let mut req = self
            .client
            .request(method.clone(), format!("{}{path}", self.base));
        if let Some(b) = body {
            req = req.json(b);
        }
        if let Some(t) = token {
            req = req.bearer_auth(t);
        }
        let resp = req
            .send()
            .await
            .unwrap_or_else(|e| panic!("{method} {path}: {e}"));
        let status = resp.status();
        let headers = resp.headers().clone();
        let bytes = resp.bytes().await.expect("body");
        let body = if bytes.is_empty() {
            Value::Null
        } else {
            serde_json::from_slice(&bytes)
                .unwrap_or_else(|_| Value::String(String::from_utf8_lossy(&bytes).into_owned()))
        };
        Answer {
            status,
            headers,
            body,
        }
    }

    /// As [`Self::call`], `None` when the request fails (the server went away).
    pub(crate) async fn try_call(
        &self,
        method: Method,
        path: &str,
        body: Option<&Value>,
        token: Option<&str>,
    ) -> Option<StatusCode> {
        let mut req = self.client.request(method, format!("{}{path}", self.base));
        if let Some(b) = body {
            req = req.json(b);
        }
        if let Some(t) = token {
            req = req.bearer_auth(t);
        }
        let resp = req.send().await.ok()?;
        let status = resp.status();
        resp.bytes().await.ok()?;
        Some(status)
    }

    pub(crate) async fn get(&self, path: &str) -> Answer {
        self.call(Method::GET, path, None, None).await
    }

    /// GET that must answer 200; its body.
    pub(crate) async fn get_ok(&self, path: &str) -> Value {
        let a = self.get(path).await;
        assert_eq!(a.status, StatusCode::OK, "GET {path}: {:#}", a.body);
        a.body
    }

    /// A change with the plant's token.
    pub(crate) async fn change(&self, method: Method, path: &str, body: Option<&Value>) -> Answer {
        self.call(method, path, body, Some(TOKEN)).await
    }

    /// `/metrics` as text.
    pub(crate) async fn metrics(&self) -> String {
        match self.get("/metrics").await.body {
            Value::String(s) => s,
            other => panic!("/metrics is not text: {other}"),
        }
    }

    /// Waits until `/readyz` answers 200.
    pub(crate) async fn wait_ready(&self) {
        let deadline = Instant::now() + READY_TIMEOUT;
        loop {
            let a = self.get("/readyz").await;
            if a.status == StatusCode::OK {
                assert_eq!(a.body["status"], "ready");
                return;
            }
            assert_eq!(a.status, StatusCode::SERVICE_UNAVAILABLE, "{:#}", a.body);
            assert!(Instant::now() < deadline, "never ready: {:#}", a.body);
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }

    /// Polls `path` until `done` holds for its body; panics after `timeout`.
    pub(crate) async fn wait_for(
        &self,
        path: &str,
        timeout: Duration,
        what: &str,
        done: impl Fn(&Value) -> bool,
    ) -> Value {
        let deadline = Instant::now() + timeout;
        loop {
            let body = self.get_ok(path).await;
            if done(&body) {
                return body;
            }
            assert!(Instant::now() < deadline, "{what}: never; last {body:#}");
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }
}

/// The value of an unlabelled sample in a Prometheus exposition.
pub(crate) fn sample(exposition: &str, name: &str) -> Option<f64> {
    exposition.lines().find_map(|l| {
        let (n, v) = l.split_once(' ')?;
        (n == name).then(|| v.trim().parse().ok()).flatten()
    })
}

/// The plant's configuration.
pub(crate) fn plant_config(drive: &Path, ks: &Path, ascii: &Path, token_file: &Path) -> String {
    let lines = two_device_lines(drive, ks, "500ms", None);
    format!(
        r#"
[gateway]
name = "rest-e2e"

[modbus_tcp]
listen = "127.0.0.1:0"

[http]
listen = "127.0.0.1:0"
token_file = "{token}"

{lines}
[lines.ascii]
port = "{ascii}"
protocol = "ascii"
interface = "rs232"
baud = 9600
end_criterion = "end-chars"
end_chars = [0x03]
unit_id = 101
"#,
        token = token_file.display(),
        ascii = ascii.display(),
    )
}

/// `gateway run` with its links, simulators and token file.
pub(crate) struct Plant {
    pub(crate) dir: PathBuf,
    pub(crate) config: PathBuf,
    /// The configuration file as the test wrote it.
    pub(crate) config_text: String,
    pub(crate) drive: SocatLink,
    pub(crate) drive_sim: ChildGuard,
    _ks: SocatLink,
    _ks_sim: ChildGuard,
    _ascii: SocatLink,
    _ascii_sim: ChildGuard,
    pub(crate) gw: Gateway,
    pub(crate) api: Api,
}

impl Plant {
    /// Starts everything and waits until the gateway is ready.
    pub(crate) async fn start(test: &str) -> Self {
        let dir = temp_dir(test);
        let drive = SocatLink::new(&dir, "drive");
        let ks = SocatLink::new(&dir, "ks");
        let ascii = SocatLink::new(&dir, "ascii");
        let drive_sim = device_sim("altivar71", &drive.b);
        let ks_sim = device_sim("ksvario", &ks.b);
        let ascii_sim = start_sim(&[
            "--device",
            "ascii",
            "--port",
            path(&ascii.b),
            "--baud",
            "9600",
            "--every",
            "300ms",
        ]);
        let token_file = dir.join("api-token");
        std::fs::write(&token_file, format!("{TOKEN}\n")).expect("write token");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&token_file, std::fs::Permissions::from_mode(0o600))
                .expect("chmod token");
        }
        let config = dir.join("gateway.toml");
        let config_text = plant_config(&drive.a, &ks.a, &ascii.a, &token_file);
        std::fs::write(&config, &config_text).expect("write config");
        let gw = Gateway::run(&config);
        let api = Api::new(gw.http.expect("the gateway announces its HTTP address"));
        api.wait_ready().await;
        Self {
            dir,
            config,
            config_text,
            drive,
            drive_sim,
            _ks: ks,
            _ks_sim: ks_sim,
            _ascii: ascii,
            _ascii_sim: ascii_sim,
            gw,
            api,
        }
    }
}

pub(crate) fn path(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// `gateway check --config FILE`: its exit code and output.
pub(crate) fn check(config: &Path) -> (bool, String) {
    check_config(config)
}
