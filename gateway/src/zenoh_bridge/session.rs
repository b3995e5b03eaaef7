//! The life of the bridge's session: opened (a client retries in the background), the fleet
//! followed, the name taken, the subscribers, queryables and token declared once the name is
//! ours, and at shutdown the pending publications sent, the tokens undeclared and the session
//! closed.

use std::sync::Arc;
use std::time::Duration;

use serde_json::{json, Value};
use tokio_util::sync::CancellationToken;
use zenoh::pubsub::Subscriber;
use zenoh::query::Queryable;
use zenoh::Session;

use super::publish::Outbox;
use super::queryable::{self, Answerer, Queries, QueryKind};
use super::subscribe::{self, Commands, CommandsConfig};
use super::{fleet, BridgeBackend, BridgeStats, Keys, Mode, OnDuplicate};

/// First wait before a client retries opening its session.
const RETRY_MIN: Duration = Duration::from_secs(1);
/// Longest wait between retries.
const RETRY_MAX: Duration = Duration::from_secs(30);

/// What the driver task needs.
pub(super) struct Parts {
    pub(super) keys: Arc<Keys>,
    pub(super) outbox: Arc<Outbox>,
    pub(super) stats: Arc<BridgeStats>,
    pub(super) backend: Arc<dyn BridgeBackend>,
    pub(super) mode: Mode,
    pub(super) command_queue: usize,
    pub(super) query_queue: usize,
    pub(super) max_payload: usize,
    /// The listen endpoints in force (JSON list), for the gateway status.
    pub(super) listen: Value,
    pub(super) gateway_name: String,
    pub(super) fleet: Arc<fleet::FleetView>,
    pub(super) on_duplicate: OnDuplicate,
}

/// The subscribers and queryables; dropping them undeclares them.
struct Declared {
    _subscribers: Vec<Subscriber<()>>,
    _queryables: Vec<Queryable<()>>,
}

pub(super) async fn drive(
    parts: Parts,
    session: Option<Session>,
    zcfg: zenoh::Config,
    thread: std::thread::JoinHandle<()>,
    shutdown: CancellationToken,
) {
    let session = match session {
        Some(s) => Some(s),
        None => match open_with_retry(zcfg, &shutdown).await {
            // A client that connected late checks the fleet then; refused, it stays off the
            // fabric (the process runs on: its lines, Modbus TCP and REST are not zenoh's).
            Some(s) if parts.on_duplicate == OnDuplicate::Exit => {
                match fleet::refuse_duplicate(&s, &parts.keys, &parts.gateway_name).await {
                    Ok(()) => Some(s),
                    Err(e) => {
                        crate::error_limited!("zenoh duplicate gateway", error = %e, "zenoh: this gateway stays off the fabric");
                        if let Err(close) = s.close().await {
                            tracing::debug!(error = %close, "zenoh session close failed");
                        }
                        None
                    }
                }
            }
            other => other,
        },
    };
    let mut declared = None;
    if let Some(session) = &session {
        parts.stats.set_session_open(true);
        // The fleet is followed whoever holds this gateway's name.
        crate::task::spawn(
            "zenoh fleet follow",
            fleet::follow(
                session.clone(),
                parts.keys.clone(),
                parts.fleet.clone(),
                shutdown.clone(),
            ),
        );
        // Publications, queryables, subscribers and the token only once the name is ours.
        let ours = parts.on_duplicate == OnDuplicate::Exit
            || fleet::take_name(
                session,
                &parts.keys,
                &parts.gateway_name,
                &parts.stats,
                &shutdown,
            )
            .await;
        if ours {
            match declare(&parts, session, &shutdown).await {
                Ok(d) => declared = Some(d),
                Err(e) => {
                    crate::error_limited!("zenoh declare failed", error = %e, "zenoh subscribers and queryables not declared")
                }
            }
            parts.outbox.push_presence(parts.keys.gateway_token(), true);
            parts.outbox.set_session(session.clone());
            tracing::info!(zid = %session.zid(), prefix = parts.keys.prefix(), mode = parts.mode.as_str(), "zenoh session open");
            shutdown.cancelled().await;
        }
    }
    // Stop taking commands and queries, publish what is pending, undeclare the tokens (the
    // publisher thread does both), then close the session.
    drop(declared);
    parts.outbox.close();
    if tokio::task::spawn_blocking(move || thread.join())
        .await
        .is_err()
    {
        crate::error_limited!(
            "zenoh publisher thread panicked",
            "zenoh publisher thread panicked"
        );
    }
    if let Some(session) = session {
        if let Err(e) = session.close().await {
            crate::warn_limited!("zenoh session close failed", error = %e, "zenoh session close failed");
        }
    }
    parts.stats.set_session_open(false);
    parts.stats.set_name_conflict(None);
    tracing::info!("zenoh bridge stopped");
}

