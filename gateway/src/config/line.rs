//! One serial line: its serial settings and its protocol with the protocol's parameters, in one
//! flat TOML table `[lines.<name>]` (003 6.1: the CP runs one protocol driver per interface).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::device::DeviceConfig;
use super::modbus::{ModbusMasterAsciiConfig, ModbusMasterRtuConfig, ModbusSlaveRtuConfig};
use super::reader::{check_name, Cx, Fields};
use super::section::{AckConfig, ProtocolSection};
use super::serial::{SerialConfig, DEFAULT_BAUD};
use super::tap::{ModbusRtuTapConfig, Proc3964TapConfig};
use super::telegram::{AsciiConfig, Proc3964Config};

/// A line: where and how to talk, and what protocol to speak.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LineConfig {
    #[serde(flatten)]
    pub serial: SerialConfig,
    #[serde(flatten)]
    pub protocol: ProtocolConfig,
}

/// The protocol driver of a line (003 6.1) with its parameters; `protocol = "..."` in TOML.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "protocol")]
pub enum ProtocolConfig {
    #[serde(rename = "modbus-master-rtu")]
    ModbusMasterRtu(ModbusMasterRtuConfig),
    #[serde(rename = "modbus-master-ascii")]
    ModbusMasterAscii(ModbusMasterAsciiConfig),
    #[serde(rename = "modbus-slave-rtu")]
    ModbusSlaveRtu(ModbusSlaveRtuConfig),
    /// Listen-only: stores what another master's traffic shows.
    #[serde(rename = "modbus-rtu-tap")]
    ModbusRtuTap(ModbusRtuTapConfig),
    #[serde(rename = "3964r")]
    Proc3964(Proc3964Config),
    /// Listen-only: both directions of a 3964(R) link on two ports.
    #[serde(rename = "3964r-tap")]
    Proc3964Tap(Proc3964TapConfig),
    #[serde(rename = "ascii")]
    Ascii(AsciiConfig),
}

/// The value of a line's `protocol` key.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum ProtocolKind {
    #[serde(rename = "modbus-master-rtu")]
    ModbusMasterRtu,
    #[serde(rename = "modbus-master-ascii")]
    ModbusMasterAscii,
    #[serde(rename = "modbus-slave-rtu")]
    ModbusSlaveRtu,
    /// Listen-only Modbus RTU.
    #[serde(rename = "modbus-rtu-tap")]
    ModbusRtuTap,
    /// 3964 or 3964R, by `block_check`.
    #[serde(rename = "3964r")]
    Proc3964,
    /// Listen-only 3964(R) on two ports.
    #[serde(rename = "3964r-tap")]
    Proc3964Tap,
    #[serde(rename = "ascii")]
    Ascii,
}

// === impl ProtocolKind ===

impl ProtocolKind {
    /// The TOML spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::ModbusMasterRtu => "modbus-master-rtu",
            Self::ModbusMasterAscii => "modbus-master-ascii",
            Self::ModbusSlaveRtu => "modbus-slave-rtu",
            Self::ModbusRtuTap => "modbus-rtu-tap",
            Self::Proc3964 => "3964r",
            Self::Proc3964Tap => "3964r-tap",
            Self::Ascii => "ascii",
        }
    }

    /// Whether the line polls devices.
    pub fn is_master(self) -> bool {
        matches!(self, Self::ModbusMasterRtu | Self::ModbusMasterAscii)
    }

    /// Whether the line lists devices (a master polls them, a tap listens to them).
    pub fn has_devices(self) -> bool {
        self.is_master() || self == Self::ModbusRtuTap
    }
}

// === impl ProtocolConfig ===

impl ProtocolConfig {
    /// The protocol's own section: the one match over the protocols in the configuration.
    pub(crate) fn section(&self) -> &dyn ProtocolSection {
        match self {
            Self::ModbusMasterRtu(c) => c,
            Self::ModbusMasterAscii(c) => c,
            Self::ModbusSlaveRtu(c) => c,
            Self::ModbusRtuTap(c) => c,
            Self::Proc3964(c) => c,
            Self::Proc3964Tap(c) => c,
            Self::Ascii(c) => c,
        }
    }

    /// The section of a line that serves the CP memory (the memory's layout spans every such
    /// line).
    pub fn cp_memory_slave(&self) -> Option<&ModbusSlaveRtuConfig> {
        match self {
            Self::ModbusSlaveRtu(c) => Some(c),
            _ => None,
        }
    }

    /// The protocol's own section, to change it.
    pub(crate) fn section_mut(&mut self) -> &mut dyn ProtocolSection {
        match self {
            Self::ModbusMasterRtu(c) => c,
            Self::ModbusMasterAscii(c) => c,
            Self::ModbusSlaveRtu(c) => c,
            Self::ModbusRtuTap(c) => c,
            Self::Proc3964(c) => c,
            Self::Proc3964Tap(c) => c,
            Self::Ascii(c) => c,
        }
    }

