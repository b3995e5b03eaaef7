//! The zenoh bridge wired to the running gateway: the backend that answers queries and commands
//! from the supervisor's snapshot (image, tags, lines), and the start of the feeds that publish
//! (tag values on change, events, received telegrams, device presence: [`crate::feeds::zenoh`]).
//!
//! Lines come and go with configuration changes: the feeds of one line (its events, its
//! telegrams) run under that line's token and stop with it; a line started later gets its own.
//! A write from zenoh takes the same path and checks as a Modbus TCP write ([`super::tag_io`]).

use crate::protocols::telegram::TelegramSendError;
use std::sync::{Arc, PoisonError, Weak};

use proto_core::profiles::Value;
use serde_json::{json, Value as Json};
use tokio_util::sync::CancellationToken;
use tracing::info;

use super::status::line_view;
use super::supervisor::{Follower, Snapshot, Supervisor, ZenohState};
use super::tag_io::{self, WriteRefused};
use super::AppError;
use crate::api::model::ScalarValue;
use crate::api::BoxFuture;
use crate::feeds::zenoh as feeds;
use crate::tags::TagWriteError;
use crate::zenoh_bridge::accounting::{self, WriteReason};
use crate::zenoh_bridge::{
    BackendFuture, Bridge, BridgeBackend, BridgeError, BridgeHandle, BridgeStats, OnDuplicate,
    TagValue, ZenohConfig,
};

/// A running bridge.
struct ZenohRun {
    bridge: Bridge,
    handle: BridgeHandle,
    token: CancellationToken,
}

/// The bridge as the supervisor's follower: it holds the running bridge, if any.
#[derive(Default)]
struct ZenohFollower {
    run: tokio::sync::Mutex<Option<ZenohRun>>,
}

impl Follower for ZenohFollower {
    fn lines_started<'a>(
        &'a self,
        snapshot: &'a Snapshot,
        names: &'a [String],
    ) -> BoxFuture<'a, ()> {
        Box::pin(lines_started(self, snapshot, names))
    }

    fn renamed<'a>(&'a self, sup: &'a Arc<Supervisor>) -> BoxFuture<'a, bool> {
        Box::pin(restart(self, sup))
    }

    fn stop<'a>(&'a self, sup: &'a Supervisor) -> BoxFuture<'a, ()> {
        Box::pin(stop(self, sup))
    }
}

/// The bridge's session settings: the command line's endpoint (with the config's prefix and
/// publishing policy), or the config's `[zenoh]`; `None` when the gateway joins no zenoh fabric.
fn session_config(sup: &Supervisor, snapshot: &Snapshot) -> Result<Option<ZenohConfig>, AppError> {
    Ok(
        match (&sup.overrides.zenoh_listen, &snapshot.config.zenoh) {
            (Some(endpoint), base) => {
                let mut cfg = ZenohConfig::loopback_peer(endpoint).map_err(AppError::Setup)?;
                if let Some(base) = base {
                    cfg.prefix.clone_from(&base.prefix);
                    cfg.publish.clone_from(&base.publish);
                }
                Some(cfg)
            }
            (None, Some(cfg)) if cfg.enabled => Some(cfg.clone()),
            (None, _) => None,
        },
    )
}

/// Starts the bridge when the config has a `[zenoh]` section (or the command line names an
/// endpoint), with its feeds, and makes it follow the supervisor's lines.
pub(crate) async fn start(sup: &Arc<Supervisor>) -> Result<(), AppError> {
    let follower = Arc::new(ZenohFollower::default());
    open(&follower, sup).await?;
    if sup.follow(follower).is_err() {
        return Err(AppError::Setup(
            "zenoh: the bridge was started twice".into(),
        ));
    }
    Ok(())
}

