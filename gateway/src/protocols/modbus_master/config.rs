//! Protocol parameters of the Modbus master lines: RTU (003 6.4.2.1) and ASCII (003 6.4.2.2),
//! and what the Modbus RTU lines share (operating mode, delay multiplier, 8 data bits).

use std::collections::BTreeMap;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::config::check::{Check, Line};
use crate::config::reader::{check_name, Cx, Fields};
use crate::config::section::ProtocolSection;
use crate::config::Baud;
use crate::config::DeviceConfig;
use crate::config::{DataBits, SerialConfig};
use crate::protocols::ReadSection;

/// 003 6.4.2.1/6.4.2.2 "Reply monitoring time ... Range: 5 ... 65500ms".
pub const REPLY_TIMEOUT_RANGE: (Duration, Duration) =
    (Duration::from_millis(5), Duration::from_millis(65_500));
/// 003 6.4.2.1/6.4.2.2 "Reply monitoring time ... Default value 2000".
pub const DEFAULT_REPLY_TIMEOUT: Duration = Duration::from_millis(2000);
/// 003 6.4.2.1 "Operating mode ... Default value Normal operation".
pub const DEFAULT_OPERATING_MODE: OperatingMode = OperatingMode::Normal;
/// 003 6.4.2.1/6.4.5.1 "Multiplier character delay time ... Range: 1 ... 10", default 1.
pub const DEFAULT_DELAY_MULTIPLIER: u8 = 1;
/// 003 6.4.2.1: range of the multiplier.
pub const MAX_DELAY_MULTIPLIER: u8 = 10;
/// The seeds name no repetition for the Modbus master: a request is sent once (7.2 reports
/// 08 30h "no reply" after the reply monitoring time).
pub const DEFAULT_RETRIES: u8 = 0;
/// Upper bound of retries so that one silent device cannot hold a line for minutes.
pub const MAX_RETRIES: u8 = 10;
/// While a poll is due, at most this many commands (writes, on-demand reads, pass-through
/// requests) go in a row before it by default. The seeds leave the order of requests to the S7
/// program; the rule is the gateway's.
pub const DEFAULT_COMMANDS_IN_ROW: u32 = 2;
/// Range of `commands_in_row` (0: a due poll always goes before any command).
pub const COMMANDS_IN_ROW_RANGE: (u32, u32) = (0, 100);
/// The RTU master's wait after a broadcast. 003 names no such parameter for RTU; Modbus over
/// Serial Line V1.02 2.4.1 gives the turnaround delay as "typically 100 ms to 200 ms".
pub const DEFAULT_RTU_TURNAROUND_DELAY: Duration = Duration::from_millis(100);
/// 003 6.4.2.2 "Turnaround Delay ... Range of values: 0 ... 65535ms", default 0 (deactivated).
pub const DEFAULT_ASCII_TURNAROUND_DELAY: Duration = Duration::ZERO;
/// 003 6.4.2.2: range of the turnaround delay (used for RTU too).
pub const MAX_TURNAROUND_DELAY: Duration = Duration::from_millis(65_535);
/// 003 6.4.2.2 "Character Delay Time ... Range of values: 1 ... 6500ms", default 1000.
pub const DEFAULT_MASTER_ASCII_CHARACTER_DELAY: Duration = Duration::from_millis(1000);
/// 003 6.4.2.2: range of the ASCII master's character delay time.
pub const MASTER_ASCII_CHARACTER_DELAY_RANGE: (Duration, Duration) =
    (Duration::from_millis(1), Duration::from_millis(6500));
/// 003 6.4.2.2 "with 32-Bit Register ... deactivated".
pub const DEFAULT_REGISTERS32: bool = false;
/// `transparent_units` by default: every address a slave may have (Modbus over Serial Line
/// V1.02, 2.2: 1..247).
pub const DEFAULT_TRANSPARENT_UNITS: (u8, u8) = (1, 247);

/// 003 6.4.2.1 "Operating mode": in interference suppression, transmission errors and breaks
/// are ignored while the driver is idle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OperatingMode {
    Normal,
    InterferenceSuppression,
}

/// Modbus master RTU (003 6.4.2.1), with the devices it polls.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModbusMasterRtuConfig {
    /// Reply monitoring time, 5 ms..=65500 ms.
    #[serde(with = "humantime_serde")]
    pub reply_timeout: Duration,
    pub operating_mode: OperatingMode,
    /// Multiplies the 3.5-character end-of-frame time, 1..=10.
    pub delay_multiplier: u8,
    /// Repetitions of a request that got no valid reply, 0..=10.
    pub retries: u8,
    /// Wait after a broadcast before the next request.
    #[serde(with = "humantime_serde")]
    pub turnaround_delay: Duration,
    /// At most this many commands in a row while a poll is due.
    pub commands_in_row: u32,
    /// Modbus TCP requests for unit ids nobody claims go to the slave of the same address.
    #[serde(flatten)]
    pub transparent: Transparent,
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub devices: BTreeMap<String, DeviceConfig>,
}

