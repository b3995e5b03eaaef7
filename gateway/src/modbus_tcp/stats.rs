//! Counters of the Modbus TCP server.
//!
//! Every label set is bounded and carries no client address, no register address. With
//! [`ServerStats::with_metrics`] every count is mirrored into the Prometheus families of
//! [`Metrics`]: open and accepted connections, rejected ones by reason (failed accepts as
//! `accept_error`), closed ones by reason, requests by function and result.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock, PoisonError};

use prometheus::IntCounter;

use crate::metrics::{self, Metrics, TcpConnectionGuard};

/// Why a connection was closed at accept.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum RejectReason {
    /// `max_connections` connections were open.
    Limit,
    /// The client is outside `allowed_networks`.
    Network,
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

/// Function codes counted by name; the others share `"other"`.
const FUNCTIONS: [u8; 15] = [
    0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x0B, 0x0C, 0x0F, 0x10, 0x11, 0x17, 0x2B,
];
const FUNCTION_LABELS: [&str; 16] = [
    "01", "02", "03", "04", "05", "06", "07", "08", "0B", "0C", "0F", "10", "11", "17", "2B",
    "other",
];
/// Exception codes counted by name; the others share `"other"`. Index 0 is `"ok"`.
const EXCEPTIONS: [u8; 10] = [0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x0A, 0x0B];
const RESULT_LABELS: [&str; 12] = [
    "ok", "01", "02", "03", "04", "05", "06", "07", "08", "0A", "0B", "other",
];

/// The answer a request got: [`RequestResult::Ok`] or [`RequestResult::Exception`] (the server
/// answers a device that did not reply with exception 0Bh, so it never counts `Timeout` or `Error`;
/// should it, they count with the unknown exception codes).
pub use crate::metrics::RequestResult;

/// One line of [`ServerStats::requests`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RequestCount {
    /// Function code as two upper-case hex digits (`"03"`), or `"other"`.
    pub function: &'static str,
    /// `"ok"`, the exception code as two upper-case hex digits (`"0B"`), or `"other"`.
    pub result: &'static str,
    /// Requests so far.
    pub count: u64,
}

/// Counters of one server. Shared by `serve` and whoever exports them.
#[derive(Debug, Default)]
pub struct ServerStats {
    connections_open: AtomicU64,
    connections_accepted: AtomicU64,
    rejected_limit: AtomicU64,
    rejected_network: AtomicU64,
    accept_errors: [AtomicU64; 4],
    closed: [AtomicU64; 5],
    frames_rejected: [AtomicU64; 3],
    requests: [[AtomicU64; RESULT_LABELS.len()]; FUNCTION_LABELS.len()],
    /// Requests refused by role, by the role's label (bounded by the configured roles).
    refused: Mutex<BTreeMap<String, u64>>,
    handshakes_failed: AtomicU64,
    /// The Prometheus families the counts are mirrored into, if any.
    metrics: Option<Metrics>,
    /// The request series of `metrics` for the functions counted by name, each looked up once
    /// (the series of a function counted as `"other"` here may have a label of its own there, so
    /// those are looked up every time).
    request_series: [[OnceLock<IntCounter>; RESULT_LABELS.len()]; FUNCTIONS.len()],
}

// === impl ServerStats ===

impl ServerStats {
    /// All counters at zero.
    pub fn new() -> Self {
        Self::default()
    }

