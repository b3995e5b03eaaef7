//! Starting a line from its config section: the seam each protocol implements next to its
//! adapter.
//!
//! A protocol's config section (`ModbusMasterRtuConfig`, `Proc3964Config`, ...) implements
//! [`StartLine`] in the protocol's own folder (`modbus_master/build.rs`, `modbus_slave/build.rs`,
//! `modbus_tap/build.rs`, `telegram/convert.rs`): it turns the section into its adapter's settings
//! and spawns the line. The protocols' table finds a line's section
//! (`ProtocolConfig::starter`), so a section only ever builds its own line and there is no "not a
//! line of this protocol" case. What every protocol shares, the port settings of the
//! serial section, lives here.

use proto_core::cpmem::MemoryLayout;
use tokio_util::sync::CancellationToken;

use crate::config::{self, ConfigIssue, GatewaySection};
use crate::cpmem::SharedCpMemory;
use crate::image::ProcessImage;
use crate::line::metrics::LineFamilies;
use crate::line::LineHandle;
use crate::protocols::LineConfig;
use crate::serial::{self, PortSettings};

/// What starting a line needs from the gateway.
pub(crate) struct StartDeps<'a> {
    /// The gateway-wide settings (the diagnostic buffer depth).
    pub(crate) gateway: &'a GatewaySection,
    /// Whether zenoh is on (the acknowledgement default of telegram lines, [`super::ack_mode`]).
    pub(crate) zenoh_on: bool,
    /// The process image master and tap lines keep their devices' values in.
    pub(crate) image: &'a ProcessImage,
    /// Where the line counts its events, traffic and requests.
    pub(crate) metrics: &'a LineFamilies,
    /// The CP memory slave lines serve (`None` without slave lines).
    pub(crate) cp_memory: Option<&'a SharedCpMemory>,
    /// The line's own token: cancelling it stops the line.
    pub(crate) token: CancellationToken,
    /// What the line this one replaces left (a configuration change restarted it): a telegram
    /// line takes over its waiting telegrams and numbers.
    pub(crate) carried: Option<crate::mailbox::Carried>,
}

/// Why a line did not start: the message names the line.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub(crate) struct StartError(pub(crate) String);

/// A protocol's config section starting its own line.
pub(crate) trait StartLine {
    /// Converts the section of line `name` into its adapter's settings and spawns the line.
    ///
    /// # Errors
    ///
    /// What the section's engine or the gateway's resources refuse (parameters the config
    /// check let pass, a CP memory that does not fit, a journal that cannot be opened).
    fn start(
        &self,
        name: &str,
        line: &LineConfig,
        deps: &StartDeps<'_>,
    ) -> Result<LineHandle, StartError>;

    /// The checks of [`start`](Self::start) that need no task: what would make the line fail
    /// to start, each with its path. `layout` is the CP memory the slave lines would serve.
    fn start_issues(
        &self,
        _name: &str,
        _line: &LineConfig,
        _layout: Option<&MemoryLayout>,
    ) -> Vec<ConfigIssue> {
        Vec::new()
    }
}

/// The runtime's port settings of a line.
pub(crate) fn port_settings(serial: &config::SerialConfig) -> PortSettings {
    let mut port = PortSettings::new(serial.port.clone(), serial.baud.get());
    port.data_bits = match serial.data_bits {
        config::DataBits::Seven => serial::DataBits::Seven,
        config::DataBits::Eight => serial::DataBits::Eight,
    };
    port.parity = match serial.parity {
        config::Parity::None => serial::Parity::None,
        config::Parity::Odd => serial::Parity::Odd,
        config::Parity::Even => serial::Parity::Even,
    };
    port.stop_bits = match serial.stop_bits {
        config::StopBits::One => serial::StopBits::One,
        config::StopBits::Two => serial::StopBits::Two,
    };
    port.monitor_frames = usize::try_from(serial.monitor_frames).unwrap_or(usize::MAX);
    port.interface = match serial.interface {
        config::Interface::Rs232 => serial::Interface::Rs232,
        config::Interface::Rs422 => serial::Interface::Rs422,
        config::Interface::Rs485 => {
            let rs485 = serial.rs485.clone().unwrap_or_default();
            serial::Interface::Rs485(serial::Rs485 {
                rts_on_send: rs485.rts_on_send,
                delay_before_send: rs485.delay_before_send,
                delay_after_send: rs485.delay_after_send,
            })
        }
    };
    port
}
