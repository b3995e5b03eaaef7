//! The line protocols, one folder each, and the one table that lists them.
//!
//! A line is its serial settings and its protocol with the protocol's parameters, in one flat
//! TOML table `[lines.<name>]` (003 6.1: the CP runs one protocol driver per interface). Each
//! protocol's folder holds its config section (`config.rs`), its adapter over the line runtime,
//! its start (`build.rs`, `convert.rs`: `start::StartLine`) and its simulated partner
//! (`partner.rs`):
//! - [`modbus_master`]: Modbus master RTU and ASCII, polling devices into the process image; its
//!   partner is the simulated slave bus (the device models of [`crate::sim`]);
//! - [`modbus_slave`]: Modbus slave RTU serving the CP memory; its partner the simulated serial
//!   master (the demo's HMI);
//! - [`modbus_tap`]: listen-only Modbus RTU;
//! - [`telegram`]: 3964(R) and ASCII lines with their mailboxes and partners, and the
//!   listen-only 3964(R) tap (`telegram/tap/`).
//!
//! The `protocols!` table below makes [`ProtocolConfig`], [`ProtocolKind`] and their one match
//! each; a new protocol is its folder and one row here.

pub mod modbus_master;
pub mod modbus_slave;
pub mod modbus_tap;
pub(crate) mod start;
pub mod telegram;

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::config::reader::{check_name, Cx, Fields};
use crate::config::section::{AckConfig, ProtocolSection};
use crate::config::{Baud, DeviceConfig, SerialConfig, DEFAULT_BAUD};
use start::StartLine;

pub use modbus_master::config::*;
pub use modbus_master::{
    exception_for, exception_for_queue, merge_ranges, plan, spawn_modbus_master_line, AddrRange,
    CommandError, CommandResult, DeviceLimits, DeviceSettings, DeviceUnit, LineClient,
    LineSettings, PollGroup, ProbeSettings, QueueError, ReadBlock, ScannerSettings,
    PROBE_TIMEOUT_FACTOR, SCANNER_WORDS,
};
pub use modbus_master::{TransparentSettings, TransparentUnit};
pub use modbus_slave::config::*;
pub use modbus_slave::{spawn_modbus_slave_line, CpMemoryView, SlaveCounters, SlaveLineSettings};
pub use modbus_tap::config::*;
pub use modbus_tap::{spawn_modbus_tap_line, TapLineSettings, TAP_PROTOCOL};
pub use telegram::config::*;
pub use telegram::Proc3964TapConfig;

/// A line: where and how to talk, and what protocol to speak.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LineConfig {
    #[serde(flatten)]
    pub serial: SerialConfig,
    #[serde(flatten)]
    pub protocol: ProtocolConfig,
}

