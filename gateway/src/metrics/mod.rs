//! Prometheus metrics of the gateway: typed families in one registry, created in `main` and passed
//! down; no global registry, no default registry.
//!
//! [`Metrics::register`] registers every family of [`METRIC_NAMES`] in the registry it is given
//! and returns a cheap-to-clone handle. Each subsystem defines and registers its own families
//! ([`LineFamilies`] for the serial lines and their devices, [`ServerMetrics`] for the Modbus TCP
//! server, [`AuditMetrics`], [`BridgeMetrics`] for zenoh, [`HttpMetrics`]) and calls their small
//! typed methods through the handle's accessors. [`encode_text`] renders the registry for
//! `/metrics`, and [`serve_metrics`] is a minimal HTTP/1.1 listener answering `GET /metrics`.
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
//! metrics.line().init_line("drive", "modbus-master-rtu");
//! metrics.line().init_device("drive", "atv71");
//! let shutdown = tokio_util::sync::CancellationToken::new();
//! let listener = tokio::net::TcpListener::bind("127.0.0.1:8080").await?;
//! let server = tokio::spawn(serve_metrics(listener, registry.clone(), shutdown.clone()));
//! metrics.line().line_started("drive", "modbus-master-rtu"); // line up, event 00 03h
//! // ... on SIGTERM:
//! shutdown.cancel();
//! server.await?;
//! # Ok(()) }
//! ```

use prometheus::{IntGaugeVec, Opts, Registry, TextEncoder};

mod http;
pub mod labels;
mod tag_values;

pub use http::serve_metrics;
pub use labels::{function_label, Direction, RequestResult};

pub use crate::api::metrics::{ConnectionPool, HttpMetrics, HttpRejectReason};
pub use crate::audit::AuditMetrics;
pub use crate::line::line_metrics::{
    FrameDiscard, LineFamilies, MonitorDrop, PollCycleKind, POLL_DURATION_BUCKETS,
};
pub use crate::modbus_tcp::stats::{ServerMetrics, TcpConnectionGuard};
pub use crate::zenoh_bridge::stats::BridgeMetrics;
pub use tag_values::{TagValues, QUALITY_UNKNOWN, TAG_QUALITY, TAG_VALUE};

/// Every metric family the gateway exports. Dashboards use only these names (checked by a test).
pub const METRIC_NAMES: &[&str] = &[
    BUILD_INFO,
    LineFamilies::NAMES[0],
    LineFamilies::NAMES[1],
    LineFamilies::NAMES[2],
    LineFamilies::NAMES[3],
    LineFamilies::NAMES[4],
    LineFamilies::NAMES[5],
    LineFamilies::NAMES[6],
    LineFamilies::NAMES[7],
    LineFamilies::NAMES[8],
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
    BridgeMetrics::NAMES[2],
    LineFamilies::NAMES[9],
    LineFamilies::NAMES[10],
    HttpMetrics::NAMES[0],
    HttpMetrics::NAMES[1],
    HttpMetrics::NAMES[2],
];

const BUILD_INFO: &str = "gateway_build_info";

/// The typed metric families of the gateway. Clones share the same series.
#[derive(Clone, Debug)]
pub struct Metrics {
    /// The serial lines' and their devices' families.
    line: LineFamilies,
    /// The Modbus TCP server's families.
    modbus_tcp: ServerMetrics,
    /// The audit's family of writes from outside.
    audit: AuditMetrics,
    /// The zenoh bridge's families.
    zenoh: BridgeMetrics,
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
            line: LineFamilies::register(registry)?,
            modbus_tcp: ServerMetrics::register(registry)?,
            audit: AuditMetrics::register(registry)?,
            zenoh: BridgeMetrics::register(registry)?,
            http: HttpMetrics::register(registry)?,
        };

        registry.register(Box::new(build_info.clone()))?;

        build_info
            .with_label_values(&[env!("CARGO_PKG_VERSION")])
            .set(1);
        Ok(metrics)
    }

    // --- serial lines ---

    /// The serial lines' and their devices' families (registered by [`LineFamilies::register`]).
    pub fn line(&self) -> &LineFamilies {
        &self.line
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
    use std::time::{Duration, Instant};

    use proto_core::modbus::rtu;

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
        metrics.line().init_line("drive", "modbus-master-rtu");
        metrics.line().line_started("drive", "modbus-master-rtu");
        metrics.line().init_device("drive", "atv71");
        metrics
            .line()
            .modbus_request("drive", "atv71", 0x03, RequestResult::Ok);
        metrics
            .line()
            .device_image_updated("drive", "atv71", Instant::now());
        metrics.line().set_poll_cycle(
            "drive",
            "atv71",
            Duration::from_millis(200),
            PollCycleKind::Planned,
            Duration::from_millis(200),
        );
        metrics.modbus_tcp().request(0x03, RequestResult::Ok);
        metrics
            .line()
            .frame_discarded("hmi", rtu::DiscardReason::TrailingData);
        let _ = metrics
            .line()
            .monitor_dropped("drive", MonitorDrop::Overwritten);
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
}
