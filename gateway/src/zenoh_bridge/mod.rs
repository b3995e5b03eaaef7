//! The zenoh bridge: telegrams, tag values, queries, writes, events and presence on the zenoh
//! fabric, through one session per gateway.
//!
//! The rest of the gateway sees two narrow types and knows nothing of zenoh:
//! - [`BridgeHandle`] (cheap to clone): `publish_telegram`, `publish_tag(s)`, `publish_event`,
//!   `device_online`. None of them waits: they queue into bounded queues and count what does
//!   not fit (policy in [`config`]).
//! - [`BridgeBackend`] (implemented by the gateway): answers tag and status queries from the
//!   image, sends telegrams and writes tags for commands that come from the fabric.
//!
//! ```text
//!   lines / image ---BridgeHandle---> Outbox ---publisher thread---> zenoh session
//!                                                                    |  ^
//!   BridgeBackend <--command workers <--command queue <--callbacks --+  |
//!   BridgeBackend <--query task      <--query queue   <--callbacks --+  |
//!                                         results, replies ------------+
//! ```
//!
//! Key layout: see [`keys`]. Payloads:
//! - `<prefix>/<line>/rx`: the telegram bytes as they were received (encoding
//!   `application/octet-stream`). The attachment is UTF-8 JSON
//!   `{"seq": <u64 sequence number of the line>, "time": "<receive time, RFC 3339 UTC, µs>"}`
//!   (Python: `json.loads(sample.attachment.to_string())`). The sample timestamp is the
//!   session's (its HLC if timestamping is on, else the wall clock) at publication.
//! - `<prefix>/<line>/<device>/<tag>` (and its query replies): JSON
//!   `{"value": .., "unit": "rpm" | "", "quality": "good", "timestamp": "<RFC 3339>"}` (`""`
//!   for a tag without a unit, as REST shows it).
//! - `<prefix>/<line>/events`: JSON `{"class": 8, "number": 10, "event": "080A", "name": ..,
//!   "text": .., "time": "<RFC 3339>"}`.
//! - `<prefix>/<line>/tx`: the telegram bytes to send. `<prefix>/<line>/<device>/<tag>/set`: the
//!   value as JSON (`1500`, `true`, `"text"`). Either as a put, or as a get with the payload (the
//!   result is then also the reply). Results on `<prefix>/<line>/tx/result` and
//!   `<prefix>/<line>/<device>/<tag>/set/result`, JSON: `{"ok": true, "line", "len", "result"}`
//!   for a send, `{"ok": true, "line", "device", "tag", "value", "result"}` for a write, with
//!   `"ok": false` and `"error": "<text>"` instead of `result` on failure (bad payload, unknown
//!   line, `busy`, or the backend's refusal). The command's attachment is copied to its result.
//!
//! Order: the publications of one key keep their order (a newer tag value may replace one not
//! yet published). Between keys there is none: a write's result and the tag value the write
//! changed come in either order, so a subscriber waiting for both must not skip the other key's
//! samples while it waits for one.
//!
//! Bounds: what a peer sends is bounded before it costs anything. A message larger than
//! `[zenoh] max_payload` + [`config::PAYLOAD_HEADROOM`] (64 KiB for the key, the attachment and
//! zenoh's framing) is dropped by zenoh while it reassembles the fragments
//! (`transport/link/rx/max_message_size`), so it never takes more memory than that; zenoh drops
//! it silently (a TRACE line of its own), the gateway never sees it and cannot count it, and the
//! link stays up. A payload over `max_payload` that gets through (up to the headroom, or from a
//! local or shared-memory path) is refused in the callback before it is copied. Every command
//! refused (too large, not JSON, unknown line, device or tag, writes off, queue full) is answered
//! on its result key and counted and audited in one place, [`accounting`]:
//! `gateway_writes_total{path="zenoh",result="refused",reason}`. A read query (tags, status)
//! with a payload over `max_payload` gets no reply and is counted in the bridge's `dropped`
//! (`query_too_large`) and `gateway_dropped_updates_total{reason="too_large"}`. Nothing a peer
//! can make happen is logged at WARN or above more than once per [`crate::log_limit::INTERVAL`]
//! per kind (the audit log likewise), checked by a test over these sources.
//!
//! Session: peer by default; `Bridge::start` fails if a peer cannot open its session (a listen
//! endpoint in use, a bad config file). A client keeps retrying its first connection in the
//! background (1 s doubling to 30 s) and publishes once connected; after a loss zenoh itself
//! reconnects to the configured endpoints, in both modes. Publications made while no peer
//! subscribes are not stored anywhere (zenoh has no storage here); a subscriber that joins late
//! gets the current tag values from the image instead: a get on the tag keys, or zenoh-ext's
//! advanced subscriber with history, whose history query `<key expression>/@adv/**` the bridge
//! answers (see `queryable.rs`).
//!
//! Name: the bridge declares, publishes and answers only once its name is its own: while another
//! session holds the token `<prefix>` the session stays open (the fleet is followed) but nothing
//! is declared or published, the conflict is reported ([`BridgeStats::name_conflict`]), and the
//! name is taken when it is free ([`fleet::take_name`]); with [`OnDuplicate::Exit`] the start is
//! refused instead ([`BridgeError::Duplicate`]).
//!
//! Runtime: call `start` inside a multi-threaded tokio runtime.
//!
//! Cargo features: zenoh is built with `transport_tcp`, and with `transport_tls` through the
//! default feature `zenoh-tls` (`tls/` endpoints; certificates and mutual authentication are
//! set in the zenoh config file); access control (`access_control` in the file) needs no
//! feature.