/// The protocols, in one table: each row is the variant, its `protocol = "..."` spelling and the
/// type of its section (which reads itself, [`ReadSection`]). The row makes the variant of
/// [`ProtocolConfig`] and of [`ProtocolKind`], the spelling, the section's accessors and the
/// reader's dispatch; a new protocol is one row here (and its section type).
macro_rules! protocols {
    ($($(#[doc = $doc:literal])* $variant:ident = $name:literal => $config:ty;)+) => {
        /// The protocol driver of a line (003 6.1) with its parameters; `protocol = "..."` in TOML.
        #[derive(Debug, Clone, PartialEq, Serialize)]
        #[serde(tag = "protocol")]
        pub enum ProtocolConfig {
            $($(#[doc = $doc])* #[serde(rename = $name)] $variant($config),)+
        }

        /// The value of a line's `protocol` key.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
        pub enum ProtocolKind {
            $($(#[doc = $doc])* #[serde(rename = $name)] $variant,)+
        }

        impl ProtocolKind {
            /// Every protocol, in the table's order.
            pub const ALL: &[Self] = &[$(Self::$variant),+];

            /// The TOML spelling.
            pub fn as_str(self) -> &'static str {
                match self {
                    $(Self::$variant => $name,)+
                }
            }
        }

        impl ProtocolConfig {
            /// The protocol's own section: the one match over the protocols in the configuration.
            pub(crate) fn section(&self) -> &dyn ProtocolSection {
                match self {
                    $(Self::$variant(c) => c,)+
                }
            }

            /// The protocol's own section, as the part of its protocol that starts the line (each
            /// implements [`StartLine`] next to its adapter): the one match over the protocols in
            /// starting a line.
            pub(crate) fn starter(&self) -> &dyn StartLine {
                match self {
                    $(Self::$variant(c) => c,)+
                }
            }

            /// The protocol's own section, to change it.
            pub(crate) fn section_mut(&mut self) -> &mut dyn ProtocolSection {
                match self {
                    $(Self::$variant(c) => c,)+
                }
            }

            pub fn kind(&self) -> ProtocolKind {
                match self {
                    $(Self::$variant(_) => ProtocolKind::$variant,)+
                }
            }

            /// Reads the section of `kind` from the line's table.
            fn read(kind: ProtocolKind, cx: &mut Cx, f: &mut Fields<'_>, baud: Baud) -> Self {
                match kind {
                    $(ProtocolKind::$variant => Self::$variant(<$config>::read_section(cx, f, baud)),)+
                }
            }
        }
    };
}

protocols! {
    ModbusMasterRtu = "modbus-master-rtu" => ModbusMasterRtuConfig;
    ModbusMasterAscii = "modbus-master-ascii" => ModbusMasterAsciiConfig;
    ModbusSlaveRtu = "modbus-slave-rtu" => ModbusSlaveRtuConfig;
    /// Listen-only Modbus RTU: stores what another master's traffic shows.
    ModbusRtuTap = "modbus-rtu-tap" => ModbusRtuTapConfig;
    /// 3964 or 3964R, by `block_check`.
    Proc3964 = "3964r" => Proc3964Config;
    /// Listen-only: both directions of a 3964(R) link on two ports.
    Proc3964Tap = "3964r-tap" => Proc3964TapConfig;
    Ascii = "ascii" => AsciiConfig;
}

/// A protocol's section reads its keys from the line's table (`baud`: the line's, for the
/// protocols whose defaults follow it).
pub(crate) trait ReadSection {
    fn read_section(cx: &mut Cx, f: &mut Fields<'_>, baud: Baud) -> Self;
}

// === impl ProtocolKind ===

impl ProtocolKind {
    /// Whether the line polls devices.
    pub fn is_master(self) -> bool {
        matches!(self, Self::ModbusMasterRtu | Self::ModbusMasterAscii)
    }

    /// Whether the line lists devices (a master polls them, a tap listens to them).
    pub fn has_devices(self) -> bool {
        self.is_master() || self == Self::ModbusRtuTap
    }

    /// Every spelling, as a message lists them: `a, b or c`.
    fn listed() -> String {
        let names: Vec<&str> = Self::ALL.iter().map(|k| k.as_str()).collect();
        match names.split_last() {
            Some((last, [])) => (*last).to_owned(),
            Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
            None => String::new(),
        }
    }
}

// === impl ProtocolConfig ===

impl ProtocolConfig {
    /// The section of a line that serves the CP memory (the memory's layout spans every such
    /// line).
    pub fn cp_memory_slave(&self) -> Option<&ModbusSlaveRtuConfig> {
        match self {
            Self::ModbusSlaveRtu(c) => Some(c),
            _ => None,
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
                format!("missing required key ({})", ProtocolKind::listed()),
            );
        }
        let serial = SerialConfig::read(cx, &mut f);
        // Without a protocol the valid keys are unknown: report nothing more for this line.
        let kind = kind?;
        let baud = serial.as_ref().map_or(DEFAULT_BAUD, |s| s.baud);
        let protocol = ProtocolConfig::read(kind, cx, &mut f, baud);
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

/// Who acknowledges the telegrams of `line`: its `ack`, else "on-publish" when the line has no
/// Modbus TCP `unit_id` and zenoh is on (`zenoh_on`: nobody else could), else "explicit".
pub fn ack_mode(zenoh_on: bool, line: &LineConfig) -> AckConfig {
    line.ack()
        .unwrap_or(if line.unit_id().is_none() && zenoh_on {
            AckConfig::OnPublish
        } else {
            AckConfig::Explicit
        })
}

#[cfg(test)]
mod tests {
    use proto_core::modbus::master::Framing;

    use super::*;
    use crate::line::rtu_timing;
    use crate::serial::PortSettings;

    /// 003 6.4.3 "Time_Out for message end": 76800 -> 0.5 ms, 38400 -> 1 ms, 19200 -> 2 ms,
    /// 9600 -> 4 ms, 300 -> 128 ms (3.5 characters of 11 bits, rounded in the manual).
    #[test]
    fn rtu_lines_end_a_frame_after_the_cps_time_out_at_every_baud_rate() {
        for (baud, manual_us) in [
            (76_800, 500),
            (38_400, 1_000),
            (19_200, 2_000),
            (9_600, 4_000),
            (300, 128_000),
        ] {
            let port = PortSettings::new("/dev/null", baud);
            let t35 = rtu_timing(&port).t3_5().as_micros();
            let off = t35.abs_diff(manual_us);
            assert!(off * 100 <= manual_us * 3, "{baud} Bd: {t35} us");
            // The master line and the slave line take the same timing.
            let Framing::Rtu { timing } = LineSettings::rtu("l", port.clone()).master.framing
            else {
                panic!("an RTU line");
            };
            assert_eq!(timing.t3_5().as_micros(), t35);
            let params = proto_core::cpmem::SlaveParams::new(
                1,
                proto_core::cpmem::OperatingMode::Normal,
                1,
                proto_core::cpmem::AddressMap::manual_example(),
            )
            .expect("params");
            let slave = SlaveLineSettings::new("s", port, params);
            assert_eq!(slave.timing().t3_5().as_micros(), t35);
        }
        // The multiplier (003 6.4.2.1, 1..10) on top: 2 at 38400 Bd gives 2 ms.
        let doubled = rtu_timing(&PortSettings::new("/dev/null", 38_400)).with_multiplier(2);
        assert_eq!(doubled.t3_5().as_micros(), 2_005);
    }

    /// The only files outside the protocols' own folders (`src/protocols/<folder>/`) that may
    /// name the protocols one by one: the table and the demo's simulated partners.
    const LISTING_FILES: [&str; 2] = ["protocols/mod.rs", "app/demo.rs"];

    /// The variants of `ProtocolConfig`: those of the protocols' table, which makes
    /// `ProtocolKind` with the same names.
    fn variants() -> Vec<String> {
        ProtocolKind::ALL
            .iter()
            .map(|kind| format!("{kind:?}"))
            .collect()
    }

    fn rust_files(dir: &std::path::Path, found: &mut Vec<std::path::PathBuf>) {
        for entry in std::fs::read_dir(dir).expect("source directory") {
            let path = entry.expect("directory entry").path();
            if path.is_dir() {
                rust_files(&path, found);
            } else if path.extension().is_some_and(|e| e == "rs") {
                found.push(path);
            }
        }
    }

    /// A file in a protocol's own folder: `protocols/<folder>/...` (`protocols/modbus_master/`,
    /// `protocols/telegram/`, ...), where its section, adapter, start and partner live.
    fn in_protocol_folder(relative: &str) -> bool {
        relative
            .strip_prefix("protocols/")
            .is_some_and(|rest| rest.contains('/'))
    }

    #[test]
    fn the_protocols_are_named_only_in_their_table_their_folders_and_the_demo() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let src = root.join("src");
        let variants = variants();
        assert!(
            variants.len() >= 7,
            "ProtocolConfig's variants not found in the protocols' table: {variants:?}"
        );
        let mut files = Vec::new();
        rust_files(&src, &mut files);
        let mut listing: Vec<String> = files
            .iter()
            .filter_map(|path| {
                let relative = path.strip_prefix(&src).ok()?.to_string_lossy().into_owned();
                let text = std::fs::read_to_string(path).ok()?;
                let names_one = variants.iter().any(|v| {
                    text.contains(&format!("ProtocolConfig::{v}"))
                        || text.contains(&format!("ProtocolKind::{v}"))
                        || text.contains(&format!("{v} = \""))
                });
                (names_one && !in_protocol_folder(&relative)).then_some(relative)
            })
            .collect();
        listing.sort();
        let stray: Vec<&String> = listing
            .iter()
            .filter(|f| !LISTING_FILES.contains(&f.as_str()))
            .collect();
        assert!(
            stray.is_empty(),
            "the protocols are named one by one in {stray:?}, outside their table \
             (protocols/mod.rs), their own folders (protocols/<folder>/) and the demo \
             (app/demo.rs). A protocol answers for its line through config::ProtocolSection and \
             protocols::start::StartLine; see \"Adding a line protocol\" in docs/architecture.md"
        );
        assert!(
            listing.contains(&"protocols/mod.rs".to_owned()),
            "the protocols' table is not in protocols/mod.rs: {listing:?}"
        );
        let architecture = std::fs::read_to_string(root.join("../docs/architecture.md"))
            .expect("docs/architecture.md");
        let unnamed: Vec<&String> = listing
            .iter()
            .filter(|f| !architecture.contains(&format!("`{f}`")))
            .collect();
        assert!(
            unnamed.is_empty(),
            "docs/architecture.md (\"Adding a line protocol\") does not name {unnamed:?}, which \
             name the protocols: list them among the files a new protocol touches"
        );
    }
}