    pub fn kind(&self) -> ProtocolKind {
        match self {
            Self::ModbusMasterRtu(_) => ProtocolKind::ModbusMasterRtu,
            Self::ModbusMasterAscii(_) => ProtocolKind::ModbusMasterAscii,
            Self::ModbusSlaveRtu(_) => ProtocolKind::ModbusSlaveRtu,
            Self::ModbusRtuTap(_) => ProtocolKind::ModbusRtuTap,
            Self::Proc3964(_) => ProtocolKind::Proc3964,
            Self::Proc3964Tap(_) => ProtocolKind::Proc3964Tap,
            Self::Ascii(_) => ProtocolKind::Ascii,
        }
    }
}

// === impl LineConfig ===

impl LineConfig {
    /// The devices this line polls or listens to (empty unless it is a Modbus master or tap).
    pub fn devices(&self) -> impl Iterator<Item = (&String, &DeviceConfig)> {
        static NONE: BTreeMap<String, DeviceConfig> = BTreeMap::new();
        self.protocol.section().devices().unwrap_or(&NONE).iter()
    }

    /// The second receive port of a line that has one (`port_b` of a 3964(R) tap).
    pub fn second_port(&self) -> Option<&str> {
        self.protocol.section().second_port()
    }

    /// The Modbus TCP unit id of the line itself (slave memory or telegram mailbox), if any.
    pub fn unit_id(&self) -> Option<u8> {
        self.protocol.section().unit_id()
    }

    /// Whether telegrams may be sent on this line (`sends`); `false` for a line without
    /// telegrams.
    pub fn sends(&self) -> bool {
        self.protocol.section().telegrams().is_some_and(|t| t.sends)
    }

    /// The `ack` of a telegram line, if set.
    pub fn ack(&self) -> Option<AckConfig> {
        self.protocol.section().telegrams().and_then(|t| t.ack)
    }

    /// The `journal` of a telegram line, if set.
    pub fn journal(&self) -> Option<&std::path::Path> {
        self.protocol.section().telegrams().and_then(|t| t.journal)
    }

    /// Reads `[lines.<name>]` at `path`.
    pub(crate) fn read(cx: &mut Cx, name: &str, path: &str, value: &toml::Value) -> Option<Self> {
        check_name(cx, path, name);
        let mut f = Fields::of(cx, value, path.to_owned())?;
        let kind = f.choice::<ProtocolKind>(cx, "protocol");
        if !f.has("protocol") {
            cx.issue(
                f.at("protocol"),
                "missing required key (modbus-master-rtu, modbus-master-ascii, modbus-slave-rtu, modbus-rtu-tap, 3964r, 3964r-tap or ascii)",
            );
        }
        let serial = SerialConfig::read(cx, &mut f);
        // Without a protocol the valid keys are unknown: report nothing more for this line.
        let kind = kind?;
        let baud = serial.as_ref().map_or(DEFAULT_BAUD, |s| s.baud);
        let protocol = match kind {
            ProtocolKind::ModbusMasterRtu => {
                ProtocolConfig::ModbusMasterRtu(ModbusMasterRtuConfig::read(cx, &mut f))
            }
            ProtocolKind::ModbusMasterAscii => {
                ProtocolConfig::ModbusMasterAscii(ModbusMasterAsciiConfig::read(cx, &mut f))
            }
            ProtocolKind::ModbusSlaveRtu => {
                ProtocolConfig::ModbusSlaveRtu(ModbusSlaveRtuConfig::read(cx, &mut f))
            }
            ProtocolKind::ModbusRtuTap => {
                ProtocolConfig::ModbusRtuTap(ModbusRtuTapConfig::read(cx, &mut f))
            }
            ProtocolKind::Proc3964 => ProtocolConfig::Proc3964(Proc3964Config::read(cx, &mut f)),
            ProtocolKind::Proc3964Tap => {
                ProtocolConfig::Proc3964Tap(Proc3964TapConfig::read(cx, &mut f))
            }
            ProtocolKind::Ascii => ProtocolConfig::Ascii(AsciiConfig::read(cx, &mut f, baud)),
        };
        if !kind.has_devices() && f.has("devices") {
            let _ = f.raw("devices");
            cx.issue(
                f.at("devices"),
                format!(
                    "devices are listed only on modbus-master-rtu, modbus-master-ascii and modbus-rtu-tap lines, not on a {} line",
                    kind.as_str()
                ),
            );
        }
        f.finish(cx);
        Some(Self {
            serial: serial?,
            protocol,
        })
    }
}

/// Who acknowledges the telegrams of `line` in `config`: its `ack`, else "on-publish" when the
/// line has no Modbus TCP `unit_id` and zenoh is on (nobody else could), else "explicit".
pub fn ack_mode(config: &super::Config, line: &LineConfig) -> AckConfig {
    let zenoh_on = config.zenoh.as_ref().is_some_and(|z| z.enabled);
    line.ack()
        .unwrap_or(if line.unit_id().is_none() && zenoh_on {
            AckConfig::OnPublish
        } else {
            AckConfig::Explicit
        })
}