pub mod accounting;
pub mod config;
pub mod fleet;
pub mod fleet_cli;
pub mod keys;
pub mod metrics;

mod handle;
mod policy;
mod presence;
mod publish;
mod queryable;
mod session;
mod subscribe;
mod tag_queue;

use std::future::Future;
use std::path::PathBuf;
use std::pin::Pin;
use std::sync::Arc;
use std::time::SystemTime;

use serde_json::{json, Value};
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

pub use crate::config::{Deadband, TagPolicy, TagRule};
pub use config::{Endpoint, Mode, ZenohConfig};
pub use handle::BridgeHandle;
use keys::{KeyError, Keys};
pub use metrics::{BridgeStats, CommandKind, CommandOutcome, DropReason, PublicationKind};

use policy::Publishing;
use publish::{Limits, Outbox, PublisherThread};

/// Monitored frames waiting for the publisher thread (`<line>/frames`), all lines together;
/// more are dropped and counted (`frame_queue_full`): the line's ring keeps them for REST.
const FRAME_QUEUE: usize = 1024;

/// The future a [`BridgeBackend`] command returns.
pub type BackendFuture<T> = Pin<Box<dyn Future<Output = T> + Send + 'static>>;

/// One tag value as the bridge publishes it.
#[derive(Clone, Debug, PartialEq)]
pub struct TagValue {
    /// The value in engineering units (number, bool, string...).
    pub value: Value,
    /// The unit, if the tag has one (published as `""` when it has none, as REST shows it).
    pub unit: Option<String>,
    /// `good`, `stale`, `not_defined`, `off`, `out_of_range`, `comm_failure`...
    pub quality: &'static str,
    /// When the value was read from the device.
    pub timestamp: SystemTime,
    /// The tag's description, if it has one (published as `"description"`, as REST shows it).
    pub description: Option<String>,
}

impl TagValue {
    /// The JSON published and replied: `{"value", "unit", "quality", "timestamp"}`, and
    /// `"description"` when the tag has one; a tag without a unit has `"unit": ""`, as in the
    /// REST API.
    pub fn to_json(&self) -> Value {
        let mut v = json!({
            "value": self.value,
            "unit": self.unit.as_deref().unwrap_or(""),
            "quality": self.quality,
            "timestamp": publish::rfc3339(self.timestamp),
        });
        if let (Some(d), Some(o)) = (&self.description, v.as_object_mut()) {
            o.insert("description".to_owned(), json!(d));
        }
        v
    }
}

