//! The serial settings every line has: port, interface, baud rate and character frame
//! (003 6.1 "Character frame"), and the kernel RS485 options for two-wire lines.

use std::fmt;
use std::time::Duration;

use serde::{Deserialize, Serialize, Serializer};

use super::reader::{Cx, Fields};

/// 003 6.2.1, 6.3.3, 6.4.2.1, 6.4.5.1: "Baud rate ... Default value 9600" for every protocol.
pub const DEFAULT_BAUD: Baud = Baud(9600);
/// 003 6.2.1 ff.: "Data bits ... Default value 8".
pub const DEFAULT_DATA_BITS: DataBits = DataBits::Eight;
/// 003 6.2.1 ff.: "Parity ... Default value even".
pub const DEFAULT_PARITY: Parity = Parity::Even;
/// 003 6.2.1 ff.: "Stop bits ... Default value 1".
pub const DEFAULT_STOP_BITS: StopBits = StopBits::One;
/// 003 6.2.1 "Interface": "Full-duplex (RS422) Four-wire operation (default value: active)".
pub const DEFAULT_INTERFACE: Interface = Interface::Rs422;

/// Linux `SER_RS485_RTS_ON_SEND` is the usual transceiver wiring: RTS high drives the bus.
pub const DEFAULT_RS485_RTS_ON_SEND: bool = true;
/// Linux `SER_RS485_RTS_AFTER_SEND`: the opposite level, off by default.
pub const DEFAULT_RS485_RTS_AFTER_SEND: bool = false;
/// No extra delay between raising RTS and the first bit.
pub const DEFAULT_RS485_DELAY_BEFORE_SEND: Duration = Duration::ZERO;
/// No extra delay between the last bit and dropping RTS.
pub const DEFAULT_RS485_DELAY_AFTER_SEND: Duration = Duration::ZERO;
/// Two-wire half duplex: the receiver is off while we send (no echo of our own frames).
pub const DEFAULT_RS485_RX_DURING_TX: bool = false;
/// Linux serial_core clamps `delay_rts_before_send`/`delay_rts_after_send` to 100 ms
/// (`RS485_MAX_RTS_DELAY`); the seeds are silent on these delays.
pub const MAX_RS485_DELAY: Duration = Duration::from_millis(100);

/// Frames a line's frame monitor keeps by default (`monitor_frames`; 0 turns it off).
pub const DEFAULT_MONITOR_FRAMES: u32 = 256;
/// The most frames a line's frame monitor may keep.
pub const MAX_MONITOR_FRAMES: u32 = 65_536;

fn is_default_monitor_frames(n: &u32) -> bool {
    *n == DEFAULT_MONITOR_FRAMES
}

/// The prefix of a port created by `gateway demo` (a pseudo-terminal), e.g. `pty:drive`.
pub const PTY_PREFIX: &str = "pty:";

/// A baud rate the gateway supports: the CP 341's list (003 6.2.1: 300 ... 76800) widened by
/// 150 and 115200: the gateway runs 150..115200 Bd, beyond the CP's 76800.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(transparent)]
pub struct Baud(u32);

// === impl Baud ===

impl Baud {
    /// Every supported rate, ascending.
    pub const SUPPORTED: [u32; 12] = [
        150, 300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 76800, 115_200,
    ];

    /// `rate` if it is one of [`Self::SUPPORTED`].
    pub fn try_new(rate: u32) -> Result<Self, InvalidBaud> {
        if Self::SUPPORTED.contains(&rate) {
            Ok(Self(rate))
        } else {
            Err(InvalidBaud(rate))
        }
    }

    /// Bits per second.
    pub fn get(self) -> u32 {
        self.0
    }
}

impl fmt::Display for Baud {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.fmt(f)
    }
}

/// A baud rate outside [`Baud::SUPPORTED`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error(
    "{0} baud is not supported; use one of 150, 300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 76800, 115200 \
     (003 6.2.1; 150 and 115200 go beyond the CP 341)"
)]
pub struct InvalidBaud(pub u32);

/// Data bits of a character (003 6.2.1: 7 or 8).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DataBits {
    Seven,
    Eight,
}

impl DataBits {
    pub fn get(self) -> u8 {
        match self {
            Self::Seven => 7,
            Self::Eight => 8,
        }
    }

    /// The highest character code that fits (003 6.2.1: "0...7Fh/FFh (7/8 data bits)").
    pub fn max_code(self) -> u8 {
        match self {
            Self::Seven => 0x7F,
            Self::Eight => 0xFF,
        }
    }
}

