//! The audit trail of changes made from outside: every accepted, refused or failed write is
//! logged once (tracing target `audit`) with its path, its source (client address, certificate
//! role, or the northbound interface), its target, its result and the reason of a refusal, and
//! counted in `gateway_writes_total{path,result,reason}`.
//!
//! The log lines are rate-limited per source, path, result and reason: the first write of a source on a
//! path with a result is logged, then at most one line per [`AUDIT_INTERVAL`] that says how many
//! more there were since the line before (`more`, over `in_last`). A client that writes every cycle,
//! or a flood, leaves a few lines a minute, so it cannot fill the disk; a new client, a new path or
//! a new result (a refusal after accepted writes) is logged at once. The counter counts every
//! write.

use std::fmt::Display;
use std::time::Duration;

use tracing::info;

use crate::log_limit::Limiter;

mod metrics;

pub use metrics::AuditMetrics;

/// At most one audit line per source, path and result in this interval.
pub const AUDIT_INTERVAL: Duration = Duration::from_secs(10);

/// When each (source, path, result) was last logged, and how many writes were left out since.
static AUDIT_LOG: Limiter = Limiter::new(AUDIT_INTERVAL);

/// Records one write: counted always, logged within the rate limit. The reason is the one the
/// path gives every write of that result ([`WriteReason::of`]); [`record_reason`] names another.
pub fn record(
    metrics: Option<&AuditMetrics>,
    path: WritePath,
    source: &dyn Display,
    target: &dyn Display,
    result: WriteResult,
    detail: &dyn Display,
) {
    record_reason(
        metrics,
        path,
        source,
        target,
        result,
        WriteReason::of(result),
        detail,
    );
}

/// [`record`] with the reason of the result (which check refused the write).
pub fn record_reason(
    metrics: Option<&AuditMetrics>,
    path: WritePath,
    source: &dyn Display,
    target: &dyn Display,
    result: WriteResult,
    reason: WriteReason,
    detail: &dyn Display,
) {
    if let Some(m) = metrics {
        m.write(path, result, reason);
    }
    let key = format!(
        "{}/{}/{}/{source}",
        path.as_str(),
        result.as_str(),
        reason.as_str()
    );
    match AUDIT_LOG.admit_since(key, std::time::Instant::now()) {
        None => {}
        Some((0, _)) => info!(
            target: "audit",
            path = path.as_str(),
            %source,
            %target,
            result = result.as_str(),
            reason = reason.as_str(),
            %detail,
            "write"
        ),
        Some((more, since)) => info!(
            target: "audit",
            path = path.as_str(),
            %source,
            %target,
            result = result.as_str(),
            reason = reason.as_str(),
            %detail,
            more,
            in_last = ?since,
            "write ({more} more of this source, path, result and reason not logged in the last {}s)",
            since.as_secs()
        ),
    }
}

/// The interface a write came through.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum WritePath {
    /// Plain Modbus TCP.
    ModbusTcp,
    /// Modbus/TCP Security.
    ModbusTls,
    /// The REST API.
    Rest,
    /// zenoh (`tx`, tag `set`).
    Zenoh,
}

impl WritePath {
    /// Every path, for the zero series.
    pub const ALL: [Self; 4] = [Self::ModbusTcp, Self::ModbusTls, Self::Rest, Self::Zenoh];

    /// The label value.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::ModbusTcp => "modbus_tcp",
            Self::ModbusTls => "modbus_tcp_tls",
            Self::Rest => "rest",
            Self::Zenoh => "zenoh",
        }
    }
}

/// How a write ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum WriteResult {
    /// Passed the policy and the device took it.
    Accepted,
    /// Refused by the write policy or the role: never sent to the device.
    Refused,
    /// Passed the policy; the device or the line did not take it.
    Failed,
}

impl WriteResult {
    /// Every result, for the zero series.
    pub const ALL: [Self; 3] = [Self::Accepted, Self::Refused, Self::Failed];

    /// The label value.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Accepted => "accepted",
            Self::Refused => "refused",
            Self::Failed => "failed",
        }
    }
}

/// Why a write ended as it did: the `reason` label of `gateway_writes_total`. Accepted and failed
/// writes say `none` (the result says it all); a refusal says which check refused it. Modbus TCP
/// and REST refusals are `policy`; the zenoh side names each of its checks, so that a flood of
/// one kind is told apart from the others.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum WriteReason {
    /// Not refused: accepted, or failed at the device or line.
    None,
    /// The write or send policy, the role, the token, or a check of the request itself (a
    /// read-only tag, a value that does not fit, a line that does not send).
    Policy,
    /// `[zenoh] writes = false`.
    WritesOff,
    /// The payload is larger than `[zenoh] max_payload`.
    TooLarge,
    /// The payload is not what the key takes: not a JSON value, an empty telegram.
    BadPayload,
    /// No such line, device or tag.
    UnknownTarget,
    /// A command queue was full: the command was answered `busy`.
    QueueFull,
}

impl WriteReason {
    /// Every reason.
    pub const ALL: [Self; 7] = [
        Self::None,
        Self::Policy,
        Self::WritesOff,
        Self::TooLarge,
        Self::BadPayload,
        Self::UnknownTarget,
        Self::QueueFull,
    ];

    /// The reasons a refusal over zenoh can have, for the zero series.
    pub const ZENOH_REFUSALS: [Self; 6] = [
        Self::Policy,
        Self::WritesOff,
        Self::TooLarge,
        Self::BadPayload,
        Self::UnknownTarget,
        Self::QueueFull,
    ];

    /// The reason of a write of `result` on a path that does not say more: `none` for accepted
    /// and failed writes, `policy` for a refusal.
    pub const fn of(result: WriteResult) -> Self {
        match result {
            WriteResult::Accepted | WriteResult::Failed => Self::None,
            WriteResult::Refused => Self::Policy,
        }
    }

    /// The label value (`queue_full` as in `gateway_dropped_updates_total`).
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Policy => "policy",
            Self::WritesOff => "writes_off",
            Self::TooLarge => "too_large",
            Self::BadPayload => "bad_payload",
            Self::UnknownTarget => "unknown_target",
            Self::QueueFull => "queue_full",
        }
    }
}
