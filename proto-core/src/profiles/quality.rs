//! How far a value can be trusted.

use core::fmt;

/// How far a value in the process image can be trusted: good, one of the device's special values
/// (out of range, off, not defined), refused by the device, stale, or no communication.
///
/// [`DeviceProfile::decode`](super::DeviceProfile::decode) produces `Good`, `NotDefined`, `Off`,
/// `OutOfRange` (the device's special values: KS vario 31000 / 32000 / 0x8000 / 1.5E37, Altivar
/// 0x8000) and `CommFailure` (fewer words than the tag needs); the register-level image sets
/// `Good`, `Stale`, `Rejected` and `CommFailure`.
///
/// The order is the severity: [`Quality::worst`] of a range is the maximum.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Quality {
    /// A value the device reported as valid, within its freshness limit.
    Good,
    /// The device says the value does not fit the transfer format (KS vario 0x8000).
    OutOfRange,
    /// The device says the function behind the datum is switched off (KS vario 32000).
    Off,
    /// The device says the datum does not exist or is not available (KS vario 31000 / 1.5E37,
    /// Altivar 16#8000).
    NotDefined,
    /// The device answered the poll of this address with an exception.
    Rejected,
    /// The last good value, older than its freshness limit (a multiple of its poll period).
    Stale,
    /// The device did not answer (offline), the port is closed, or the answer did not carry the
    /// tag's words.
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

    /// Whether the value can be used as a measurement.
    pub const fn is_good(self) -> bool {
        matches!(self, Self::Good)
    }

    /// A stable snake_case name for logs, labels and JSON.
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
