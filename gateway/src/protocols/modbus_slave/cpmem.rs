//! From a `modbus-slave-rtu` line of the configuration to the slave's parameters, and from every
//! such line to the memory's layout.
//!
//! The config speaks Modbus addresses (areas as `start`/`count`/`plc`, write enables as Modbus
//! ranges); proto-core's [`AddressMap`] speaks the CP's parameter dialog (003 6.4.5): one row per
//! area from its Modbus start to the next row's start, and write limits as one byte range for M,
//! one for Q and one range of DB numbers ("Limits"). The conversion is exact or refused: a write
//! enable that the limits cannot express without enabling more than the config says (a range that
//! starts or ends inside a byte or a DB, two separate ranges in one area) is an issue, never
//! silently widened.

use std::collections::BTreeSet;

use proto_core::cpmem::{
    AddressMap, Area, BitMapping, MemoryLayout, OperatingMode, SlaveParams, WriteLimits,
    WORDS_PER_DB,
};

use crate::config::{AddressRange, ModbusTable};
use crate::protocols::{BitArea, ModbusSlaveRtuConfig};

/// One problem converting a slave line's config: the key below the line's table
/// (`write_enable[1]`, `coils`) and what is wrong.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConvertIssue {
    /// The key, relative to `[lines.<name>]`.
    pub key: String,
    /// What is wrong.
    pub message: String,
}

impl std::fmt::Display for ConvertIssue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}: {}", self.key, self.message)
    }
}

fn issue(key: impl Into<String>, message: impl Into<String>) -> ConvertIssue {
    ConvertIssue {
        key: key.into(),
        message: message.into(),
    }
}

/// Bits per timer or counter word (003 6.4.8.1).
const BITS_PER_WORD: u32 = 16;
/// The Modbus address space.
const ADDRESS_SPACE: u32 = 0x1_0000;

fn rows(areas: &[(Area, BitArea)]) -> Vec<BitMapping> {
    areas
        .iter()
        .filter(|(_, a)| a.count > 0)
        .map(|&(area, a)| BitMapping {
            area,
            modbus_start: a.start,
            plc_start: a.plc,
        })
        .collect()
}

fn coil_areas(cfg: &ModbusSlaveRtuConfig) -> [(Area, BitArea); 4] {
    let c = &cfg.coils;
    [
        (Area::M, c.memory),
        (Area::Q, c.outputs),
        (Area::T, c.timers),
        (Area::C, c.counters),
    ]
}

fn input_areas(cfg: &ModbusSlaveRtuConfig) -> [(Area, BitArea); 2] {
    let i = &cfg.discrete_inputs;
    [(Area::M, i.memory), (Area::I, i.inputs)]
}

/// The size an area needs for `a`: bytes for M, Q and I, words for T and C.
fn area_units(area: Area, a: BitArea) -> u32 {
    if a.count == 0 {
        return 0;
    }
    let per_unit = if matches!(area, Area::T | Area::C) {
        BITS_PER_WORD
    } else {
        8
    };
    u32::from(a.plc) + a.count.div_ceil(per_unit)
}

/// A layout that holds everything the slave lines map: M, Q, I, T and C up to the end of their
/// last configured area (so an access past a row's `count` at the top of an area is refused with
/// 7.2 0E 38h, as on a CPU whose area ends there), and `data_blocks` or, if `None`, a DB of 512
/// words for each base DB and each DB a write enable reaches.
pub fn memory_layout<'a>(
    lines: impl IntoIterator<Item = &'a ModbusSlaveRtuConfig>,
    data_blocks: Option<&[(u16, u16)]>,
) -> MemoryLayout {
    let mut layout = MemoryLayout {
        m_bytes: 0,
        q_bytes: 0,
        i_bytes: 0,
        timers: 0,
        counters: 0,
        data_blocks: Vec::new(),
    };
    let mut dbs = BTreeSet::new();
    for cfg in lines {
        for (area, a) in coil_areas(cfg).into_iter().chain(input_areas(cfg)) {
            let size = match area {
                Area::M => &mut layout.m_bytes,
                Area::Q => &mut layout.q_bytes,
                Area::I => &mut layout.i_bytes,
                Area::T => &mut layout.timers,
                Area::C => &mut layout.counters,
                Area::Db(_) => continue,
            };
            *size = (*size).max(area_units(area, a));
        }
        dbs.insert(cfg.holding_db);
        dbs.insert(cfg.input_db);
        for range in cfg
            .write_enable
            .iter()
            .filter(|r| r.table == ModbusTable::Holding)
        {
            let (first, last) = db_span(cfg.holding_db, range);
            dbs.extend(first..=last);
        }
    }
    layout.data_blocks = match data_blocks {
        Some(list) => list.to_vec(),
        None => dbs.into_iter().map(|db| (db, WORDS_PER_DB)).collect(),
    };
    layout
}