/// What the gateway provides to the bridge. Sync methods must be quick (an image read); the
/// command methods return futures that end when the line has done the work.
pub trait BridgeBackend: Send + Sync + 'static {
    /// The names of the lines (for line status queries and to check commands).
    fn lines(&self) -> Vec<String>;

    /// The current value of every tag matching the filters (`None` = any), as
    /// `(line, device, tag, value)`.
    fn query_tags(
        &self,
        line: Option<&str>,
        device: Option<&str>,
        tag: Option<&str>,
    ) -> Vec<(String, String, String, TagValue)>;

    /// Status of one line, `None` if there is no such line.
    fn line_status(&self, line: &str) -> Option<Value>;

    /// Status of the gateway (the bridge adds a `"zenoh"` member when it is an object).
    fn gateway_status(&self) -> Value;

    /// Sends one telegram on `line`; the result (or the error text) becomes `<line>/tx/result`.
    fn send_telegram(&self, line: &str, bytes: Vec<u8>) -> BackendFuture<Result<Value, String>>;

    /// Acknowledges the received telegram `seq` of `line` (a put on `<line>/ack`), as the
    /// mailbox's acknowledge register does; the result answers a query on the key.
    fn ack_telegram(&self, line: &str, seq: u16) -> BackendFuture<Result<Value, String>> {
        let answer = format!("line {line}: acknowledgements are not served here (seq {seq})");
        Box::pin(async move { Err(answer) })
    }

    /// Whether commands (`tx`, `set`) over zenoh are taken at all; `Err` with the text of the
    /// refusal when they are switched off. Asked in the zenoh callback before a command is
    /// queued (so it must be quick); the command methods check again when they run.
    fn writes_allowed(&self) -> Result<(), String> {
        Ok(())
    }

    /// Writes `value` to a tag, with the same checks as a Modbus TCP write; the result (or the
    /// error text) becomes `<line>/<device>/<tag>/set/result`.
    fn write_tag(
        &self,
        line: &str,
        device: &str,
        tag: &str,
        value: Value,
    ) -> BackendFuture<Result<Value, String>>;
}

/// Why the bridge did not start.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// A key of the `[zenoh]` section that zenoh refused.
    #[error("zenoh config: {0}")]
    Config(String),
    /// The zenoh config file could not be read or parsed.
    #[error("zenoh config file {path}: {reason}")]
    ConfigFile {
        /// The file.
        path: PathBuf,
        /// zenoh's message.
        reason: String,
    },
    /// The prefix or gateway name does not make a key expression.
    #[error(transparent)]
    Key(#[from] KeyError),
    /// The session did not open (peer mode).
    #[error("zenoh session: {0}")]
    Open(String),
    /// A gateway under the same key prefix is already live on the fabric (see [`fleet`]).
    #[error("gateway name {name:?} is already live on the zenoh fabric (liveliness token {key}), held by {other}: a second gateway of that name is refused; give this one another [gateway] name or [zenoh] prefix, or stop the other")]
    Duplicate {
        /// This gateway's name.
        name: String,
        /// The token (the key prefix).
        key: String,
        /// Who holds it and where it runs.
        other: String,
    },
    /// The publisher thread could not be started.
    #[error("zenoh publisher thread: {0}")]
    Thread(std::io::Error),
}

/// The running bridge. Stops when the shutdown token given to [`Bridge::start`] is cancelled;
/// [`Bridge::join`] waits for that.
#[derive(Debug)]
pub struct Bridge {
    driver: JoinHandle<()>,
    stats: Arc<BridgeStats>,
    fleet: Arc<fleet::FleetView>,
}

