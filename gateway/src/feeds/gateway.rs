//! The gateway in force as the REST and zenoh backends see it: the lines, tags and write policy
//! of the configuration in force ([`InForce`]), the image and units they read and write through,
//! and what only the running gateway answers ([`Gateway`]; app/'s supervisor is one).

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::Arc;

use proto_core::cpmem::AddressMap;
use serde_json::Value as Json;
use tokio_util::sync::CancellationToken;

use crate::api::model::{
    ApplyReport, ConfigOverride, GatewayStatus, LinePlace, LineStatusView, Readiness,
};
use crate::api::{ApiError, BoxFuture};
use crate::audit::AuditMetrics;
use crate::config::ConfigIssue;
use crate::image::ProcessImage;
use crate::line::LineHandle;
use crate::plant::Config;
use crate::tags::TagDirectory;
use crate::unit::write_policy::WritePolicy;
use crate::unit::{SharedUnits, UnitService};
use crate::zenoh_bridge::fleet::FleetMember;

/// A running line and what it registered.
#[derive(Clone)]
pub(crate) struct RunningLine {
    /// The line's task: status, events, capabilities.
    pub(crate) handle: LineHandle,
    /// Cancels this line only (a child of the gateway's lines token).
    pub(crate) token: CancellationToken,
    /// The config's protocol name (`modbus-master-rtu`, `3964r`, ...).
    pub(crate) protocol: &'static str,
    /// The serial port's path.
    pub(crate) port: String,
    /// The second receive port's path, for a line that has one (`3964r-tap`).
    pub(crate) port_b: Option<String>,
    /// The Modbus TCP units the line answers.
    pub(crate) units: Vec<(u8, Arc<dyn UnitService>)>,
    /// The CP memory mirror a slave line keeps in the image: its unit id and address map.
    pub(crate) mirror: Option<(u8, AddressMap)>,
}

impl std::fmt::Debug for RunningLine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunningLine")
            .field("handle", &self.handle)
            .field("protocol", &self.protocol)
            .field("port", &self.port)
            .field(
                "units",
                &self.units.iter().map(|(u, _)| *u).collect::<Vec<_>>(),
            )
            .finish_non_exhaustive()
    }
}

/// The view of line `name` now, as REST's `GET /api/v1/lines/{line}` and zenoh's
/// `<prefix>/<line>/status` answer it. Every line counts its frames, bytes and commands itself
/// since it started ([`LineHandle::traffic`]); the Prometheus families are fed from the same
/// counting, cumulative over the process.
pub(crate) fn line_view(name: &str, line: &RunningLine) -> LineStatusView {
    let place = LinePlace {
        name,
        protocol: line.protocol,
        port: &line.port,
        port_b: line.port_b.as_deref(),
        restarting: line.token.is_cancelled(),
    };
    LineStatusView::new(place, &line.handle.status(), line.handle.traffic())
}

/// The configuration in force with what it started, taken as one (a change replaces it whole).
pub(crate) trait InForce: Send + Sync {
    /// The configuration.
    fn config(&self) -> &Arc<Config>;
    /// The running lines by name.
    fn lines(&self) -> &BTreeMap<String, RunningLine>;
    /// The tag directory.
    fn tags(&self) -> &Arc<TagDirectory>;
    /// The Modbus TCP server's write checks (they apply to REST and zenoh writes too).
    fn writes(&self) -> &WritePolicy;
}

/// The running gateway, as the backends ask it.
pub(crate) trait Gateway: Send + Sync + 'static {
    /// What is in force now.
    fn in_force(&self) -> Arc<dyn InForce>;
    /// The process image the lines keep their devices' values in.
    fn image(&self) -> &ProcessImage;
    /// The Modbus TCP units: tag reads and writes go to a device through its unit.
    fn units(&self) -> &SharedUnits;
    /// The audit's family, where writes over REST and zenoh are counted.
    fn audit_metrics(&self) -> &AuditMetrics;
    /// The command line's settings that take precedence over the configuration, with the value
    /// in force (`http_local`: where the HTTP listener bound, once bound).
    fn overrides(&self, http_local: Option<SocketAddr>) -> Vec<ConfigOverride>;
    /// Whether `config` can run (the checks of a start, against the running system).
    fn validate(&self, config: &Config) -> Result<(), Vec<ConfigIssue>>;
    /// The issues of `config` besides those `found` already.
    fn config_issues(&self, config: &Config, found: &[ConfigIssue]) -> Vec<ConfigIssue>;
    /// Puts `config` in force, restarting only what changed.
    fn apply(
        self: Arc<Self>,
        config: Arc<Config>,
    ) -> BoxFuture<'static, Result<ApplyReport, ApiError>>;
    /// The other gateways seen on the fabric.
    fn fleet(&self) -> Vec<FleetMember>;
    /// The gateway's status, as REST's `GET /api/v1/status` answers it.
    fn status(&self) -> GatewayStatus;
    /// The gateway's status as zenoh's `<prefix>/status` answers it.
    fn fleet_status(&self) -> Json;
    /// What `/readyz` answers.
    fn readiness(&self) -> Readiness;
}
