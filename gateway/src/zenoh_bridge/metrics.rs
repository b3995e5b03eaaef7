//! Counters of the bridge, with bounded label sets, and its Prometheus families.
//!
//! The bridge counts by its own, finer kinds and reasons (shown by the gateway status queryable).
//! [`BridgeMetrics`] registers `gateway_zenoh_publications_total{kind}` and
//! `gateway_dropped_updates_total{reason}`, whose label sets are coarser: the same enums give
//! both labels ([`PublicationKind::as_str`] and [`PublicationKind::metric_label`],
//! [`DropReason::as_str`] and [`DropReason::metric_label`]). With [`BridgeStats::with_metrics`]
//! every count is also made there. `gateway_zenoh_name_conflict` is 1 while another session
//! holds this gateway's name (its token) and the gateway publishes nothing on zenoh.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use prometheus::{IntCounterVec, IntGauge, Opts, Registry};

use crate::audit::AuditMetrics;

/// What was published.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum PublicationKind {
    /// A received telegram on `<line>/rx`.
    Telegram,
    /// A tag value on `<line>/<device>/<tag>`.
    Tag,
    /// An event on `<line>/events`.
    Event,
    /// A send result on `<line>/tx/result`.
    TxResult,
    /// A write result on `<line>/<device>/<tag>/set/result`.
    SetResult,
    /// A monitored frame on `<line>/frames`.
    Frame,
}

impl PublicationKind {
    const ALL: [Self; 6] = [
        Self::Telegram,
        Self::Tag,
        Self::Event,
        Self::TxResult,
        Self::SetResult,
        Self::Frame,
    ];

    /// Whether the kind is published through a declared publisher kept per key: telegrams and
    /// events and frames, three keys per line. Tag values (one key per tag, thousands of them) and results
    /// (keys named by commands) are plain session puts.
    pub(crate) fn declared_publisher(self) -> bool {
        matches!(self, Self::Telegram | Self::Event | Self::Frame)
    }

    /// The label in the bridge's own counters.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Telegram => "telegram",
            Self::Tag => "tag",
            Self::Event => "event",
            Self::TxResult => "tx_result",
            Self::SetResult => "set_result",
            Self::Frame => "frame",
        }
    }

    /// The `kind` of `gateway_zenoh_publications_total`: both result kinds are `send_result`,
    /// the others their own label.
    pub fn metric_label(self) -> &'static str {
        match self {
            Self::TxResult | Self::SetResult => SEND_RESULT,
            other => other.as_str(),
        }
    }
}

/// The `kind` of `gateway_zenoh_publications_total` of a send or write result.
const SEND_RESULT: &str = "send_result";
/// The `kind` of `gateway_zenoh_publications_total` of a queryable's reply (tag value, status).
const REPLY: &str = "reply";

/// The `reason` of `gateway_dropped_updates_total` of an update a full bounded queue refused.
const QUEUE_FULL: &str = "queue_full";
/// The `reason` of an update replaced by a newer one, or lost by a feed that fell behind.
const LAGGED: &str = "lagged";
/// The `reason` of an update the closed bridge or session did not take.
const CLOSED: &str = "closed";
/// The `reason` of a query larger than `max_payload`.
const TOO_LARGE: &str = "too_large";

/// Why an update was not published, or a command or query not served.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DropReason {
    /// The telegram queue was full; the new telegram was dropped.
    TelegramQueueFull,
    /// The event queue was full; the new event was dropped.
    EventQueueFull,
    /// A newer value of the same tag replaced a pending one.
    TagSuperseded,
    /// `tag_queue` keys were pending; the value of a new key was dropped.
    TagQueueFull,
    /// The result queue was full; the new result was dropped.
    ResultQueueFull,
    /// The frame queue was full; the new frame was dropped.
    FrameQueueFull,
    /// The command queue (total or of the line) was full; the command was answered `busy`.
    CommandQueueFull,
    /// The query queue was full; the query got no reply.
    QueryQueueFull,
    /// A query (tag, status) carried a payload larger than `max_payload`; it got no reply.
    QueryTooLarge,
    /// A line, device or tag name that is not one key chunk.
    BadKey,
    /// zenoh refused the publication (session closed, access control).
    PublishError,
    /// The bridge was shutting down.
    BridgeClosed,
    /// A feed of the bridge (tag changes, events, received telegrams) fell behind its source and
    /// lost the oldest updates.
    FeedLagged,
}

