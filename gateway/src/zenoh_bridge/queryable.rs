//! Queryables: tag values from the image (`<prefix>/<line>/<device>/<tag>`, wildcards work), line
//! status (`<prefix>/<line>/status`) and gateway status (`<prefix>/status`).
//!
//! Current values for late subscribers: zenoh-ext's advanced subscriber with history asks
//! `<its key expression>/@adv/**` for the samples the advanced publishers under it keep in their
//! caches, and accepts replies under any key. One queryable on `<prefix>/*/*/*/@adv/**` answers
//! that query with the current value of every tag the subscriber's key expression matches, from
//! the image: the same as a cache of depth 1 in front of every tag, without a declared publisher,
//! queryable and cache per tag (a declared publisher alone costs about 3 KiB of routing state, 35
//! MiB for 10 000 tags). The replies carry no zenoh timestamp and no source sequence number, so
//! the subscriber delivers them at once, before the live samples that arrived during the query;
//! `max_samples` is met by the one current value per tag, and a subscriber's `max_age` is not
//! applied (a tag's age is in its JSON `timestamp`). Plain subscribers see nothing of this.
//!
//! The zenoh callback only queues the query (bounded; a full queue leaves the query without a
//! reply and counts `query_queue_full`; a query whose payload is over `[zenoh] max_payload`
//! gets no reply either and counts `query_too_large`; both warnings are rate-limited). One task serves the queue; each query is answered on
//! the blocking pool, since the backend reads the image under a lock and a reply may wait under
//! congestion. A wildcard query asks the backend for the tags its literal chunks name (see
//! [`Keys::tag_filter`]) and replies with every tag whose key intersects the query.
//!
//! Replies: a tag as `{"value", "unit", "quality", "timestamp"}`, the status objects as the
//! backend gives them; the gateway status gets a `"zenoh"` member with the bridge's zenoh id,
//! prefix and counters.

use std::sync::Arc;

use serde_json::Value;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;
use zenoh::bytes::Encoding;
use zenoh::query::Query;
use zenoh::Wait;

use super::keys::{self, Keys};
use super::metrics::{BridgeStats, DropReason};
use super::BridgeBackend;

/// Which queryable a query came to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum QueryKind {
    Tags,
    /// The history query of an advanced subscriber (`<key expression>/@adv/**`).
    History,
    LineStatus,
    GatewayStatus,
}

/// The queue entry shared by the query callbacks.
pub(crate) struct Queries {
    queue: mpsc::Sender<(QueryKind, Query)>,
    stats: Arc<BridgeStats>,
    /// The largest payload a query may carry (`[zenoh] max_payload`); these queries use none.
    max_payload: usize,
}

// === impl Queries ===

impl Queries {
    pub(crate) fn new(
        stats: Arc<BridgeStats>,
        capacity: usize,
        max_payload: usize,
    ) -> (Arc<Self>, mpsc::Receiver<(QueryKind, Query)>) {
        let (queue, rx) = mpsc::channel(capacity);
        let this = Self {
            queue,
            stats,
            max_payload,
        };
        (Arc::new(this), rx)
    }

    /// The queryable callback: queue without waiting. A query with a payload over
    /// `max_payload` is left without a reply (and dropped at once, with its payload).
    pub(crate) fn on_query(&self, kind: QueryKind, query: Query) {
        let len = query.payload().map_or(0, zenoh::bytes::ZBytes::len);
        if len > self.max_payload {
            self.stats.dropped(DropReason::QueryTooLarge);
            crate::warn_limited!(
                "zenoh query too large",
                len,
                max_payload = self.max_payload,
                "zenoh query with a payload over [zenoh] max_payload left without reply"
            );
            return;
        }
        if self.queue.try_send((kind, query)).is_err() {
            self.stats.dropped(DropReason::QueryQueueFull);
            crate::warn_limited!(
                "zenoh query queue full",
                "zenoh query queue full, queries left without reply"
            );
        }
    }
}

/// What answering needs.
pub(crate) struct Answerer {
    pub(crate) keys: Arc<Keys>,
    pub(crate) backend: Arc<dyn BridgeBackend>,
    pub(crate) stats: Arc<BridgeStats>,
    /// `{"zid", "prefix", "mode"}`, merged into the gateway status with the counters.
    pub(crate) identity: Value,
}

/// Serves queued queries one after the other until shutdown.
pub(crate) async fn serve(
    answerer: Arc<Answerer>,
    mut rx: mpsc::Receiver<(QueryKind, Query)>,
    shutdown: CancellationToken,
) {
    loop {
        let (kind, query) = tokio::select! {
            q = rx.recv() => match q { Some(q) => q, None => break },
            () = shutdown.cancelled() => break,
        };
        let answerer = answerer.clone();
        let done = tokio::task::spawn_blocking(move || answerer.answer(kind, &query)).await;
        if let Err(e) = done {
            crate::error_limited!("zenoh query task failed", error = %e, "zenoh query task failed");
        }
    }
}

// === impl Answerer ===

impl Answerer {
    fn answer(&self, kind: QueryKind, query: &Query) {
        let q = query.key_expr().as_str();
        match kind {
            QueryKind::Tags => self.answer_tags(query, q),
            QueryKind::History => {
                if let Some(subject) = Keys::history_subject(q) {
                    self.answer_tags(query, subject);
                }
            }
            QueryKind::LineStatus => {
                for line in self.backend.lines() {
                    let key = self.keys.line_status(&line);
                    if keys::check_chunk("line", &line).is_ok() && keys::intersects(q, &key) {
                        if let Some(status) = self.backend.line_status(&line) {
                            reply(query, key, &status);
                        }
                    }
                }
            }
            QueryKind::GatewayStatus => {
                let key = self.keys.gateway_status();
                if keys::intersects(q, &key) {
                    let mut zenoh = self.identity.clone();
                    zenoh["stats"] = self.stats.to_json();
                    let status = match self.backend.gateway_status() {
                        Value::Object(mut map) => {
                            map.insert("zenoh".to_owned(), zenoh);
                            Value::Object(map)
                        }
                        other => serde_json::json!({"gateway": other, "zenoh": zenoh}),
                    };
                    reply(query, key, &status);
                }
            }
        }
        self.stats.query_served();
    }

    /// Replies with the value of every tag whose key intersects `q` (a tag query's key, or the
    /// key expression a history query names).
    fn answer_tags(&self, query: &Query, q: &str) {
        let filter = self.keys.tag_filter(q);
        let tags = self.backend.query_tags(
            filter.line.as_deref(),
            filter.device.as_deref(),
            filter.tag.as_deref(),
        );
        for (line, device, tag, value) in tags {
            // Tag names compare without letter case (as in the config and REST): a
            // query that names the tag literally is answered under its own spelling,
            // which zenoh requires of a reply (`.../acc` gets `.../acc`, not `ACC`).
            let tag = match &filter.tag {
                Some(asked) if asked.eq_ignore_ascii_case(&tag) => asked.clone(),
                _ => tag,
            };
            let names_ok = keys::check_chunk("line", &line).is_ok()
                && keys::check_chunk("device", &device).is_ok()
                && keys::check_chunk("tag", &tag).is_ok();
            let key = self.keys.tag(&line, &device, &tag);
            if names_ok && keys::intersects(q, &key) {
                reply(query, key, &value.to_json());
            }
        }
    }
}

fn reply(query: &Query, key: String, body: &Value) {
    let result = query
        .reply(key, body.to_string())
        .encoding(Encoding::APPLICATION_JSON)
        .wait();
    if let Err(e) = result {
        tracing::debug!(error = %e, "zenoh reply failed");
    }
}
