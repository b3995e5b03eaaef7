//! A backend over an in-memory tag table and a record of sent telegrams (a simple gateway, not
//! a mock of zenoh), and helpers for second sessions on explicit loopback endpoints.

use std::collections::BTreeMap;
use std::net::TcpListener;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, SystemTime};

use gateway::zenoh_bridge::{
    BackendFuture, Bridge, BridgeBackend, BridgeHandle, TagValue, ZenohConfig,
};
use serde_json::{json, Value};
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;
use zenoh::sample::Sample;
use zenoh::Session;

/// The gateway name in every test: keys start with `gw/test`.
pub(crate) const NAME: &str = "test";

/// A free port on 127.0.0.1 (bound, read, released).
pub(crate) fn free_port() -> u16 {
    let l = TcpListener::bind("127.0.0.1:0").unwrap();
    l.local_addr().unwrap().port()
}

pub(crate) fn endpoint(port: u16) -> String {
    format!("tcp/127.0.0.1:{port}")
}

type TagKey = (String, String, String);

/// Tags, lines, and what the bridge asked for.
pub(crate) struct TestBackend {
    pub(crate) lines: Vec<String>,
    pub(crate) tags: Mutex<BTreeMap<TagKey, TagValue>>,
    /// Tags a write is refused for (as a device answering exception 04 would).
    pub(crate) read_only: Vec<TagKey>,
    pub(crate) sent: Mutex<Vec<(String, Vec<u8>)>>,
    pub(crate) writes: Mutex<Vec<(String, String, String, Value)>>,
    /// Set after start: writes publish the new value, as the image would.
    pub(crate) handle: OnceLock<BridgeHandle>,
}

pub(crate) fn value(v: Value, unit: Option<&str>) -> TagValue {
    TagValue {
        value: v,
        unit: unit.map(str::to_owned),
        quality: "good",
        timestamp: SystemTime::now(),
        description: None,
    }
}

fn key(l: &str, d: &str, t: &str) -> TagKey {
    (l.to_owned(), d.to_owned(), t.to_owned())
}

impl TestBackend {
    /// Lines `drive`, `ksvario`, `r3964`; tags drive/atv/{eta,speed,cmd} and
    /// ksvario/ks/{x1,w1}; `eta` is read-only.
    pub(crate) fn new() -> Arc<Self> {
        let mut tags = BTreeMap::new();
        tags.insert(key("drive", "atv", "eta"), value(json!(0x0237), None));
        tags.insert(
            key("drive", "atv", "speed"),
            value(json!(1450), Some("rpm")),
        );
        tags.insert(key("drive", "atv", "cmd"), value(json!(0), None));
        tags.insert(
            key("ksvario", "ks", "x1"),
            value(json!(106.6), Some("degC")),
        );
        tags.insert(
            key("ksvario", "ks", "w1"),
            value(json!(140.0), Some("degC")),
        );
        Arc::new(Self {
            lines: vec!["drive".into(), "ksvario".into(), "r3964".into()],
            tags: Mutex::new(tags),
            read_only: vec![key("drive", "atv", "eta")],
            sent: Mutex::new(Vec::new()),
            writes: Mutex::new(Vec::new()),
            handle: OnceLock::new(),
        })
    }
}

impl BridgeBackend for TestBackend {
    fn lines(&self) -> Vec<String> {
        self.lines.clone()
    }

    fn query_tags(
        &self,
        line: Option<&str>,
        device: Option<&str>,
        tag: Option<&str>,
    ) -> Vec<(String, String, String, TagValue)> {
        let ok = |want: Option<&str>, have: &str| want.is_none_or(|w| w == have);
        self.tags
            .lock()
            .unwrap()
            .iter()
            .filter(|((l, d, t), _)| ok(line, l) && ok(device, d) && ok(tag, t))
            .map(|((l, d, t), v)| (l.clone(), d.clone(), t.clone(), v.clone()))
            .collect()
    }

    fn line_status(&self, line: &str) -> Option<Value> {
        self.lines
            .iter()
            .any(|l| l == line)
            .then(|| json!({"line": line, "state": "running"}))
    }

    fn gateway_status(&self) -> Value {
        json!({"name": NAME, "lines": self.lines})
    }

    fn send_telegram(&self, line: &str, bytes: Vec<u8>) -> BackendFuture<Result<Value, String>> {
        let len = bytes.len();
        self.sent.lock().unwrap().push((line.to_owned(), bytes));
        Box::pin(async move { Ok(json!({"sent": len})) })
    }

    fn write_tag(
        &self,
        line: &str,
        device: &str,
        tag: &str,
        value: Value,
    ) -> BackendFuture<Result<Value, String>> {
        let k = key(line, device, tag);
        let result = if self.read_only.contains(&k) {
            Err("exception 04: server device failure (read-only)".to_owned())
        } else if let Some(slot) = self.tags.lock().unwrap().get_mut(&k) {
            self.writes.lock().unwrap().push((
                line.to_owned(),
                device.to_owned(),
                tag.to_owned(),
                value.clone(),
            ));
            slot.value = value.clone();
            slot.timestamp = SystemTime::now();
            if let Some(h) = self.handle.get() {
                h.publish_tag(line, device, tag, slot.clone());
            }
            Ok(json!({"written": value}))
        } else {
            Err(format!("no tag {line}/{device}/{tag}"))
        };
        Box::pin(async move { result })
    }
}