impl DropReason {
    const ALL: [Self; 13] = [
        Self::TelegramQueueFull,
        Self::EventQueueFull,
        Self::TagSuperseded,
        Self::TagQueueFull,
        Self::ResultQueueFull,
        Self::FrameQueueFull,
        Self::CommandQueueFull,
        Self::QueryQueueFull,
        Self::QueryTooLarge,
        Self::BadKey,
        Self::PublishError,
        Self::BridgeClosed,
        Self::FeedLagged,
    ];

    /// The label in the bridge's own counters.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::TelegramQueueFull => "telegram_queue_full",
            Self::EventQueueFull => "event_queue_full",
            Self::TagSuperseded => "tag_superseded",
            Self::TagQueueFull => "tag_queue_full",
            Self::ResultQueueFull => "result_queue_full",
            Self::FrameQueueFull => "frame_queue_full",
            Self::CommandQueueFull => "command_queue_full",
            Self::QueryQueueFull => "query_queue_full",
            Self::QueryTooLarge => "query_too_large",
            Self::BadKey => "bad_key",
            Self::PublishError => "publish_error",
            Self::BridgeClosed => "bridge_closed",
            Self::FeedLagged => "feed_lagged",
        }
    }

    /// The `reason` of `gateway_dropped_updates_total`, `None` for a name that is no key chunk
    /// (a configuration mistake the bridge logs and counts in its own counters only; the metric's
    /// reasons are the delivery path's).
    ///
    /// A full queue of any kind is `queue_full`; an update replaced by a newer one before it was
    /// published, or lost by a feed that fell behind, is `lagged`; a bridge or session that had
    /// closed is `closed`; a query refused for its size is `too_large`.
    pub const fn metric_label(self) -> Option<&'static str> {
        match self {
            Self::TelegramQueueFull
            | Self::EventQueueFull
            | Self::TagQueueFull
            | Self::ResultQueueFull
            | Self::FrameQueueFull
            | Self::CommandQueueFull
            | Self::QueryQueueFull => Some(QUEUE_FULL),
            Self::TagSuperseded | Self::FeedLagged => Some(LAGGED),
            Self::PublishError | Self::BridgeClosed => Some(CLOSED),
            Self::QueryTooLarge => Some(TOO_LARGE),
            Self::BadKey => None,
        }
    }
}

/// A command from the fabric.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CommandKind {
    /// A telegram to send (`<line>/tx`).
    Tx,
    /// A tag write (`<line>/<device>/<tag>/set`).
    Set,
    /// An acknowledgement of a received telegram (`<line>/ack`).
    Ack,
}

impl CommandKind {
    const ALL: [Self; 3] = [Self::Tx, Self::Set, Self::Ack];

    /// The metric label.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Tx => "tx",
            Self::Set => "set",
            Self::Ack => "ack",
        }
    }
}

/// How a command ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CommandOutcome {
    /// The backend did it.
    Ok,
    /// The backend refused or failed (the device's answer, a timeout, a check).
    Failed,
    /// The command itself was unusable: bad payload, unknown line.
    Rejected,
    /// A queue was full.
    Busy,
}

impl CommandOutcome {
    const ALL: [Self; 4] = [Self::Ok, Self::Failed, Self::Rejected, Self::Busy];

    /// The metric label.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Ok => "ok",
            Self::Failed => "failed",
            Self::Rejected => "rejected",
            Self::Busy => "busy",
        }
    }
}