/// Opens a client session, retrying with back-off; `None` on shutdown.
async fn open_with_retry(zcfg: zenoh::Config, shutdown: &CancellationToken) -> Option<Session> {
    let mut wait = RETRY_MIN;
    loop {
        tokio::select! {
            () = tokio::time::sleep(wait) => {}
            () = shutdown.cancelled() => return None,
        }
        match zenoh::open(zcfg.clone()).await {
            Ok(s) => return Some(s),
            Err(e) => {
                crate::warn_limited!("zenoh client not connected", error = %e, retry_in = ?wait, "zenoh client still not connected");
            }
        }
        wait = (wait * 2).min(RETRY_MAX);
    }
}

async fn declare(
    parts: &Parts,
    session: &Session,
    shutdown: &CancellationToken,
) -> zenoh::Result<Declared> {
    let keys = &parts.keys;
    let (commands, command_rx) = Commands::new(
        keys.clone(),
        parts.outbox.clone(),
        parts.stats.clone(),
        parts.backend.clone(),
        &CommandsConfig {
            capacity: parts.command_queue,
            max_payload: parts.max_payload,
        },
        tokio::runtime::Handle::current(),
    );
    crate::task::spawn(
        "zenoh subscriber dispatch",
        subscribe::dispatch(
            commands.clone(),
            command_rx,
            parts.backend.clone(),
            shutdown.clone(),
        ),
    );
    let (queries, query_rx) =
        Queries::new(parts.stats.clone(), parts.query_queue, parts.max_payload);
    let answerer = Arc::new(Answerer {
        keys: keys.clone(),
        backend: parts.backend.clone(),
        stats: parts.stats.clone(),
        identity: json!({
            "zid": session.zid().to_string(),
            "prefix": keys.prefix(),
            "mode": parts.mode.as_str(),
            "listen": parts.listen,
        }),
    });
    crate::task::spawn(
        "zenoh queryable",
        queryable::serve(answerer, query_rx, shutdown.clone()),
    );

    let mut subscribers = Vec::new();
    for key in [keys.tx_pattern(), keys.set_pattern(), keys.ack_pattern()] {
        let commands = commands.clone();
        let sub = session
            .declare_subscriber(key)
            .callback(move |sample| commands.on_sample(&sample))
            .await?;
        subscribers.push(sub);
    }
    let mut queryables = Vec::new();
    for key in [keys.tx_pattern(), keys.set_pattern(), keys.ack_pattern()] {
        let commands = commands.clone();
        let q = session
            .declare_queryable(key)
            .callback(move |query| commands.on_query(query))
            .await?;
        queryables.push(q);
    }
    for (key, kind) in [
        (keys.tag_pattern(), QueryKind::Tags),
        (keys.history_pattern(), QueryKind::History),
        (keys.line_status_pattern(), QueryKind::LineStatus),
        (keys.gateway_status(), QueryKind::GatewayStatus),
    ] {
        let queries = queries.clone();
        let q = session
            .declare_queryable(key)
            .complete(true)
            .callback(move |query| queries.on_query(kind, query))
            .await?;
        queryables.push(q);
    }
    Ok(Declared {
        _subscribers: subscribers,
        _queryables: queryables,
    })
}
