//! Prometheus metrics of the gateway: typed families in one registry, created in `main` and passed
//! down; no global registry, no default registry.
//!
//! [`Metrics::register`] registers every family of [`METRIC_NAMES`] in the registry it is given
//! and returns a cheap-to-clone handle; the serial lines, the Modbus TCP server and the zenoh
//! bridge call its small typed methods. [`encode_text`] renders the registry for `/metrics`, and
//! [`serve_metrics`] is a minimal HTTP/1.1 listener answering `GET /metrics`.
//!
//! Label sets are bounded:
//! - `line`, `device`, `protocol` come from the configuration (line and device names, the
//!   `protocol` key), so there are as many as the configuration has;
//! - `class`, `event`, `class_name` come from the event catalog of 003 7.2 (`class` two upper-case
//!   hex digits such as `"08"`, `event` four such as `"0830"`, `class_name` the manual's class title
//!   in lower case, `"unknown"` for a class the catalog does not list);
//! - `function` is two upper-case hex digits for the functions the gateway knows and `"other"`
//!   for the rest, `result` is `ok`, `exception_NN`, `exception_other`, `timeout` or `error`
//!   (see [`labels`]);
//! - `direction`, `reason`, `kind` are enums.
//!
//! No label carries a client address, a register address or a telegram's content.
//!
//! Wiring, in `main` or `app`:
//!
//! ```no_run
//! # async fn wire() -> Result<(), Box<dyn std::error::Error>> {
//! use gateway::metrics::{serve_metrics, Metrics};
//!
//! let registry = prometheus::Registry::new();
//! let metrics = Metrics::register(&registry)?; // clone it into every task
//! metrics.init_line("drive", "modbus-master-rtu");
//! metrics.init_device("drive", "atv71");
//! let shutdown = tokio_util::sync::CancellationToken::new();
//! let listener = tokio::net::TcpListener::bind("127.0.0.1:8080").await?;
//! let server = tokio::spawn(serve_metrics(listener, registry.clone(), shutdown.clone()));
//! metrics.line_started("drive", "modbus-master-rtu"); // line up, event 00 03h
//! // ... on SIGTERM:
//! shutdown.cancel();
//! server.await?;
//! # Ok(()) }
//! ```

use std::collections::{BTreeMap, BTreeSet};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use prometheus::{
    GaugeVec, Histogram, HistogramOpts, HistogramVec, IntCounter, IntCounterVec, IntGaugeVec, Opts,
    Registry, TextEncoder,
};
use proto_core::event::{self, EventId};

mod http;
mod image_age;
pub mod labels;
mod tag_values;

pub use http::serve_metrics;
pub use labels::{function_label, Direction, RequestResult};

pub use crate::api::metrics::{ConnectionPool, HttpMetrics, HttpRejectReason};
pub use crate::audit::AuditMetrics;
pub use crate::modbus_tcp::stats::{ServerMetrics, TcpConnectionGuard};
pub use crate::zenoh_bridge::stats::BridgeMetrics;
pub use tag_values::{TagValues, QUALITY_UNKNOWN, TAG_QUALITY, TAG_VALUE};

use image_age::ImageAge;

/// Every metric family the gateway exports. Dashboards use only these names (checked by a test).
pub const METRIC_NAMES: &[&str] = &[
    BUILD_INFO,
    EVENTS,
    TELEGRAMS,
    BYTES,
    LINE_UP,
    MODBUS_REQUESTS,
    POLL_DURATION,
    DEVICE_UP,
    DEVICE_IMAGE_AGE,
    POLL_CYCLE,
    ServerMetrics::NAMES[0],
    ServerMetrics::NAMES[1],
    ServerMetrics::NAMES[2],
    ServerMetrics::NAMES[3],
    ServerMetrics::NAMES[4],
    ServerMetrics::NAMES[5],
    ServerMetrics::NAMES[6],
    AuditMetrics::NAME,
    BridgeMetrics::NAMES[0],
    BridgeMetrics::NAMES[1],
    FRAMES_DISCARDED,
    MONITOR_DROPPED,
    HttpMetrics::NAMES[0],
    HttpMetrics::NAMES[1],
    HttpMetrics::NAMES[2],
];

