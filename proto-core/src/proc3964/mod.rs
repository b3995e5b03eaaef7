//! The 3964(R) procedure (manual 003 6.3, identical in 000 6.3), sans-IO.
//!
//! [`Proc3964`] is one station of a 3964(R) point-to-point link. It plays both roles: the active
//! partner that sends a telegram (STX, wait for DLE, the telegram, wait for DLE) and the passive
//! partner that receives one (answer STX with DLE, collect the telegram, answer DLE or NAK).
//!
//! ```text
//!  active (sends)                         passive (receives)
//!   STX  ─────────────────────────────▶     (QVZ runs on the active side)
//!        ◀───────────────────────────── DLE
//!   data (DLE doubled) DLE ETX [BCC] ──▶     (ZVZ runs on the passive side)
//!        ◀───────────────────────────── DLE  (NAK: repeat, up to the transmission attempts)
//! ```
//!
//! - [`frame`]: DLE doubling, DLE ETX and the BCC, both directions;
//! - [`Params3964`]: the validated parameters of 6.3.3, with the manual's defaults;
//! - [`Proc3964`]: the state machine, driven like every engine of this crate (see its docs).

pub mod frame;
mod machine;
pub mod tap;

use core::time::Duration;

pub use crate::telegram::{
    ConfigError, Interface, LineError, SendError, TelegramEvent, TelegramId,
};
pub use machine::Proc3964;

use crate::telegram::common::{check_baud, check_baud_minimum, check_millis, check_range};

/// What [`Proc3964::poll_event`] returns: received telegrams, send results and every diagnostic
/// event of 7.2.
pub type Event3964 = TelegramEvent;

/// 003 6.3.1 "The control codes": 02h = STX (start of text).
pub const STX: u8 = 0x02;
/// 003 6.3.1 "The control codes": 03h = ETX (end of text).
pub const ETX: u8 = 0x03;
/// 003 6.3.1 "The control codes": 10h = DLE (data link escape).
pub const DLE: u8 = 0x10;
/// 003 6.3.1 "The control codes": 15h = NAK (negative acknowledge).
pub const NAK: u8 = 0x15;

/// 003 6.3.1: "You can maximally transfer 250 byte per telegram."
pub const DEFAULT_MAX_LEN: u16 = 250;
/// The CP's telegram buffer: 7.2, 05 17h "Transmission length > 1 kbyte too great for CP".
pub const MAX_LEN_LIMIT: u16 = 1024;
/// 003 6.3.3 "Protocol": "Default values with block check: Character delay time: 220 ms".
pub const DEFAULT_ZVZ: Duration = Duration::from_millis(220);
/// 003 6.3.3 "Protocol": "Acknowledgement delay time: 2000 ms" (with block check).
pub const DEFAULT_QVZ: Duration = Duration::from_millis(2000);
/// 003 6.3.3, acknowledgement delay time: "2000 ms (550 ms at 3964 without block check)".
pub const DEFAULT_QVZ_WITHOUT_BCC: Duration = Duration::from_millis(550);
/// 003 6.3.3 "Protocol": "Setup attempts: 6", "Transmission attempts: 6".
pub const DEFAULT_ATTEMPTS: u8 = 6;
/// 003 6.3.3: ZVZ and QVZ "Range of values: 20...65535 ms".
const TIME_RANGE_MS: (u64, u64) = (20, 65_535);
/// 003 6.3.3: the shortest ZVZ and QVZ by baud rate: 300 -> 60 ms, 600 -> 40, 1200 -> 30,
/// 2400 ... 76800 -> 20 (the German table in 000 6.3.3 lists the same rates without values).
const TIME_MINIMUM_BY_BAUD: [(u32, u64); 4] = [(300, 60), (600, 40), (1200, 30), (2400, 20)];
/// Received telegrams kept until `take_received` when no other number is set. The 3964(R)
/// chapter gives none; this is the ASCII driver's default (003 6.2.1 "Buffered receive message
/// frames": 250).
pub const DEFAULT_RECEIVE_BUFFERS: u16 = 250;
/// Telegrams `send` accepts while one is in progress (our choice; the CP takes one per FB call).
pub const DEFAULT_SEND_QUEUE: u16 = 16;