/// Modbus master ASCII (003 6.4.2.2), with the devices it polls.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModbusMasterAsciiConfig {
    /// Longest gap between two characters of a frame, 1 ms..=6500 ms.
    #[serde(with = "humantime_serde")]
    pub character_delay: Duration,
    #[serde(with = "humantime_serde")]
    pub reply_timeout: Duration,
    #[serde(with = "humantime_serde")]
    pub turnaround_delay: Duration,
    pub operating_mode: OperatingMode,
    /// 32-bit registers by bit 6 of the function code (43h/46h/50h).
    pub registers32: bool,
    pub retries: u8,
    /// At most this many commands in a row while a poll is due.
    pub commands_in_row: u32,
    /// Modbus TCP requests for unit ids nobody claims go to the slave of the same address.
    #[serde(flatten)]
    pub transparent: Transparent,
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub devices: BTreeMap<String, DeviceConfig>,
}

/// Transparent forwarding of a Modbus master line (`transparent`, `transparent_units`): a Modbus
/// TCP request for a unit id that no device or unit of the gateway claims goes, on demand, to the
/// slave address of the same number on this line (as mbusd or a Moxa MGate forward).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Transparent {
    /// Forwarding on.
    #[serde(rename = "transparent", skip_serializing_if = "std::ops::Not::not")]
    pub enabled: bool,
    /// The unit ids forwarded, `[FROM, TO]`.
    #[serde(
        rename = "transparent_units",
        skip_serializing_if = "Transparent::default_units"
    )]
    pub units: (u8, u8),
}

impl Default for Transparent {
    fn default() -> Self {
        Self {
            enabled: false,
            units: DEFAULT_TRANSPARENT_UNITS,
        }
    }
}

// === impl Transparent ===

impl Transparent {
    fn default_units(units: &(u8, u8)) -> bool {
        *units == DEFAULT_TRANSPARENT_UNITS
    }

    /// The unit ids forwarded, if forwarding is on.
    pub fn range(&self) -> Option<std::ops::RangeInclusive<u8>> {
        self.enabled.then_some(self.units.0..=self.units.1)
    }

    fn read(cx: &mut Cx, f: &mut Fields<'_>) -> Self {
        const CITE: &str = "Modbus over Serial Line V1.02 2.2";
        let enabled = f.bool_or(cx, "transparent", false);
        let path = f.at("transparent_units");
        let mut units = DEFAULT_TRANSPARENT_UNITS;
        if let Some(v) = f.raw("transparent_units") {
            let (lo, hi) = DEFAULT_TRANSPARENT_UNITS;
            match v.as_array().map(Vec::as_slice) {
                Some([from, to]) => {
                    let [from, to] = [(0, from), (1, to)].map(|(i, v)| {
                        let at = format!("{path}[{i}]");
                        crate::config::reader::int_value(cx, v, &at, lo..=hi, CITE)
                    });
                    if let (Some(from), Some(to)) = (from, to) {
                        if from > to {
                            cx.issue(
                                path.clone(),
                                format!("[FROM, TO] with FROM <= TO, found [{from}, {to}]"),
                            );
                        } else {
                            units = (from, to);
                        }
                    }
                }
                _ => cx.issue(
                    path.clone(),
                    "expected [FROM, TO], two unit ids within 1..=247",
                ),
            }
            if !enabled {
                cx.issue(
                    path,
                    "has no effect without transparent = true on this line",
                );
            }
        }
        Self { enabled, units }
    }
}

// === readers ===

pub(crate) fn read_devices(cx: &mut Cx, f: &mut Fields<'_>) -> BTreeMap<String, DeviceConfig> {
    let mut devices = BTreeMap::new();
    for (name, path, value) in f.named_tables(cx, "devices") {
        check_name(cx, &path, &name);
        if let Some(d) = crate::config::template::read_device(cx, &path, value) {
            devices.insert(name, d);
        }
    }
    devices
}

fn commands_in_row(cx: &mut Cx, f: &mut Fields<'_>) -> u32 {
    let (lo, hi) = COMMANDS_IN_ROW_RANGE;
    f.int_or(cx, "commands_in_row", lo..=hi, DEFAULT_COMMANDS_IN_ROW, "")
}

