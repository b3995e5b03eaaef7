//! The counters of a line and their Prometheus side: one handle per line task that knows the
//! line's name and protocol. Frames and bytes per direction are counted here since the line
//! started ([`LineTraffic`], what REST shows) and, when the gateway exports metrics, into the
//! Prometheus families at the same time (cumulative over the process).
//!
//! The line tasks call it where the status is updated, so that the status (diagnostic buffer,
//! counters), the log and `/metrics` tell the same story: every event raised, the start-up event
//! 00 03h, the port's state, telegrams and bytes on the wire, and per device the Modbus requests,
//! the poll durations, whether it answers and when its image was last updated.
//!
//! The families themselves are the line subsystem's too: [`LineFamilies::register`] defines them
//! (called by `Metrics::register` in `main`), with the labels' vocabulary of the lines written
//! once as enums: [`FrameDiscard`] (the receivers' own discard reasons), [`MonitorDrop`] and
//! [`PollCycleKind`]; `direction`, `function` and `result` are shared with the Modbus TCP server
//! (`crate::metrics::labels`).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use prometheus::{
    GaugeVec, Histogram, HistogramOpts, HistogramVec, IntCounter, IntCounterVec, IntGaugeVec, Opts,
    Registry,
};
use proto_core::event::{self, ids, EventId};
use proto_core::modbus::master::Outcome;
use proto_core::modbus::{rtu, slave};
use proto_core::proc3964::tap::Fault;

use super::image_age::ImageAge;
use crate::metrics::labels::{function_label, label_enum, Direction, RequestResult};

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
    families: LineFamilies,
    line: String,
    protocol: &'static str,
}

// === impl LineMetrics ===

impl LineMetrics {
    /// The metrics of the line `line` speaking `protocol` (the config's `protocol` key); creates
    /// its series at 0 (line down) so that it shows before its port opens.
    pub(crate) fn new(families: Option<LineFamilies>, line: &str, protocol: &'static str) -> Self {
        let inner = families.map(|families| {
            families.init_line(line, protocol);
            Inner {
                families,
                line: line.to_owned(),
                protocol,
            }
        });
        Self {
            wire: Arc::default(),
            inner,
        }
    }

    /// Calls `f` with the line's families and labels; nothing without metrics.
    fn each(&self, f: impl FnOnce(&Inner)) {
        if let Some(inner) = &self.inner {
            f(inner);
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
        self.each(|i| i.families.line_started(&i.line, i.protocol));
    }

    /// The port closed or failed: line down.
    pub(crate) fn port_closed(&self) {
        self.each(|i| i.families.set_line_up(&i.line, i.protocol, false));
    }

    /// One event raised on the line.
    pub(crate) fn event(&self, id: EventId) {
        self.each(|i| i.families.event(&i.line, id));
    }

    /// `len` bytes written to the port (telegram lines: framing included).
    pub(crate) fn sent_bytes(&self, len: usize) {
        self.wire
            .bytes_sent
            .fetch_add(len as u64, Ordering::Relaxed);
        if let (Some(i), true) = (&self.inner, len > 0) {
            i.families.bytes(&i.line, Direction::Tx, len);
        }
    }

    /// One frame written (Modbus lines), or one user telegram sent and acknowledged by the
    /// partner (telegram lines).
    pub(crate) fn sent_telegram(&self) {
        self.wire.frames_sent.fetch_add(1, Ordering::Relaxed);
        self.each(|i| i.families.telegram(&i.line, Direction::Tx));
    }

    /// `len` bytes read from the port.
    pub(crate) fn received_bytes(&self, len: usize) {
        self.wire
            .bytes_received
            .fetch_add(len as u64, Ordering::Relaxed);
        self.each(|i| i.families.bytes(&i.line, Direction::Rx, len));
    }

    /// One complete telegram (frame) received and accepted.
    pub(crate) fn received_telegram(&self) {
        self.wire.frames_received.fetch_add(1, Ordering::Relaxed);
        self.each(|i| i.families.telegram(&i.line, Direction::Rx));
    }

    /// Creates the series of a configured device at 0 (down, empty histogram).
    pub(crate) fn init_device(&self, device: &str) {
        self.each(|i| i.families.init_device(&i.line, device));
    }

    /// Creates the slave line's discard series at 0, one per reason.
    pub(crate) fn init_frames_discarded<R: Into<FrameDiscard> + Copy>(&self, reasons: &[R]) {
        self.each(|i| i.families.init_frames_discarded(&i.line, reasons));
    }

    /// One received frame discarded unanswered by a slave line, for `reason`.
    pub(crate) fn frame_discarded(&self, reason: impl Into<FrameDiscard>) {
        self.each(|i| i.families.frame_discarded(&i.line, reason));
    }

    /// One Modbus request with function code `function` to (or, on a slave line, from) `device`.
    pub(crate) fn request(&self, device: &str, function: u8, result: RequestResult) {
        self.each(|i| i.families.modbus_request(&i.line, device, function, result));
    }

    /// The duration of one poll exchange of `device`.
    pub(crate) fn poll_duration(&self, device: &str, duration: Duration) {
        self.each(|i| i.families.poll_duration(&i.line, device, duration));
    }

    /// The poll cycle of the poll group of `period` of `device`.
    pub(crate) fn poll_cycle(
        &self,
        device: &str,
        period: Duration,
        kind: PollCycleKind,
        value: Duration,
    ) {
        self.each(|i| {
            i.families
                .set_poll_cycle(&i.line, device, period, kind, value)
        });
    }

    /// Whether `device` answers.
    pub(crate) fn device_up(&self, device: &str, up: bool) {
        self.each(|i| i.families.set_device_up(&i.line, device, up));
    }

    /// The image of `device` was updated from a reply just now.
    pub(crate) fn image_updated(&self, device: &str) {
        self.each(|i| {
            i.families
                .device_image_updated(&i.line, device, Instant::now())
        });
    }
}

/// Why a line did not use a received frame: the `reason` label of
/// `gateway_frames_discarded_total`. The reasons are the receivers' own (the RTU receivers'
/// [`rtu::DiscardReason`], the 3964(R) tap's [`Fault`]); their label is written once, here.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameDiscard {
    /// A frame a Modbus slave line discarded unanswered, or a Modbus tap line did not use.
    Rtu(rtu::DiscardReason),
    /// An exchange a 3964(R) tap line saw fail.
    Tap3964(Fault),
}