/// 3964 or 3964R (003 6.3.3: "without block check: 3964", "with block check: 3964R").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Variant {
    /// Without block check character.
    P3964,
    /// With block check character (the CP's default).
    #[default]
    P3964R,
}

/// 003 6.3.3 "Priority": "If both communication partners issue a send request at the same time,
/// the partner with the lower priority temporarily withdraws its request."
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Priority {
    /// Keeps its send request in an initialization conflict (the default).
    #[default]
    High,
    /// Answers the partner's STX with DLE, receives first, then sends.
    Low,
}

/// The parameters of 003 6.3.3 as given, before validation.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Settings3964 {
    /// With or without block check (default with).
    pub variant: Variant,
    /// The priority in an initialization conflict (default high).
    pub priority: Priority,
    /// The line speed, for the minimum times (default 9600, 6.3.3 "Speed").
    pub baud: u32,
    /// The physical interface; two-wire RS485 is refused (default RS422 four-wire).
    pub interface: Interface,
    /// Character delay time ZVZ: the longest gap between two received characters.
    pub zvz: Duration,
    /// Acknowledgement delay time QVZ: the longest wait for DLE after STX and after the telegram.
    pub qvz: Duration,
    /// How often STX is sent before the setup is given up (1..=255).
    pub setup_attempts: u8,
    /// How often a telegram is sent before it is given up (1..=255).
    pub transmission_attempts: u8,
    /// The most user bytes of one telegram, both directions (1..=1024, default 250).
    pub max_len: u16,
    /// Received telegrams kept until taken (1..=250); STX is answered with NAK while full.
    pub receive_buffers: u16,
    /// Telegrams `send` queues behind the one in progress (1..=1024).
    pub send_queue: u16,
    /// Whether the final DLE of a received telegram waits for
    /// [`Proc3964::confirm_received`] (default off: it is sent at once). The runtime sets it
    /// when it must store a telegram durably before the partner is told it arrived (003 6.3.1:
    /// the partner takes the DLE after the BCC as "received"); a refusal is answered with NAK,
    /// which the partner answers by repeating (6.3.1).
    pub hold_ack: bool,
}

// === impl Settings3964 ===

impl Settings3964 {
    /// The manual's defaults for `variant` (003 6.3.3 "Use default values").
    pub const fn new(variant: Variant) -> Self {
        Self {
            variant,
            priority: Priority::High,
            baud: 9600,
            interface: Interface::Rs422,
            zvz: DEFAULT_ZVZ,
            qvz: match variant {
                Variant::P3964 => DEFAULT_QVZ_WITHOUT_BCC,
                Variant::P3964R => DEFAULT_QVZ,
            },
            setup_attempts: DEFAULT_ATTEMPTS,
            transmission_attempts: DEFAULT_ATTEMPTS,
            max_len: DEFAULT_MAX_LEN,
            receive_buffers: DEFAULT_RECEIVE_BUFFERS,
            send_queue: DEFAULT_SEND_QUEUE,
            hold_ack: false,
        }
    }
}

impl Default for Settings3964 {
    fn default() -> Self {
        Self::new(Variant::P3964R)
    }
}

/// Validated 3964(R) parameters: only [`Params3964::try_new`] makes them.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Params3964 {
    settings: Settings3964,
}

// === impl Params3964 ===

