//! The parameters of the Modbus master (manual 003, 6.4.2.1 RTU and 6.4.2.2 ASCII).

use core::time::Duration;

use crate::modbus::rtu::CharTiming;

/// The reply monitoring time the CP uses unless told otherwise (003 6.4.2.1 "Reply monitoring
/// time", 6.4.2.2 "Response Time-out": default 2000 ms).
pub const DEFAULT_REPLY_TIMEOUT: Duration = Duration::from_millis(2000);
/// Shortest reply monitoring time (003 6.4.2.1: "Range: 5 ... 65500ms").
pub const MIN_REPLY_TIMEOUT: Duration = Duration::from_millis(5);
/// Longest reply monitoring time (003 6.4.2.1: "Range: 5 ... 65500ms").
pub const MAX_REPLY_TIMEOUT: Duration = Duration::from_millis(65_500);
/// Longest turnaround delay after a broadcast (003 6.4.2.2 "Turnaround Delay": "0 ... 65535ms",
/// default 0 = deactivated).
pub const MAX_TURNAROUND_DELAY: Duration = Duration::from_millis(65_535);
/// Default ASCII character delay time (003 6.4.2.2 "Character Delay Time": default 1000 ms).
pub const DEFAULT_CHAR_DELAY: Duration = Duration::from_millis(1000);
/// Shortest ASCII character delay time (003 6.4.2.2: "Range of values: 1 ... 6500ms").
pub const MIN_CHAR_DELAY: Duration = Duration::from_millis(1);
/// Longest ASCII character delay time (003 6.4.2.2: "Range of values: 1 ... 6500ms").
pub const MAX_CHAR_DELAY: Duration = Duration::from_millis(6500);

/// The parameters of one Modbus master line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MasterConfig {
    /// RTU or ASCII, with the framing's own timing.
    pub framing: Framing,
    /// How long the master waits for the start of a reply after the request left the line
    /// (003 6.4.2.1 "Reply monitoring time", 5..65500 ms, default 2000 ms).
    pub reply_timeout: Duration,
    /// How often a failed attempt is repeated (0 = one attempt). The CP has no such parameter and
    /// never repeats a Modbus request (003 6.4.2); the default 0 keeps its behaviour.
    pub retries: u8,
    /// How long the master stays silent after a broadcast (003 6.4.2.2 "Turnaround Delay",
    /// 0..65535 ms, default 0 = only the inter-frame gap).
    pub turnaround_delay: Duration,
    /// Normal operation or interference suppression (003 6.4.2.1 "Operating mode").
    pub mode: OperatingMode,
}

/// The transmission mode (003 6.4.1 "ASCII-, RTU Modus").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Framing {
    /// Binary frames delimited by 3.5 character times of silence (003 6.4.3 "CRC-CHECK").
    Rtu {
        /// The character time of the line, with the CP's multiplier applied.
        timing: CharTiming,
    },
    /// `:` hex LRC CR LF frames (003 6.4.2.2).
    Ascii {
        /// The longest gap allowed between two characters of one frame (003 6.4.2.2 "Character
        /// Delay Time", 1..6500 ms, default 1000 ms).
        char_delay: Duration,
        /// Whether 32-bit register jobs (function codes 43h/46h/50h in the CP's send DB) are
        /// enabled (003 6.4.2.2 "with 32-Bit Register", default deactivated).
        registers32: bool,
    },
}

/// What the driver does with transmission errors while it is idle (003 6.4.2.1 "Operating mode").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum OperatingMode {
    /// "every recognized transmission error and break will result in error handling, even if the
    /// driver is in idle mode" (the default).
    #[default]
    Normal,
    /// "transmission errors and breaks are ignored when the driver is in idle mode".
    InterferenceSuppression,
}

/// A parameter outside the range the manual allows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ConfigError {
    /// The reply monitoring time is outside 5..65500 ms (003 6.4.2.1).
    #[error("reply monitoring time {0:?} outside 5..65500 ms")]
    ReplyTimeout(Duration),
    /// The turnaround delay is longer than 65535 ms (003 6.4.2.2).
    #[error("turnaround delay {0:?} longer than 65535 ms")]
    TurnaroundDelay(Duration),
    /// The ASCII character delay time is outside 1..6500 ms (003 6.4.2.2).
    #[error("character delay time {0:?} outside 1..6500 ms")]
    CharDelay(Duration),
}

// === impl Framing ===

impl Framing {
    /// Whether the holding registers are 32 bits wide (ASCII "with 32-Bit Register", 003 6.4.4).
    pub const fn registers32(&self) -> bool {
        matches!(
            self,
            Self::Ascii {
                registers32: true,
                ..
            }
        )
    }
}

// === impl MasterConfig ===

