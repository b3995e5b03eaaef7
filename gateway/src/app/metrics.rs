//! The gateway's metric families in one handle, registered where the wiring hands out the
//! registry.
//!
//! [`Metrics::register`] registers every family of [`METRIC_NAMES`] in the registry it is given
//! and returns a cheap-to-clone handle. Each subsystem defines and registers its own families in
//! its `metrics.rs` ([`LineFamilies`] for the serial lines and their devices, [`ServerMetrics`]
//! for the Modbus TCP server, [`AuditMetrics`], [`BridgeMetrics`] for zenoh, [`HttpMetrics`]);
//! the wiring gives each subsystem its own families through the handle's accessors. The label
//! vocabulary, the encoding and the `/metrics` listener are in [`crate::metrics`], which knows
//! none of the subsystems.
//!
//! Wiring, in `main` or `app`:
//!
//! ```no_run
//! # async fn wire() -> Result<(), Box<dyn std::error::Error>> {
//! use gateway::app::Metrics;
//! use gateway::metrics::serve_metrics;
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

use prometheus::{IntGaugeVec, Opts, Registry};

use crate::api::metrics::HttpMetrics;
use crate::audit::AuditMetrics;
use crate::line::metrics::LineFamilies;
use crate::modbus_tcp::metrics::ServerMetrics;
use crate::zenoh_bridge::metrics::BridgeMetrics;

/// Every metric family the gateway exports: each owner's `NAMES` in turn. Dashboards use only
/// these names (checked by a test).
pub const METRIC_NAMES: &[&str] = &chain::<{ count(OWNERS) }>(OWNERS);

/// The names of each owner's families.
const OWNERS: &[&[&str]] = &[
    &[BUILD_INFO],
    &LineFamilies::NAMES,
    &ServerMetrics::NAMES,
    &[AuditMetrics::NAME],
    &BridgeMetrics::NAMES,
    &HttpMetrics::NAMES,
];

/// How many names `parts` hold together.
const fn count(parts: &[&[&str]]) -> usize {
    match parts {
        [first, rest @ ..] => first.len() + count(rest),
        [] => 0,
    }
}

/// The names of `parts` one after the other, in an array of their [`count`].
const fn chain<const N: usize>(parts: &[&[&'static str]]) -> [&'static str; N] {
    let mut names = [""; N];
    let (mut n, mut i) = (0, 0);
    while i < parts.len() {
        let mut j = 0;
        while j < parts[i].len() {
            names[n] = parts[i][j];
            (n, j) = (n + 1, j + 1);
        }
        i += 1;
    }
    names
}

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

    /// The serial lines' and their devices' families (registered by [`LineFamilies::register`]).
    pub fn line(&self) -> &LineFamilies {
        &self.line
    }

    /// The Modbus TCP server's families (registered by [`ServerMetrics::register`]).
    pub fn modbus_tcp(&self) -> &ServerMetrics {
        &self.modbus_tcp
    }

    /// The audit's family of writes from outside (registered by [`AuditMetrics::register`]).
    pub fn audit(&self) -> &AuditMetrics {
        &self.audit
    }

    /// The HTTP listener's families (registered by [`HttpMetrics::register`]).
    pub fn http(&self) -> &HttpMetrics {
        &self.http
    }

    /// The zenoh bridge's families (registered by [`BridgeMetrics::register`]).
    pub fn zenoh(&self) -> &BridgeMetrics {
        &self.zenoh
    }
}

#[cfg(test)]
mod tests {
    use std::time::{Duration, Instant};

    use proto_core::modbus::rtu;

    use super::*;
    use crate::line::metrics::{MonitorDrop, PollCycleKind};
    use crate::metrics::RequestResult;

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
