//! The quality of a value in the process image and the four Modbus tables.

use std::fmt;

/// The four Modbus data tables of a unit (Modbus Application Protocol V1.1b3, 4.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Table {
    /// Read/write bits (FC 01, 05, 15).
    Coils,
    /// Read-only bits (FC 02).
    DiscreteInputs,
    /// Read/write registers (FC 03, 06, 16, 23).
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
}

impl fmt::Display for Table {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// How far a value in the image can be trusted (SPEC "Polling": good, stale, not defined, off,
/// out of range, comm failure).
///
/// The register-level image sets `Good`, `Stale`, `Rejected` and `CommFailure`; the special-value
/// qualities (`NotDefined`, `Off`, `OutOfRange`) are set by a device profile that recognises its
/// device's special values (KS vario 31000 / 32000 / 0x8000, Altivar 0x8000). This enum is the
/// image's own until the profile models in proto-core carry a shared one; the variants are meant to
/// map one to one.
///
/// The order is the severity: [`Quality::worst`] of a range is the maximum.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Quality {
    /// Read from the device within its freshness limit.
    Good,
    /// The device reports the value as out of its representable range.
    OutOfRange,
    /// The device reports the function as switched off.
    Off,
    /// The device reports the value as not defined.
    NotDefined,
    /// The device answered the poll of this address with an exception.
    Rejected,
    /// Older than the freshness limit (a multiple of its poll period).
    Stale,
    /// The device did not answer (offline), or the port is closed.
    CommFailure,
}

// === impl Quality ===

impl Quality {
    /// The worse of two qualities.
    #[must_use]
    pub fn worst(self, other: Self) -> Self {
        self.max(other)
    }

    /// Whether a value of this quality is what the device currently holds (it answered recently),
    /// special values included.
    pub const fn is_live(self) -> bool {
        matches!(
            self,
            Self::Good | Self::OutOfRange | Self::Off | Self::NotDefined
        )
    }

    /// A short stable name for logs, labels and JSON.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Good => "good",
            Self::OutOfRange => "out_of_range",
            Self::Off => "off",
            Self::NotDefined => "not_defined",
            Self::Rejected => "rejected",
            Self::Stale => "stale",
            Self::CommFailure => "comm_failure",
        }
    }
}

impl fmt::Display for Quality {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn worst_is_the_most_severe() {
        assert_eq!(Quality::Good.worst(Quality::Stale), Quality::Stale);
        assert_eq!(
            Quality::CommFailure.worst(Quality::Stale),
            Quality::CommFailure
        );
        assert_eq!(
            Quality::NotDefined.worst(Quality::Good),
            Quality::NotDefined
        );
        assert!(Quality::NotDefined.is_live());
        assert!(!Quality::Stale.is_live());
        assert!(!Quality::Rejected.is_live());
    }
}
