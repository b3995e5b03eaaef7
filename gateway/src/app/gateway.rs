//! The REST API and zenoh backends wired to the supervisor: the supervisor is the running
//! [`Gateway`] they ask ([`crate::feeds::rest`], [`crate::feeds::zenoh_backend`]), its snapshot
//! what is in force; what only the supervisor knows (the command line's overrides, applying a
//! configuration, the Modbus TCP listener, zenoh's state) it answers here.

use std::net::SocketAddr;
use std::sync::{Arc, PoisonError};

use serde_json::Value as Json;

use crate::api::model::{
    ApplyReport, ConfigOverride, GatewayStatus, ModbusTcpStatus, Readiness, Timestamp, ZenohStatus,
};
use crate::api::{ApiError, BoxFuture};
use crate::audit::AuditMetrics;
use crate::config::ConfigIssue;
use crate::feeds::gateway::{line_view, Gateway, InForce, RunningLine};
use crate::image::ProcessImage;
use crate::plant::Config;
use crate::tags::TagDirectory;
use crate::unit::write_policy::WritePolicy;
use crate::unit::SharedUnits;
use crate::zenoh_bridge::fleet::FleetMember;

use super::supervisor::{Snapshot, Supervisor};

impl InForce for Snapshot {
    fn config(&self) -> &Arc<Config> {
        &self.config
    }

    fn lines(&self) -> &std::collections::BTreeMap<String, RunningLine> {
        &self.lines
    }

    fn tags(&self) -> &Arc<TagDirectory> {
        &self.tags
    }

    fn writes(&self) -> &WritePolicy {
        &self.server.writes
    }
}

impl Gateway for Supervisor {
    fn in_force(&self) -> Arc<dyn InForce> {
        self.snapshot()
    }

    fn image(&self) -> &ProcessImage {
        &self.image
    }

    fn units(&self) -> &SharedUnits {
        &self.units
    }

    fn audit_metrics(&self) -> &AuditMetrics {
        self.exported.metrics.audit()
    }

    fn overrides(&self, http_local: Option<SocketAddr>) -> Vec<ConfigOverride> {
        let given = &self.overrides;
        let mut overrides = Vec::new();
        if let Some(addr) = given.modbus_tcp {
            let in_force = if self.snapshot().config.modbus_tcp.enabled {
                self.tcp_listen().0.to_string()
            } else {
                "switched off (modbus_tcp.enabled = false)".to_owned()
            };
            overrides.push(ConfigOverride {
                key: "modbus_tcp.listen".into(),
                option: "--modbus-tcp".into(),
                given: addr.to_string(),
                in_force,
                note: None,
            });
        }
        if let Some(addr) = given.http {
            overrides.push(ConfigOverride {
                key: "http.listen".into(),
                option: "--http".into(),
                given: addr.to_string(),
                in_force: http_local.unwrap_or(addr).to_string(),
                note: None,
            });
        }
        if let Some(endpoint) = &given.zenoh_listen {
            overrides.push(ConfigOverride {
                key: "zenoh.listen".into(),
                option: "--zenoh-listen".into(),
                given: endpoint.clone(),
                in_force: endpoint.clone(),
                note: Some(
                    "a peer that listens there only: zenoh.mode = \"peer\", no zenoh.connect, \
                     zenoh.multicast_scouting = false; prefix and publishing from the configuration"
                        .into(),
                ),
            });
        }
        overrides
    }

    fn validate(&self, config: &Config) -> Result<(), Vec<ConfigIssue>> {
        Self::validate(self, config)
    }

    fn config_issues(&self, config: &Config, found: &[ConfigIssue]) -> Vec<ConfigIssue> {
        crate::plant::check::config_issues(config, found)
    }

    fn apply(
        self: Arc<Self>,
        config: Arc<Config>,
    ) -> BoxFuture<'static, Result<ApplyReport, ApiError>> {
        Box::pin(async move { Self::apply(&self, config).await })
    }

    fn fleet(&self) -> Vec<FleetMember> {
        super::fleet::members(self)
    }

    fn status(&self) -> GatewayStatus {
        let snapshot = self.snapshot();
        let lines = snapshot
            .lines
            .iter()
            .map(|(name, line)| line_view(name, line))
            .collect();
        let (listen, up) = self.tcp_listen();
        let stats = &self.tcp_stats;
        let requests = stats.requests();
        let zenoh = self
            .zenoh_state
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
            .map(|z| ZenohStatus {
                up: z.stats.as_ref().is_some_and(|s| s.session_open()),
                mode: z.mode.to_owned(),
                publications_total: z
                    .stats
                    .as_ref()
                    .map_or(0, |s| s.publication_counts().iter().map(|(_, n)| n).sum()),
                name_conflict: z.stats.as_ref().and_then(|s| s.name_conflict()),
            });
        GatewayStatus {
            name: snapshot.config.gateway.name.clone(),
            version: env!("CARGO_PKG_VERSION").to_owned(),
            started: Timestamp(self.started),
            uptime_seconds: self.started.elapsed().map_or(0, |d| d.as_secs()),
            ready: self.readiness().is_ready(),
            lines,
            modbus_tcp: ModbusTcpStatus {
                listen: listen.to_string(),
                up,
                connections: stats.connections_open(),
                requests_total: requests.iter().map(|r| r.count).sum(),
                exceptions_total: requests
                    .iter()
                    .filter(|r| r.result != "ok")
                    .map(|r| r.count)
                    .sum(),
            },
            zenoh,
        }
    }

    fn fleet_status(&self) -> Json {
        super::fleet::gateway_status(self)
    }

    fn readiness(&self) -> Readiness {
        let zenoh = self
            .zenoh_state
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone();
        let snapshot = self.snapshot();
        Readiness {
            lines: snapshot
                .lines
                .iter()
                .map(|(n, l)| {
                    let opened = l.handle.status().port_opens > 0 || self.opened_before(n, &l.port);
                    (n.clone(), opened)
                })
                .collect(),
            modbus_tcp: self.tcp_ready(),
            zenoh: zenoh
                .as_ref()
                .map(|z| z.stats.as_ref().is_some_and(|s| s.session_open())),
            zenoh_name_conflict: zenoh
                .as_ref()
                .and_then(|z| z.stats.as_ref())
                .and_then(|s| s.name_conflict()),
        }
    }
}
