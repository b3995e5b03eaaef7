//! The ASCII driver's parameters (003 6.2.1, 000 6.2.1 and 5.4), with the manual's defaults.

use core::time::Duration;

use super::common::{
    check_baud, check_baud_minimum, check_millis, check_range, ConfigError, Interface,
};

/// 003 6.2.1 "Data flow control parameters": XON code default "11 (DC1)".
pub const DEFAULT_XON: u8 = 0x11;
/// 003 6.2.1 "Data flow control parameters": XOFF code default "13 (DC3)".
pub const DEFAULT_XOFF: u8 = 0x13;
/// 003 6.2.1 "End character 1: 3 (03h = ETX)".
pub const DEFAULT_END_CHAR: u8 = 0x03;
/// 003 6.2.1 "Message frame length": default 240 bytes.
pub const DEFAULT_FIXED_LENGTH: u16 = 240;
/// The most bytes of one telegram (003 6.2.1 "Message frame length ... 1 ... 1024 bytes"; 7.2,
/// 1E 41h "Keep to the value range of 1 to 1024 bytes").
pub const MAX_TELEGRAM: usize = 1024;
/// 003 6.2.1 "Character delay time (ZVZ)": default 4 ms.
pub const DEFAULT_ZVZ: Duration = Duration::from_millis(4);
/// 003 6.2.1 ZVZ "Range of values: 2 ms ... 65535 ms in 1 ms steps".
const ZVZ_RANGE_MS: (u64, u64) = (2, 65_535);
/// 003 6.2.1 "The shortest character delay time (ZVZ) depends on the baud rate": 300 -> 130 ms,
/// 600 -> 65, 1200 -> 32, 2400 -> 16, 4800 -> 8, 9600 -> 4, "19200, 57600, 76800" -> 2.
const ZVZ_MINIMUM_BY_BAUD: [(u32, u64); 7] = [
    (300, 130),
    (600, 65),
    (1200, 32),
    (2400, 16),
    (4800, 8),
    (9600, 4),
    (19_200, 2),
];
/// 003 6.2.1 "Wait for XON after XOFF (Wait time for CTS=ON)": default 20 000 ms.
pub const DEFAULT_FLOW_WAIT: Duration = Duration::from_millis(20_000);
/// 003 6.2.1: "Range of values: 20 ... 65535 ms in 10 ms steps".
const FLOW_WAIT_RANGE_MS: (u64, u64) = (20, 65_535);
/// 000 6.2.1 "RTS-Wegnahmezeit" (RTS hold time after sending): default 10 ms.
pub const DEFAULT_RTS_HOLD: Duration = Duration::from_millis(10);
/// 000 6.2.1 "Datenausgabewartezeit" (data output wait time after RTS on): default 10 ms.
pub const DEFAULT_OUTPUT_WAIT: Duration = Duration::from_millis(10);
/// 000 6.2.1: both "Wertebereich: 0 ... 65535 ms in 10 ms Schritten".
const V24_TIME_RANGE_MS: (u64, u64) = (0, 65_535);
/// 003 6.2.1 "Buffered receive message frames": default 250, "Range of values: 1 ... 250".
pub const DEFAULT_RECEIVE_BUFFERS: u16 = 250;
/// Telegrams `send` accepts while one is in progress (our choice; the CP takes one per FB call).
pub const DEFAULT_SEND_QUEUE: u16 = 16;
/// Bytes handed out at a time when the partner can stop us (XON/XOFF, RTS/CTS, automatic V24
/// signals): the most we send after an XOFF or CTS = OFF (our choice; the manual is silent).
pub const DEFAULT_TX_CHUNK: u16 = 8;

/// How the end of a received telegram is recognized (003 6.2.1 "End code of a message").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum EndCriterion {
    /// "on expiry of character delay time" (000 6.2.1: the default).
    #[default]
    CharacterDelay,
    /// "on receipt of fixed number of characters" (1..=1024).
    FixedLength(u16),
    /// "on receipt of end character(s)": "maximally 2 end characters may be defined"; the end
    /// characters stay part of the telegram.
    EndChars {
        /// End character 1.
        first: u8,
        /// End character 2, if the telegram ends with two characters.
        second: Option<u8>,
    },
}

