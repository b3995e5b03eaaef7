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
use crate::metrics::Metrics;
pub use crate::metrics::{WritePath, WriteReason, WriteResult};

/// At most one audit line per source, path and result in this interval.
pub const AUDIT_INTERVAL: Duration = Duration::from_secs(10);

/// When each (source, path, result) was last logged, and how many writes were left out since.
static AUDIT_LOG: Limiter = Limiter::new(AUDIT_INTERVAL);

/// Records one write: counted always, logged within the rate limit. The reason is the one the
/// path gives every write of that result ([`WriteReason::of`]); [`record_reason`] names another.
pub fn record(
    metrics: Option<&Metrics>,
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
    metrics: Option<&Metrics>,
    path: WritePath,
    source: &dyn Display,
    target: &dyn Display,
    result: WriteResult,
    reason: WriteReason,
    detail: &dyn Display,
) {
    if let Some(m) = metrics {
        m.write_audited(path, result, reason);
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