/// The Prometheus families of the zenoh bridge. Clones share the same series.
#[derive(Clone, Debug)]
pub struct BridgeMetrics {
    /// `gateway_zenoh_publications_total{kind}`.
    publications: IntCounterVec,
    /// `gateway_dropped_updates_total{reason}`.
    dropped: IntCounterVec,
    /// `gateway_zenoh_name_conflict`: 1 while another session holds this gateway's name.
    name_conflict: IntGauge,
}

// === impl BridgeMetrics ===

impl BridgeMetrics {
    /// The names of the families.
    pub const NAMES: [&'static str; 3] = [
        "gateway_zenoh_publications_total",
        "gateway_dropped_updates_total",
        "gateway_zenoh_name_conflict",
    ];

    /// Registers the families in `registry`, with every kind's and reason's series at 0.
    pub fn register(registry: &Registry) -> Result<Self, prometheus::Error> {
        let [publications, dropped, name_conflict] = Self::NAMES;
        let metrics = Self {
            publications: IntCounterVec::new(
                Opts::new(publications, "zenoh publications and replies, by kind."),
                &["kind"],
            )?,
            dropped: IntCounterVec::new(
                Opts::new(
                    dropped,
                    "Updates dropped instead of delivered (full bounded channel, lag, closed).",
                ),
                &["reason"],
            )?,
            name_conflict: IntGauge::new(
                name_conflict,
                "1 while another zenoh session holds this gateway's name: the gateway publishes nothing on zenoh until it is free.",
            )?,
        };
        registry.register(Box::new(metrics.publications.clone()))?;
        registry.register(Box::new(metrics.dropped.clone()))?;
        registry.register(Box::new(metrics.name_conflict.clone()))?;
        for kind in PublicationKind::ALL {
            metrics
                .publications
                .with_label_values(&[kind.metric_label()]);
        }
        metrics.publications.with_label_values(&[REPLY]);
        for reason in DropReason::ALL.iter().filter_map(|r| r.metric_label()) {
            metrics.dropped.with_label_values(&[reason]);
        }
        Ok(metrics)
    }

    /// Counts one publication of `kind`.
    pub fn published(&self, kind: PublicationKind) {
        self.published_many(kind, 1);
    }

    /// Counts `count` publications of `kind`.
    pub fn published_many(&self, kind: PublicationKind, count: u64) {
        self.publications
            .with_label_values(&[kind.metric_label()])
            .inc_by(count);
    }

    /// Counts one reply of a queryable.
    pub fn replied(&self) {
        self.publications.with_label_values(&[REPLY]).inc();
    }

    /// Counts `count` updates dropped for `reason` (nothing for a reason the metric leaves out).
    pub fn dropped(&self, reason: DropReason, count: u64) {
        if let Some(label) = reason.metric_label() {
            self.dropped.with_label_values(&[label]).inc_by(count);
        }
    }
}

/// The bridge's counters. Shared by the bridge and whoever exports them.
#[derive(Debug, Default)]
pub struct BridgeStats {
    session_open: AtomicBool,
    /// Who holds this gateway's name while another session does (bounded and escaped text,
    /// see [`super::fleet::take_name`]).
    name_conflict: std::sync::Mutex<Option<String>>,
    publications: [AtomicU64; PublicationKind::ALL.len()],
    drops: [AtomicU64; DropReason::ALL.len()],
    commands: [[AtomicU64; CommandOutcome::ALL.len()]; CommandKind::ALL.len()],
    queries: AtomicU64,
    /// Tag values left unpublished by a deadband.
    within_deadband: AtomicU64,
    /// Tag values published again by a heartbeat.
    heartbeats: AtomicU64,
    /// The Prometheus families the counts are mirrored into, if any.
    metrics: Option<(BridgeMetrics, AuditMetrics)>,
}

// === impl BridgeStats ===

impl BridgeStats {
    /// All counters at zero.
    pub fn new() -> Self {
        Self::default()
    }