    /// All counters at zero, every count also made in the Prometheus families of `metrics`.
    pub fn with_metrics(metrics: Metrics) -> Self {
        Self {
            metrics: Some(metrics),
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
        match reason {
            RejectReason::Limit => &self.rejected_limit,
            RejectReason::Network => &self.rejected_network,
        }
        .load(Ordering::Relaxed)
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

    /// Requests with function code `function` that got `result` (unknown codes count together).
    pub fn request_count(&self, function: u8, result: RequestResult) -> u64 {
        self.requests[function_index(function)][result_index(result)].load(Ordering::Relaxed)
    }

    /// Every non-zero request counter.
    pub fn requests(&self) -> Vec<RequestCount> {
        let mut counts = Vec::new();
        for (function, row) in FUNCTION_LABELS.iter().zip(&self.requests) {
            for (result, counter) in RESULT_LABELS.iter().zip(row) {
                let count = counter.load(Ordering::Relaxed);
                if count > 0 {
                    counts.push(RequestCount {
                        function,
                        result,
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

    /// The Prometheus families the counts are mirrored into, if any.
    pub(crate) fn metrics(&self) -> Option<&Metrics> {
        self.metrics.as_ref()
    }

    pub(crate) fn count_refused(&self, role: &str) {
        *self
            .refused
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .entry(role.to_owned())
            .or_default() += 1;
        if let Some(m) = &self.metrics {
            m.tcp_refused(role);
        }
    }

    pub(crate) fn count_handshake_failed(&self) {
        self.handshakes_failed.fetch_add(1, Ordering::Relaxed);
        if let Some(m) = &self.metrics {
            m.tcp_handshake_failed();
            m.tcp_connection_closed(metrics::TcpCloseReason::TlsHandshake);
        }
    }

    pub(crate) fn count_accepted(self: &Arc<Self>) -> OpenConnection {
        self.connections_accepted.fetch_add(1, Ordering::Relaxed);
        self.connections_open.fetch_add(1, Ordering::Relaxed);
        OpenConnection {
            stats: Arc::clone(self),
            _metrics: self.metrics.as_ref().map(Metrics::tcp_connection_accepted),
        }
    }

    pub(crate) fn count_rejected(&self, reason: RejectReason) {
        match reason {
            RejectReason::Limit => &self.rejected_limit,
            RejectReason::Network => &self.rejected_network,
        }
        .fetch_add(1, Ordering::Relaxed);
        if let Some(m) = &self.metrics {
            let (rejected, closed) = match reason {
                RejectReason::Limit => {
                    (metrics::RejectReason::Limit, metrics::TcpCloseReason::Limit)
                }
                RejectReason::Network => (
                    metrics::RejectReason::Network,
                    metrics::TcpCloseReason::Network,
                ),
            };
            m.tcp_connection_rejected(rejected);
            m.tcp_connection_closed(closed);
        }
    }

    pub(crate) fn count_accept_error(&self, kind: AcceptError) {
        self.accept_errors[kind as usize].fetch_add(1, Ordering::Relaxed);
        if let Some(m) = &self.metrics {
            m.tcp_connection_rejected(metrics::RejectReason::AcceptError);
        }
    }

    pub(crate) fn count_closed(&self, reason: CloseReason) {
        self.closed[reason as usize].fetch_add(1, Ordering::Relaxed);
        if let Some(m) = &self.metrics {
            m.tcp_connection_closed(match reason {
                CloseReason::Peer => metrics::TcpCloseReason::Client,
                CloseReason::Idle => metrics::TcpCloseReason::Idle,
                CloseReason::BadFrame => metrics::TcpCloseReason::BadFrame,
                CloseReason::Io => metrics::TcpCloseReason::IoError,
                CloseReason::Shutdown => metrics::TcpCloseReason::Shutdown,
            });
        }
    }

    pub(crate) fn count_frame_rejected(&self, reason: FrameReject) {
        self.frames_rejected[reason as usize].fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn count_request(&self, function: u8, result: RequestResult) {
        let (row, column) = (function_index(function), result_index(result));
        self.requests[row][column].fetch_add(1, Ordering::Relaxed);
        let Some(m) = &self.metrics else {
            return;
        };
        let labelled = result;
        // Every exception code counted as "other" here is "exception_other" there as well.
        match self.request_series.get(row).and_then(|r| r.get(column)) {
            Some(series) => series
                .get_or_init(|| m.tcp_request_series(function, labelled))
                .inc(),
            None => m.tcp_request(function, labelled),
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

fn function_index(function: u8) -> usize {
    FUNCTIONS
        .iter()
        .position(|&known| known == function)
        .unwrap_or(FUNCTIONS.len())
}

fn result_index(result: RequestResult) -> usize {
    let code = match result {
        RequestResult::Ok => return 0,
        RequestResult::Exception(code) => code,
        RequestResult::Timeout | RequestResult::Error => return RESULT_LABELS.len() - 1,
    };
    let byte = u8::from(code);
    EXCEPTIONS
        .iter()
        .position(|&known| known == byte)
        .map_or(RESULT_LABELS.len() - 1, |at| at + 1)
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
        assert!(counts.len() <= FUNCTION_LABELS.len() * RESULT_LABELS.len());
        let other = counts
            .iter()
            .find(|c| c.function == "other" && c.result == "ok")
            .expect("other");
        assert_eq!(other.count, 256 - FUNCTIONS.len() as u64);
        assert_eq!(stats.request_count(0x03, RequestResult::Ok), 1);
        assert_eq!(stats.request_count(0x42, RequestResult::Ok), other.count);
        let code_03 = RequestResult::Exception(ExceptionCode::IllegalDataValue);
        // Function 0x03 got Other(0x03), which counts as exception 03.
        assert_eq!(stats.request_count(0x03, code_03), 1);
    }

    #[test]
    fn counts_are_mirrored_into_the_prometheus_families() {
        let registry = prometheus::Registry::new();
        let stats = Arc::new(ServerStats::with_metrics(
            Metrics::register(&registry).expect("register"),
        ));
        let open = stats.count_accepted();
        stats.count_rejected(RejectReason::Limit);
        stats.count_accept_error(AcceptError::ProcessFdLimit);
        stats.count_request(0x03, RequestResult::Ok);
        stats.count_request(
            0x10,
            RequestResult::Exception(ExceptionCode::GatewayTargetFailedToRespond),
        );
        let text = metrics::encode_text(&registry);
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
        let text = metrics::encode_text(&registry);
        for expected in [
            r#"gateway_modbus_tcp_requests_total{function="03",result="ok"} 2"#,
            r#"gateway_modbus_tcp_requests_total{function="43",result="ok"} 1"#,
            r#"gateway_modbus_tcp_requests_total{function="other",result="ok"} 1"#,
            r#"gateway_modbus_tcp_requests_total{function="03",result="exception_other"} 2"#,
        ] {
            assert!(text.contains(expected), "{expected} missing in\n{text}");
        }
        drop(open);
        let text = metrics::encode_text(&registry);
        assert!(text.contains("gateway_modbus_tcp_connections 0"), "{text}");
    }

    #[test]
    fn every_connection_end_is_counted_by_reason() {
        let registry = prometheus::Registry::new();
        let stats = ServerStats::with_metrics(Metrics::register(&registry).expect("register"));
        stats.count_closed(CloseReason::Peer);
        stats.count_closed(CloseReason::Peer);
        stats.count_closed(CloseReason::Idle);
        stats.count_closed(CloseReason::BadFrame);
        stats.count_closed(CloseReason::Shutdown);
        stats.count_rejected(RejectReason::Limit);
        stats.count_rejected(RejectReason::Network);
        stats.count_handshake_failed();
        assert_eq!(stats.connections_closed(CloseReason::Peer), 2);
        let text = metrics::encode_text(&registry);
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
