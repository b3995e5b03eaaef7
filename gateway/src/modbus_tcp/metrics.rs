//! Counters of the Modbus TCP server and its Prometheus families.
//!
//! Every label set is bounded and carries no client address, no register address. The reasons a
//! connection ends are this module's enums, each with its label written once ([`CloseReason`],
//! [`RejectReason`], [`AcceptError::LABEL`]); requests are counted by the Modbus vocabulary the
//! master lines share (`crate::metrics::labels`: `function` and `result`). [`ServerMetrics`]
//! registers the families; with [`ServerStats::with_metrics`] every count is made there as well:
//! open and accepted connections, rejected ones by reason (failed accepts as `accept_error`),
//! closed ones by reason, requests by function and result.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock, PoisonError};

use prometheus::{IntCounter, IntCounterVec, IntGauge, Opts, Registry};

use crate::audit::AuditMetrics;
use crate::metrics::labels::{function_index, function_label, function_label_at, FUNCTION_COUNT};

/// Why a connection was closed at accept.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum RejectReason {
    /// `max_connections` connections were open.
    Limit,
    /// The client is outside `allowed_networks`.
    Network,
}

// === impl RejectReason ===

impl RejectReason {
    /// Every reason, for pre-creating series.
    pub const ALL: [Self; 2] = [Self::Limit, Self::Network];

    /// The `reason` label of `gateway_modbus_tcp_connections_rejected_total` and
    /// `gateway_modbus_tcp_connections_closed_total`.
    pub const fn as_label(self) -> &'static str {
        match self {
            Self::Limit => "limit",
            Self::Network => "network",
        }
    }
}

/// An `accept()` that failed and was retried.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AcceptError {
    /// EMFILE: the process ran out of file descriptors.
    ProcessFdLimit,
    /// ENFILE: the system ran out of file descriptors.
    SystemFdLimit,
    /// ECONNABORTED: the client gave up before the accept.
    ConnectionAborted,
    /// ENOBUFS, ENOMEM and the network errors `accept()` passes on.
    Other,
}

// === impl AcceptError ===

impl AcceptError {
    /// The `reason` label of `gateway_modbus_tcp_connections_rejected_total` for every kind.
    pub const LABEL: &'static str = "accept_error";
}

/// Why a connection ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CloseReason {
    /// The client closed it.
    Peer,
    /// No complete request for `idle_timeout`, or a response not taken within it.
    Idle,
    /// A frame the server cannot answer: bad MBAP header, or no function code.
    BadFrame,
    /// A socket error.
    Io,
    /// The server shut down.
    Shutdown,
}

// === impl CloseReason ===

impl CloseReason {
    /// Every reason, for pre-creating series.
    pub const ALL: [Self; 5] = [
        Self::Peer,
        Self::Idle,
        Self::BadFrame,
        Self::Io,
        Self::Shutdown,
    ];

    /// The `reason` label of `gateway_modbus_tcp_connections_closed_total`.
    pub const fn as_label(self) -> &'static str {
        match self {
            Self::Peer => "client",
            Self::Idle => "idle",
            Self::BadFrame => "bad_frame",
            Self::Io => "io_error",
            Self::Shutdown => "shutdown",
        }
    }
}

/// The `reason` of `gateway_modbus_tcp_connections_closed_total` of a connection refused at the
/// TLS handshake (Modbus/TCP Security).
const TLS_HANDSHAKE: &str = "tls_handshake";

/// Why a frame was refused (and its connection closed).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FrameReject {
    /// Protocol id not 0.
    ProtocolId,
    /// Length field 0 or above 254.
    Length,
    /// Length field 1: a unit id and no function code, nothing to answer an exception to.
    EmptyPdu,
}

/// The answer a request got: [`RequestResult::Ok`] or [`RequestResult::Exception`] (the server
/// answers a device that did not reply with exception 0Bh, so it never counts `Timeout` or
/// `Error`).
pub use crate::metrics::labels::RequestResult;