/// A bridge named `test` with `cfg`, on `backend`.
pub(crate) async fn start(
    cfg: ZenohConfig,
    backend: Arc<TestBackend>,
) -> (Bridge, BridgeHandle, CancellationToken) {
    let shutdown = CancellationToken::new();
    let (bridge, handle) = Bridge::start(cfg, NAME, backend.clone(), shutdown.clone())
        .await
        .expect("bridge starts");
    let _ = backend.handle.set(handle.clone());
    (bridge, handle, shutdown)
}

/// A bridge listening on a fresh loopback port, scouting off. Returns the port too.
pub(crate) async fn start_listening(
    backend: Arc<TestBackend>,
) -> (Bridge, BridgeHandle, CancellationToken, u16) {
    let port = free_port();
    let cfg = ZenohConfig::loopback_peer(&endpoint(port)).unwrap();
    let (b, h, s) = start(cfg, backend).await;
    (b, h, s, port)
}

/// A second session: peer, multicast scouting off, connecting to and listening on the given
/// endpoints only.
pub(crate) async fn peer(connect: &[String], listen: &[String]) -> Session {
    let mut c = zenoh::Config::default();
    c.insert_json5("mode", r#""peer""#).unwrap();
    c.insert_json5("scouting/multicast/enabled", "false")
        .unwrap();
    c.insert_json5("connect/endpoints", &json!(connect).to_string())
        .unwrap();
    c.insert_json5("listen/endpoints", &json!(listen).to_string())
        .unwrap();
    zenoh::open(c).await.expect("test session opens")
}

/// Every sample on `key` into an unbounded channel (a test must not push back on zenoh).
pub(crate) async fn subscribe(
    session: &Session,
    key: &str,
) -> (
    zenoh::pubsub::Subscriber<()>,
    mpsc::UnboundedReceiver<Sample>,
) {
    let (tx, rx) = mpsc::unbounded_channel();
    let sub = session
        .declare_subscriber(key.to_owned())
        .callback(move |s| {
            let _ = tx.send(s);
        })
        .await
        .unwrap();
    (sub, rx)
}

/// Receives until `pred` holds, within `limit`.
pub(crate) async fn recv_until(
    rx: &mut mpsc::UnboundedReceiver<Sample>,
    limit: Duration,
    mut pred: impl FnMut(&Sample) -> bool,
) -> Sample {
    tokio::time::timeout(limit, async {
        loop {
            let s = rx.recv().await.expect("subscriber open");
            if pred(&s) {
                return s;
            }
        }
    })
    .await
    .expect("expected sample within the limit")
}

/// Receives until a sample of every key in `keys` has come, in any order, within `limit`: the
/// first sample of each, by key. Samples of other keys are skipped. (The bridge keeps the order
/// of publications per key only: waiting for one key with [`recv_until`] skips what another key
/// published meanwhile.)
pub(crate) async fn recv_keys(
    rx: &mut mpsc::UnboundedReceiver<Sample>,
    limit: Duration,
    keys: &[&str],
) -> BTreeMap<String, Sample> {
    let mut got = BTreeMap::new();
    let all = tokio::time::timeout(limit, async {
        while got.len() < keys.len() {
            let s = rx.recv().await.expect("subscriber open");
            let key = s.key_expr().as_str();
            if keys.contains(&key) && !got.contains_key(key) {
                got.insert(key.to_owned(), s);
            }
        }
    })
    .await;
    assert!(
        all.is_ok(),
        "expected samples of {keys:?} within {limit:?}, got {:?}",
        got.keys().collect::<Vec<_>>()
    );
    got
}

/// Publishes a tag value over and over until the subscriber sees it: the way to know routes
/// are in place after a (re)connection. Returns the sample.
pub(crate) async fn publish_until_seen(
    handle: &BridgeHandle,
    rx: &mut mpsc::UnboundedReceiver<Sample>,
    marker: i64,
) -> Sample {
    let want = format!("{}/drive/atv/speed", handle.prefix());
    tokio::time::timeout(Duration::from_secs(20), async {
        loop {
            handle.publish_tag("drive", "atv", "speed", value(json!(marker), Some("rpm")));
            let got = tokio::time::timeout(Duration::from_millis(200), async {
                loop {
                    let s = rx.recv().await.expect("subscriber open");
                    if s.key_expr().as_str() == want && json_of(&s)["value"] == json!(marker) {
                        return s;
                    }
                }
            })
            .await;
            if let Ok(s) = got {
                return s;
            }
        }
    })
    .await
    .expect("publication seen within 20 s")
}

pub(crate) fn json_of(s: &Sample) -> Value {
    serde_json::from_slice(&s.payload().to_bytes()).expect("JSON payload")
}
