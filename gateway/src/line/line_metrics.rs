//! The counters of a line and their Prometheus side: one handle per line task that knows the
//! line's name and protocol. Frames and bytes per direction are counted here since the line
//! started ([`LineTraffic`], what REST shows) and, when the gateway exports metrics, into the
//! Prometheus families at the same time (cumulative over the process).
//!
//! The line tasks call it where the status is updated, so that the status (diagnostic buffer,
//! counters), the log and `/metrics` tell the same story: every event raised, the start-up event
//! 00 03h, the port's state, telegrams and bytes on the wire, and per device the Modbus requests,
//! the poll durations, whether it answers and when its image was last updated.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use proto_core::event::{ids, EventId};
use proto_core::modbus::master::Outcome;
use proto_core::modbus::slave;

use crate::metrics::{Direction, Metrics, PollCycleKind, RequestResult};

/// The `device` label of master requests to slave address 0 (broadcast, 003 6.4.3 "ADDR").
pub(crate) const BROADCAST_DEVICE: &str = "broadcast";
/// The `device` label of master requests to a slave address no configured device has.
pub(crate) const UNKNOWN_DEVICE: &str = "unknown";
/// The `device` label of the requests a Modbus slave line serves: its partner, the serial master.
pub(crate) const SLAVE_LINE_PARTNER: &str = "master";

/// Frames and bytes in each direction and commands of one line since it started.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LineTraffic {
    /// Frames (telegrams) written.
    pub frames_sent: u64,
    /// Frames (telegrams) received complete.
    pub frames_received: u64,
    /// Bytes written.
    pub bytes_sent: u64,
    /// Bytes read.
    pub bytes_received: u64,
    /// Commands answered (Modbus master: by the device, exceptions included; slave: requests
    /// served; telegram lines: telegrams sent).
    pub commands_answered: u64,
    /// Commands that failed (no answer, an exception served, a send given up).
    pub commands_failed: u64,
}

/// The frame and byte counts of a line (relaxed atomics: counts, not synchronisation).
#[derive(Debug, Default)]
struct Wire {
    frames_sent: AtomicU64,
    frames_received: AtomicU64,
    bytes_sent: AtomicU64,
    bytes_received: AtomicU64,
}

/// The counters and metrics of one line; the Prometheus side is a no-op without metrics.
#[derive(Clone, Debug, Default)]
pub(crate) struct LineMetrics {
    wire: Arc<Wire>,
    inner: Option<Inner>,
}

#[derive(Clone, Debug)]
struct Inner {
    metrics: Metrics,
    line: String,
    protocol: &'static str,
}

// === impl LineMetrics ===

impl LineMetrics {
    /// The metrics of the line `line` speaking `protocol` (the config's `protocol` key); creates
    /// its series at 0 (line down) so that it shows before its port opens.
    pub(crate) fn new(metrics: Option<Metrics>, line: &str, protocol: &'static str) -> Self {
        let inner = metrics.map(|metrics| {
            metrics.init_line(line, protocol);
            Inner {
                metrics,
                line: line.to_owned(),
                protocol,
            }
        });
        Self {
            wire: Arc::default(),
            inner,
        }
    }

    /// Frames and bytes since the line started (commands zero: the status counts them).
    pub(crate) fn traffic(&self) -> LineTraffic {
        let w = &self.wire;
        LineTraffic {
            frames_sent: w.frames_sent.load(Ordering::Relaxed),
            frames_received: w.frames_received.load(Ordering::Relaxed),
            bytes_sent: w.bytes_sent.load(Ordering::Relaxed),
            bytes_received: w.bytes_received.load(Ordering::Relaxed),
            commands_answered: 0,
            commands_failed: 0,
        }
    }

    /// The line took its parameters and its port is open: line up and event 00 03h counted
    /// (the event itself is raised by [`Shared::started`](super::status::Shared::started)).
    pub(crate) fn started(&self) {
        if let Some(i) = &self.inner {
            i.metrics.line_started(&i.line, i.protocol);
        }
    }

    /// The port closed or failed: line down.
    pub(crate) fn port_closed(&self) {
        if let Some(i) = &self.inner {
            i.metrics.set_line_up(&i.line, i.protocol, false);
        }
    }