/// Opens the session and starts the feeds.
async fn open(follower: &ZenohFollower, sup: &Arc<Supervisor>) -> Result<(), AppError> {
    let snapshot = sup.snapshot();
    let Some(cfg) = session_config(sup, &snapshot)? else {
        info!("no [zenoh] section: the gateway joins no zenoh fabric");
        return Ok(());
    };
    let mode = cfg.mode.map_or("peer", |m| m.as_str());
    *sup.zenoh_state
        .lock()
        .unwrap_or_else(PoisonError::into_inner) = Some(ZenohState {
        stats: None,
        mode,
        fleet: None,
    });
    let listen = cfg.listen.clone().unwrap_or_default();
    let token = sup.root.child_token();
    let backend = ZenohBackend {
        sup: Arc::downgrade(sup),
    };
    let on_duplicate = if sup.overrides.exit_on_duplicate_name {
        OnDuplicate::Exit
    } else {
        OnDuplicate::Wait
    };
    let (bridge, handle) = Bridge::start_with(
        cfg,
        &snapshot.config.gateway.name,
        Arc::new(backend),
        token.clone(),
        BridgeStats::with_metrics(
            sup.exported.metrics.zenoh().clone(),
            sup.exported.metrics.audit().clone(),
        ),
        on_duplicate,
    )
    .await
    .map_err(|e| match e {
        BridgeError::Duplicate { .. } => AppError::Refused(format!("zenoh: {e}")),
        e => AppError::Setup(format!("zenoh: {e}")),
    })?;
    spawn_feeds(sup, &handle, &token);
    for (name, line) in &snapshot.lines {
        feeds::spawn_line_feeds(&handle, name, &line.handle, &line.token, &token);
    }
    let endpoints: Vec<&str> = listen
        .iter()
        .map(crate::zenoh_bridge::Endpoint::as_str)
        .collect();
    info!(prefix = %handle.prefix(), ?endpoints, "zenoh session open");
    println!("zenoh session open, prefix {}", handle.prefix());
    *sup.zenoh_state
        .lock()
        .unwrap_or_else(PoisonError::into_inner) = Some(ZenohState {
        stats: Some(Arc::clone(bridge.stats())),
        mode,
        fleet: Some(Arc::clone(bridge.fleet())),
    });
    *follower.run.lock().await = Some(ZenohRun {
        bridge,
        handle,
        token,
    });
    Ok(())
}

/// Stops the bridge: pending publications sent, tokens undeclared, session closed.
async fn stop(follower: &ZenohFollower, sup: &Supervisor) {
    let run = follower.run.lock().await.take();
    if let Some(run) = run {
        run.token.cancel();
        run.bridge.join().await;
    }
    if let Some(state) = sup
        .zenoh_state
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .as_mut()
    {
        state.stats = None;
        state.fleet = None;
    }
}

/// Restarts a running bridge under the gateway's new name (its key prefix); whether it runs
/// again.
async fn restart(follower: &ZenohFollower, sup: &Arc<Supervisor>) -> bool {
    if follower.run.lock().await.is_none() {
        return false;
    }
    stop(follower, sup).await;
    match open(follower, sup).await {
        Ok(()) => true,
        Err(e) => {
            crate::warn_limited!("zenoh did not restart", error = %e, "zenoh did not restart");
            false
        }
    }
}

/// Starts the feeds of lines started by a configuration change.
async fn lines_started(follower: &ZenohFollower, snapshot: &Snapshot, names: &[String]) {
    let run = follower.run.lock().await;
    let Some(run) = run.as_ref() else { return };
    for name in names {
        if let Some(line) = snapshot.lines.get(name) {
            feeds::spawn_line_feeds(&run.handle, name, &line.handle, &line.token, &run.token);
        }
    }
}

/// What the bridge asks of the gateway.
struct ZenohBackend {
    sup: Weak<Supervisor>,
}

impl BridgeBackend for ZenohBackend {
    fn lines(&self) -> Vec<String> {
        self.sup
            .upgrade()
            .map(|s| s.snapshot().lines.keys().cloned().collect())
            .unwrap_or_default()
    }

