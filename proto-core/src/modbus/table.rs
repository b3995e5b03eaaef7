//! The four Modbus data tables.

use core::fmt;

/// The four data tables of a Modbus unit (Modbus Application Protocol V1.1b3, 4.3): what a tag
/// lives in, what the process image keeps, what a Modbus TCP request reaches.
///
/// The order (coils, discrete inputs, holding registers, input registers) is the order in which
/// the gateway lists and sorts them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Table {
    /// Read/write bits (FC 01 read, FC 05 / 15 write).
    Coils,
    /// Read-only bits (FC 02).
    DiscreteInputs,
    /// Read/write registers (FC 03 read, FC 06 / 16 / 23 write).
    HoldingRegisters,
    /// Read-only registers (FC 04).
    InputRegisters,
}

// === impl Table ===

impl Table {
    /// All four tables.
    pub const ALL: [Self; 4] = [
        Self::Coils,
        Self::DiscreteInputs,
        Self::HoldingRegisters,
        Self::InputRegisters,
    ];

    /// Whether the table holds bits (coils, discrete inputs) rather than 16-bit registers.
    pub const fn is_bits(self) -> bool {
        matches!(self, Self::Coils | Self::DiscreteInputs)
    }

    /// A short stable name for logs and keys.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Coils => "coils",
            Self::DiscreteInputs => "discrete_inputs",
            Self::HoldingRegisters => "holding_registers",
            Self::InputRegisters => "input_registers",
        }
    }

    /// The table a read function reaches: FC 01, 02, 03, 04 (`None` for the others).
    pub const fn read_by(function: u8) -> Option<Self> {
        match function {
            0x01 => Some(Self::Coils),
            0x02 => Some(Self::DiscreteInputs),
            0x03 => Some(Self::HoldingRegisters),
            0x04 => Some(Self::InputRegisters),
            _ => None,
        }
    }
}

impl fmt::Display for Table {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}