/// One line of [`ServerStats::requests`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RequestCount {
    /// The `function` label: two upper-case hex digits (`"03"`), or `"other"`.
    pub function: &'static str,
    /// The `result` label: `"ok"`, `"exception_0B"`, `"exception_other"`, ...
    pub result: &'static str,
    /// Requests so far.
    pub count: u64,
}

/// The Prometheus families of the Modbus TCP server. Clones share the same series.
#[derive(Clone, Debug)]
pub struct ServerMetrics {
    /// `gateway_modbus_tcp_connections`: connections being served now.
    connections: IntGauge,
    /// `gateway_modbus_tcp_connections_accepted_total`.
    accepted: IntCounter,
    /// `gateway_modbus_tcp_connections_rejected_total{reason}`.
    rejected: IntCounterVec,
    /// `gateway_modbus_tcp_connections_closed_total{reason}`: every connection's end by reason.
    closed: IntCounterVec,
    /// `gateway_modbus_tcp_requests_total{function,result}`.
    requests: IntCounterVec,
    /// `gateway_modbus_tcp_refused_total{role}`: Modbus/TCP Security requests refused by role.
    refused: IntCounterVec,
    /// `gateway_modbus_tcp_tls_handshakes_failed_total`.
    handshakes_failed: IntCounter,
}

// === impl ServerMetrics ===

impl ServerMetrics {
    /// The names of the families.
    pub const NAMES: [&'static str; 7] = [
        "gateway_modbus_tcp_connections",
        "gateway_modbus_tcp_connections_accepted_total",
        "gateway_modbus_tcp_connections_rejected_total",
        "gateway_modbus_tcp_connections_closed_total",
        "gateway_modbus_tcp_requests_total",
        "gateway_modbus_tcp_refused_total",
        "gateway_modbus_tcp_tls_handshakes_failed_total",
    ];

    /// Registers the families in `registry`, with the series of the fixed reasons at 0.
    pub fn register(registry: &Registry) -> Result<Self, prometheus::Error> {
        let [connections, accepted, rejected, closed, requests, refused, handshakes] = Self::NAMES;
        let metrics = Self {
            connections: IntGauge::new(connections, "Modbus TCP connections being served now.")?,
            accepted: IntCounter::new(accepted, "Modbus TCP connections accepted and served.")?,
            rejected: IntCounterVec::new(
                Opts::new(
                    rejected,
                    "Modbus TCP connections refused at accept, and failed accepts, by reason.",
                ),
                &["reason"],
            )?,
            closed: IntCounterVec::new(
                Opts::new(
                    closed,
                    "Modbus TCP connections closed, by reason (served ones and those refused at accept or at the TLS handshake).",
                ),
                &["reason"],
            )?,
            requests: IntCounterVec::new(
                Opts::new(requests, "Modbus TCP requests by function code and result."),
                &["function", "result"],
            )?,
            refused: IntCounterVec::new(
                Opts::new(
                    refused,
                    "Modbus/TCP Security requests refused by the client certificate's role.",
                ),
                &["role"],
            )?,
            handshakes_failed: IntCounter::new(
                handshakes,
                "Modbus/TCP Security TLS handshakes that failed or timed out (bad or missing \
                 client certificate included).",
            )?,
        };
        registry.register(Box::new(metrics.connections.clone()))?;
        registry.register(Box::new(metrics.accepted.clone()))?;
        registry.register(Box::new(metrics.rejected.clone()))?;
        registry.register(Box::new(metrics.closed.clone()))?;
        registry.register(Box::new(metrics.requests.clone()))?;
        registry.register(Box::new(metrics.refused.clone()))?;
        registry.register(Box::new(metrics.handshakes_failed.clone()))?;
        // A certificate without a role: the one role label every Modbus/TCP Security server has.
        metrics.refused.with_label_values(&["none"]);
        for reason in RejectReason::ALL {
            metrics.rejected.with_label_values(&[reason.as_label()]);
            metrics.closed.with_label_values(&[reason.as_label()]);
        }
        metrics.rejected.with_label_values(&[AcceptError::LABEL]);
        for reason in CloseReason::ALL {
            metrics.closed.with_label_values(&[reason.as_label()]);
        }
        metrics.closed.with_label_values(&[TLS_HANDSHAKE]);
        Ok(metrics)
    }