impl Serialize for DataBits {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_u8(self.get())
    }
}

/// Parity (003 6.2.1: none, odd, even).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Parity {
    None,
    Odd,
    Even,
}

/// Stop bits (003 6.2.1: 1 or 2).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum StopBits {
    One,
    Two,
}

impl StopBits {
    pub fn get(self) -> u8 {
        match self {
            Self::One => 1,
            Self::Two => 2,
        }
    }
}

impl Serialize for StopBits {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_u8(self.get())
    }
}

/// The electrical interface. RS232 and RS422 are full duplex and need nothing from the kernel;
/// RS485 is two-wire half duplex and is switched on with the kernel's RS485 ioctl
/// (`TIOCSRS485`) using [`Rs485Config`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Interface {
    /// RS232 with the modem signals (000 5.4: DTR/DSR/RTS/CTS/DCD/RI).
    Rs232,
    /// RS422 four-wire full duplex (003 6.2.1 default).
    Rs422,
    /// RS485 two-wire half duplex (003 6.2.1 "Half-duplex (RS485)").
    Rs485,
}

/// The kernel RS485 settings (`struct serial_rs485`), used only with `interface = "rs485"`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Rs485Config {
    /// RTS level while sending is high (`SER_RS485_RTS_ON_SEND`).
    pub rts_on_send: bool,
    /// RTS level after sending is high (`SER_RS485_RTS_AFTER_SEND`); must differ from
    /// `rts_on_send`.
    pub rts_after_send: bool,
    /// Delay between RTS on and the first bit (`delay_rts_before_send`), 0..=100 ms.
    #[serde(with = "humantime_serde")]
    pub delay_before_send: Duration,
    /// Delay between the last bit and RTS off (`delay_rts_after_send`), 0..=100 ms.
    #[serde(with = "humantime_serde")]
    pub delay_after_send: Duration,
    /// Keep the receiver on while sending (`SER_RS485_RX_DURING_TX`).
    pub rx_during_tx: bool,
}

impl Default for Rs485Config {
    fn default() -> Self {
        Self {
            rts_on_send: DEFAULT_RS485_RTS_ON_SEND,
            rts_after_send: DEFAULT_RS485_RTS_AFTER_SEND,
            delay_before_send: DEFAULT_RS485_DELAY_BEFORE_SEND,
            delay_after_send: DEFAULT_RS485_DELAY_AFTER_SEND,
            rx_during_tx: DEFAULT_RS485_RX_DURING_TX,
        }
    }
}

/// Port and character frame of one line.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct SerialConfig {
    /// Device path (`/dev/ttyS0`, `/dev/serial/by-id/...`), or `pty:<name>` for a pseudo-terminal
    /// that `gateway demo` creates and substitutes before the line starts.
    pub port: String,
    pub interface: Interface,
    pub baud: Baud,
    pub data_bits: DataBits,
    pub parity: Parity,
    pub stop_bits: StopBits,
    /// Present exactly when `interface` is RS485.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rs485: Option<Rs485Config>,
    /// Frames the line's frame monitor keeps (0: no monitor).
    #[serde(skip_serializing_if = "is_default_monitor_frames")]
    pub monitor_frames: u32,
}

// === impl SerialConfig ===

impl SerialConfig {
    /// A port at `port` with every default.
    pub fn new(port: impl Into<String>) -> Self {
        Self {
            port: port.into(),
            interface: DEFAULT_INTERFACE,
            baud: DEFAULT_BAUD,
            data_bits: DEFAULT_DATA_BITS,
            parity: DEFAULT_PARITY,
            stop_bits: DEFAULT_STOP_BITS,
            rs485: None,
            monitor_frames: DEFAULT_MONITOR_FRAMES,
        }
    }

    /// The demo pseudo-terminal name when `port` is `pty:<name>`.
    pub fn pty_name(&self) -> Option<&str> {
        self.port.strip_prefix(PTY_PREFIX)
    }

    /// Bits on the wire per character: start + data + parity + stop.
    pub fn bits_per_char(&self) -> u8 {
        1 + self.data_bits.get() + u8::from(self.parity != Parity::None) + self.stop_bits.get()
    }