// === impl FrameDiscard ===

impl FrameDiscard {
    /// The `reason` label.
    pub const fn as_label(self) -> &'static str {
        match self {
            Self::Rtu(reason) => reason.as_str(),
            Self::Tap3964(fault) => fault.as_str(),
        }
    }
}

impl From<rtu::DiscardReason> for FrameDiscard {
    fn from(reason: rtu::DiscardReason) -> Self {
        Self::Rtu(reason)
    }
}

impl From<Fault> for FrameDiscard {
    fn from(fault: Fault) -> Self {
        Self::Tap3964(fault)
    }
}

label_enum! {
    /// Why a line's frame monitor let a frame go: the `reason` label of
    /// `gateway_monitor_dropped_total`.
    pub enum MonitorDrop {
        /// Pushed out of the full ring by a newer frame.
        Overwritten = "overwritten",
        /// Missed by a live follower that fell behind.
        Lagged = "lagged",
    }
}

label_enum! {
    /// The `kind` label of `gateway_poll_cycle_seconds`.
    pub enum PollCycleKind {
        /// The configured period.
        Planned = "planned",
        /// The longest cycle the fairness rule of the line allows.
        Bound = "bound",
        /// The last cycle.
        Achieved = "achieved",
        /// The longest cycle seen while the device answered.
        AchievedMax = "achieved_max",
    }
}

/// Buckets of `gateway_poll_duration_seconds`, 1 ms .. 5 s.
///
/// One serial exchange takes from about 2 ms (a short FC03 at 115200 baud) over 15..40 ms (the
/// demo's polls at 19200 baud) to over a second (a long read at 300 baud); the reply monitoring
/// time is 2 s by default (003 6.4.3), so a timeout lands in the 2 s or 5 s bucket, and one above
/// 5 s (up to the manual's maximum of 65.5 s) in `+Inf`.
pub const POLL_DURATION_BUCKETS: &[f64] = &[
    0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0,
];

/// The `period` labels of the poll cycle gauges, by line and device.
type PollCyclePeriods = BTreeMap<(String, String), BTreeSet<String>>;

/// The `class_name` label of a class the event catalog does not list.
const UNKNOWN_CLASS: &str = "unknown";

