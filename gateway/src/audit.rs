//! The audit trail of changes made from outside: every accepted, refused or failed write is
//! logged once (tracing target `audit`) with its path, its source (client address, certificate
//! role, or the northbound interface), its target and its result, and counted in
//! `gateway_writes_total{path,result}`.
//!
//! The log lines are rate-limited: a flood of writes writes a burst of lines a window and then
//! one line with the number left out, so it cannot fill the disk. The counter counts every write.

use std::fmt::Display;
use std::time::Duration;

use tracing::info;

use crate::log_limit::{LogLimit, Verdict};
use crate::metrics::Metrics;
pub use crate::metrics::{WritePath, WriteResult};

/// 50 audit lines per 10 s, then one line with the count left out.
static AUDIT_LOG: LogLimit = LogLimit::new(Duration::from_secs(10), 50);

/// Records one write: counted always, logged within the rate limit.
pub fn record(
    metrics: Option<&Metrics>,
    path: WritePath,
    source: &dyn Display,
    target: &dyn Display,
    result: WriteResult,
    detail: &dyn Display,
) {
    if let Some(m) = metrics {
        m.write_audited(path.as_str(), result.as_str());
    }
    if let Verdict::Log { suppressed } = AUDIT_LOG.check() {
        info!(
            target: "audit",
            path = path.as_str(),
            %source,
            %target,
            result = result.as_str(),
            %detail,
            suppressed,
            "write"
        );
    }
}
