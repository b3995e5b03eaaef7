//! The zenoh bridge wired to the running gateway: the backend that answers queries and commands
//! from the supervisor's snapshot (image, tags, lines), and the tasks that feed publications
//! (tag values on change, events, received telegrams, device presence).
//!
//! Lines come and go with configuration changes: the feeds of one line (its events, its
//! telegrams) run under that line's token and stop with it; a line started later gets its own.
//! A write from zenoh takes the same path and checks as a Modbus TCP write ([`super::tag_io`]).

use crate::line::telegram::TelegramSendError;
use crate::mailbox::AckMode;
use std::collections::BTreeSet;
use std::sync::{Arc, PoisonError, Weak};
use std::time::Duration;

use proto_core::event;
use proto_core::profiles::Value;
use serde_json::{json, Value as Json};
use tokio::sync::broadcast::error::RecvError;
use tokio_util::sync::CancellationToken;
use tracing::{debug, info};

use super::lines::RunningLine;
use super::status::line_view;
use super::supervisor::{Follower, Snapshot, Supervisor, ZenohState};
use super::tag_io::{self, WriteRefused};
use super::AppError;
use crate::api::model::ScalarValue;
use crate::api::BoxFuture;
use crate::image::ProcessImage;
use crate::line::LineEvent;
use crate::tags::{TagDirectory, TagEntry, TagWriteError};
use crate::zenoh_bridge::accounting::{self, WriteReason};
use crate::zenoh_bridge::{
    BackendFuture, Bridge, BridgeBackend, BridgeError, BridgeHandle, BridgeStats, DropReason,
    OnDuplicate, TagValue, ZenohConfig,
};

/// How often device presence is compared with the last published state.
const PRESENCE_PERIOD: Duration = Duration::from_millis(500);

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
        spawn_line_feeds(&handle, name, line, &token);
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
            spawn_line_feeds(&run.handle, name, line, &run.token);
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
                let value = tag_value(&snapshot.tags, &sup.image, e)?;
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

/// A tag's value as the bridge publishes it.
fn tag_value(tags: &TagDirectory, image: &ProcessImage, entry: &TagEntry) -> Option<TagValue> {
    let reading = tags.read(image, entry)?;
    let value = json!(ScalarValue::from(reading.value));
    let unit = (!reading.unit.is_empty()).then_some(reading.unit);
    Some(TagValue {
        value,
        unit,
        quality: reading.quality,
        timestamp: reading.timestamp,
        description: (!entry.description().is_empty()).then(|| entry.description().to_owned()),
    })
}

/// The feeds of the whole gateway: tag values on change (every image change maps to the tags
/// it overlaps in the directory in force) and device presence.
fn spawn_feeds(sup: &Arc<Supervisor>, bridge: &BridgeHandle, token: &CancellationToken) {
    {
        let bridge = bridge.clone();
        let weak = Arc::downgrade(sup);
        let image = sup.image.clone();
        let mut changes = image.subscribe();
        let token = token.clone();
        tokio::spawn(async move {
            loop {
                let change = tokio::select! {
                    () = token.cancelled() => return,
                    change = changes.recv() => change,
                };
                match change {
                    Ok(change) => {
                        let Some(sup) = weak.upgrade() else { return };
                        let tags = Arc::clone(&sup.snapshot().tags);
                        let count = u16::try_from(change.values.len()).unwrap_or(u16::MAX);
                        for entry in
                            tags.overlapping(change.unit, change.table, change.start, count)
                        {
                            if let Some(value) = tag_value(&tags, &image, entry) {
                                bridge.publish_tag(
                                    entry.line(),
                                    entry.device(),
                                    entry.name(),
                                    value,
                                );
                            }
                        }
                    }
                    Err(RecvError::Lagged(n)) => {
                        // The newest values follow; publishing skipped ones would be stale.
                        bridge.stats().dropped_many(DropReason::FeedLagged, n);
                        debug!(
                            skipped = n,
                            "zenoh feed fell behind the image; newest values win"
                        );
                    }
                    Err(RecvError::Closed) => return,
                }
            }
        });
    }
    // Presence: a liveliness token per line whose port is open and per online device, of the
    // lines in force.
    let bridge = bridge.clone();
    let weak = Arc::downgrade(sup);
    let token = token.clone();
    tokio::spawn(async move {
        let mut online: BTreeSet<(String, String)> = BTreeSet::new();
        let mut open: BTreeSet<String> = BTreeSet::new();
        let mut ticker = tokio::time::interval(PRESENCE_PERIOD);
        loop {
            tokio::select! {
                () = token.cancelled() => return,
                _ = ticker.tick() => {}
            }
            let Some(sup) = weak.upgrade() else { return };
            let mut now: BTreeSet<(String, String)> = BTreeSet::new();
            let mut open_now: BTreeSet<String> = BTreeSet::new();
            for line in sup.snapshot().lines.values() {
                let status = line.handle.status();
                if status.port_open {
                    open_now.insert(status.name.clone());
                }
                for d in status.devices.iter().filter(|d| d.online) {
                    now.insert((status.name.clone(), d.name.clone()));
                }
            }
            for key in online.difference(&now) {
                bridge.device_online(&key.0, &key.1, false);
            }
            for line in open.difference(&open_now) {
                bridge.line_online(line, false);
            }
            for line in open_now.difference(&open) {
                bridge.line_online(line, true);
            }
            open = open_now;
            for key in now.difference(&online) {
                bridge.device_online(&key.0, &key.1, true);
            }
            online = now;
        }
    });
}