/// Data flow control (003 6.2.1 "Data flow control"; 000 6.2.1 adds RTS/CTS and the automatic
/// V24 signal handling for RS232).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum FlowControl {
    /// No flow control (the default).
    #[default]
    None,
    /// The partner stops us with XOFF and lets us go on with XON; we do the same when our receive
    /// buffer is full.
    XonXoff {
        /// The XON code (default 11h).
        xon: u8,
        /// The XOFF code (default 13h).
        xoff: u8,
    },
    /// We send only while CTS = ON; we set RTS = OFF while our receive buffer is full.
    RtsCts,
    /// 000 5.4 "Prinzip der automatischen Bedienung der Begleitsignale": RTS on, wait the data
    /// output wait time, send if CTS = ON, RTS off after the RTS hold time; DSR = OFF aborts.
    AutoV24 {
        /// "Datenausgabewartezeit": from RTS = ON to the first byte; CTS must be ON by then.
        output_wait: Duration,
        /// "RTS-Wegnahmezeit": from the last byte to RTS = OFF.
        rts_hold: Duration,
    },
}

// === impl FlowControl ===

impl FlowControl {
    /// XON/XOFF with the manual's codes 11h/13h.
    pub const XON_XOFF: Self = Self::XonXoff {
        xon: DEFAULT_XON,
        xoff: DEFAULT_XOFF,
    };
    /// Automatic V24 signal handling with the manual's times (10 ms, 10 ms).
    pub const AUTO_V24: Self = Self::AutoV24 {
        output_wait: DEFAULT_OUTPUT_WAIT,
        rts_hold: DEFAULT_RTS_HOLD,
    };

    /// Whether the partner can hold our sending back, so telegrams go out in chunks.
    pub(crate) const fn can_pause(self) -> bool {
        !matches!(self, Self::None)
    }
}

/// The ASCII parameters as given, before validation.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AsciiSettings {
    /// The line speed, for the minimum ZVZ (default 9600).
    pub baud: u32,
    /// 7 or 8 (default 8); with 7, received bytes are masked to 7 bits and sent ones must fit.
    pub data_bits: u8,
    /// The physical interface (default RS422 four-wire).
    pub interface: Interface,
    /// How a received telegram ends.
    pub end: EndCriterion,
    /// Character delay time: the longest gap inside a received telegram, in every end mode.
    pub zvz: Duration,
    /// 003 6.2.1 "Transmission pause" (default on): keep the line quiet for at least the ZVZ
    /// between two sent telegrams, so that the receiver can separate them.
    pub send_pause: bool,
    /// Data flow control.
    pub flow: FlowControl,
    /// "Wait for XON after XOFF (Wait time for CTS=ON)": how long a held-back send may wait.
    pub flow_wait: Duration,
    /// Received telegrams kept until taken (1..=250).
    pub receive_buffers: u16,
    /// 003 6.2.1 "Prevent overwriting" (default on): a full buffer drops the new telegram (08 0Ah).
    /// Off (only with one buffer): the new telegram replaces the buffered one.
    pub prevent_overwrite: bool,
    /// Telegrams `send` queues behind the one in progress (1..=1024).
    pub send_queue: u16,
    /// Bytes handed out at a time under flow control (1..=1024).
    pub tx_chunk: u16,
}

impl Default for AsciiSettings {
    /// The manual's defaults.
    fn default() -> Self {
        Self {
            baud: 9600,
            data_bits: 8,
            interface: Interface::Rs422,
            end: EndCriterion::CharacterDelay,
            zvz: DEFAULT_ZVZ,
            send_pause: true,
            flow: FlowControl::None,
            flow_wait: DEFAULT_FLOW_WAIT,
            receive_buffers: DEFAULT_RECEIVE_BUFFERS,
            prevent_overwrite: true,
            send_queue: DEFAULT_SEND_QUEUE,
            tx_chunk: DEFAULT_TX_CHUNK,
        }
    }
}

/// How much of a telegram given to `send` goes out: 003 6.2.1 "Send with end character": "Here
/// end character(s) may be defined or the length set in the FB may be specified as soon as 'End
/// character' is activated at the end ID."
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum SendLength {
    /// The length set in the FB: the telegram as given (the default, and the only choice unless
    /// received telegrams end with end characters).
    #[default]
    AsGiven,
    /// Up to and including the end character(s) (003 6.2.1 "End character 1/2": "The length of
    /// the respective telegram is limited by an end character"); a telegram without them goes out
    /// as given. Only with [`EndCriterion::EndChars`].
    UpToEndChars,
}

/// Validated ASCII parameters: only [`AsciiParams::try_new`] makes them.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct AsciiParams {
    settings: AsciiSettings,
    send_length: SendLength,
}

// === impl AsciiParams ===

