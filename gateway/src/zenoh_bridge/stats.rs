//! Counters of the bridge, with bounded label sets, for `gateway_zenoh_publications_total{kind}`,
//! `gateway_dropped_updates_total{reason}` and `gateway_zenoh_commands_total{kind,result}`.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

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
}

impl PublicationKind {
    const ALL: [Self; 5] = [
        Self::Telegram,
        Self::Tag,
        Self::Event,
        Self::TxResult,
        Self::SetResult,
    ];

    /// Whether the kind is published through a declared publisher kept per key: telegrams and
    /// events, two keys per line. Tag values (one key per tag, thousands of them) and results
    /// (keys named by commands) are plain session puts.
    pub(crate) fn declared_publisher(self) -> bool {
        matches!(self, Self::Telegram | Self::Event)
    }

    /// The metric label.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Telegram => "telegram",
            Self::Tag => "tag",
            Self::Event => "event",
            Self::TxResult => "tx_result",
            Self::SetResult => "set_result",
        }
    }
}

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
    /// The command queue (total or of the line) was full; the command was answered `busy`.
    CommandQueueFull,
    /// The query queue was full; the query got no reply.
    QueryQueueFull,
    /// A line, device or tag name that is not one key chunk.
    BadKey,
    /// zenoh refused the publication (session closed, access control).
    PublishError,
    /// The bridge was shutting down.
    BridgeClosed,
}

impl DropReason {
    const ALL: [Self; 10] = [
        Self::TelegramQueueFull,
        Self::EventQueueFull,
        Self::TagSuperseded,
        Self::TagQueueFull,
        Self::ResultQueueFull,
        Self::CommandQueueFull,
        Self::QueryQueueFull,
        Self::BadKey,
        Self::PublishError,
        Self::BridgeClosed,
    ];

    /// The metric label.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::TelegramQueueFull => "telegram_queue_full",
            Self::EventQueueFull => "event_queue_full",
            Self::TagSuperseded => "tag_superseded",
            Self::TagQueueFull => "tag_queue_full",
            Self::ResultQueueFull => "result_queue_full",
            Self::CommandQueueFull => "command_queue_full",
            Self::QueryQueueFull => "query_queue_full",
            Self::BadKey => "bad_key",
            Self::PublishError => "publish_error",
            Self::BridgeClosed => "bridge_closed",
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
}

impl CommandKind {
    const ALL: [Self; 2] = [Self::Tx, Self::Set];

    /// The metric label.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Tx => "tx",
            Self::Set => "set",
        }
    }
}

/// How a command ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CommandResult {
    /// The backend did it.
    Ok,
    /// The backend refused or failed (the device's answer, a timeout, a check).
    Failed,
    /// The command itself was unusable: bad payload, unknown line.
    Rejected,
    /// A queue was full.
    Busy,
}

impl CommandResult {
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

/// The bridge's counters. Shared by the bridge and whoever exports them.
#[derive(Debug, Default)]
pub struct BridgeStats {
    session_open: AtomicBool,
    publications: [AtomicU64; PublicationKind::ALL.len()],
    drops: [AtomicU64; DropReason::ALL.len()],
    commands: [[AtomicU64; CommandResult::ALL.len()]; CommandKind::ALL.len()],
    queries: AtomicU64,
}

// === impl BridgeStats ===

impl BridgeStats {
    /// All counters at zero.
    pub fn new() -> Self {
        Self::default()
    }

    /// Whether the session is open (for readiness).
    pub fn session_open(&self) -> bool {
        self.session_open.load(Ordering::Acquire)
    }

    pub(crate) fn set_session_open(&self, open: bool) {
        self.session_open.store(open, Ordering::Release);
    }

    pub(crate) fn published(&self, kind: PublicationKind) {
        self.publications[kind as usize].fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn dropped(&self, reason: DropReason) {
        self.drops[reason as usize].fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn command(&self, kind: CommandKind, result: CommandResult) {
        self.commands[kind as usize][result as usize].fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn query_served(&self) {
        self.queries.fetch_add(1, Ordering::Relaxed);
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
    pub fn commands(&self, kind: CommandKind, result: CommandResult) -> u64 {
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

    /// Every command counter with its `kind` and `result` labels.
    pub fn command_counts(&self) -> Vec<(&'static str, &'static str, u64)> {
        CommandKind::ALL
            .iter()
            .flat_map(|k| {
                CommandResult::ALL
                    .iter()
                    .map(move |r| (k.as_str(), r.as_str(), self.commands(*k, *r)))
            })
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
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_are_unique_and_indexes_match() {
        for (i, k) in PublicationKind::ALL.iter().enumerate() {
            assert_eq!(*k as usize, i);
        }
        for (i, r) in DropReason::ALL.iter().enumerate() {
            assert_eq!(*r as usize, i);
        }
        for (i, r) in CommandResult::ALL.iter().enumerate() {
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
        s.command(CommandKind::Set, CommandResult::Busy);
        assert_eq!(s.publications(PublicationKind::Tag), 1);
        assert_eq!(s.drops(DropReason::TagSuperseded), 2);
        assert!(s.drop_counts().contains(&("tag_superseded", 2)));
        assert!(s.command_counts().contains(&("set", "busy", 1)));
        assert_eq!(s.to_json()["dropped"]["tag_superseded"], 2);
    }
}