/// The feeds of one line: its events and its received telegrams (in order, each once; the
/// bridge's queue counts what it must drop). They end with the line or the bridge.
fn spawn_line_feeds(
    bridge: &BridgeHandle,
    name: &str,
    line: &RunningLine,
    token: &CancellationToken,
) {
    let mut events = line.handle.subscribe_events();
    {
        let bridge = bridge.clone();
        let (token, line_token) = (token.clone(), line.token.clone());
        tokio::spawn(async move {
            loop {
                let received = tokio::select! {
                    () = token.cancelled() => return,
                    () = line_token.cancelled() => return,
                    e = events.recv() => e,
                };
                match received {
                    Ok(e) => publish_event(&bridge, &e),
                    Err(RecvError::Lagged(n)) => {
                        bridge.stats().dropped_many(DropReason::FeedLagged, n);
                        crate::warn_limited!(
                            "zenoh event feed lagged",
                            missed = n,
                            "zenoh event feed fell behind a line"
                        );
                    }
                    Err(RecvError::Closed) => return,
                }
            }
        });
    }
    if let Some(monitor) = line.handle.monitor() {
        spawn_frame_feed(bridge, Arc::clone(monitor), token, &line.token);
    }
    let Some(mut rx) = line.handle.subscribe_rx() else {
        return;
    };
    if let Some(mailbox) = line
        .handle
        .mailbox()
        .filter(|m| m.settings().ack == AckMode::OnPublish)
    {
        spawn_on_publish_feed(bridge, mailbox, rx, token, &line.token);
        return;
    }
    let bridge = bridge.clone();
    let (token, line_token) = (token.clone(), line.token.clone());
    let name = name.to_owned();
    tokio::spawn(async move {
        loop {
            let received = tokio::select! {
                () = token.cancelled() => return,
                () = line_token.cancelled() => return,
                t = rx.recv() => t,
            };
            match received {
                Ok(t) => {
                    let data = t.data.to_vec();
                    if bridge
                        .publish_telegram_from(
                            &t.line,
                            u64::from(t.seq),
                            t.received,
                            t.side.map(proto_core::proc3964::tap::Side::as_str),
                            data,
                        )
                        .is_err()
                    {
                        debug!(line = %t.line, seq = t.seq, "zenoh telegram queue full; the drop is counted");
                    }
                }
                Err(RecvError::Lagged(n)) => {
                    bridge.stats().dropped_many(DropReason::FeedLagged, n);
                    crate::warn_limited!(format!("zenoh telegram feed lagged {name}"), line = %name, missed = n, "zenoh telegram feed fell behind a line; the telegrams stay in the mailbox");
                }
                Err(RecvError::Closed) => return,
            }
        }
    });
}