impl AsciiParams {
    /// Checks `settings` against the ranges of 003 6.2.1 and 000 6.2.1.
    ///
    /// # Errors
    ///
    /// The first parameter the manual does not allow, as a [`ConfigError`] for the operator.
    pub fn try_new(settings: AsciiSettings) -> Result<Self, ConfigError> {
        let s = &settings;
        check_baud(s.baud)?;
        // 003 6.2.1 "Data bits": 7, 8.
        check_range("data bits", s.data_bits.into(), 7, 8)?;
        check_millis(
            "character delay time (ZVZ)",
            s.zvz,
            ZVZ_RANGE_MS.0,
            ZVZ_RANGE_MS.1,
        )?;
        check_baud_minimum(
            "character delay time (ZVZ)",
            s.zvz,
            &ZVZ_MINIMUM_BY_BAUD,
            s.baud,
        )?;
        let code_max: u8 = if s.data_bits == 7 { 0x7F } else { 0xFF };
        let end_chars = check_end(s.end, code_max)?;
        check_flow(s, code_max, end_chars)?;
        check_millis(
            "wait time for XON / CTS = ON",
            s.flow_wait,
            FLOW_WAIT_RANGE_MS.0,
            FLOW_WAIT_RANGE_MS.1,
        )?;
        check_range(
            "buffered receive telegrams",
            s.receive_buffers.into(),
            1,
            250,
        )?;
        // 003 6.2.1 "Prevent overwriting": "You can only deactivate this check box if the parameter
        // 'Buffered receive message frames' is set to '1'."
        if !s.prevent_overwrite && s.receive_buffers != 1 {
            return Err(ConfigError::OverwriteNeedsSingleBuffer {
                buffers: s.receive_buffers,
            });
        }
        check_range("send queue", s.send_queue.into(), 1, 1024)?;
        check_range("transmit chunk", s.tx_chunk.into(), 1, MAX_TELEGRAM as u64)?;
        Ok(Self {
            settings,
            send_length: SendLength::AsGiven,
        })
    }

    /// The same parameters with the "send with end character" choice of 003 6.2.1.
    ///
    /// # Errors
    ///
    /// [`ConfigError::SendLengthNeedsEndChars`] for [`SendLength::UpToEndChars`] unless received
    /// telegrams end with end characters (the option exists "as soon as 'End character' is
    /// activated at the end ID", 003 6.2.1).
    pub fn with_send_length(self, send_length: SendLength) -> Result<Self, ConfigError> {
        let end_chars = matches!(self.settings.end, EndCriterion::EndChars { .. });
        if send_length == SendLength::UpToEndChars && !end_chars {
            return Err(ConfigError::SendLengthNeedsEndChars);
        }
        Ok(Self {
            send_length,
            ..self
        })
    }

    /// The validated settings.
    pub fn settings(&self) -> &AsciiSettings {
        &self.settings
    }

    /// How much of a telegram goes out (003 6.2.1 "Send with end character").
    pub fn send_length(&self) -> SendLength {
        self.send_length
    }
}

/// A code that must fit the character: 7 data bits carry 00..7Fh (003 6.2.1).
fn check_fits(name: &'static str, value: u8, code_max: u8) -> Result<(), ConfigError> {
    if value > code_max {
        Err(ConfigError::CodeTooWide { name, value })
    } else {
        Ok(())
    }
}

/// The end criterion of 003 6.2.1 "End of message frame"; returns the end characters.
fn check_end(end: EndCriterion, code_max: u8) -> Result<[Option<u8>; 2], ConfigError> {
    match end {
        EndCriterion::CharacterDelay => Ok([None, None]),
        EndCriterion::FixedLength(len) => {
            check_range("message frame length", len.into(), 1, MAX_TELEGRAM as u64)?;
            Ok([None, None])
        }
        EndCriterion::EndChars { first, second } => {
            check_fits("end character 1", first, code_max)?;
            if let Some(second) = second {
                check_fits("end character 2", second, code_max)?;
            }
            Ok([Some(first), second])
        }
    }
}