    fn query_tags(
        &self,
        line: Option<&str>,
        device: Option<&str>,
        tag: Option<&str>,
    ) -> Vec<(String, String, String, TagValue)> {
        let Some(sup) = self.sup.upgrade() else {
            return Vec::new();
        };
        let snapshot = sup.snapshot();
        snapshot
            .tags
            .iter()
            .filter(|e| line.is_none_or(|l| l == e.line()))
            .filter(|e| device.is_none_or(|d| d == e.device()))
            .filter(|e| tag.is_none_or(|t| t.eq_ignore_ascii_case(e.name())))
            .filter_map(|e| {
                let value = feeds::tag_value(&snapshot.tags, &sup.image, e)?;
                Some((
                    e.line().to_owned(),
                    e.device().to_owned(),
                    e.name().to_owned(),
                    value,
                ))
            })
            .collect()
    }

    /// The line's view, as REST's `GET /api/v1/lines/{line}` answers it.
    fn line_status(&self, line: &str) -> Option<Json> {
        let sup = self.sup.upgrade()?;
        let snapshot = sup.snapshot();
        let running = snapshot.lines.get(line)?;
        serde_json::to_value(line_view(line, running)).ok()
    }

    fn gateway_status(&self) -> Json {
        self.sup
            .upgrade()
            .map_or_else(|| json!({}), |sup| super::fleet::gateway_status(&sup))
    }

    fn writes_allowed(&self) -> Result<(), String> {
        let on = self.sup.upgrade().is_some_and(|sup| {
            sup.snapshot()
                .config
                .zenoh
                .as_ref()
                .is_some_and(|z| z.writes)
        });
        if on {
            Ok(())
        } else {
            Err("writes over zenoh are off ([zenoh] writes = false)".to_owned())
        }
    }

    fn send_telegram(&self, line: &str, bytes: Vec<u8>) -> BackendFuture<Result<Json, String>> {
        let metrics = self.metrics();
        let target = format!("{line}/tx ({} bytes)", bytes.len());
        if let Err(e) = self.writes_allowed() {
            accounting::refused(metrics.as_ref(), &target, WriteReason::WritesOff, &e);
            return Box::pin(async move { Err(e) });
        }
        let client = self
            .sup
            .upgrade()
            .and_then(|s| s.snapshot().lines.get(line)?.handle.telegram_client());
        let Some(client) = client else {
            let answer = format!("line {line} does not send telegrams");
            accounting::refused(metrics.as_ref(), &target, WriteReason::Policy, &answer);
            return Box::pin(async move { Err(answer) });
        };
        Box::pin(async move {
            let len = bytes.len();
            match client.send(bytes).await {
                Ok(()) => {
                    accounting::finished(metrics.as_ref(), &target, true, &"sent");
                    Ok(json!({ "sent": len }))
                }
                Err(e) => {
                    let refused = matches!(
                        e,
                        TelegramSendError::NotAllowed { .. } | TelegramSendError::ListenOnly { .. }
                    );
                    let e = e.to_string();
                    if refused {
                        accounting::refused(metrics.as_ref(), &target, WriteReason::Policy, &e);
                    } else {
                        accounting::finished(metrics.as_ref(), &target, false, &e);
                    }
                    Err(e)
                }
            }
        })
    }

    fn ack_telegram(&self, line: &str, seq: u16) -> BackendFuture<Result<Json, String>> {
        let metrics = self.metrics();
        let target = format!("{line}/telegrams/{seq} ack");
        if let Err(e) = self.writes_allowed() {
            accounting::refused(metrics.as_ref(), &target, WriteReason::WritesOff, &e);
            return Box::pin(async move { Err(e) });
        }
        let mailbox = self
            .sup
            .upgrade()
            .and_then(|s| s.snapshot().lines.get(line)?.handle.mailbox());
        let Some(mailbox) = mailbox else {
            let answer = format!("line {line} does not receive telegrams");
            accounting::refused(
                metrics.as_ref(),
                &target,
                WriteReason::UnknownTarget,
                &answer,
            );
            return Box::pin(async move { Err(answer) });
        };
        let answer = match mailbox.ack(seq) {
            Ok(()) => {
                accounting::finished(metrics.as_ref(), &target, true, &"acknowledged");
                Ok(json!({ "acknowledged": seq }))
            }
            Err(e) => {
                let e = e.to_string();
                accounting::refused(metrics.as_ref(), &target, WriteReason::Policy, &e);
                Err(e)
            }
        };
        Box::pin(async move { answer })
    }