impl MasterConfig {
    /// An RTU master with the CP's defaults (003 6.4.2.1): reply monitoring time 2000 ms, normal
    /// operation, multiplier 1, no turnaround delay, no repetition. The end-of-frame time is 3.5
    /// character times, fixed at 1.75 ms above 19200 Bd (Modbus over Serial Line V1.02, 2.5.1.1,
    /// which devices such as the Altivar follow); set `framing` with [`CharTiming::exact`] for the
    /// CP's own table at every baud rate (003 6.4.3: "76800 -> 0.5 ms ... 300 -> 128 ms"), and
    /// [`CharTiming::with_multiplier`] for the CP's multiplier.
    ///
    /// `bits_per_char` counts start, data, parity and stop bits (11 for 8E1).
    pub fn rtu(baud: u32, bits_per_char: u8) -> Self {
        Self {
            framing: Framing::Rtu {
                timing: CharTiming::new(baud, bits_per_char),
            },
            reply_timeout: DEFAULT_REPLY_TIMEOUT,
            retries: 0,
            turnaround_delay: Duration::ZERO,
            mode: OperatingMode::Normal,
        }
    }

    /// An ASCII master with the CP's defaults (003 6.4.2.2): character delay time 1000 ms,
    /// response time-out 2000 ms, turnaround delay 0, normal operation, 16-bit registers only.
    pub fn ascii() -> Self {
        Self {
            framing: Framing::Ascii {
                char_delay: DEFAULT_CHAR_DELAY,
                registers32: false,
            },
            reply_timeout: DEFAULT_REPLY_TIMEOUT,
            retries: 0,
            turnaround_delay: Duration::ZERO,
            mode: OperatingMode::Normal,
        }
    }

    /// Checks every parameter against the range of 003 6.4.2.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if !(MIN_REPLY_TIMEOUT..=MAX_REPLY_TIMEOUT).contains(&self.reply_timeout) {
            return Err(ConfigError::ReplyTimeout(self.reply_timeout));
        }
        if self.turnaround_delay > MAX_TURNAROUND_DELAY {
            return Err(ConfigError::TurnaroundDelay(self.turnaround_delay));
        }
        if let Framing::Ascii { char_delay, .. } = self.framing {
            if !(MIN_CHAR_DELAY..=MAX_CHAR_DELAY).contains(&char_delay) {
                return Err(ConfigError::CharDelay(char_delay));
            }
        }
        Ok(())
    }

    /// The silence that must precede a request and that ends an RTU frame: 3.5 character times
    /// (003 6.4.3 "CRC-CHECK"; Modbus over Serial Line V1.02, 2.5.1.1). ASCII frames are
    /// delimited by `:` and CR LF, so ASCII needs no silent interval (Modbus over Serial Line
    /// V1.02, 2.5.2.1).
    pub(crate) fn frame_gap(&self) -> Duration {
        match self.framing {
            Framing::Rtu { timing } => timing.t35,
            Framing::Ascii { .. } => Duration::ZERO,
        }
    }

    /// The silence that separates two bursts of unexpected bytes (one event per burst): the RTU
    /// frame gap, the ASCII character delay time.
    pub(crate) fn burst_gap(&self) -> Duration {
        match self.framing {
            Framing::Rtu { timing } => timing.t35,
            Framing::Ascii { char_delay, .. } => char_delay,
        }
    }

    /// Whether the framing is ASCII.
    pub(crate) fn is_ascii(&self) -> bool {
        matches!(self.framing, Framing::Ascii { .. })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_manuals() {
        let rtu = MasterConfig::rtu(9600, 11);
        assert_eq!(rtu.reply_timeout, Duration::from_millis(2000));
        assert_eq!(rtu.retries, 0);
        assert_eq!(rtu.mode, OperatingMode::Normal);
        assert_eq!(rtu.validate(), Ok(()));
        let ascii = MasterConfig::ascii();
        assert_eq!(
            ascii.framing,
            Framing::Ascii {
                char_delay: Duration::from_millis(1000),
                registers32: false
            }
        );
        assert_eq!(ascii.validate(), Ok(()));
        assert_eq!(ascii.frame_gap(), Duration::ZERO);
    }

    #[test]
    fn ranges_are_checked() {
        let mut c = MasterConfig::rtu(19200, 11);
        c.reply_timeout = Duration::from_millis(4);
        assert_eq!(
            c.validate(),
            Err(ConfigError::ReplyTimeout(Duration::from_millis(4)))
        );
        c.reply_timeout = Duration::from_millis(65_501);
        assert!(c.validate().is_err());
        c.reply_timeout = Duration::from_millis(65_500);
        assert_eq!(c.validate(), Ok(()));
        c.turnaround_delay = Duration::from_millis(65_536);
        assert_eq!(
            c.validate(),
            Err(ConfigError::TurnaroundDelay(Duration::from_millis(65_536)))
        );
        let mut a = MasterConfig::ascii();
        a.framing = Framing::Ascii {
            char_delay: Duration::ZERO,
            registers32: true,
        };
        assert_eq!(a.validate(), Err(ConfigError::CharDelay(Duration::ZERO)));
        a.framing = Framing::Ascii {
            char_delay: Duration::from_millis(6501),
            registers32: true,
        };
        assert!(a.validate().is_err());
    }
}