    /// A connection was accepted: counts it and keeps `gateway_modbus_tcp_connections` up until
    /// the returned guard is dropped (move it into the connection task).
    pub fn connection_accepted(&self) -> TcpConnectionGuard {
        self.accepted.inc();
        self.connections.inc();
        TcpConnectionGuard {
            open: self.connections.clone(),
        }
    }

    /// A connection was refused at accept for `reason` (rejected and closed).
    pub fn connection_rejected(&self, reason: RejectReason) {
        self.rejected.with_label_values(&[reason.as_label()]).inc();
        self.closed.with_label_values(&[reason.as_label()]).inc();
    }

    /// `accept()` failed.
    pub fn accept_failed(&self) {
        self.rejected.with_label_values(&[AcceptError::LABEL]).inc();
    }

    /// A served connection ended for `reason`.
    pub fn connection_closed(&self, reason: CloseReason) {
        self.closed.with_label_values(&[reason.as_label()]).inc();
    }

    /// A Modbus/TCP Security handshake failed: counted, and the connection as closed.
    pub fn handshake_failed(&self) {
        self.handshakes_failed.inc();
        self.closed.with_label_values(&[TLS_HANDSHAKE]).inc();
    }

    /// Counts one Modbus TCP request with function code `function` and its answer.
    pub fn request(&self, function: u8, result: RequestResult) {
        self.request_series(function, result).inc();
    }

    /// The series [`Self::request`] counts into, to keep and count into without looking it up
    /// (by its labels, under the family's lock) for every request.
    pub fn request_series(&self, function: u8, result: RequestResult) -> IntCounter {
        self.requests
            .with_label_values(&[function_label(function), result.as_str()])
    }

    /// Counts one Modbus/TCP Security request refused for the role labelled `role`.
    pub fn refused(&self, role: &str) {
        self.refused.with_label_values(&[role]).inc();
    }
}

/// Keeps one Modbus TCP connection counted in `gateway_modbus_tcp_connections` while it lives.
#[derive(Debug)]
#[must_use = "the connection counts as open only while the guard lives"]
pub struct TcpConnectionGuard {
    open: IntGauge,
}

impl Drop for TcpConnectionGuard {
    fn drop(&mut self) {
        self.open.dec();
    }
}

/// Counters of one server. Shared by `serve` and whoever exports them.
#[derive(Debug, Default)]
pub struct ServerStats {
    connections_open: AtomicU64,
    connections_accepted: AtomicU64,
    rejected: [AtomicU64; RejectReason::ALL.len()],
    accept_errors: [AtomicU64; 4],
    closed: [AtomicU64; CloseReason::ALL.len()],
    frames_rejected: [AtomicU64; 3],
    requests: [[AtomicU64; RequestResult::COUNT]; FUNCTION_COUNT],
    /// Requests refused by role, by the role's label (bounded by the configured roles).
    refused: Mutex<BTreeMap<String, u64>>,
    handshakes_failed: AtomicU64,
    /// The Prometheus families the counts are mirrored into, if any (the server's own, and
    /// the audit's through [`Self::audit`]).
    metrics: Option<(ServerMetrics, AuditMetrics)>,
    /// The request series of `metrics`, each looked up once.
    request_series: [[OnceLock<IntCounter>; RequestResult::COUNT]; FUNCTION_COUNT],
}

// === impl ServerStats ===

impl ServerStats {
    /// All counters at zero.
    pub fn new() -> Self {
        Self::default()
    }