fn reply_timeout(cx: &mut Cx, f: &mut Fields<'_>, cite: &str) -> Duration {
    let (lo, hi) = REPLY_TIMEOUT_RANGE;
    f.duration_or(cx, "reply_timeout", lo..=hi, DEFAULT_REPLY_TIMEOUT, cite)
}

impl ReadSection for ModbusMasterRtuConfig {
    fn read_section(cx: &mut Cx, f: &mut Fields<'_>, _baud: Baud) -> Self {
        const CITE: &str = "003 6.4.2.1";
        Self {
            reply_timeout: reply_timeout(cx, f, CITE),
            operating_mode: f.choice_or(cx, "operating_mode", DEFAULT_OPERATING_MODE),
            delay_multiplier: f.int_or(
                cx,
                "delay_multiplier",
                1..=MAX_DELAY_MULTIPLIER,
                DEFAULT_DELAY_MULTIPLIER,
                CITE,
            ),
            retries: f.int_or(cx, "retries", 0..=MAX_RETRIES, DEFAULT_RETRIES, ""),
            turnaround_delay: f.duration_or(
                cx,
                "turnaround_delay",
                Duration::ZERO..=MAX_TURNAROUND_DELAY,
                DEFAULT_RTU_TURNAROUND_DELAY,
                "003 6.4.2.2",
            ),
            commands_in_row: commands_in_row(cx, f),
            transparent: Transparent::read(cx, f),
            devices: read_devices(cx, f),
        }
    }
}

impl ReadSection for ModbusMasterAsciiConfig {
    fn read_section(cx: &mut Cx, f: &mut Fields<'_>, _baud: Baud) -> Self {
        const CITE: &str = "003 6.4.2.2";
        let (lo, hi) = MASTER_ASCII_CHARACTER_DELAY_RANGE;
        Self {
            character_delay: f.duration_or(
                cx,
                "character_delay",
                lo..=hi,
                DEFAULT_MASTER_ASCII_CHARACTER_DELAY,
                CITE,
            ),
            reply_timeout: reply_timeout(cx, f, CITE),
            turnaround_delay: f.duration_or(
                cx,
                "turnaround_delay",
                Duration::ZERO..=MAX_TURNAROUND_DELAY,
                DEFAULT_ASCII_TURNAROUND_DELAY,
                CITE,
            ),
            operating_mode: f.choice_or(cx, "operating_mode", DEFAULT_OPERATING_MODE),
            registers32: f.bool_or(cx, "registers32", DEFAULT_REGISTERS32),
            retries: f.int_or(cx, "retries", 0..=MAX_RETRIES, DEFAULT_RETRIES, ""),
            commands_in_row: commands_in_row(cx, f),
            transparent: Transparent::read(cx, f),
            devices: read_devices(cx, f),
        }
    }
}

// === impl ProtocolSection for the Modbus lines ===

impl Check<Line<'_>> for ModbusMasterRtuConfig {
    fn check(&self, line: &Line<'_>, cx: &mut Cx) {
        check_rtu_data_bits(cx, line.path, line.serial);
    }
}

impl Check<Line<'_>> for ModbusMasterAsciiConfig {}

/// Both master sections forward and list their devices alike.
macro_rules! master_sections {
    ($($section:ty),+) => {$(
        impl ProtocolSection for $section {
            fn transparent_units(&self) -> Option<std::ops::RangeInclusive<u8>> {
                self.transparent.range()
            }

            fn devices(&self) -> Option<&BTreeMap<String, DeviceConfig>> {
                Some(&self.devices)
            }

            fn devices_mut(&mut self) -> Option<&mut BTreeMap<String, DeviceConfig>> {
                Some(&mut self.devices)
            }
        }
    )+};
}

master_sections!(ModbusMasterRtuConfig, ModbusMasterAsciiConfig);

/// Modbus RTU frames have 8 data bits (003 6.4.2.1), on a master, a slave and a tap line alike.
pub(crate) fn check_rtu_data_bits(cx: &mut Cx, path: &str, serial: &SerialConfig) {
    if serial.data_bits != DataBits::Eight {
        cx.issue(
            format!("{path}.data_bits"),
            "Modbus RTU uses 8 data bits (003 6.4.2.1: \"8 (fix)\")",
        );
    }
}

// === transparent forwarding across lines ===

/// The unit ids `line` forwards transparently (`transparent = true` on a Modbus master line).
pub fn transparent_units(
    line: &crate::protocols::LineConfig,
) -> Option<std::ops::RangeInclusive<u8>> {
    line.protocol.section().transparent_units()
}