// === impl Bridge ===

impl Bridge {
    /// Opens the session (a client retries in the background), declares the subscribers,
    /// queryables and the gateway's liveliness token, and starts the publisher thread.
    pub async fn start(
        cfg: ZenohConfig,
        gateway_name: &str,
        backend: Arc<dyn BridgeBackend>,
        shutdown: CancellationToken,
    ) -> Result<(Self, BridgeHandle), BridgeError> {
        Self::start_counted(cfg, gateway_name, backend, shutdown, BridgeStats::new()).await
    }

    /// [`Self::start`] counting into `stats` (made with [`BridgeStats::with_metrics`] to feed the
    /// Prometheus families).
    pub async fn start_counted(
        cfg: ZenohConfig,
        gateway_name: &str,
        backend: Arc<dyn BridgeBackend>,
        shutdown: CancellationToken,
        stats: BridgeStats,
    ) -> Result<(Self, BridgeHandle), BridgeError> {
        Self::start_with(
            cfg,
            gateway_name,
            backend,
            shutdown,
            stats,
            OnDuplicate::Wait,
        )
        .await
    }

    /// [`Self::start_counted`] with what to do when another session holds the gateway's name:
    /// wait for it ([`OnDuplicate::Wait`], serving everything but zenoh meanwhile) or refuse
    /// the start ([`OnDuplicate::Exit`], `Err(BridgeError::Duplicate)`).
    pub async fn start_with(
        cfg: ZenohConfig,
        gateway_name: &str,
        backend: Arc<dyn BridgeBackend>,
        shutdown: CancellationToken,
        stats: BridgeStats,
        on_duplicate: OnDuplicate,
    ) -> Result<(Self, BridgeHandle), BridgeError> {
        let keys = Arc::new(Keys::new(&cfg.prefix_for(gateway_name)?)?);
        let (zcfg, mode) = cfg.to_zenoh()?;
        let stats = Arc::new(stats);
        let limits = Limits {
            telegrams: cfg.telegram_queue.get(),
            events: cfg.event_queue.get(),
            results: cfg.result_queue.get(),
            tags: cfg.tag_queue.get(),
            frames: FRAME_QUEUE,
        };
        let outbox = Arc::new(Outbox::new(limits, stats.clone()));

        let session = match zenoh::open(zcfg.clone()).await {
            Ok(s) => {
                if on_duplicate == OnDuplicate::Exit {
                    if let Err(e) = fleet::refuse_duplicate(&s, &keys, gateway_name).await {
                        if let Err(close) = s.close().await {
                            tracing::debug!(error = %close, "zenoh session close failed");
                        }
                        return Err(e);
                    }
                }
                Some(s)
            }
            Err(e) if mode == Mode::Client => {
                crate::warn_limited!("zenoh client not connected", error = %e, "zenoh client not connected yet, retrying in the background");
                None
            }
            Err(e) => return Err(BridgeError::Open(e.to_string())),
        };

        let thread = {
            let worker = PublisherThread::new(
                outbox.clone(),
                stats.clone(),
                presence::Presence::new(keys.gateway_token()),
            );
            std::thread::Builder::new()
                .name("zenoh-publish".to_owned())
                .spawn(move || worker.run())
                .map_err(BridgeError::Thread)?
        };

        let parts = session::Parts {
            keys: keys.clone(),
            outbox: outbox.clone(),
            stats: stats.clone(),
            backend,
            mode,
            command_queue: cfg.command_queue.get(),
            query_queue: cfg.query_queue.get(),
            max_payload: cfg.max_payload.get(),
            listen: zcfg
                .get_json("listen/endpoints")
                .ok()
                .and_then(|l| serde_json::from_str(&l).ok())
                .unwrap_or(Value::Null),
            gateway_name: gateway_name.to_owned(),
            fleet: Arc::new(fleet::FleetView::default()),
            on_duplicate,
        };
        let fleet_view = parts.fleet.clone();
        let publishing = Arc::new(Publishing::new(cfg.publish.clone()));
        let handle = BridgeHandle {
            keys,
            outbox,
            stats: stats.clone(),
            publishing,
        };
        if let Some(tick) = handle.publishing.tick() {
            crate::task::spawn(
                "zenoh heartbeats",
                handle::heartbeats(
                    handle.clone(),
                    parts.backend.clone(),
                    tick,
                    shutdown.clone(),
                ),
            );
        }
        let driver = crate::task::spawn(
            "zenoh session driver",
            session::drive(parts, session, zcfg, thread, shutdown),
        );
        Ok((
            Self {
                driver,
                stats,
                fleet: fleet_view,
            },
            handle,
        ))
    }