/// The first and last DB a holding range reaches from base `base`.
fn db_span(base: u16, range: &AddressRange) -> (u16, u16) {
    let words = u32::from(WORDS_PER_DB);
    let first = u32::from(range.start) / words;
    let last = (u32::from(range.start) + range.count.max(1) - 1).min(ADDRESS_SPACE - 1) / words;
    let db = |offset: u32| base.saturating_add(u16::try_from(offset).unwrap_or(u16::MAX));
    (db(first), db(last))
}

/// The address map of a slave line, its write limits checked against `layout` (the memory the
/// line will serve).
pub fn address_map(
    cfg: &ModbusSlaveRtuConfig,
    layout: &MemoryLayout,
) -> Result<AddressMap, Vec<ConvertIssue>> {
    let coils = rows(&coil_areas(cfg));
    let inputs = rows(&input_areas(cfg));
    let map = AddressMap::new(
        &coils,
        &inputs,
        cfg.holding_db,
        cfg.input_db,
        WriteLimits::NONE,
    )
    .map_err(|e| vec![issue("coils", e.to_string())])?;
    let limits = write_limits(cfg, &map, layout)?;
    map.with_limits(limits)
        .map_err(|e| vec![issue("write_enable", e.to_string())])
}

/// The parameters of a slave line (003 6.4.5.1) with its address map.
pub fn slave_params(
    cfg: &ModbusSlaveRtuConfig,
    layout: &MemoryLayout,
) -> Result<SlaveParams, Vec<ConvertIssue>> {
    let map = address_map(cfg, layout)?;
    let mode = match cfg.operating_mode {
        crate::protocols::OperatingMode::Normal => OperatingMode::Normal,
        crate::protocols::OperatingMode::InterferenceSuppression => {
            OperatingMode::InterferenceSuppression
        }
    };
    SlaveParams::new(cfg.address, mode, cfg.delay_multiplier, map)
        .map_err(|e| vec![issue("address", e.to_string())])
}

/// Every problem of a slave line's config that the conversion finds (empty: it converts), for
/// `gateway check`. Uses the layout [`memory_layout`] derives from this line alone.
pub fn check(cfg: &ModbusSlaveRtuConfig) -> Vec<ConvertIssue> {
    let layout = memory_layout([cfg], None);
    slave_params(cfg, &layout).err().unwrap_or_default()
}

/// The write limits that enable exactly the config's `write_enable` ranges.
fn write_limits(
    cfg: &ModbusSlaveRtuConfig,
    map: &AddressMap,
    layout: &MemoryLayout,
) -> Result<WriteLimits, Vec<ConvertIssue>> {
    let mut issues = Vec::new();
    let mut limits = WriteLimits::NONE;
    bit_write_limits(cfg, map, layout, &mut limits, &mut issues);
    limits.data_blocks = db_write_limits(cfg, layout, &mut issues);
    if issues.is_empty() {
        Ok(limits)
    } else {
        Err(issues)
    }
}