impl Params3964 {
    /// Checks `settings` against the ranges of 003 6.3.3.
    ///
    /// # Errors
    ///
    /// The first parameter the manual does not allow, as a [`ConfigError`] for the operator.
    pub fn try_new(settings: Settings3964) -> Result<Self, ConfigError> {
        if !settings.interface.is_full_duplex() {
            return Err(ConfigError::TwoWireNotSupported);
        }
        check_baud(settings.baud)?;
        check_millis(
            "character delay time (ZVZ)",
            settings.zvz,
            TIME_RANGE_MS.0,
            TIME_RANGE_MS.1,
        )?;
        check_millis(
            "acknowledgement delay time (QVZ)",
            settings.qvz,
            TIME_RANGE_MS.0,
            TIME_RANGE_MS.1,
        )?;
        check_baud_minimum(
            "character delay time (ZVZ)",
            settings.zvz,
            &TIME_MINIMUM_BY_BAUD,
            settings.baud,
        )?;
        check_baud_minimum(
            "acknowledgement delay time (QVZ)",
            settings.qvz,
            &TIME_MINIMUM_BY_BAUD,
            settings.baud,
        )?;
        // 003 6.3.3: setup attempts and transmission attempts "Range of values: 1...255".
        check_range("setup attempts", settings.setup_attempts.into(), 1, 255)?;
        check_range(
            "transmission attempts",
            settings.transmission_attempts.into(),
            1,
            255,
        )?;
        check_range(
            "telegram length",
            settings.max_len.into(),
            1,
            MAX_LEN_LIMIT.into(),
        )?;
        // 003 6.2.1 "Buffered receive message frames": 1 ... 250.
        check_range(
            "buffered receive telegrams",
            settings.receive_buffers.into(),
            1,
            250,
        )?;
        check_range("send queue", settings.send_queue.into(), 1, 1024)?;
        Ok(Self { settings })
    }

    /// The validated settings.
    pub fn settings(&self) -> &Settings3964 {
        &self.settings
    }
}

impl Default for Params3964 {
    /// 3964R with the manual's defaults.
    fn default() -> Self {
        Self {
            settings: Settings3964::default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_manuals() {
        let r = Settings3964::new(Variant::P3964R);
        assert_eq!(
            (r.zvz, r.qvz),
            (Duration::from_millis(220), Duration::from_millis(2000))
        );
        assert_eq!(
            (r.setup_attempts, r.transmission_attempts, r.max_len),
            (6, 6, 250)
        );
        assert_eq!(
            Settings3964::new(Variant::P3964).qvz,
            Duration::from_millis(550)
        );
        assert_eq!(
            Params3964::try_new(r).map(|p| p.settings().priority),
            Ok(Priority::High)
        );
        assert!(Params3964::try_new(Settings3964::new(Variant::P3964)).is_ok());
    }

    #[test]
    fn refuses_what_the_manual_does_not_allow() {
        let with = |f: fn(&mut Settings3964)| {
            let mut s = Settings3964::default();
            f(&mut s);
            Params3964::try_new(s)
        };
        assert_eq!(
            with(|s| s.interface = Interface::Rs485),
            Err(ConfigError::TwoWireNotSupported)
        );
        assert!(with(|s| s.interface = Interface::Rs232).is_ok());
        assert!(matches!(
            with(|s| s.setup_attempts = 0),
            Err(ConfigError::OutOfRange { min: 1, .. })
        ));
        assert!(matches!(
            with(|s| s.transmission_attempts = 0),
            Err(ConfigError::OutOfRange { .. })
        ));
        assert!(matches!(
            with(|s| s.max_len = 1025),
            Err(ConfigError::OutOfRange { max: 1024, .. })
        ));
        assert!(with(|s| s.max_len = 1024).is_ok());
        assert!(matches!(
            with(|s| s.qvz = Duration::from_millis(10)),
            Err(ConfigError::OutOfRange { .. })
        ));
        assert!(matches!(
            with(|s| s.zvz = Duration::from_secs(70)),
            Err(ConfigError::OutOfRange { .. })
        ));
        let slow = with(|s| {
            s.baud = 300;
            s.zvz = Duration::from_millis(50);
        });
        assert_eq!(
            slow,
            Err(ConfigError::BelowBaudMinimum {
                name: "character delay time (ZVZ)",
                value_ms: 50,
                min_ms: 60,
                baud: 300
            })
        );
        assert!(with(|s| {
            s.baud = 1200;
            s.qvz = Duration::from_millis(30);
        })
        .is_ok());
    }
}
