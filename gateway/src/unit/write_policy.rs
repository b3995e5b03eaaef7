//! Which writes clients may make: the read-only mode and the write-enabled ranges of
//! `[modbus_tcp]`. The Modbus TCP server answers a refused request with the exception given here,
//! and REST and zenoh refuse a tag write the same way before it reaches the unit.

use proto_core::modbus::pdu::{ExceptionCode, Request};

/// The write policy of the units.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct WritePolicy {
    /// Every request that changes state is answered with exception 01 (illegal function): writes
    /// (FC 05, 06, 15, 16, the write part of 23) and the FC 08 sub-functions that change the
    /// device (restart, change delimiter, listen-only, clear counters). 01 rather than 02 tells
    /// the client the function itself is switched off here, whatever the address.
    pub read_only: bool,
    /// Table writes allowed, per unit id; `None` allows all. A write touching any address outside
    /// the ranges of its unit and table is answered with exception 02 (illegal data address).
    pub write_ranges: Option<Vec<WriteRange>>,
}

// === impl WritePolicy ===

impl WritePolicy {
    /// The exception a request to `unit` gets from the write policy, if any.
    pub fn check_write(&self, unit: u8, request: &Request) -> Option<ExceptionCode> {
        let access = Access::of(request);
        if access == Access::Read {
            return None;
        }
        if self.read_only {
            return Some(ExceptionCode::IllegalFunction);
        }
        let (
            Some(ranges),
            Access::Table {
                table,
                address,
                count,
            },
        ) = (&self.write_ranges, access)
        else {
            return None;
        };
        (!covered(ranges, unit, table, address, count)).then_some(ExceptionCode::IllegalDataAddress)
    }
}

/// The table a write goes to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum WriteTable {
    /// Coils (FC 05, 15).
    Coils,
    /// Holding registers (FC 06, 16, 23).
    HoldingRegisters,
}

/// Addresses `first..=last` of one table of one unit that clients may write.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct WriteRange {
    /// The unit id.
    pub unit: u8,
    /// The table.
    pub table: WriteTable,
    /// First writable address (protocol address, 0-based).
    pub first: u16,
    /// Last writable address, inclusive.
    pub last: u16,
}

// === impl WriteRange ===

impl WriteRange {
    /// Whether this range is of `unit` and `table` and holds `address`.
    pub fn contains(&self, unit: u8, table: WriteTable, address: u16) -> bool {
        self.unit == unit && self.table == table && (self.first..=self.last).contains(&address)
    }
}

/// What a request does to the unit, for the write policy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Access {
    /// Reads only.
    Read,
    /// Writes `count` entries of `table` from `address`.
    Table {
        table: WriteTable,
        address: u16,
        count: usize,
    },
    /// Changes the device without a table address (FC 08 control sub-functions).
    Control,
}

// === impl Access ===

impl Access {
    fn of(request: &Request) -> Self {
        use WriteTable::{Coils, HoldingRegisters};
        let table = |table, address, count| Self::Table {
            table,
            address,
            count,
        };
        match request {
            Request::WriteSingleCoil { address, .. } => table(Coils, *address, 1),
            Request::WriteSingleRegister { address, .. } => table(HoldingRegisters, *address, 1),
            Request::WriteMultipleCoils { address, values } => table(Coils, *address, values.len()),
            Request::WriteMultipleRegisters { address, values } => {
                table(HoldingRegisters, *address, values.len())
            }
            Request::ReadWriteMultipleRegisters {
                write_address,
                values,
                ..
            } => table(HoldingRegisters, *write_address, values.len()),
            // Modbus Application Protocol V1.1b3, 6.8.1: 00 return query data, 02 return
            // diagnostic register, 0B..12 return counters only read; 01 restart, 03 change ASCII
            // delimiter, 04 force listen-only, 0A and 14 clear counters change the device (the KS
            // vario of seed 001 answers nothing in listen-only mode until a restart).
            Request::Diagnostics { sub_function, .. } => match sub_function {
                0x00 | 0x02 | 0x0B..=0x12 => Self::Read,
                _ => Self::Control,
            },
            Request::ReadCoils { .. }
            | Request::ReadDiscreteInputs { .. }
            | Request::ReadHoldingRegisters { .. }
            | Request::ReadInputRegisters { .. }
            | Request::ReadExceptionStatus
            | Request::GetCommEventCounter
            | Request::GetCommEventLog
            | Request::ReportServerId
            | Request::ReadDeviceIdentification { .. } => Self::Read,
        }
    }
}