/// The flow control of 003 6.2.1 "Data flow control" and 000 6.2.1 (automatic V24 signals).
fn check_flow(
    s: &AsciiSettings,
    code_max: u8,
    end_chars: [Option<u8>; 2],
) -> Result<(), ConfigError> {
    if s.flow.can_pause() && !s.interface.is_full_duplex() {
        return Err(ConfigError::FlowControlNeedsFullDuplex);
    }
    match s.flow {
        FlowControl::None => {}
        FlowControl::XonXoff { xon, xoff } => {
            check_fits("XON code", xon, code_max)?;
            check_fits("XOFF code", xoff, code_max)?;
            if xon == xoff {
                return Err(ConfigError::SameCode {
                    first: "XON code",
                    second: "XOFF code",
                    value: xon,
                });
            }
            // An end character equal to XON or XOFF could never end a telegram.
            for (name, code) in [("XON code", xon), ("XOFF code", xoff)] {
                if end_chars.contains(&Some(code)) {
                    return Err(ConfigError::SameCode {
                        first: name,
                        second: "end character",
                        value: code,
                    });
                }
            }
        }
        FlowControl::RtsCts => {
            if s.interface != Interface::Rs232 {
                return Err(ConfigError::NeedsRs232("RTS/CTS flow control"));
            }
        }
        FlowControl::AutoV24 {
            output_wait,
            rts_hold,
        } => {
            if s.interface != Interface::Rs232 {
                return Err(ConfigError::NeedsRs232("automatic V24 signal handling"));
            }
            check_millis(
                "data output wait time",
                output_wait,
                V24_TIME_RANGE_MS.0,
                V24_TIME_RANGE_MS.1,
            )?;
            check_millis(
                "RTS hold time",
                rts_hold,
                V24_TIME_RANGE_MS.0,
                V24_TIME_RANGE_MS.1,
            )?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with(f: impl FnOnce(&mut AsciiSettings)) -> Result<AsciiParams, ConfigError> {
        let mut s = AsciiSettings::default();
        f(&mut s);
        AsciiParams::try_new(s)
    }

    #[test]
    fn defaults_are_valid() {
        assert!(AsciiParams::try_new(AsciiSettings::default()).is_ok());
        assert!(with(|s| {
            s.interface = Interface::Rs232;
            s.flow = FlowControl::AUTO_V24;
        })
        .is_ok());
    }

    #[test]
    fn zvz_minimum_follows_the_baud_table() {
        assert!(with(|s| s.zvz = Duration::from_millis(4)).is_ok());
        assert_eq!(
            with(|s| s.zvz = Duration::from_millis(3)),
            Err(ConfigError::BelowBaudMinimum {
                name: "character delay time (ZVZ)",
                value_ms: 3,
                min_ms: 4,
                baud: 9600
            })
        );
        assert!(with(|s| {
            s.baud = 19_200;
            s.zvz = Duration::from_millis(2);
        })
        .is_ok());
        assert!(matches!(
            with(|s| {
                s.baud = 300;
                s.zvz = Duration::from_millis(100);
            }),
            Err(ConfigError::BelowBaudMinimum { min_ms: 130, .. })
        ));
    }

    #[test]
    fn refuses_what_the_manual_does_not_allow() {
        assert!(matches!(
            with(|s| s.end = EndCriterion::FixedLength(0)),
            Err(ConfigError::OutOfRange { .. })
        ));
        assert!(matches!(
            with(|s| s.end = EndCriterion::FixedLength(1025)),
            Err(ConfigError::OutOfRange { .. })
        ));
        assert!(with(|s| s.end = EndCriterion::FixedLength(1024)).is_ok());
        assert_eq!(
            with(|s| s.prevent_overwrite = false),
            Err(ConfigError::OverwriteNeedsSingleBuffer { buffers: 250 })
        );
        assert!(with(|s| {
            s.prevent_overwrite = false;
            s.receive_buffers = 1;
        })
        .is_ok());
        assert_eq!(
            with(|s| {
                s.interface = Interface::Rs485;
                s.flow = FlowControl::XON_XOFF;
            }),
            Err(ConfigError::FlowControlNeedsFullDuplex)
        );
        assert_eq!(
            with(|s| s.flow = FlowControl::RtsCts),
            Err(ConfigError::NeedsRs232("RTS/CTS flow control"))
        );
        assert!(matches!(
            with(|s| {
                s.data_bits = 7;
                s.end = EndCriterion::EndChars {
                    first: 0x83,
                    second: None,
                };
            }),
            Err(ConfigError::CodeTooWide { value: 0x83, .. })
        ));
        assert!(matches!(
            with(|s| s.flow = FlowControl::XonXoff {
                xon: 0x11,
                xoff: 0x11
            }),
            Err(ConfigError::SameCode { .. })
        ));
        assert!(matches!(
            with(|s| {
                s.flow = FlowControl::XON_XOFF;
                s.end = EndCriterion::EndChars {
                    first: 0x13,
                    second: None,
                };
            }),
            Err(ConfigError::SameCode { .. })
        ));
        assert!(matches!(
            with(|s| s.data_bits = 6),
            Err(ConfigError::OutOfRange { .. })
        ));
        assert!(matches!(
            with(|s| s.flow_wait = Duration::from_millis(5)),
            Err(ConfigError::OutOfRange { .. })
        ));
        assert!(matches!(
            with(|s| s.receive_buffers = 251),
            Err(ConfigError::OutOfRange { .. })
        ));
    }
}