    fn write_tag(
        &self,
        line: &str,
        device: &str,
        tag: &str,
        value: Json,
    ) -> BackendFuture<Result<Json, String>> {
        let prepared = self
            .writes_allowed()
            .map_err(|e| (WriteReason::WritesOff, e))
            .and_then(|()| self.prepare_write(line, device, tag, &value));
        let metrics = self.metrics();
        let target = format!("{line}/{device}/{tag} = {value}");
        Box::pin(async move {
            let (write, name) = match prepared {
                Ok(prepared) => prepared,
                Err((reason, e)) => {
                    accounting::refused(metrics.as_ref(), &target, reason, &e);
                    return Err(e);
                }
            };
            match write.send().await {
                Ok(_) => {
                    accounting::finished(metrics.as_ref(), &target, true, &"ok");
                    Ok(json!({ "tag": name, "written": value }))
                }
                Err(code) => {
                    let e = TagWriteError::Exception(code).to_string();
                    accounting::finished(metrics.as_ref(), &target, false, &e);
                    Err(e)
                }
            }
        })
    }
}

impl ZenohBackend {
    /// The Prometheus families, while the gateway runs.
    /// The audit's family the bridge's commands are counted in (while the gateway runs).
    fn metrics(&self) -> Option<crate::audit::AuditMetrics> {
        self.sup
            .upgrade()
            .map(|sup| sup.exported.metrics.audit().clone())
    }

    /// The checked write of a JSON value, or why there is none (and which check refused it).
    fn prepare_write(
        &self,
        line: &str,
        device: &str,
        tag: &str,
        value: &Json,
    ) -> Result<(tag_io::PreparedWrite, String), (WriteReason, String)> {
        let sup = self
            .sup
            .upgrade()
            .ok_or((WriteReason::Policy, "the gateway is stopping".to_owned()))?;
        let value = json_value(value).ok_or_else(|| {
            (
                WriteReason::BadPayload,
                format!(
                    "value {value} is not a number, a bool or a text (send JSON: 4.5, true, \"SN-1\")"
                ),
            )
        })?;
        let write = tag_io::prepare_write(&sup.snapshot(), &sup.units, line, device, tag, &value)
            .map_err(|e| {
            let reason = match e {
                WriteRefused::Tag(TagWriteError::UnknownTag(_)) => WriteReason::UnknownTarget,
                _ => WriteReason::Policy,
            };
            (reason, e.to_string())
        })?;
        let name = format!("{line}/{device}/{}", write.entry.name());
        Ok((write, name))
    }
}

/// The value of a tag write sent as JSON: a number (whole numbers exact up to 64 bits), a bool,
/// a string, or an object with one of them under `value`.
fn json_value(value: &Json) -> Option<Value> {
    let scalar = match value {
        Json::Object(o) => o.get("value").filter(|v| !v.is_object())?,
        other => other,
    };
    // As a REST tag write reads its `value`.
    let scalar: ScalarValue = serde_json::from_value(scalar.clone()).ok()?;
    Some(scalar.into())
}

/// The feeds of the whole gateway ([`crate::feeds::zenoh`]): tag values on change, from the
/// tag directory in force, and the presence of the lines in force and their devices.
fn spawn_feeds(sup: &Arc<Supervisor>, bridge: &BridgeHandle, token: &CancellationToken) {
    let weak = Arc::downgrade(sup);
    let tags = move || weak.upgrade().map(|sup| Arc::clone(&sup.snapshot().tags));
    feeds::spawn_tag_feed(bridge, sup.image.clone(), tags, token);
    let weak = Arc::downgrade(sup);
    let statuses = move || {
        weak.upgrade().map(|sup| {
            let snapshot = sup.snapshot();
            snapshot.lines.values().map(|l| l.handle.status()).collect()
        })
    };
    feeds::spawn_presence_feed(bridge, statuses, token);
}