/// How long the feed of a line acknowledged on publication waits before it offers a telegram
/// again that zenoh did not take (its queue full, a put that failed).
const ON_PUBLISH_RETRY: Duration = Duration::from_millis(100);

/// `<prefix>/<line>/rx` of a line with `ack = "on-publish"`: the mailbox's waiting telegrams,
/// oldest first, each acknowledged once zenoh took its put (so a telegram the journal restored
/// is published after a restart, and one zenoh did not take waits and is offered again). The
/// broadcast of received telegrams only wakes the feed.
fn spawn_on_publish_feed(
    bridge: &BridgeHandle,
    mailbox: Arc<crate::mailbox::Mailbox>,
    mut arrivals: tokio::sync::broadcast::Receiver<crate::mailbox::TelegramRx>,
    token: &CancellationToken,
    line_token: &CancellationToken,
) {
    let bridge = bridge.clone();
    let (token, line_token) = (token.clone(), line_token.clone());
    tokio::spawn(async move {
        loop {
            while let Some(t) = mailbox.head() {
                let pushed = bridge.publish_telegram_confirmed(
                    &t.line,
                    u64::from(t.seq),
                    t.received,
                    t.data.to_vec(),
                );
                let taken = match pushed {
                    Ok(done) => tokio::select! {
                        () = token.cancelled() => return,
                        () = line_token.cancelled() => return,
                        ok = done => ok.unwrap_or(false),
                    },
                    Err(DropReason::BridgeClosed) => return,
                    Err(_) => false,
                };
                if taken {
                    // A client may have acknowledged it meanwhile: either way it is done.
                    let _ = mailbox.ack(t.seq);
                } else {
                    tokio::select! {
                        () = token.cancelled() => return,
                        () = line_token.cancelled() => return,
                        () = tokio::time::sleep(ON_PUBLISH_RETRY) => {}
                    }
                }
            }
            let arrived = tokio::select! {
                () = token.cancelled() => return,
                () = line_token.cancelled() => return,
                t = arrivals.recv() => t,
            };
            if let Err(RecvError::Closed) = arrived {
                return;
            }
        }
    });
}

/// `<prefix>/<line>/frames`: every frame of the line's monitor, as the REST API shows it. The
/// copy of each frame is made only while this feed listens (the bridge is on).
fn spawn_frame_feed(
    bridge: &BridgeHandle,
    monitor: Arc<crate::line::FrameMonitor>,
    token: &CancellationToken,
    line_token: &CancellationToken,
) {
    let mut frames = monitor.subscribe();
    let bridge = bridge.clone();
    let (token, line_token) = (token.clone(), line_token.clone());
    tokio::spawn(async move {
        let ended = monitor.ended();
        tokio::pin!(ended);
        loop {
            let received = tokio::select! {
                () = token.cancelled() => return,
                () = line_token.cancelled() => return,
                () = &mut ended => return,
                f = frames.recv() => f,
            };
            match received {
                Ok(frame) => {
                    let view = crate::api::model::FrameView::new(&monitor, &frame);
                    let json = serde_json::to_vec(&view).unwrap_or_default();
                    if bridge.publish_frame(monitor.line(), json).is_err() {
                        debug!(line = %monitor.line(), seq = frame.seq, "zenoh frame queue full; the drop is counted");
                    }
                }
                Err(RecvError::Lagged(n)) => {
                    monitor.count_lagged(n);
                    bridge.stats().dropped_many(DropReason::FeedLagged, n);
                }
                Err(RecvError::Closed) => return,
            }
        }
    });
}

fn publish_event(bridge: &BridgeHandle, e: &LineEvent) {
    let name = event::class_name(e.id.class).unwrap_or("unknown");
    let text = event::lookup(e.id).map_or("", |i| i.description);
    if bridge
        .publish_event(&e.line, e.id.class, e.id.number, name, text)
        .is_err()
    {
        debug!(line = %e.line, event = %e.id, "zenoh event queue full; the drop is counted");
    }
}
