//! The zenoh bridge wired to the running gateway: the bridge opened with its backend over the
//! supervisor ([`crate::feeds::zenoh_backend`], queries and commands from the fabric), and the
//! start of the feeds that publish (tag values on change, events, received telegrams, device
//! presence: [`crate::feeds::zenoh`]).
//!
//! Lines come and go with configuration changes: the feeds of one line (its events, its
//! telegrams) run under that line's token and stop with it; a line started later gets its own.

use std::sync::{Arc, PoisonError};

use tokio_util::sync::CancellationToken;
use tracing::info;

use super::supervisor::{Follower, Snapshot, Supervisor, ZenohState};
use super::AppError;
use crate::api::BoxFuture;
use crate::feeds::zenoh as feeds;
use crate::feeds::zenoh_backend::ZenohBackend;
use crate::zenoh_bridge::{
    Bridge, BridgeError, BridgeHandle, BridgeStats, OnDuplicate, ZenohConfig,
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
    let backend = ZenohBackend::new(Arc::downgrade(sup) as _);
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