    /// One event raised on the line.
    pub(crate) fn event(&self, id: EventId) {
        if let Some(i) = &self.inner {
            i.metrics.event(&i.line, id);
        }
    }

    /// `len` bytes written to the port (telegram lines: framing included).
    pub(crate) fn sent_bytes(&self, len: usize) {
        self.wire
            .bytes_sent
            .fetch_add(len as u64, Ordering::Relaxed);
        if let (Some(i), true) = (&self.inner, len > 0) {
            i.metrics.bytes(&i.line, Direction::Tx, len);
        }
    }

    /// One frame written (Modbus lines), or one user telegram sent and acknowledged by the
    /// partner (telegram lines).
    pub(crate) fn sent_telegram(&self) {
        self.wire.frames_sent.fetch_add(1, Ordering::Relaxed);
        if let Some(i) = &self.inner {
            i.metrics.telegram(&i.line, Direction::Tx);
        }
    }

    /// `len` bytes read from the port.
    pub(crate) fn received_bytes(&self, len: usize) {
        self.wire
            .bytes_received
            .fetch_add(len as u64, Ordering::Relaxed);
        if let Some(i) = &self.inner {
            i.metrics.bytes(&i.line, Direction::Rx, len);
        }
    }

    /// One complete telegram (frame) received and accepted.
    pub(crate) fn received_telegram(&self) {
        self.wire.frames_received.fetch_add(1, Ordering::Relaxed);
        if let Some(i) = &self.inner {
            i.metrics.telegram(&i.line, Direction::Rx);
        }
    }

    /// Creates the series of a configured device at 0 (down, empty histogram).
    pub(crate) fn init_device(&self, device: &str) {
        if let Some(i) = &self.inner {
            i.metrics.init_device(&i.line, device);
        }
    }

    /// Creates the slave line's discard series at 0, one per reason.
    pub(crate) fn init_frames_discarded(&self, reasons: &[&'static str]) {
        if let Some(i) = &self.inner {
            i.metrics.init_frames_discarded(&i.line, reasons);
        }
    }

    /// One received frame discarded unanswered by a slave line, for `reason`.
    pub(crate) fn frame_discarded(&self, reason: &'static str) {
        if let Some(i) = &self.inner {
            i.metrics.frame_discarded(&i.line, reason);
        }
    }

    /// One Modbus request with function code `function` to (or, on a slave line, from) `device`.
    pub(crate) fn request(&self, device: &str, function: u8, result: RequestResult) {
        if let Some(i) = &self.inner {
            i.metrics.modbus_request(&i.line, device, function, result);
        }
    }

    /// The duration of one poll exchange of `device`.
    pub(crate) fn poll_duration(&self, device: &str, duration: Duration) {
        if let Some(i) = &self.inner {
            i.metrics.poll_duration(&i.line, device, duration);
        }
    }

    /// The poll cycle of the poll group of `period` of `device`.
    pub(crate) fn poll_cycle(
        &self,
        device: &str,
        period: Duration,
        kind: PollCycleKind,
        value: Duration,
    ) {
        if let Some(i) = &self.inner {
            i.metrics
                .set_poll_cycle(&i.line, device, period, kind, value);
        }
    }

    /// Whether `device` answers.
    pub(crate) fn device_up(&self, device: &str, up: bool) {
        if let Some(i) = &self.inner {
            i.metrics.set_device_up(&i.line, device, up);
        }
    }

    /// The image of `device` was updated from a reply just now.
    pub(crate) fn image_updated(&self, device: &str) {
        if let Some(i) = &self.inner {
            i.metrics
                .device_image_updated(&i.line, device, std::time::Instant::now());
        }
    }
}

/// The `result` label of a master transaction: no reply within the reply monitoring time (event
/// 08 30h, 003 7.2) is a timeout, any other failure (checksum, wrong slave, bad length: the event
/// of the last attempt's first error) an error. A broadcast is sent and never answered
/// (003 6.4.3 "ADDR"): it counts as ok.
pub(crate) fn master_result<R>(outcome: &Outcome<R>) -> RequestResult {
    match outcome {
        Outcome::Response(_) | Outcome::Broadcast => RequestResult::Ok,
        Outcome::Exception(code) => RequestResult::Exception(*code),
        Outcome::Failed(id) if *id == ids::MODBUS_NO_REPLY => RequestResult::Timeout,
        Outcome::Failed(_) => RequestResult::Error,
    }
}

/// The `result` label of a request a slave line served: a refused broadcast counts with the
/// exception it would have been answered with.
pub(crate) fn slave_result(outcome: slave::Outcome) -> RequestResult {
    match outcome {
        slave::Outcome::Answered | slave::Outcome::BroadcastApplied => RequestResult::Ok,
        slave::Outcome::Exception(code) | slave::Outcome::BroadcastRefused(code) => {
            RequestResult::Exception(code)
        }
    }
}

#[cfg(test)]
mod tests {
    use prometheus::Registry;
    use proto_core::modbus::pdu::ExceptionCode;