/// The Prometheus families of the serial lines and their polled devices, registered by
/// [`LineFamilies::register`]. Clones share the same series.
#[derive(Clone, Debug)]
pub struct LineFamilies {
    /// `gateway_events_total{line,class,event,class_name}`: every event raised on a line.
    events: IntCounterVec,
    /// `gateway_telegrams_total{line,direction}`: telegrams and Modbus frames.
    telegrams: IntCounterVec,
    /// `gateway_bytes_total{line,direction}`: every byte on the wire, control characters included.
    bytes: IntCounterVec,
    /// `gateway_line_up{line,protocol}`: 1 while the line's port is open and its driver runs.
    line_up: IntGaugeVec,
    /// `gateway_modbus_requests_total{line,device,function,result}`: master requests on a line.
    modbus_requests: IntCounterVec,
    /// `gateway_poll_duration_seconds{line,device}`: request sent .. reply checked or timed out.
    poll_duration: HistogramVec,
    /// `gateway_device_up{line,device}`: 1 while the device answers (not backed off).
    device_up: IntGaugeVec,
    /// `gateway_device_image_age_seconds{line,device}`: computed at scrape time.
    image_age: ImageAge,
    /// `gateway_poll_cycle_seconds{line,device,period,kind}`: planned, bound and achieved poll
    /// cycles of a device's poll groups.
    poll_cycle: GaugeVec,
    /// The `period` labels of `poll_cycle` by line and device, to remove them with the device.
    poll_cycle_periods: Arc<Mutex<PollCyclePeriods>>,
    /// `gateway_frames_discarded_total{line,reason}`: received frames a slave line did not serve
    /// or a tap line did not use.
    frames_discarded: IntCounterVec,
    /// `gateway_monitor_dropped_total{line,reason}`: frames the line's frame monitor let go.
    monitor_dropped: IntCounterVec,
}

// === impl LineFamilies ===

impl LineFamilies {
    /// The names of the families (`app::METRIC_NAMES` chains every owner's).
    pub const NAMES: [&'static str; 11] = [
        "gateway_events_total",
        "gateway_telegrams_total",
        "gateway_bytes_total",
        "gateway_line_up",
        "gateway_modbus_requests_total",
        "gateway_poll_duration_seconds",
        "gateway_device_up",
        "gateway_device_image_age_seconds",
        "gateway_poll_cycle_seconds",
        "gateway_frames_discarded_total",
        "gateway_monitor_dropped_total",
    ];

    /// Registers the line families in `registry`; fails if one is registered already.
    pub fn register(registry: &Registry) -> Result<Self, prometheus::Error> {
        let [events, telegrams, bytes, line_up, modbus_requests, poll_duration, device_up, image_age, poll_cycle, frames_discarded, monitor_dropped] =
            Self::NAMES;
        let families = Self {
            events: IntCounterVec::new(
                Opts::new(
                    events,
                    "Diagnostic events raised on a line, by CP 341 event class and number (manual 7.2).",
                ),
                &["line", "class", "event", "class_name"],
            )?,
            telegrams: IntCounterVec::new(
                Opts::new(telegrams, "Telegrams and Modbus frames received and sent on a line."),
                &["line", "direction"],
            )?,
            bytes: IntCounterVec::new(
                Opts::new(bytes, "Bytes received and sent on a line, control characters included."),
                &["line", "direction"],
            )?,
            line_up: IntGaugeVec::new(
                Opts::new(line_up, "1 while the line's port is open and its driver runs, else 0."),
                &["line", "protocol"],
            )?,
            modbus_requests: IntCounterVec::new(
                Opts::new(
                    modbus_requests,
                    "Modbus master requests on a line, by device, function code and result.",
                ),
                &["line", "device", "function", "result"],
            )?,
            poll_duration: HistogramVec::new(
                HistogramOpts::new(
                    poll_duration,
                    "Time from sending a Modbus request to the checked reply or the timeout.",
                )
                .buckets(POLL_DURATION_BUCKETS.to_vec()),
                &["line", "device"],
            )?,
            device_up: IntGaugeVec::new(
                Opts::new(device_up, "1 while the device answers its polls, else 0."),
                &["line", "device"],
            )?,
            image_age: ImageAge::new(
                image_age,
                "Seconds since the device's image was last updated from a reply.",
            )?,
            poll_cycle: GaugeVec::new(
                Opts::new(
                    poll_cycle,
                    "Poll cycle of a device's poll group (by its configured period): planned, \
                     bound (the longest the fairness rule allows), achieved (the last) and \
                     achieved_max.",
                ),
                &["line", "device", "period", "kind"],
            )?,
            poll_cycle_periods: Arc::default(),
            frames_discarded: IntCounterVec::new(
                Opts::new(
                    frames_discarded,
                    "Received frames a Modbus slave line discarded unanswered, or a tap line did not use, by reason.",
                ),
                &["line", "reason"],
            )?,
            monitor_dropped: IntCounterVec::new(
                Opts::new(
                    monitor_dropped,
                    "Frames a line's frame monitor let go: pushed out of its full ring \
                     (overwritten) or missed by a live follower that fell behind (lagged).",
                ),
                &["line", "reason"],
            )?,
        };
        macro_rules! register {
            ($($family:ident),+) => {$(registry.register(Box::new(families.$family.clone()))?;)+};
        }
        register!(
            events,
            telegrams,
            bytes,
            line_up,
            modbus_requests,
            poll_duration,
            device_up,
            image_age,
            poll_cycle,
            frames_discarded,
            monitor_dropped
        );
        Ok(families)
    }