/// The write limits of the bit areas (M, Q) from the config's coil ranges: one byte range each.
fn bit_write_limits(
    cfg: &ModbusSlaveRtuConfig,
    map: &AddressMap,
    layout: &MemoryLayout,
    limits: &mut WriteLimits,
    issues: &mut Vec<ConvertIssue>,
) {
    let coil_ranges: Vec<(usize, &AddressRange)> = cfg
        .write_enable
        .iter()
        .enumerate()
        .filter(|(_, r)| r.table == ModbusTable::Coil)
        .collect();
    let rows = map.coils();
    for (index, row) in rows.iter().enumerate() {
        // The row as the slave serves it: to the next row's start, and no further than its area.
        let next = rows
            .get(index + 1)
            .map_or(ADDRESS_SPACE, |n| u32::from(n.modbus_start));
        let lo = u32::from(row.modbus_start);
        let area_end = match row.area {
            Area::M => layout.m_bytes.saturating_sub(u32::from(row.plc_start)) * 8,
            Area::Q => layout.q_bytes.saturating_sub(u32::from(row.plc_start)) * 8,
            _ => next - lo,
        };
        let hi = next.min(lo + area_end);
        let mut hits: Vec<(u32, u32, usize)> = coil_ranges
            .iter()
            .filter_map(|&(k, r)| {
                let a = u32::from(r.start).max(lo);
                let b = (u32::from(r.start) + r.count).min(hi);
                (a < b).then(|| (a - lo, b - lo, k))
            })
            .collect();
        hits.sort_unstable();
        let mut hits = hits.into_iter();
        let Some((mut a, mut b, key)) = hits.next() else {
            continue;
        };
        let key = format!("write_enable[{key}]");
        let slot = match row.area {
            Area::M => &mut limits.memory,
            Area::Q => &mut limits.outputs,
            area => {
                issues.push(issue(key, format!("reaches {area}, which is read-only (003 6.4.5: timers and counters are read with FC 01 only)")));
                continue;
            }
        };
        // Sorted by start: the ranges join when none starts after the end so far.
        let mut joined = true;
        for (ha, hb, _) in hits {
            joined &= ha <= b;
            a = a.min(ha);
            b = b.max(hb);
        }
        let row_len = hi - lo;
        if !joined {
            issues.push(issue(key, format!("the write limits of {} are one byte range (003 6.4.5 \"Limits\"): enable one contiguous range in this area", row.area)));
        } else if a % 8 != 0 || (b % 8 != 0 && b != row_len) {
            issues.push(issue(key, format!("the write limits of {} are whole bytes (003 6.4.5 \"Limits\"): start and end the range on a multiple of 8 from the area's start {}", row.area, row.modbus_start)));
        } else {
            let first = u32::from(row.plc_start) + a / 8;
            let last = u32::from(row.plc_start) + (b - 1) / 8;
            match (u16::try_from(first), u16::try_from(last)) {
                (Ok(first), Ok(last)) => *slot = Some((first, last)),
                _ => issues.push(issue(key, "reaches past byte 65535")),
            }
        }
    }
}

/// The write limits of the data blocks from the config's holding ranges: one range of whole DBs.
fn db_write_limits(
    cfg: &ModbusSlaveRtuConfig,
    layout: &MemoryLayout,
    issues: &mut Vec<ConvertIssue>,
) -> Option<(u16, u16)> {
    let db_len = |db: u16| {
        layout
            .data_blocks
            .iter()
            .rev()
            .find(|(n, _)| *n == db)
            .map_or(0, |&(_, words)| u32::from(words.min(WORDS_PER_DB)))
    };
    let mut dbs: Option<(u16, u16, usize)> = None;
    for (k, range) in cfg.write_enable.iter().enumerate() {
        let key = format!("write_enable[{k}]");
        match range.table {
            ModbusTable::Coil => continue,
            ModbusTable::Holding => {}
            ModbusTable::Input | ModbusTable::Discrete => {
                issues.push(issue(key, "only coil (FC 05/15) and holding (FC 06/16) ranges can be write-enabled (003 6.4.5)"));
                continue;
            }
        }
        let (first, last) = db_span(cfg.holding_db, range);
        let words = u32::from(WORDS_PER_DB);
        let start_word = u32::from(range.start) % words;
        let end = u32::from(range.start) + range.count;
        let end_word = end - u32::from(last - cfg.holding_db) * words;
        if start_word != 0 || end_word < db_len(last).max(1).min(words) {
            issues.push(issue(key, format!("the write limits of the data blocks are whole DBs (003 6.4.5 \"Limits\"): this range covers part of DB {} (register {} .. {} of {} words each)", if start_word != 0 { first } else { last }, range.start, end - 1, WORDS_PER_DB)));
            continue;
        }
        dbs = match dbs {
            None => Some((first, last, k)),
            Some((a, b, _)) if first <= b.saturating_add(1) && a <= last.saturating_add(1) => {
                Some((a.min(first), b.max(last), k))
            }
            Some(_) => {
                issues.push(issue(key, "the write limits of the data blocks are one range of DB numbers (003 6.4.5 \"Limits\"): enable one contiguous range"));
                dbs
            }
        };
    }
    dbs.map(|(a, b, _)| (a, b))
}

#[cfg(test)]
mod tests;