    /// All counters at zero, every publication, reply and drop also counted in the Prometheus
    /// families of `metrics`.
    pub fn with_metrics(bridge: BridgeMetrics, audit: AuditMetrics) -> Self {
        Self {
            metrics: Some((bridge, audit)),
            ..Self::default()
        }
    }

    /// Whether the session is open (for readiness).
    pub fn session_open(&self) -> bool {
        self.session_open.load(Ordering::Acquire)
    }

    pub(crate) fn set_session_open(&self, open: bool) {
        self.session_open.store(open, Ordering::Release);
    }

    /// While another session holds this gateway's name: who, in words (bounded, escaped).
    pub fn name_conflict(&self) -> Option<String> {
        self.name_conflict
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .clone()
    }

    pub(crate) fn set_name_conflict(&self, holder: Option<String>) {
        let on = holder.is_some();
        *self
            .name_conflict
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = holder;
        self.each(|m| m.name_conflict.set(i64::from(on)));
    }

    pub(crate) fn published(&self, kind: PublicationKind) {
        self.published_many(kind, 1);
    }

    /// Counts `count` publications of one kind (a chunk of tag values at once).
    pub(crate) fn published_many(&self, kind: PublicationKind, count: u64) {
        self.publications[kind as usize].fetch_add(count, Ordering::Relaxed);
        self.each(|m| m.published_many(kind, count));
    }

    /// The audit's Prometheus family the commands are counted in, if any.
    pub fn audit(&self) -> Option<&AuditMetrics> {
        self.metrics.as_ref().map(|(_, audit)| audit)
    }

    /// Calls `f` with the bridge's families, if the counts are mirrored there.
    fn each(&self, f: impl FnOnce(&BridgeMetrics)) {
        if let Some((bridge, _)) = &self.metrics {
            f(bridge);
        }
    }

    pub(crate) fn dropped(&self, reason: DropReason) {
        self.dropped_many(reason, 1);
    }

    /// Counts `count` updates dropped for one reason.
    pub fn dropped_many(&self, reason: DropReason, count: u64) {
        self.drops[reason as usize].fetch_add(count, Ordering::Relaxed);
        self.each(|m| m.dropped(reason, count));
    }