    // --- serial lines ---

    /// Creates the series of a configured line at 0 (line down, no telegrams, no bytes, no frames
    /// let go by its monitor), so that it
    /// shows on the dashboards before its port opens. `protocol` is the line's `protocol` key.
    pub fn init_line(&self, line: &str, protocol: &str) {
        self.line_up.with_label_values(&[line, protocol]).set(0);
        for direction in Direction::ALL {
            self.telegrams
                .with_label_values(&[line, direction.as_str()]);
            self.bytes.with_label_values(&[line, direction.as_str()]);
        }
        for reason in MonitorDrop::ALL {
            self.monitor_dropped
                .with_label_values(&[line, reason.as_str()]);
        }
    }

    /// A line has taken its parameters and runs: `gateway_line_up` 1 and event 00 03h "PtP
    /// parameters accepted" counted, as the CP reports at start-up (003 7.2, class 00h).
    pub fn line_started(&self, line: &str, protocol: &str) {
        self.set_line_up(line, protocol, true);
        self.event(line, ids::PTP_PARAMS_ACCEPTED);
    }

    /// Whether the line's port is open and its driver runs.
    pub fn set_line_up(&self, line: &str, protocol: &str, up: bool) {
        self.line_up
            .with_label_values(&[line, protocol])
            .set(i64::from(up));
    }

    /// Removes the series of a line that left the configuration (its event counters stay).
    pub fn forget_line(&self, line: &str, protocol: &str) {
        // Series never created cannot be removed; that is not an error here.
        let _ = self.line_up.remove_label_values(&[line, protocol]);
        for direction in Direction::ALL {
            let _ = self
                .telegrams
                .remove_label_values(&[line, direction.as_str()]);
            let _ = self.bytes.remove_label_values(&[line, direction.as_str()]);
        }
        for reason in MonitorDrop::ALL {
            let _ = self
                .monitor_dropped
                .remove_label_values(&[line, reason.as_str()]);
        }
    }

    /// Creates the discard series of a slave line on `line` at 0, one per `reasons`, so that a
    /// rate over them exists before the first discard.
    pub fn init_frames_discarded<R: Into<FrameDiscard> + Copy>(&self, line: &str, reasons: &[R]) {
        for &reason in reasons {
            self.frames_discarded
                .with_label_values(&[line, reason.into().as_label()]);
        }
    }

    /// Counts one received frame that a slave line on `line` discarded unanswered, or a tap line
    /// did not use, for `reason`.
    pub fn frame_discarded(&self, line: &str, reason: impl Into<FrameDiscard>) {
        self.frames_discarded
            .with_label_values(&[line, reason.into().as_label()])
            .inc();
    }

    /// The counter of frames the frame monitor of `line` let go for `reason`, created at 0; the
    /// monitor keeps it and counts without a label lookup.
    pub fn monitor_dropped(&self, line: &str, reason: MonitorDrop) -> IntCounter {
        self.monitor_dropped
            .with_label_values(&[line, reason.as_str()])
    }

    /// Counts one event raised on `line` (every event of 003 7.2, start-up included).
    pub fn event(&self, line: &str, id: EventId) {
        let class = format!("{:02X}", id.class);
        let number = format!("{:02X}{:02X}", id.class, id.number);
        let class_name = event::class_name(id.class).unwrap_or(UNKNOWN_CLASS);
        self.events
            .with_label_values(&[line, &class, &number, class_name])
            .inc();
    }

    /// Counts one telegram (or Modbus frame) received or sent on `line`.
    pub fn telegram(&self, line: &str, direction: Direction) {
        self.telegrams
            .with_label_values(&[line, direction.as_str()])
            .inc();
    }

    /// Counts `count` bytes received or sent on `line`.
    pub fn bytes(&self, line: &str, direction: Direction, count: usize) {
        self.bytes
            .with_label_values(&[line, direction.as_str()])
            .inc_by(u64::try_from(count).unwrap_or(u64::MAX));
    }

    // --- polled devices ---