/// The table, first address and count a request writes, if it writes a table.
pub(crate) fn written(request: &Request) -> Option<(WriteTable, u16, usize)> {
    match Access::of(request) {
        Access::Table {
            table,
            address,
            count,
        } => Some((table, address, count)),
        Access::Read | Access::Control => None,
    }
}

/// Whether every address `address..address + count` of `unit`/`table` lies in some range (ranges
/// may touch or overlap; a write may span several).
pub(crate) fn covered(
    ranges: &[WriteRange],
    unit: u8,
    table: WriteTable,
    address: u16,
    count: usize,
) -> bool {
    let end = u32::from(address) + u32::try_from(count).unwrap_or(u32::MAX);
    let mut next = u32::from(address);
    while next < end {
        let Ok(at) = u16::try_from(next) else {
            return false; // past the last address
        };
        let Some(range) = ranges.iter().find(|range| range.contains(unit, table, at)) else {
            return false;
        };
        next = u32::from(range.last) + 1;
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    fn range(unit: u8, table: WriteTable, first: u16, last: u16) -> WriteRange {
        WriteRange {
            unit,
            table,
            first,
            last,
        }
    }

    fn registers(address: u16, count: usize) -> Request {
        Request::WriteMultipleRegisters {
            address,
            values: vec![0; count],
        }
    }

    #[test]
    fn reads_pass_every_policy() {
        let policy = WritePolicy {
            read_only: true,
            write_ranges: Some(Vec::new()),
        };
        let read = Request::ReadHoldingRegisters {
            address: 0,
            quantity: 1,
        };
        assert_eq!(policy.check_write(1, &read), None);
        let echo = Request::Diagnostics {
            sub_function: 0,
            data: vec![1, 2],
        };
        assert_eq!(policy.check_write(1, &echo), None);
    }

    #[test]
    fn read_only_refuses_writes_and_device_control_with_01() {
        let policy = WritePolicy {
            read_only: true,
            ..WritePolicy::default()
        };
        for request in [
            Request::WriteSingleCoil {
                address: 0,
                value: true,
            },
            Request::WriteSingleRegister {
                address: 0,
                value: 1,
            },
            registers(0, 2),
            Request::ReadWriteMultipleRegisters {
                read_address: 0,
                read_quantity: 1,
                write_address: 0,
                values: vec![1],
            },
            Request::Diagnostics {
                sub_function: 0x04,
                data: vec![0, 0],
            },
        ] {
            assert_eq!(
                policy.check_write(1, &request),
                Some(ExceptionCode::IllegalFunction),
                "{request:?}"
            );
        }
    }

    #[test]
    fn write_ranges_are_per_unit_and_table() {
        let policy = WritePolicy {
            write_ranges: Some(vec![
                range(1, WriteTable::HoldingRegisters, 100, 109),
                range(1, WriteTable::HoldingRegisters, 110, 119),
                range(2, WriteTable::Coils, 0, 7),
            ]),
            ..WritePolicy::default()
        };
        assert_eq!(
            policy.check_write(1, &registers(100, 20)),
            None,
            "spans two touching ranges"
        );
        assert_eq!(
            policy.check_write(1, &registers(99, 2)),
            Some(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            policy.check_write(1, &registers(115, 6)),
            Some(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            policy.check_write(2, &registers(100, 1)),
            Some(ExceptionCode::IllegalDataAddress)
        );
        let coil = Request::WriteSingleCoil {
            address: 7,
            value: true,
        };
        assert_eq!(policy.check_write(2, &coil), None);
        assert_eq!(
            policy.check_write(1, &coil),
            Some(ExceptionCode::IllegalDataAddress)
        );
        let control = Request::Diagnostics {
            sub_function: 0x01,
            data: vec![0, 0],
        };
        assert_eq!(
            policy.check_write(1, &control),
            None,
            "ranges restrict table writes only"
        );
    }

    #[test]
    fn ranges_up_to_the_last_address() {
        let ranges = [range(1, WriteTable::Coils, 0xFFF0, 0xFFFF)];
        assert!(covered(&ranges, 1, WriteTable::Coils, 0xFFF0, 16));
        assert!(!covered(&ranges, 1, WriteTable::Coils, 0xFFF0, 17));
    }
}
