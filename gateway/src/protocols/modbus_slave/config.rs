//! Protocol parameters of the Modbus slave RTU line with the CP memory mapping (003 6.4.5,
//! 6.4.8).

use serde::Serialize;

use crate::config::check::{Check, Line};
use crate::config::reader::{Cx, Fields};
use crate::config::section::ProtocolSection;
use crate::config::tag::{self, AddressRange};
use crate::config::Baud;
use crate::protocols::modbus_master::config::{
    check_rtu_data_bits, OperatingMode, DEFAULT_DELAY_MULTIPLIER, DEFAULT_OPERATING_MODE,
    MAX_DELAY_MULTIPLIER,
};
use crate::protocols::ReadSection;

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

impl ReadSection for ModbusSlaveRtuConfig {
    fn read_section(cx: &mut Cx, f: &mut Fields<'_>, _baud: Baud) -> Self {
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

// === impl ProtocolSection ===

impl Check<Line<'_>> for ModbusSlaveRtuConfig {
    fn check(&self, line: &Line<'_>, cx: &mut Cx) {
        check_rtu_data_bits(cx, line.path, line.serial);
        check_slave(cx, line.path, self);
    }
}

impl ProtocolSection for ModbusSlaveRtuConfig {
    fn unit_id(&self) -> Option<u8> {
        self.unit_id
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