const BUILD_INFO: &str = "gateway_build_info";
const EVENTS: &str = "gateway_events_total";
const TELEGRAMS: &str = "gateway_telegrams_total";
const BYTES: &str = "gateway_bytes_total";
const LINE_UP: &str = "gateway_line_up";
const MODBUS_REQUESTS: &str = "gateway_modbus_requests_total";
const POLL_DURATION: &str = "gateway_poll_duration_seconds";
const DEVICE_UP: &str = "gateway_device_up";
const DEVICE_IMAGE_AGE: &str = "gateway_device_image_age_seconds";
const POLL_CYCLE: &str = "gateway_poll_cycle_seconds";
const FRAMES_DISCARDED: &str = "gateway_frames_discarded_total";
const MONITOR_DROPPED: &str = "gateway_monitor_dropped_total";

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

/// The `kind` label of `gateway_poll_cycle_seconds`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PollCycleKind {
    /// The configured period.
    Planned,
    /// The longest cycle the fairness rule of the line allows.
    Bound,
    /// The last cycle.
    Achieved,
    /// The longest cycle seen while the device answered.
    AchievedMax,
}

impl PollCycleKind {
    /// Every kind.
    pub const ALL: [Self; 4] = [
        Self::Planned,
        Self::Bound,
        Self::Achieved,
        Self::AchievedMax,
    ];

    /// The label value.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Planned => "planned",
            Self::Bound => "bound",
            Self::Achieved => "achieved",
            Self::AchievedMax => "achieved_max",
        }
    }
}

/// The `class_name` label of a class the event catalog does not list.
const UNKNOWN_CLASS: &str = "unknown";

/// The typed metric families of the gateway. Clones share the same series.
#[derive(Clone, Debug)]
pub struct Metrics {
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
    /// The Modbus TCP server's families.
    modbus_tcp: ServerMetrics,
    /// The audit's family of writes from outside.
    audit: AuditMetrics,
    /// The zenoh bridge's families.
    zenoh: BridgeMetrics,
    /// `gateway_frames_discarded_total{line,reason}`: received frames a slave line did not serve
    /// or a tap line did not use.
    frames_discarded: IntCounterVec,
    /// `gateway_monitor_dropped_total{line,reason}`: frames the line's frame monitor let go.
    monitor_dropped: IntCounterVec,
    /// The HTTP listener's families.
    http: HttpMetrics,
}

// === impl Metrics ===

