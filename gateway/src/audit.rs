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