    use super::*;
    use crate::metrics::encode_text;

    #[test]
    fn outcomes_map_to_their_result_labels() {
        let code = ExceptionCode::IllegalDataAddress;
        assert_eq!(master_result(&Outcome::Response(())), RequestResult::Ok);
        assert_eq!(master_result::<()>(&Outcome::Broadcast), RequestResult::Ok);
        assert_eq!(
            master_result::<()>(&Outcome::Exception(code)),
            RequestResult::Exception(code)
        );
        assert_eq!(
            master_result::<()>(&Outcome::Failed(ids::MODBUS_NO_REPLY)),
            RequestResult::Timeout
        );
        assert_eq!(
            master_result::<()>(&Outcome::Failed(EventId::new(0x0E, 0x57))),
            RequestResult::Error
        );
        assert_eq!(
            slave_result(slave::Outcome::BroadcastRefused(code)),
            RequestResult::Exception(code)
        );
        assert_eq!(
            slave_result(slave::Outcome::BroadcastApplied),
            RequestResult::Ok
        );
    }

    #[test]
    fn a_line_without_metrics_records_nothing_and_one_with_metrics_everything() {
        LineMetrics::new(None, "drive", "modbus-master-rtu").started();
        let registry = Registry::new();
        let metrics = Metrics::register(&registry).expect("register");
        let line = LineMetrics::new(Some(metrics), "drive", "modbus-master-rtu");
        let text = encode_text(&registry);
        assert!(text.contains(r#"gateway_line_up{line="drive",protocol="modbus-master-rtu"} 0"#));
        line.started();
        line.sent_bytes(8);
        line.sent_telegram();
        line.received_bytes(5);
        line.received_telegram();
        line.init_device("atv71");
        line.request("atv71", 0x03, RequestResult::Timeout);
        line.device_up("atv71", true);
        line.image_updated("atv71");
        line.port_closed();
        let text = encode_text(&registry);
        for expected in [
            r#"gateway_line_up{line="drive",protocol="modbus-master-rtu"} 0"#,
            r#"gateway_events_total{class="00",class_name="cp start-up",event="0003",line="drive"} 1"#,
            r#"gateway_bytes_total{direction="tx",line="drive"} 8"#,
            r#"gateway_bytes_total{direction="rx",line="drive"} 5"#,
            r#"gateway_telegrams_total{direction="rx",line="drive"} 1"#,
            r#"gateway_modbus_requests_total{device="atv71",function="03",line="drive",result="timeout"} 1"#,
            r#"gateway_device_up{device="atv71",line="drive"} 1"#,
            r#"gateway_device_image_age_seconds{device="atv71",line="drive"}"#,
        ] {
            assert!(text.contains(expected), "{expected} missing in\n{text}");
        }
    }

    #[test]
    fn the_line_counts_its_traffic_with_or_without_metrics() {
        for metrics in [
            None,
            Some(Metrics::register(&Registry::new()).expect("register")),
        ] {
            let line = LineMetrics::new(metrics, "drive", "modbus-master-rtu");
            line.sent_bytes(8);
            line.sent_telegram();
            line.received_bytes(5);
            line.received_bytes(2);
            line.received_telegram();
            assert_eq!(
                line.traffic(),
                LineTraffic {
                    frames_sent: 1,
                    frames_received: 1,
                    bytes_sent: 8,
                    bytes_received: 7,
                    commands_answered: 0,
                    commands_failed: 0,
                }
            );
        }
    }
}
