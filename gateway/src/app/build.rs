//! From the validated config to the Modbus TCP server's write policy.
//!
//! The lines are built by their own protocols (`protocols::start`: each config section converts and
//! starts its line next to its adapter); what stays here is the servers' part.

use crate::config::{self, ModbusTable};
use crate::unit::write_policy::{WriteRange, WriteTable};

/// The Modbus TCP write policy of the config (`None`: every address of every unit is writable).
pub(crate) fn write_ranges(cfg: &config::ModbusTcpConfig) -> Option<Vec<WriteRange>> {
    unit_write_ranges(&cfg.write_ranges)
}

/// Configured write ranges as the server checks them; `None` (no limit) when there are none.
pub(crate) fn unit_write_ranges(ranges: &[config::UnitRange]) -> Option<Vec<WriteRange>> {
    if ranges.is_empty() {
        return None;
    }
    let ranges = ranges
        .iter()
        .filter_map(|r| {
            let table = match r.table {
                ModbusTable::Holding => WriteTable::HoldingRegisters,
                ModbusTable::Coil => WriteTable::Coils,
                // Input registers and discrete inputs are never written; the validation refuses
                // such ranges.
                ModbusTable::Input | ModbusTable::Discrete => return None,
            };
            let last = (u32::from(r.start) + r.count.max(1) - 1).min(u32::from(u16::MAX)) as u16;
            Some(WriteRange {
                unit: r.unit_id,
                table,
                first: r.start,
                last,
            })
        })
        .collect();
    Some(ranges)
}