impl Metrics {
    /// Registers every family of [`METRIC_NAMES`] in `registry`, sets `gateway_build_info` and
    /// creates the series of the fixed label sets at 0 so that `rate()` works from the first scrape.
    ///
    /// Fails if `registry` already holds one of the families (registering twice).
    pub fn register(registry: &Registry) -> Result<Self, prometheus::Error> {
        let build_info = IntGaugeVec::new(
            Opts::new(BUILD_INFO, "Build of the running gateway; always 1."),
            &["version"],
        )?;
        let metrics = Self {
            events: IntCounterVec::new(
                Opts::new(
                    EVENTS,
                    "Diagnostic events raised on a line, by CP 341 event class and number (manual 7.2).",
                ),
                &["line", "class", "event", "class_name"],
            )?,
            telegrams: IntCounterVec::new(
                Opts::new(TELEGRAMS, "Telegrams and Modbus frames received and sent on a line."),
                &["line", "direction"],
            )?,
            bytes: IntCounterVec::new(
                Opts::new(BYTES, "Bytes received and sent on a line, control characters included."),
                &["line", "direction"],
            )?,
            line_up: IntGaugeVec::new(
                Opts::new(LINE_UP, "1 while the line's port is open and its driver runs, else 0."),
                &["line", "protocol"],
            )?,
            modbus_requests: IntCounterVec::new(
                Opts::new(
                    MODBUS_REQUESTS,
                    "Modbus master requests on a line, by device, function code and result.",
                ),
                &["line", "device", "function", "result"],
            )?,
            poll_duration: HistogramVec::new(
                HistogramOpts::new(
                    POLL_DURATION,
                    "Time from sending a Modbus request to the checked reply or the timeout.",
                )
                .buckets(POLL_DURATION_BUCKETS.to_vec()),
                &["line", "device"],
            )?,
            device_up: IntGaugeVec::new(
                Opts::new(DEVICE_UP, "1 while the device answers its polls, else 0."),
                &["line", "device"],
            )?,
            image_age: ImageAge::new(
                DEVICE_IMAGE_AGE,
                "Seconds since the device's image was last updated from a reply.",
            )?,
            poll_cycle: GaugeVec::new(
                Opts::new(
                    POLL_CYCLE,
                    "Poll cycle of a device's poll group (by its configured period): planned, \
                     bound (the longest the fairness rule allows), achieved (the last) and \
                     achieved_max.",
                ),
                &["line", "device", "period", "kind"],
            )?,
            poll_cycle_periods: Arc::default(),
            modbus_tcp: ServerMetrics::register(registry)?,
            audit: AuditMetrics::register(registry)?,
            zenoh: BridgeMetrics::register(registry)?,
            frames_discarded: IntCounterVec::new(
                Opts::new(
                    FRAMES_DISCARDED,
                    "Received frames a Modbus slave line discarded unanswered, or a tap line did not use, by reason.",
                ),
                &["line", "reason"],
            )?,
            monitor_dropped: IntCounterVec::new(
                Opts::new(
                    MONITOR_DROPPED,
                    "Frames a line's frame monitor let go: pushed out of its full ring \
                     (overwritten) or missed by a live follower that fell behind (lagged).",
                ),
                &["line", "reason"],
            )?,
            http: HttpMetrics::register(registry)?,
        };

        registry.register(Box::new(build_info.clone()))?;
        registry.register(Box::new(metrics.events.clone()))?;
        registry.register(Box::new(metrics.telegrams.clone()))?;
        registry.register(Box::new(metrics.bytes.clone()))?;
        registry.register(Box::new(metrics.line_up.clone()))?;
        registry.register(Box::new(metrics.modbus_requests.clone()))?;
        registry.register(Box::new(metrics.poll_duration.clone()))?;
        registry.register(Box::new(metrics.device_up.clone()))?;
        registry.register(Box::new(metrics.image_age.clone()))?;
        registry.register(Box::new(metrics.poll_cycle.clone()))?;
        registry.register(Box::new(metrics.frames_discarded.clone()))?;
        registry.register(Box::new(metrics.monitor_dropped.clone()))?;

        build_info
            .with_label_values(&[env!("CARGO_PKG_VERSION")])
            .set(1);
        Ok(metrics)
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
        for reason in ["overwritten", "lagged"] {
            self.monitor_dropped.with_label_values(&[line, reason]);
        }
    }

    /// A line has taken its parameters and runs: `gateway_line_up` 1 and event 00 03h "PtP
    /// parameters accepted" counted, as the CP reports at start-up (003 7.2, class 00h).
    pub fn line_started(&self, line: &str, protocol: &str) {
        self.set_line_up(line, protocol, true);
        self.event(line, event::ids::PTP_PARAMS_ACCEPTED);
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
        for reason in ["overwritten", "lagged"] {
            let _ = self.monitor_dropped.remove_label_values(&[line, reason]);
        }
    }

