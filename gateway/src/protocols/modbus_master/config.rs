//! Protocol parameters of the Modbus lines: master RTU (003 6.4.2.1), master ASCII (003 6.4.2.2)
//! and slave RTU with the CP memory mapping (003 6.4.5, 6.4.8).

use std::collections::BTreeMap;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::config::reader::{check_name, Cx, Fields};
use crate::config::section::ProtocolSection;
use crate::config::tag::{self, AddressRange, ModbusTable};
use crate::config::DeviceConfig;
use crate::config::{DataBits, SerialConfig};

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

/// 003 6.4.5.1 "Slave address ... Range of values: 1 ... 255", default 222.
pub const DEFAULT_SLAVE_ADDRESS: u8 = 222;
/// 003 6.4.8.3 example: "from 0 Data blocks commence at DB 800" (FC 03, 06, 16).
pub const DEFAULT_HOLDING_DB: u16 = 800;
/// FC 04 base DB. 003 6.4.5 lets FC 04 read "a further block of 128 DBs"; the gateway's memory is
/// written only through FC 05/06/15/16, so by default FC 04 reads the same DBs as FC 03.
pub const DEFAULT_INPUT_DB: u16 = 800;
/// 003 6.4.5: "Up to 128 DB may be accessed in one block".
pub const DBS_PER_BLOCK: u16 = 128;
/// 003 6.4.8: "a maximum data block length of 512 data words".
pub const WORDS_PER_DB: u16 = 512;

pub fn default_reply_timeout() -> Duration {
    DEFAULT_REPLY_TIMEOUT
}
pub fn default_operating_mode() -> OperatingMode {
    DEFAULT_OPERATING_MODE
}
pub fn default_delay_multiplier() -> u8 {
    DEFAULT_DELAY_MULTIPLIER
}
pub fn default_slave_address() -> u8 {
    DEFAULT_SLAVE_ADDRESS
}

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
                    let from = crate::config::reader::int_value(
                        cx,
                        from,
                        &format!("{path}[0]"),
                        lo..=hi,
                        CITE,
                    );
                    let to = crate::config::reader::int_value(
                        cx,
                        to,
                        &format!("{path}[1]"),
                        lo..=hi,
                        CITE,
                    );
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

/// One area of the bit-addressed CP memory: Modbus bit addresses `start..start+count` map to the
/// PLC area from byte (or timer/counter number) `plc` on (003 6.4.8.1: "Param-start-address" and
/// "PLC-area"). `count = 0` switches the area off.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct BitArea {
    pub start: u16,
    pub count: u32,
    pub plc: u16,
}

/// FC 01, 05, 15 areas (003 6.4.5 "FC 01, 05, 15, 02"); defaults are the manual's example
/// (003 6.4.8.1): 0..1023 -> M 1000.0, 1024..2047 -> Q 100.0, 2048..4063 -> T 100,
/// 4064..4111 -> C 200 (its table ends at start address 4096, C 202).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct CoilAreas {
    pub memory: BitArea,
    pub outputs: BitArea,
    /// Read with FC 01 only, in 16-bit steps.
    pub timers: BitArea,
    /// Read with FC 01 only, in 16-bit steps.
    pub counters: BitArea,
}

/// FC 02 areas; defaults from 003 6.4.8.2: 0..1023 -> M 1000.0, 1024..2047 -> I 100.0.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct InputAreas {
    pub memory: BitArea,
    pub inputs: BitArea,
}

impl Default for CoilAreas {
    fn default() -> Self {
        Self {
            memory: BitArea {
                start: 0,
                count: 1024,
                plc: 1000,
            },
            outputs: BitArea {
                start: 1024,
                count: 1024,
                plc: 100,
            },
            timers: BitArea {
                start: 2048,
                count: 2016,
                plc: 100,
            },
            counters: BitArea {
                start: 4064,
                count: 48,
                plc: 200,
            },
        }
    }
}

impl Default for InputAreas {
    fn default() -> Self {
        Self {
            memory: BitArea {
                start: 0,
                count: 1024,
                plc: 1000,
            },
            inputs: BitArea {
                start: 1024,
                count: 1024,
                plc: 100,
            },
        }
    }
}

/// Modbus slave RTU (003 6.4.5): the gateway answers a serial master from its own CP memory.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModbusSlaveRtuConfig {
    /// Own slave address, 1..=255.
    pub address: u8,
    pub operating_mode: OperatingMode,
    pub delay_multiplier: u8,
    /// The Modbus TCP unit id under which the same CP memory is served, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unit_id: Option<u8>,
    pub coils: CoilAreas,
    pub discrete_inputs: InputAreas,
    /// FC 03, 06, 16: register 0 is DBW 0 of this DB; 512 words a DB, 128 DBs.
    pub holding_db: u16,
    /// FC 04: the base DB of the second block.
    pub input_db: u16,
    /// Write-enabled ranges ("Limits"); empty: nothing may be written (003 6.4.5).
    pub write_enable: Vec<AddressRange>,
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