    pub(crate) fn command(&self, kind: CommandKind, result: CommandOutcome) {
        self.commands[kind as usize][result as usize].fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn query_served(&self) {
        self.queries.fetch_add(1, Ordering::Relaxed);
        self.each(|m| m.replied());
    }

    pub(crate) fn suppressed_by_deadband(&self) {
        self.within_deadband.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn heartbeat_sent(&self) {
        self.heartbeats.fetch_add(1, Ordering::Relaxed);
    }

    /// Tag values left unpublished because they stayed within their deadband.
    pub fn within_deadband(&self) -> u64 {
        self.within_deadband.load(Ordering::Relaxed)
    }

    /// Tag values published again by a heartbeat (also counted as tag publications).
    pub fn heartbeats(&self) -> u64 {
        self.heartbeats.load(Ordering::Relaxed)
    }

    /// Publications of one kind so far.
    pub fn publications(&self, kind: PublicationKind) -> u64 {
        self.publications[kind as usize].load(Ordering::Relaxed)
    }

    /// Drops for one reason so far.
    pub fn drops(&self, reason: DropReason) -> u64 {
        self.drops[reason as usize].load(Ordering::Relaxed)
    }

    /// Commands of one kind that ended one way so far.
    pub fn commands(&self, kind: CommandKind, result: CommandOutcome) -> u64 {
        self.commands[kind as usize][result as usize].load(Ordering::Relaxed)
    }

    /// Queries answered so far.
    pub fn queries(&self) -> u64 {
        self.queries.load(Ordering::Relaxed)
    }

    /// Every publication counter with its `kind` label.
    pub fn publication_counts(&self) -> Vec<(&'static str, u64)> {
        PublicationKind::ALL
            .iter()
            .map(|k| (k.as_str(), self.publications(*k)))
            .collect()
    }

    /// Every drop counter with its `reason` label.
    pub fn drop_counts(&self) -> Vec<(&'static str, u64)> {
        DropReason::ALL
            .iter()
            .map(|r| (r.as_str(), self.drops(*r)))
            .collect()
    }

    /// The counters as JSON (for the gateway status queryable).
    pub fn to_json(&self) -> serde_json::Value {
        let map = |v: Vec<(&'static str, u64)>| {
            v.into_iter()
                .map(|(k, n)| (k.to_owned(), serde_json::Value::from(n)))
                .collect::<serde_json::Map<_, _>>()
        };
        serde_json::json!({
            "session_open": self.session_open(),
            "publications": map(self.publication_counts()),
            "dropped": map(self.drop_counts()),
            "queries": self.queries(),
            "within_deadband": self.within_deadband(),
            "heartbeats": self.heartbeats(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    impl BridgeStats {
        /// Every command counter with its `kind` and `result` labels.
        fn command_counts(&self) -> Vec<(&'static str, &'static str, u64)> {
            CommandKind::ALL
                .iter()
                .flat_map(|k| {
                    CommandOutcome::ALL
                        .iter()
                        .map(move |r| (k.as_str(), r.as_str(), self.commands(*k, *r)))
                })
                .collect()
        }
    }

    #[test]
    fn labels_are_unique_and_indexes_match() {
        for (i, k) in PublicationKind::ALL.iter().enumerate() {
            assert_eq!(*k as usize, i);
        }
        for (i, r) in DropReason::ALL.iter().enumerate() {
            assert_eq!(*r as usize, i);
        }
        for (i, r) in CommandOutcome::ALL.iter().enumerate() {
            assert_eq!(*r as usize, i);
        }
        let mut labels: Vec<_> = DropReason::ALL.iter().map(|r| r.as_str()).collect();
        labels.sort_unstable();
        labels.dedup();
        assert_eq!(labels.len(), DropReason::ALL.len());
    }

    #[test]
    fn counters_count() {
        let s = BridgeStats::new();
        s.published(PublicationKind::Tag);
        s.dropped(DropReason::TagSuperseded);
        s.dropped(DropReason::TagSuperseded);
        s.command(CommandKind::Set, CommandOutcome::Busy);
        assert_eq!(s.publications(PublicationKind::Tag), 1);
        assert_eq!(s.drops(DropReason::TagSuperseded), 2);
        assert!(s.drop_counts().contains(&("tag_superseded", 2)));
        assert!(s.command_counts().contains(&("set", "busy", 1)));
        assert_eq!(s.to_json()["dropped"]["tag_superseded"], 2);
    }

    #[test]
    fn counts_feed_the_prometheus_families() {
        let registry = Registry::new();
        let s = BridgeStats::with_metrics(
            BridgeMetrics::register(&registry).expect("register"),
            AuditMetrics::register(&registry).expect("register"),
        );
        s.published(PublicationKind::Tag);
        s.published(PublicationKind::SetResult);
        s.query_served();
        s.dropped(DropReason::TelegramQueueFull);
        s.dropped_many(DropReason::FeedLagged, 3);
        s.dropped(DropReason::BadKey);
        let text = crate::metrics::encode_text(&registry);
        for line in [
            r#"gateway_zenoh_publications_total{kind="tag"} 1"#,
            r#"gateway_zenoh_publications_total{kind="send_result"} 1"#,
            r#"gateway_zenoh_publications_total{kind="reply"} 1"#,
            r#"gateway_dropped_updates_total{reason="queue_full"} 1"#,
            r#"gateway_dropped_updates_total{reason="lagged"} 3"#,
            r#"gateway_dropped_updates_total{reason="closed"} 0"#,
        ] {
            assert!(text.contains(line), "{line} missing in\n{text}");
        }
        assert_eq!(s.drops(DropReason::BadKey), 1);
    }
}