    /// Creates the discard series of a slave line on `line` at 0, one per `reasons`, so that a
    /// rate over them exists before the first discard.
    pub fn init_frames_discarded(&self, line: &str, reasons: &[&'static str]) {
        for reason in reasons {
            self.frames_discarded.with_label_values(&[line, reason]);
        }
    }

    /// Counts one received frame that a slave line on `line` discarded unanswered, or a tap line
    /// did not use; `reason` is one of the fixed names of
    /// `proto_core::modbus::slave::DiscardReason::as_str` or
    /// `proto_core::modbus::tap::DiscardReason::as_str`.
    pub fn frame_discarded(&self, line: &str, reason: &'static str) {
        self.frames_discarded
            .with_label_values(&[line, reason])
            .inc();
    }

    /// The counter of frames the frame monitor of `line` let go for `reason` (`overwritten` or
    /// `lagged`), created at 0; the monitor keeps it and counts without a label lookup.
    pub fn monitor_dropped(&self, line: &str, reason: &'static str) -> IntCounter {
        self.monitor_dropped.with_label_values(&[line, reason])
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

    // --- Modbus TCP server ---

    /// The Modbus TCP server's families (registered by [`ServerMetrics::register`]).
    pub fn modbus_tcp(&self) -> &ServerMetrics {
        &self.modbus_tcp
    }

    /// The audit's family of writes from outside (registered by [`AuditMetrics::register`]).
    pub fn audit(&self) -> &AuditMetrics {
        &self.audit
    }

    // --- HTTP listener ---

    /// The HTTP listener's families (registered by [`HttpMetrics::register`]).
    pub fn http(&self) -> &HttpMetrics {
        &self.http
    }

    // --- zenoh ---

    /// The zenoh bridge's families (registered by [`BridgeMetrics::register`]).
    pub fn zenoh(&self) -> &BridgeMetrics {
        &self.zenoh
    }
}

/// The registry in the Prometheus text exposition format 0.0.4, for `/metrics`.
///
/// Encoding the families this module registers cannot fail; should it fail anyway, the error is
/// logged and returned as a comment line, which scrapers skip.
pub fn encode_text(registry: &Registry) -> String {
    match TextEncoder::new().encode_to_string(&registry.gather()) {
        Ok(text) => text,
        Err(error) => {
            tracing::error!(%error, "encoding the metrics failed");
            format!("# encoding the metrics failed: {error}\n")
        }
    }
}

/// The `Content-Type` of [`encode_text`]'s output.
pub const TEXT_CONTENT_TYPE: &str = "text/plain; version=0.0.4; charset=utf-8";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn registering_twice_in_one_registry_fails() {
        let registry = Registry::new();
        Metrics::register(&registry).expect("first registration");
        assert!(Metrics::register(&registry).is_err());
    }

    #[test]
    fn every_family_is_exported_under_its_listed_name() {
        let registry = Registry::new();
        let metrics = Metrics::register(&registry).expect("register");
        // Families without fixed label sets appear once they have a series.
        metrics.init_line("drive", "modbus-master-rtu");
        metrics.line_started("drive", "modbus-master-rtu");
        metrics.init_device("drive", "atv71");
        metrics.modbus_request("drive", "atv71", 0x03, RequestResult::Ok);
        metrics.device_image_updated("drive", "atv71", Instant::now());
        metrics.set_poll_cycle(
            "drive",
            "atv71",
            Duration::from_millis(200),
            PollCycleKind::Planned,
            Duration::from_millis(200),
        );
        metrics.modbus_tcp().request(0x03, RequestResult::Ok);
        metrics.frame_discarded("hmi", "trailing_data");
        let _ = metrics.monitor_dropped("drive", "overwritten");
        let mut names: Vec<_> = registry
            .gather()
            .iter()
            .map(|family| family.name().to_owned())
            .collect();
        names.sort();
        let mut expected: Vec<_> = METRIC_NAMES.iter().map(|&n| n.to_owned()).collect();
        expected.sort();
        assert_eq!(names, expected);
    }

    #[test]
    fn poll_cycles_are_labelled_by_period_and_kind_and_leave_with_their_device() {
        let registry = Registry::new();
        let metrics = Metrics::register(&registry).expect("register");
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
        let metrics = Metrics::register(&registry).expect("register");
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