    /// Creates the series of a configured device at 0 (down, empty histogram).
    pub fn init_device(&self, line: &str, device: &str) {
        self.device_up.with_label_values(&[line, device]).set(0);
        self.poll_duration.with_label_values(&[line, device]);
    }

    /// Counts one Modbus master request to `device` with function code `function`.
    pub fn modbus_request(&self, line: &str, device: &str, function: u8, result: RequestResult) {
        self.modbus_requests
            .with_label_values(&[line, device, function_label(function), result.as_str()])
            .inc();
    }

    /// Records the duration of one poll exchange (timeouts included: they show as the reply
    /// monitoring time).
    pub fn poll_duration(&self, line: &str, device: &str, duration: Duration) {
        self.poll_histogram(line, device)
            .observe(duration.as_secs_f64());
    }

    /// The histogram of one device, for callers that want to keep it (e.g. with a timer).
    pub fn poll_histogram(&self, line: &str, device: &str) -> Histogram {
        self.poll_duration.with_label_values(&[line, device])
    }

    /// Whether the device answers.
    pub fn set_device_up(&self, line: &str, device: &str, up: bool) {
        self.device_up
            .with_label_values(&[line, device])
            .set(i64::from(up));
    }

    /// The device's image was updated from a reply at `at`; its age is computed at each scrape.
    /// A device whose image was never updated has no age series.
    pub fn device_image_updated(&self, line: &str, device: &str, at: Instant) {
        self.image_age.updated(line, device, at);
    }

    /// Sets the poll cycle of the poll group of `period` of `device`: `kind` is `planned`,
    /// `bound`, `achieved` or `achieved_max`.
    pub fn set_poll_cycle(
        &self,
        line: &str,
        device: &str,
        period: Duration,
        kind: PollCycleKind,
        value: Duration,
    ) {
        let period = humantime::format_duration(period).to_string();
        self.poll_cycle_periods
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .entry((line.to_owned(), device.to_owned()))
            .or_default()
            .insert(period.clone());
        self.poll_cycle
            .with_label_values(&[line, device, &period, kind.as_str()])
            .set(value.as_secs_f64());
    }

    /// Removes the gauges and the histogram of a device that left the configuration (its request
    /// counters stay).
    pub fn forget_device(&self, line: &str, device: &str) {
        let periods = self
            .poll_cycle_periods
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .remove(&(line.to_owned(), device.to_owned()))
            .unwrap_or_default();
        for period in periods {
            for kind in PollCycleKind::ALL {
                let _ =
                    self.poll_cycle
                        .remove_label_values(&[line, device, &period, kind.as_str()]);
            }
        }
        let _ = self.device_up.remove_label_values(&[line, device]);
        let _ = self.poll_duration.remove_label_values(&[line, device]);
        self.image_age.forget(line, device);
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
        let metrics = LineFamilies::register(&registry).expect("register");
        let line = LineMetrics::new(Some(metrics.clone()), "drive", "modbus-master-rtu");
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
            Some(LineFamilies::register(&Registry::new()).expect("register")),
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

    #[test]
    fn poll_cycles_are_labelled_by_period_and_kind_and_leave_with_their_device() {
        let registry = Registry::new();
        let metrics = LineFamilies::register(&registry).expect("register");
        let period = Duration::from_millis(200);
        for (kind, ms) in [
            (PollCycleKind::Planned, 200),
            (PollCycleKind::Bound, 4900),
            (PollCycleKind::Achieved, 212),
            (PollCycleKind::AchievedMax, 250),
        ] {
            metrics.set_poll_cycle("drive", "atv71", period, kind, Duration::from_millis(ms));
        }
        let text = encode_text(&registry);
        assert!(
            text.contains(
                "gateway_poll_cycle_seconds{device=\"atv71\",kind=\"achieved\",line=\"drive\",period=\"200ms\"} 0.212"
            ),
            "{text}"
        );
        metrics.forget_device("drive", "atv71");
        let text = encode_text(&registry);
        assert!(!text.contains("gateway_poll_cycle_seconds{"), "{text}");
    }

    #[test]
    fn start_up_counts_parameters_accepted() {
        let registry = Registry::new();
        let metrics = LineFamilies::register(&registry).expect("register");
        metrics.line_started("r3964", "3964r");
        let text = encode_text(&registry);
        assert!(
            text.contains(
                r#"gateway_events_total{class="00",class_name="cp start-up",event="0003",line="r3964"} 1"#
            ),
            "{text}"
        );
        assert!(text.contains(r#"gateway_line_up{line="r3964",protocol="3964r"} 1"#));
    }
}