    /// The bridge's counters.
    pub fn stats(&self) -> &Arc<BridgeStats> {
        &self.stats
    }

    /// The other gateways of the fleet seen so far.
    pub fn fleet(&self) -> &Arc<fleet::FleetView> {
        &self.fleet
    }

    /// Waits until the bridge has stopped: shutdown cancelled, pending publications sent,
    /// tokens undeclared, session closed.
    pub async fn join(self) {
        if let Err(e) = self.driver.await {
            crate::error_limited!("zenoh bridge task failed", error = %e, "zenoh bridge task failed");
        }
    }
}

/// What a gateway does when another session holds its name (its liveliness token `<prefix>`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum OnDuplicate {
    /// Serve the lines, Modbus TCP and REST, publish nothing on zenoh, report the conflict,
    /// and take the name when it is free ([`fleet::take_name`]).
    #[default]
    Wait,
    /// Refuse the start (`gateway run --exit-on-duplicate-name`); a client that connects
    /// only later stays off the fabric.
    Exit,
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    /// A peer decides how often the bridge's paths run: no WARN or ERROR line may be written
    /// there except through the rate-limited macros (`warn_limited!`, `error_limited!`) or the
    /// audit. Checked over every source of the bridge, of its feeds and backend and of its
    /// wiring in the app.
    #[test]
    fn no_warning_without_a_rate_limit() {
        let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
        let mut files: Vec<_> = std::fs::read_dir(src.join("zenoh_bridge"))
            .expect("zenoh_bridge sources")
            .map(|e| e.expect("dir entry").path())
            .filter(|p| p.extension().is_some_and(|e| e == "rs"))
            .collect();
        files.push(src.join("app/zenoh.rs"));
        files.push(src.join("feeds/zenoh.rs"));
        files.push(src.join("feeds/zenoh_backend.rs"));
        assert!(files.len() > 5, "{files:?}");
        // Spelled in pieces so that this test does not find itself.
        let plain = [
            concat!("warn", "!"),
            concat!("error", "!"),
            concat!("Level::", "WARN"),
            concat!("Level::", "ERROR"),
        ];
        let mut found = Vec::new();
        for file in &files {
            let text = std::fs::read_to_string(file).expect("read source");
            for (n, line) in text.lines().enumerate() {
                let code = line.split("//").next().unwrap_or_default();
                if plain.iter().any(|p| code.contains(p)) {
                    found.push(format!("{}:{}: {}", file.display(), n + 1, line.trim()));
                }
            }
        }
        assert!(
            found.is_empty(),
            "warnings without a rate limit (use crate::warn_limited! or crate::error_limited!):\n{}",
            found.join("\n")
        );
    }

    #[test]
    fn a_tag_without_a_unit_has_an_empty_unit_as_in_rest() {
        let mut value = super::TagValue {
            value: serde_json::json!(1),
            unit: None,
            quality: "good",
            timestamp: std::time::SystemTime::UNIX_EPOCH,
            description: None,
        };
        assert_eq!(value.to_json()["unit"], "");
        value.unit = Some("rpm".to_owned());
        assert_eq!(value.to_json()["unit"], "rpm");
    }
}