    /// All counters at zero, every count also made in the server's Prometheus families, and
    /// the writes in the audit's.
    pub fn with_metrics(server: ServerMetrics, audit: AuditMetrics) -> Self {
        Self {
            metrics: Some((server, audit)),
            ..Self::default()
        }
    }

    /// Connections being served now.
    pub fn connections_open(&self) -> u64 {
        self.connections_open.load(Ordering::Relaxed)
    }

    /// Connections accepted and served since start.
    pub fn connections_accepted(&self) -> u64 {
        self.connections_accepted.load(Ordering::Relaxed)
    }

    /// Connections closed at accept for `reason`.
    pub fn connections_rejected(&self, reason: RejectReason) -> u64 {
        self.rejected[reason as usize].load(Ordering::Relaxed)
    }

    /// Failed `accept()` calls of `kind`.
    pub fn accept_errors(&self, kind: AcceptError) -> u64 {
        self.accept_errors[kind as usize].load(Ordering::Relaxed)
    }

    /// Served connections that ended for `reason`.
    pub fn connections_closed(&self, reason: CloseReason) -> u64 {
        self.closed[reason as usize].load(Ordering::Relaxed)
    }

    /// Frames refused for `reason`.
    pub fn frames_rejected(&self, reason: FrameReject) -> u64 {
        self.frames_rejected[reason as usize].load(Ordering::Relaxed)
    }

    /// Requests with function code `function` that got `result` (codes without a label of
    /// their own count together, as in the metric).
    pub fn request_count(&self, function: u8, result: RequestResult) -> u64 {
        self.requests[function_index(function)][result.index()].load(Ordering::Relaxed)
    }

    /// Every non-zero request counter.
    pub fn requests(&self) -> Vec<RequestCount> {
        let mut counts = Vec::new();
        for (f, row) in self.requests.iter().enumerate() {
            for (r, counter) in row.iter().enumerate() {
                let count = counter.load(Ordering::Relaxed);
                if count > 0 {
                    counts.push(RequestCount {
                        function: function_label_at(f),
                        result: RequestResult::label_at(r),
                        count,
                    });
                }
            }
        }
        counts
    }

    /// Modbus/TCP Security requests refused for the role labelled `role` (see
    /// [`super::Authority::label`]).
    pub fn refused(&self, role: &str) -> u64 {
        self.refused
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .get(role)
            .copied()
            .unwrap_or(0)
    }

    /// Modbus/TCP Security handshakes that failed or timed out.
    pub fn handshakes_failed(&self) -> u64 {
        self.handshakes_failed.load(Ordering::Relaxed)
    }

    /// The audit's Prometheus family the server's writes are counted in, if any.
    pub(crate) fn audit(&self) -> Option<&AuditMetrics> {
        self.metrics.as_ref().map(|(_, audit)| audit)
    }

    fn families(&self) -> Option<&ServerMetrics> {
        self.metrics.as_ref().map(|(server, _)| server)
    }

    /// Calls `f` with the server's families, if the counts are mirrored there.
    fn each(&self, f: impl FnOnce(&ServerMetrics)) {
        if let Some(m) = self.families() {
            f(m);
        }
    }

    pub(crate) fn count_refused(&self, role: &str) {
        *self
            .refused
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .entry(role.to_owned())
            .or_default() += 1;
        self.each(|m| m.refused(role));
    }

    pub(crate) fn count_handshake_failed(&self) {
        self.handshakes_failed.fetch_add(1, Ordering::Relaxed);
        self.each(|m| m.handshake_failed());
    }

    pub(crate) fn count_accepted(self: &Arc<Self>) -> OpenConnection {
        self.connections_accepted.fetch_add(1, Ordering::Relaxed);
        self.connections_open.fetch_add(1, Ordering::Relaxed);
        OpenConnection {
            stats: Arc::clone(self),
            _metrics: self.families().map(ServerMetrics::connection_accepted),
        }
    }