impl ModbusMasterRtuConfig {
    pub(crate) fn read(cx: &mut Cx, f: &mut Fields<'_>) -> Self {
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

impl ModbusMasterAsciiConfig {
    pub(crate) fn read(cx: &mut Cx, f: &mut Fields<'_>) -> Self {
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

fn read_area(cx: &mut Cx, f: &mut Fields<'_>, key: &'static str, default: BitArea) -> BitArea {
    let Some(mut t) = f.table(cx, key) else {
        return default;
    };
    let area = BitArea {
        start: t.int_or(cx, "start", 0..=u16::MAX, default.start, ""),
        count: t.int_or(cx, "count", 0..=65_536, default.count, ""),
        plc: t.int_or(cx, "plc", 0..=u16::MAX, default.plc, ""),
    };
    t.finish(cx);
    area
}

impl ModbusSlaveRtuConfig {
    pub(crate) fn read(cx: &mut Cx, f: &mut Fields<'_>) -> Self {
        const CITE: &str = "003 6.4.5.1";
        let address = f.int_or(cx, "address", 1..=u8::MAX, DEFAULT_SLAVE_ADDRESS, CITE);
        let operating_mode = f.choice_or(cx, "operating_mode", DEFAULT_OPERATING_MODE);
        let delay_multiplier = f.int_or(
            cx,
            "delay_multiplier",
            1..=MAX_DELAY_MULTIPLIER,
            DEFAULT_DELAY_MULTIPLIER,
            CITE,
        );
        let unit_id = f.int(cx, "unit_id", 1..=u8::MAX, "");
        let c = CoilAreas::default();
        let coils = match f.table(cx, "coils") {
            None => c,
            Some(mut t) => {
                let a = CoilAreas {
                    memory: read_area(cx, &mut t, "memory", c.memory),
                    outputs: read_area(cx, &mut t, "outputs", c.outputs),
                    timers: read_area(cx, &mut t, "timers", c.timers),
                    counters: read_area(cx, &mut t, "counters", c.counters),
                };
                t.finish(cx);
                a
            }
        };
        let i = InputAreas::default();
        let discrete_inputs = match f.table(cx, "discrete_inputs") {
            None => i,
            Some(mut t) => {
                let a = InputAreas {
                    memory: read_area(cx, &mut t, "memory", i.memory),
                    inputs: read_area(cx, &mut t, "inputs", i.inputs),
                };
                t.finish(cx);
                a
            }
        };
        // DB 0 does not exist; the block of 128 DBs must end at DB 65535.
        let max_db = u16::MAX - (DBS_PER_BLOCK - 1);
        let holding_db = f.int_or(
            cx,
            "holding_db",
            1..=max_db,
            DEFAULT_HOLDING_DB,
            "003 6.4.8.3",
        );
        let input_db = f.int_or(cx, "input_db", 1..=max_db, DEFAULT_INPUT_DB, "003 6.4.8.4");
        let mut write_enable = Vec::new();
        for (path, v) in f.array(cx, "write_enable") {
            if let Some(r) = tag::read_range(cx, &path, v) {
                if !r.table.is_writable() {
                    cx.issue(
                        path.clone() + ".table",
                        "only \"coil\" (FC 05/15) and \"holding\" (FC 06/16) areas can be write-enabled (003 6.4.5 Limits)",
                    );
                }
                write_enable.push(r);
            }
        }
        Self {
            address,
            operating_mode,
            delay_multiplier,
            unit_id,
            coils,
            discrete_inputs,
            holding_db,
            input_db,
            write_enable,
        }
    }
}

impl ModbusTable {
    /// Whether Modbus can write this table (coils with FC 05/15, holding registers with FC 06/16).
    pub fn is_writable(self) -> bool {
        matches!(self, Self::Coil | Self::Holding)
    }
}

// === impl ProtocolSection for the Modbus lines ===

impl ProtocolSection for ModbusMasterRtuConfig {
    fn check(&self, cx: &mut Cx, path: &str, serial: &SerialConfig) {
        check_rtu_data_bits(cx, path, serial);
    }

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

impl ProtocolSection for ModbusMasterAsciiConfig {
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

impl ProtocolSection for ModbusSlaveRtuConfig {
    fn check(&self, cx: &mut Cx, path: &str, serial: &SerialConfig) {
        check_rtu_data_bits(cx, path, serial);
        check_slave(cx, path, self);
    }

    fn unit_id(&self) -> Option<u8> {
        self.unit_id
    }
}

/// Modbus RTU frames have 8 data bits (003 6.4.2.1), on a master, a slave and a tap line alike.
pub(crate) fn check_rtu_data_bits(cx: &mut Cx, path: &str, serial: &SerialConfig) {
    if serial.data_bits != DataBits::Eight {
        cx.issue(
            format!("{path}.data_bits"),
            "Modbus RTU uses 8 data bits (003 6.4.2.1: \"8 (fix)\")",
        );
    }
}

fn check_slave(cx: &mut Cx, path: &str, s: &ModbusSlaveRtuConfig) {
    let c = &s.coils;
    let coil_areas = [
        ("memory", c.memory, false),
        ("outputs", c.outputs, false),
        ("timers", c.timers, true),
        ("counters", c.counters, true),
    ];
    check_areas(cx, &format!("{path}.coils"), &coil_areas);
    let i = &s.discrete_inputs;
    check_areas(
        cx,
        &format!("{path}.discrete_inputs"),
        &[("memory", i.memory, false), ("inputs", i.inputs, false)],
    );
}

/// Areas of one function-code group: inside the address space, timer/counter areas in whole
/// 16-bit words (003 6.4.8.1), the PLC addresses inside 0..=65535, and no two areas overlapping.
fn check_areas(cx: &mut Cx, path: &str, areas: &[(&str, BitArea, bool)]) {
    for (i, (name, a, words)) in areas.iter().enumerate() {
        if a.count == 0 {
            continue;
        }
        let p = format!("{path}.{name}");
        let end = u32::from(a.start) + a.count;
        if end > 65_536 {
            cx.issue(
                format!("{p}.count"),
                format!(
                    "area {}+{} runs past Modbus address 65535",
                    a.start, a.count
                ),
            );
        }
        let plc_units = if *words {
            if a.count % 16 != 0 {
                cx.issue(
                    format!("{p}.count"),
                    "timers and counters are read in 16-bit steps: count must be a multiple of 16 (003 6.4.8.1)",
                );
            }
            a.count.div_ceil(16)
        } else {
            a.count.div_ceil(8)
        };
        if u32::from(a.plc) + plc_units > 65_536 {
            cx.issue(
                format!("{p}.plc"),
                format!(
                    "the area runs past PLC address 65535 ({} + {plc_units})",
                    a.plc
                ),
            );
        }
        for (other, b, _) in &areas[..i] {
            if b.count > 0
                && u32::from(a.start) < u32::from(b.start) + b.count
                && u32::from(b.start) < end
            {
                cx.issue(format!("{p}.start"), format!("overlaps the {other} area"));
            }
        }
    }
}

// === transparent forwarding across lines ===

/// The unit ids `line` forwards transparently (`transparent = true` on a Modbus master line).
pub fn transparent_units(
    line: &crate::protocols::LineConfig,
) -> Option<std::ops::RangeInclusive<u8>> {
    line.protocol.section().transparent_units()
}

/// Two transparent lines may not claim the same unit id; where a device or unit of the gateway
/// (`claimed`) holds the id, it wins and the overlap is harmless.
pub(crate) fn check_transparent(
    cx: &mut Cx,
    config: &crate::config::Config,
    claimed: &BTreeMap<u8, String>,
) {
    let transparent: Vec<(&String, std::ops::RangeInclusive<u8>)> = config
        .lines
        .iter()
        .filter_map(|(name, line)| transparent_units(line).map(|units| (name, units)))
        .collect();
    for (i, (name, units)) in transparent.iter().enumerate() {
        for (first, other) in transparent.iter().take(i) {
            let shared: Vec<u8> = units
                .clone()
                .filter(|u| other.contains(u) && !claimed.contains_key(u))
                .collect();
            if !shared.is_empty() {
                cx.issue(
                    format!("lines.{name}.transparent_units"),
                    format!(
                        "unit ids {} are forwarded by lines.{first} too: two transparent lines \
                         may not claim the same unit id (narrow transparent_units)",
                        show_ids(&shared)
                    ),
                );
            }
        }
    }
}

/// Unit ids as runs: `1..=9, 11, 13..=247`.
fn show_ids(ids: &[u8]) -> String {
    let mut runs: Vec<(u8, u8)> = Vec::new();
    for &id in ids {
        match runs.last_mut() {
            Some((_, last)) if last.checked_add(1) == Some(id) => *last = id,
            _ => runs.push((id, id)),
        }
    }
    runs.iter()
        .map(|&(a, b)| {
            if a == b {
                a.to_string()
            } else {
                format!("{a}..={b}")
            }
        })
        .collect::<Vec<_>>()
        .join(", ")
}