    /// Reads the serial keys of a line table. `None` when the port is missing.
    pub(crate) fn read(cx: &mut Cx, f: &mut Fields<'_>) -> Option<Self> {
        let port = f.required_string(cx, "port");
        if let Some(p) = &port {
            if p.is_empty() {
                cx.issue(f.at("port"), "must not be empty");
            } else if let Some(name) = p.strip_prefix(PTY_PREFIX) {
                if name.is_empty() {
                    cx.issue(f.at("port"), "a demo port needs a name after \"pty:\"");
                }
            }
        }
        let interface = f.choice_or(cx, "interface", DEFAULT_INTERFACE);
        let baud = match f.int::<u32>(cx, "baud", 0..=u32::MAX, "") {
            None => DEFAULT_BAUD,
            Some(rate) => Baud::try_new(rate).unwrap_or_else(|e| {
                cx.issue(f.at("baud"), e.to_string());
                DEFAULT_BAUD
            }),
        };
        let data_bits = match f.int::<u8>(cx, "data_bits", 7..=8, "003 6.2.1") {
            Some(7) => DataBits::Seven,
            _ => DEFAULT_DATA_BITS,
        };
        let parity = f.choice_or(cx, "parity", DEFAULT_PARITY);
        let stop_bits = match f.int::<u8>(cx, "stop_bits", 1..=2, "003 6.2.1") {
            Some(2) => StopBits::Two,
            _ => DEFAULT_STOP_BITS,
        };
        let monitor_frames = f.int_or(
            cx,
            "monitor_frames",
            0..=MAX_MONITOR_FRAMES,
            DEFAULT_MONITOR_FRAMES,
            "",
        );
        let rs485_table = f.table(cx, "rs485");
        let rs485 = match (interface, rs485_table) {
            (Interface::Rs485, Some(t)) => Some(read_rs485(cx, t)),
            (Interface::Rs485, None) => Some(Rs485Config::default()),
            (_, Some(t)) => {
                cx.issue(
                    t.path().to_owned(),
                    "RS485 settings need interface = \"rs485\"",
                );
                None
            }
            (_, None) => None,
        };
        Some(Self {
            port: port?,
            interface,
            baud,
            data_bits,
            parity,
            stop_bits,
            rs485,
            monitor_frames,
        })
    }
}

fn read_rs485(cx: &mut Cx, mut f: Fields<'_>) -> Rs485Config {
    let delays = Duration::ZERO..=MAX_RS485_DELAY;
    const CITE: &str = "Linux RS485_MAX_RTS_DELAY";
    let c = Rs485Config {
        rts_on_send: f.bool_or(cx, "rts_on_send", DEFAULT_RS485_RTS_ON_SEND),
        rts_after_send: f.bool_or(cx, "rts_after_send", DEFAULT_RS485_RTS_AFTER_SEND),
        delay_before_send: f.duration_or(
            cx,
            "delay_before_send",
            delays.clone(),
            DEFAULT_RS485_DELAY_BEFORE_SEND,
            CITE,
        ),
        delay_after_send: f.duration_or(
            cx,
            "delay_after_send",
            delays,
            DEFAULT_RS485_DELAY_AFTER_SEND,
            CITE,
        ),
        rx_during_tx: f.bool_or(cx, "rx_during_tx", DEFAULT_RS485_RX_DURING_TX),
    };
    if c.rts_on_send == c.rts_after_send {
        cx.issue(
            f.at("rts_after_send"),
            "must differ from rts_on_send: RTS must change level when sending starts and ends",
        );
    }
    f.finish(cx);
    c
}

/// What a port that does not exist is called, by `gateway check` (a warning) and by a change
/// over the REST API (refused): the same words.
pub(crate) fn no_such_port(port: &str) -> String {
    format!("no such serial port {port}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn baud_list_is_the_cp_list_plus_150_and_115200() {
        for rate in [300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 76800] {
            assert!(Baud::try_new(rate).is_ok(), "003 6.2.1 lists {rate}");
        }
        assert!(Baud::try_new(150).is_ok());
        assert!(Baud::try_new(115_200).is_ok());
        assert_eq!(Baud::try_new(14_400), Err(InvalidBaud(14_400)));
        assert_eq!(Baud::try_new(0), Err(InvalidBaud(0)));
    }

    #[test]
    fn bits_per_char_counts_start_parity_and_stop() {
        let mut s = SerialConfig::new("/dev/null");
        assert_eq!(s.bits_per_char(), 11); // 8E1
        s.parity = Parity::None;
        s.stop_bits = StopBits::Two;
        s.data_bits = DataBits::Seven;
        assert_eq!(s.bits_per_char(), 10);
    }

    #[test]
    fn pty_names() {
        assert_eq!(SerialConfig::new("pty:drive").pty_name(), Some("drive"));
        assert_eq!(SerialConfig::new("/dev/ttyS0").pty_name(), None);
    }
}