    pub(crate) fn count_rejected(&self, reason: RejectReason) {
        self.rejected[reason as usize].fetch_add(1, Ordering::Relaxed);
        self.each(|m| m.connection_rejected(reason));
    }

    pub(crate) fn count_accept_error(&self, kind: AcceptError) {
        self.accept_errors[kind as usize].fetch_add(1, Ordering::Relaxed);
        self.each(|m| m.accept_failed());
    }

    pub(crate) fn count_closed(&self, reason: CloseReason) {
        self.closed[reason as usize].fetch_add(1, Ordering::Relaxed);
        self.each(|m| m.connection_closed(reason));
    }

    pub(crate) fn count_frame_rejected(&self, reason: FrameReject) {
        self.frames_rejected[reason as usize].fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn count_request(&self, function: u8, result: RequestResult) {
        let (row, column) = (function_index(function), result.index());
        self.requests[row][column].fetch_add(1, Ordering::Relaxed);
        let Some(m) = self.families() else {
            return;
        };
        // Every function or exception code without a label of its own shares one series, as it
        // shares one counter here.
        match self.request_series.get(row).and_then(|r| r.get(column)) {
            Some(series) => series
                .get_or_init(|| m.request_series(function, result))
                .inc(),
            None => m.request(function, result),
        }
    }
}

/// Keeps `connections_open` (and `gateway_modbus_tcp_connections`) up while a connection is
/// served.
#[derive(Debug)]
pub(crate) struct OpenConnection {
    stats: Arc<ServerStats>,
    _metrics: Option<TcpConnectionGuard>,
}

impl Drop for OpenConnection {
    fn drop(&mut self) {
        self.stats.connections_open.fetch_sub(1, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use proto_core::modbus::pdu::ExceptionCode;

    use super::*;

    #[test]
    fn labels_stay_bounded() {
        let stats = ServerStats::new();
        for function in 0..=u8::MAX {
            stats.count_request(
                function,
                RequestResult::Exception(ExceptionCode::Other(function)),
            );
            stats.count_request(function, RequestResult::Ok);
        }
        let counts = stats.requests();
        assert!(counts.len() <= FUNCTION_COUNT * RequestResult::COUNT);
        let other = counts
            .iter()
            .find(|c| c.function == "other" && c.result == "ok")
            .expect("other");
        assert_eq!(other.count, 256 - (FUNCTION_COUNT as u64 - 1));
        assert_eq!(stats.request_count(0x03, RequestResult::Ok), 1);
        assert_eq!(stats.request_count(0x42, RequestResult::Ok), other.count);
        let code_03 = RequestResult::Exception(ExceptionCode::IllegalDataValue);
        // Function 0x03 got Other(0x03), which counts as exception 03.
        assert_eq!(stats.request_count(0x03, code_03), 1);
    }

    #[test]
    fn counts_are_mirrored_into_the_prometheus_families() {
        let registry = Registry::new();
        let stats = Arc::new(ServerStats::with_metrics(
            ServerMetrics::register(&registry).expect("register"),
            AuditMetrics::register(&registry).expect("register"),
        ));
        let open = stats.count_accepted();
        stats.count_rejected(RejectReason::Limit);
        stats.count_accept_error(AcceptError::ProcessFdLimit);
        stats.count_request(0x03, RequestResult::Ok);
        stats.count_request(
            0x10,
            RequestResult::Exception(ExceptionCode::GatewayTargetFailedToRespond),
        );
        let text = crate::metrics::encode_text(&registry);
        for expected in [
            "gateway_modbus_tcp_connections 1",
            "gateway_modbus_tcp_connections_accepted_total 1",
            r#"gateway_modbus_tcp_connections_rejected_total{reason="limit"} 1"#,
            r#"gateway_modbus_tcp_connections_rejected_total{reason="network"} 0"#,
            r#"gateway_modbus_tcp_connections_rejected_total{reason="accept_error"} 1"#,
            r#"gateway_modbus_tcp_requests_total{function="03",result="ok"} 1"#,
            r#"gateway_modbus_tcp_requests_total{function="10",result="exception_0B"} 1"#,
        ] {
            assert!(text.contains(expected), "{expected} missing in\n{text}");
        }
        // Counted again through the kept series; the functions and exceptions counted together
        // here keep their own labels there.
        stats.count_request(0x03, RequestResult::Ok);
        stats.count_request(0x43, RequestResult::Ok);
        stats.count_request(0x42, RequestResult::Ok);
        stats.count_request(0x03, RequestResult::Exception(ExceptionCode::Other(0x42)));
        stats.count_request(0x03, RequestResult::Exception(ExceptionCode::Other(0x43)));
        let text = crate::metrics::encode_text(&registry);
        for expected in [
            r#"gateway_modbus_tcp_requests_total{function="03",result="ok"} 2"#,
            r#"gateway_modbus_tcp_requests_total{function="43",result="ok"} 1"#,
            r#"gateway_modbus_tcp_requests_total{function="other",result="ok"} 1"#,
            r#"gateway_modbus_tcp_requests_total{function="03",result="exception_other"} 2"#,
        ] {
            assert!(text.contains(expected), "{expected} missing in\n{text}");
        }
        drop(open);
        let text = crate::metrics::encode_text(&registry);
        assert!(text.contains("gateway_modbus_tcp_connections 0"), "{text}");
    }

    #[test]
    fn every_connection_end_is_counted_by_reason() {
        let registry = Registry::new();
        let stats = ServerStats::with_metrics(
            ServerMetrics::register(&registry).expect("register"),
            AuditMetrics::register(&registry).expect("register"),
        );
        stats.count_closed(CloseReason::Peer);
        stats.count_closed(CloseReason::Peer);
        stats.count_closed(CloseReason::Idle);
        stats.count_closed(CloseReason::BadFrame);
        stats.count_closed(CloseReason::Shutdown);
        stats.count_rejected(RejectReason::Limit);
        stats.count_rejected(RejectReason::Network);
        stats.count_handshake_failed();
        assert_eq!(stats.connections_closed(CloseReason::Peer), 2);
        let text = crate::metrics::encode_text(&registry);
        for expected in [
            r#"gateway_modbus_tcp_connections_closed_total{reason="client"} 2"#,
            r#"gateway_modbus_tcp_connections_closed_total{reason="idle"} 1"#,
            r#"gateway_modbus_tcp_connections_closed_total{reason="bad_frame"} 1"#,
            r#"gateway_modbus_tcp_connections_closed_total{reason="io_error"} 0"#,
            r#"gateway_modbus_tcp_connections_closed_total{reason="shutdown"} 1"#,
            r#"gateway_modbus_tcp_connections_closed_total{reason="limit"} 1"#,
            r#"gateway_modbus_tcp_connections_closed_total{reason="network"} 1"#,
            r#"gateway_modbus_tcp_connections_closed_total{reason="tls_handshake"} 1"#,
        ] {
            assert!(text.contains(expected), "{expected} missing in\n{text}");
        }
    }

    #[test]
    fn connection_guard_counts_open_connections() {
        let metrics = ServerMetrics::register(&Registry::new()).expect("register");
        let first = metrics.connection_accepted();
        let second = metrics.connection_accepted();
        assert_eq!(metrics.connections.get(), 2);
        drop(first);
        assert_eq!(metrics.connections.get(), 1);
        drop(second);
        assert_eq!(metrics.connections.get(), 0);
        assert_eq!(metrics.accepted.get(), 2);
    }

    #[test]
    fn open_connections_fall_when_dropped() {
        let stats = Arc::new(ServerStats::new());
        let first = stats.count_accepted();
        let second = stats.count_accepted();
        assert_eq!(stats.connections_open(), 2);
        drop(first);
        assert_eq!(stats.connections_open(), 1);
        drop(second);
        assert_eq!(
            (stats.connections_open(), stats.connections_accepted()),
            (0, 2)
        );
    }
}
