//! Protocol parameters of the telegram lines: 3964(R) (003 6.3.3) and ASCII (003 6.2.1, with the
//! RS232 flow-control parameters of 000 6.2.1), and their Modbus TCP mailboxes.

use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::config::check::{needs, Check, Line, Needs};
use crate::config::reader::{int_value, show_duration, Cx, Fields};
use crate::config::section::{AckConfig, ProtocolSection, TelegramKeys};
use crate::config::{Baud, Interface, SerialConfig};
use crate::protocols::ReadSection;

/// 003 6.3.3 "with block check ... Default value activated" (3964R).
pub const DEFAULT_3964_BLOCK_CHECK: bool = true;
/// 003 6.3.3 "Priority ... Default value high".
pub const DEFAULT_3964_PRIORITY: Priority = Priority::High;
/// 003 6.3.3 "Character delay time (ZVZ) ... 220ms".
pub const DEFAULT_3964_CHARACTER_DELAY: Duration = Duration::from_millis(220);
/// 003 6.3.3 "Acknowledgement delay time (ADT) ... 2000ms".
pub const DEFAULT_3964_ACK_DELAY: Duration = Duration::from_millis(2000);
/// 003 6.3.3 "... (550ms at 3964 without block check)".
pub const DEFAULT_3964_ACK_DELAY_NO_BCC: Duration = Duration::from_millis(550);
/// 003 6.3.3 ZVZ and QVZ: "Range of values: 20...65535ms in 10ms steps".
pub const TIMES_3964_RANGE: (Duration, Duration) =
    (Duration::from_millis(20), Duration::from_millis(65_535));
/// 003 6.3.3: "in 10ms steps".
pub const TIMES_3964_STEP: Duration = Duration::from_millis(10);
/// 003 6.3.3 "Setup attempts ... Range of values: 1...255", default 6.
pub const DEFAULT_3964_SETUP_ATTEMPTS: u8 = 6;
/// 003 6.3.3 "Transmission attempts ... Range of values: 1...255", default 6.
pub const DEFAULT_3964_TRANSMISSION_ATTEMPTS: u8 = 6;
/// 003 6.3.1: "You can maximally transfer 250byte per telegram".
pub const DEFAULT_3964_MAX_TELEGRAM_LEN: u16 = 250;
/// The longest telegram any line accepts: the CP's buffer of 1024 bytes (250 user bytes a
/// telegram by default).
pub const MAX_TELEGRAM_LEN: u16 = 1024;
/// The seeds give no receive buffer for 3964(R); we hold as many telegrams as the ASCII driver
/// (003 6.2.1: 250).
pub const DEFAULT_3964_RECEIVE_BUFFER: u16 = 250;
/// 3964(R) can refuse a telegram (003 6.3.1: "When the driver is not ready yet at reception of
/// the STX, it sends a NAK"), so a full buffer refuses instead of dropping.
pub const DEFAULT_3964_OVERFLOW: Overflow3964 = Overflow3964::Refuse;

/// 000 6.2.1 "nach Ablauf der Zeichenverzugszeit (Default-Wert)".
pub const DEFAULT_ASCII_END_CRITERION: EndCriterion = EndCriterion::CharDelay;
/// 003 6.2.1 "Character delay time (ZVZ) ... Default value 4ms" (the minimum at 9600 baud).
pub const DEFAULT_ASCII_CHARACTER_DELAY: Duration = Duration::from_millis(4);
/// 003 6.2.1 "Range of values: 2ms ... 65535ms in 1ms steps".
pub const ASCII_CHARACTER_DELAY_RANGE: (Duration, Duration) =
    (Duration::from_millis(2), Duration::from_millis(65_535));
/// 003 6.2.1 "Message frame length ... Range of values: 1 ... 1024bytes", default 240.
pub const DEFAULT_ASCII_FIXED_LENGTH: u16 = 240;
/// 003 6.2.1 "End character 1: 3 (03h=ETX) End character 2: 0" (0 = none).
pub const DEFAULT_ASCII_END_CHARS: [u8; 1] = [0x03];
/// 003 6.2.1 "Transmission pause ... activated".
pub const DEFAULT_ASCII_SEND_PAUSE: bool = true;
/// 003 6.2.1 "Data flow control ... none".
pub const DEFAULT_ASCII_FLOW_CONTROL: FlowControl = FlowControl::None;
/// 003 6.2.1 "XON code ... 11 (DC1)".
pub const DEFAULT_XON_CODE: u8 = 0x11;
/// 003 6.2.1 "XOFF code ... 13 (DC3)".
pub const DEFAULT_XOFF_CODE: u8 = 0x13;
/// 003 6.2.1 "Wait for XON after XOFF (Wait time for CTS=ON) ... 20 000ms".
pub const DEFAULT_XON_WAIT: Duration = Duration::from_millis(20_000);
/// 003 6.2.1: "Range of values: 20 ... 65535ms in 10ms steps".
pub const XON_WAIT_RANGE: (Duration, Duration) =
    (Duration::from_millis(20), Duration::from_millis(65_535));
/// 000 6.2.1 "RTS-Wegnahmezeit ... 10ms" (RTS off delay after sending, automatic V24).
pub const DEFAULT_RTS_HOLD_TIME: Duration = Duration::from_millis(10);
/// 000 6.2.1 "Datenausgabewartezeit ... 10ms" (wait for CTS after RTS on, automatic V24).
pub const DEFAULT_DATA_OUTPUT_WAIT: Duration = Duration::from_millis(10);
/// 000 6.2.1: both V24 times "0 ... 65535ms in 10ms steps".
pub const MAX_V24_TIME: Duration = Duration::from_millis(65_535);
/// 003 6.2.1 "Buffered receive message frames ... Range of values: 1 ... 250", default 250.
pub const DEFAULT_ASCII_RECEIVE_BUFFER: u16 = 250;
/// 003 6.2.1: range of the receive buffer.
pub const MAX_RECEIVE_BUFFER: u16 = 250;
/// 003 6.2.1 "Prevent overwriting ... activated".
pub const DEFAULT_PREVENT_OVERWRITE: bool = true;
/// An ASCII telegram may use the whole buffer of 1024 bytes by default.
pub const DEFAULT_ASCII_MAX_TELEGRAM_LEN: u16 = 1024;
/// Telegrams waiting to be sent (from Modbus TCP, zenoh, REST); a full queue answers busy.
/// The CP sends one telegram per FB 8 request; the depth is ours.
pub const DEFAULT_SEND_QUEUE: u16 = 16;

/// 3964(R) priority for the initialization conflict (003 6.3.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Priority {
    High,
    Low,
}

/// What a full 3964(R) receive buffer does with the next telegram.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Overflow3964 {
    /// Answer NAK: the partner's transmission fails and it reports it; nothing is lost here.
    Refuse,
    /// Accept it and drop the oldest unacknowledged telegram (counted).
    DropOldest,
}

/// ASCII end-of-telegram criterion (003 6.2.1 "End code of a message").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum EndCriterion {
    /// The character delay time expired.
    CharDelay,
    /// `fixed_length` characters arrived.
    FixedLength,
    /// The end character(s) arrived.
    EndChars,
}

/// ASCII data flow control (003 6.2.1; RTS/CTS and automatic V24 from 000 6.2.1, RS232 only).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FlowControl {
    None,
    XonXoff,
    RtsCts,
    /// Automatic handling of the V24 signals (000 5.4): RTS on, wait `data_output_wait` for
    /// CTS, send, RTS off after `rts_hold_time`; DSR off aborts.
    AutoV24,
}

/// 3964(R) (003 6.3.3) with its mailbox.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Proc3964Config {
    /// 3964R (with BCC) or 3964.
    pub block_check: bool,
    pub priority: Priority,
    /// ZVZ.
    #[serde(with = "humantime_serde")]
    pub character_delay: Duration,
    /// QVZ; defaults to 2000 ms with BCC, 550 ms without.
    #[serde(with = "humantime_serde")]
    pub ack_delay: Duration,
    pub setup_attempts: u8,
    pub transmission_attempts: u8,
    /// Longest telegram accepted or sent, 1..=1024 bytes.
    pub max_telegram_len: u16,
    /// Received telegrams held until the client acknowledges them, 1..=250.
    pub receive_buffer: u16,
    pub overflow: Overflow3964,
    pub send_queue: u16,
    /// Modbus TCP unit id of the mailbox, if served.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unit_id: Option<u8>,
    /// Telegram sends allowed (REST, zenoh `tx`, the mailbox's send block): the line's write
    /// policy for sends.
    pub sends: bool,
    /// Who acknowledges received telegrams; unset: "on-publish" when the line has no `unit_id`
    /// and zenoh is on, else "explicit" ([`ack_mode`](crate::protocols::ack_mode)).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ack: Option<AckConfig>,
    /// The file that keeps the waiting telegrams over a restart (`journal`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub journal: Option<PathBuf>,
}

/// ASCII telegrams (003 6.2.1) with their mailbox.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct AsciiConfig {
    pub end_criterion: EndCriterion,
    /// ZVZ; defaults to 4 ms or the baud rate's minimum when that is longer.
    #[serde(with = "humantime_serde")]
    pub character_delay: Duration,
    pub fixed_length: u16,
    /// One or two end characters; a second end character 0 is "none" (003 6.2.1) and is dropped.
    pub end_chars: Vec<u8>,
    /// Keep a pause before sending so that the partner synchronizes.
    pub send_pause: bool,
    pub flow_control: FlowControl,
    pub xon_code: u8,
    pub xoff_code: u8,
    /// Wait for XON after XOFF (or for CTS = ON).
    #[serde(with = "humantime_serde")]
    pub xon_wait: Duration,
    /// Automatic V24: RTS stays on this long after the last character.
    #[serde(with = "humantime_serde")]
    pub rts_hold_time: Duration,
    /// Automatic V24: after RTS on, wait this long for CTS before sending.
    #[serde(with = "humantime_serde")]
    pub data_output_wait: Duration,
    pub receive_buffer: u16,
    /// A full buffer drops the new telegram (event 08 0Ah); off (only with a buffer of 1), the
    /// newest telegram overwrites the held one, without an event (the CP raises none).
    pub prevent_overwrite: bool,
    pub max_telegram_len: u16,
    pub send_queue: u16,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unit_id: Option<u8>,
    /// Telegram sends allowed (REST, zenoh `tx`, the mailbox's send block): the line's write
    /// policy for sends.
    pub sends: bool,
    /// Who acknowledges received telegrams; unset: "on-publish" when the line has no `unit_id`
    /// and zenoh is on, else "explicit" ([`ack_mode`](crate::protocols::ack_mode)).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ack: Option<AckConfig>,
    /// The file that keeps the waiting telegrams over a restart (`journal`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub journal: Option<PathBuf>,
}

/// Telegram sends are allowed unless a line says `sends = false`: a telegram line exists to
/// exchange telegrams, and the demo sends from every interface. A line whose partner must only
/// be listened to is closed with `sends = false` (every send path refuses then).
pub const DEFAULT_SENDS: bool = true;

/// 003 6.3.3: the shortest ZVZ and QVZ by baud rate (300: 60 ms, 600: 40 ms, 1200: 30 ms,
/// 2400 ... 76800: 20 ms). 150 baud is beyond the CP; we double the 300-baud value.
pub fn min_3964_time(baud: Baud) -> Duration {
    Duration::from_millis(match baud.get() {
        150 => 120,
        300 => 60,
        600 => 40,
        1200 => 30,
        _ => 20,
    })
}

/// 003 6.2.1: the shortest ASCII ZVZ by baud rate (300: 130, 600: 65, 1200: 32, 2400: 16,
/// 4800: 8, 9600: 4, 19200 and up: 2 ms). 150 baud is beyond the CP; we double the 300 value.
pub fn min_ascii_character_delay(baud: Baud) -> Duration {
    Duration::from_millis(match baud.get() {
        150 => 260,
        300 => 130,
        600 => 65,
        1200 => 32,
        2400 => 16,
        4800 => 8,
        9600 => 4,
        _ => 2,
    })
}

// === readers ===

fn check_step(cx: &mut Cx, path: String, d: Duration, step: Duration, cite: &str) {
    if d.as_nanos() % step.as_nanos() != 0 {
        cx.issue(
            path,
            format!("must be a multiple of {}ms ({cite})", step.as_millis()),
        );
    }
}

/// The Modbus TCP unit id of a telegram mailbox (`unit_id`).
pub(crate) fn mailbox_unit_id(cx: &mut Cx, f: &mut Fields<'_>) -> Option<u8> {
    f.int(cx, "unit_id", 1..=u8::MAX, "")
}

/// The keys a 3964(R) line and a 3964(R) tap share: the link's procedure (003 6.3.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Link3964 {
    pub(crate) block_check: bool,
    pub(crate) character_delay: Duration,
    pub(crate) ack_delay: Duration,
    pub(crate) max_telegram_len: u16,
    pub(crate) receive_buffer: u16,
}

// === impl Link3964 ===

impl Link3964 {
    /// Reads `block_check`, `character_delay`, `ack_delay`, `max_telegram_len` and
    /// `receive_buffer`.
    pub(crate) fn read(cx: &mut Cx, f: &mut Fields<'_>) -> Self {
        const CITE: &str = "003 6.3.3";
        let block_check = f.bool_or(cx, "block_check", DEFAULT_3964_BLOCK_CHECK);
        let (lo, hi) = TIMES_3964_RANGE;
        let time = |cx: &mut Cx, f: &mut Fields<'_>, key: &'static str, default: Duration| {
            let d = f.duration_or(cx, key, lo..=hi, default, CITE);
            check_step(cx, f.at(key), d, TIMES_3964_STEP, CITE);
            d
        };
        let character_delay = time(cx, f, "character_delay", DEFAULT_3964_CHARACTER_DELAY);
        let ack_default = if block_check {
            DEFAULT_3964_ACK_DELAY
        } else {
            DEFAULT_3964_ACK_DELAY_NO_BCC
        };
        let ack_delay = time(cx, f, "ack_delay", ack_default);
        Self {
            block_check,
            character_delay,
            ack_delay,
            max_telegram_len: f.int_or(
                cx,
                "max_telegram_len",
                1..=MAX_TELEGRAM_LEN,
                DEFAULT_3964_MAX_TELEGRAM_LEN,
                "003 6.3.1",
            ),
            receive_buffer: f.int_or(
                cx,
                "receive_buffer",
                1..=MAX_RECEIVE_BUFFER,
                DEFAULT_3964_RECEIVE_BUFFER,
                "",
            ),
        }
    }
}

/// `journal`: a file path, not empty.
fn journal_path(cx: &mut Cx, f: &mut Fields<'_>) -> Option<PathBuf> {
    let path = f.string(cx, "journal")?;
    if path.trim().is_empty() {
        cx.issue(
            f.at("journal"),
            "give a file path (or leave the key out: no journal)",
        );
        return None;
    }
    Some(PathBuf::from(path))
}

impl ReadSection for Proc3964Config {
    fn read_section(cx: &mut Cx, f: &mut Fields<'_>, _baud: Baud) -> Self {
        const CITE: &str = "003 6.3.3";
        let link = Link3964::read(cx, f);
        Self {
            block_check: link.block_check,
            priority: f.choice_or(cx, "priority", DEFAULT_3964_PRIORITY),
            character_delay: link.character_delay,
            ack_delay: link.ack_delay,
            setup_attempts: f.int_or(
                cx,
                "setup_attempts",
                1..=u8::MAX,
                DEFAULT_3964_SETUP_ATTEMPTS,
                CITE,
            ),
            transmission_attempts: f.int_or(
                cx,
                "transmission_attempts",
                1..=u8::MAX,
                DEFAULT_3964_TRANSMISSION_ATTEMPTS,
                CITE,
            ),
            max_telegram_len: link.max_telegram_len,
            receive_buffer: link.receive_buffer,
            overflow: f.choice_or(cx, "overflow", DEFAULT_3964_OVERFLOW),
            send_queue: f.int_or(
                cx,
                "send_queue",
                1..=MAX_RECEIVE_BUFFER,
                DEFAULT_SEND_QUEUE,
                "",
            ),
            unit_id: mailbox_unit_id(cx, f),
            sends: f.bool_or(cx, "sends", DEFAULT_SENDS),
            ack: f.choice(cx, "ack"),
            journal: journal_path(cx, f),
        }
    }
}

impl ReadSection for AsciiConfig {
    fn read_section(cx: &mut Cx, f: &mut Fields<'_>, baud: Baud) -> Self {
        const CITE: &str = "003 6.2.1";
        let (lo, hi) = ASCII_CHARACTER_DELAY_RANGE;
        let zvz_default = DEFAULT_ASCII_CHARACTER_DELAY.max(min_ascii_character_delay(baud));
        let character_delay = f.duration_or(cx, "character_delay", lo..=hi, zvz_default, CITE);
        check_step(
            cx,
            f.at("character_delay"),
            character_delay,
            Duration::from_millis(1),
            CITE,
        );
        let mut end_chars = Vec::new();
        let items = f.array(cx, "end_chars");
        for (p, v) in &items {
            end_chars.extend(int_value::<u8>(cx, v, p, 0..=u8::MAX, CITE));
        }
        // 003 6.2.1 "End character 1/2": end character 2 = 0 is the parameter screen's "none".
        if end_chars.len() == 2 && end_chars.last() == Some(&0) {
            end_chars.pop();
        }
        if !f.has("end_chars") {
            end_chars = DEFAULT_ASCII_END_CHARS.to_vec();
        } else if items.is_empty() || items.len() > 2 {
            cx.issue(
                f.at("end_chars"),
                format!(
                    "give one or two end characters ({CITE}), found {}",
                    items.len()
                ),
            );
        }
        let (xlo, xhi) = XON_WAIT_RANGE;
        let xon_wait = f.duration_or(cx, "xon_wait", xlo..=xhi, DEFAULT_XON_WAIT, CITE);
        check_step(cx, f.at("xon_wait"), xon_wait, TIMES_3964_STEP, CITE);
        let v24 = |cx: &mut Cx, f: &mut Fields<'_>, key: &'static str, default: Duration| {
            let d = f.duration_or(cx, key, Duration::ZERO..=MAX_V24_TIME, default, "000 6.2.1");
            check_step(cx, f.at(key), d, TIMES_3964_STEP, "000 6.2.1");
            d
        };
        let rts_hold_time = v24(cx, f, "rts_hold_time", DEFAULT_RTS_HOLD_TIME);
        let data_output_wait = v24(cx, f, "data_output_wait", DEFAULT_DATA_OUTPUT_WAIT);
        Self {
            end_criterion: f.choice_or(cx, "end_criterion", DEFAULT_ASCII_END_CRITERION),
            character_delay,
            fixed_length: f.int_or(
                cx,
                "fixed_length",
                1..=MAX_TELEGRAM_LEN,
                DEFAULT_ASCII_FIXED_LENGTH,
                CITE,
            ),
            end_chars,
            send_pause: f.bool_or(cx, "send_pause", DEFAULT_ASCII_SEND_PAUSE),
            flow_control: f.choice_or(cx, "flow_control", DEFAULT_ASCII_FLOW_CONTROL),
            xon_code: f.int_or(cx, "xon_code", 0..=u8::MAX, DEFAULT_XON_CODE, CITE),
            xoff_code: f.int_or(cx, "xoff_code", 0..=u8::MAX, DEFAULT_XOFF_CODE, CITE),
            xon_wait,
            rts_hold_time,
            data_output_wait,
            receive_buffer: f.int_or(
                cx,
                "receive_buffer",
                1..=MAX_RECEIVE_BUFFER,
                DEFAULT_ASCII_RECEIVE_BUFFER,
                CITE,
            ),
            prevent_overwrite: f.bool_or(cx, "prevent_overwrite", DEFAULT_PREVENT_OVERWRITE),
            max_telegram_len: f.int_or(
                cx,
                "max_telegram_len",
                1..=MAX_TELEGRAM_LEN,
                DEFAULT_ASCII_MAX_TELEGRAM_LEN,
                "",
            ),
            send_queue: f.int_or(
                cx,
                "send_queue",
                1..=MAX_RECEIVE_BUFFER,
                DEFAULT_SEND_QUEUE,
                "",
            ),
            unit_id: mailbox_unit_id(cx, f),
            sends: f.bool_or(cx, "sends", DEFAULT_SENDS),
            ack: f.choice(cx, "ack"),
            journal: journal_path(cx, f),
        }
    }
}

// === impl ProtocolSection for the telegram lines ===

impl Check<Line<'_>> for Proc3964Config {
    fn check(&self, line: &Line<'_>, cx: &mut Cx) {
        check_3964_link(
            cx,
            line.path,
            line.serial,
            (self.character_delay, self.ack_delay),
        );
    }
}

impl Check<Line<'_>> for AsciiConfig {
    fn check(&self, line: &Line<'_>, cx: &mut Cx) {
        check_ascii(cx, line.path, line.serial, self);
    }
}

/// Both telegram sections offer their mailbox and its keys alike.
macro_rules! telegram_sections {
    ($($section:ty),+) => {$(
        impl ProtocolSection for $section {
            fn unit_id(&self) -> Option<u8> {
                self.unit_id
            }

            fn telegrams(&self) -> Option<TelegramKeys<'_>> {
                Some(TelegramKeys {
                    sends: self.sends,
                    ack: self.ack,
                    journal: self.journal.as_deref(),
                })
            }
        }
    )+};
}

telegram_sections!(Proc3964Config, AsciiConfig);

/// The checks a 3964(R) line and a 3964(R) tap share: a full-duplex link, and the character
/// and acknowledgement delay times (`times`) at least the baud rate's minimum.
pub(crate) fn check_3964_link(
    cx: &mut Cx,
    path: &str,
    serial: &SerialConfig,
    times: (Duration, Duration),
) {
    if serial.interface == Interface::Rs485 {
        cx.issue(
            format!("{path}.interface"),
            "3964(R) needs a full-duplex line (rs232 or rs422): the procedure is not possible in two-wire \
             (RS485 half-duplex) mode (003 6.3.3: \"Half-duplex (RS485) - This setting is not available with 3964(R)\")",
        );
    }
    let min = min_3964_time(serial.baud);
    for (key, d) in [("character_delay", times.0), ("ack_delay", times.1)] {
        if d < min {
            cx.issue(
                format!("{path}.{key}"),
                format!(
                    "at {} baud must be at least {} (003 6.3.3), found {}",
                    serial.baud,
                    show_duration(min),
                    show_duration(d)
                ),
            );
        }
    }
}

fn check_ascii(cx: &mut Cx, path: &str, serial: &SerialConfig, a: &AsciiConfig) {
    let min = min_ascii_character_delay(serial.baud);
    if a.character_delay < min {
        cx.issue(
            format!("{path}.character_delay"),
            format!(
                "at {} baud must be at least {} (003 6.2.1), found {}",
                serial.baud,
                show_duration(min),
                show_duration(a.character_delay)
            ),
        );
    }
    match a.flow_control {
        FlowControl::None => {}
        _ if serial.interface == Interface::Rs485 => cx.issue(
            format!("{path}.flow_control"),
            "no data flow control on a half-duplex RS485 line (003 6.2.1: \"At half-duplex parameterization with \
             RS485 data flow control is not possible\")",
        ),
        FlowControl::RtsCts | FlowControl::AutoV24 if serial.interface != Interface::Rs232 => cx.issue(
            format!("{path}.flow_control"),
            "RTS/CTS and automatic V24 handling use the RS232 modem signals: set interface = \"rs232\" (000 5.4)",
        ),
        FlowControl::XonXoff if a.xon_code == a.xoff_code => {
            cx.issue(format!("{path}.xoff_code"), "XON and XOFF must be different characters");
        }
        _ => {}
    }
    let max = serial.data_bits.max_code();
    let mut codes: Vec<(String, u8)> = vec![
        (format!("{path}.xon_code"), a.xon_code),
        (format!("{path}.xoff_code"), a.xoff_code),
    ];
    codes.extend(
        a.end_chars
            .iter()
            .enumerate()
            .map(|(i, c)| (format!("{path}.end_chars[{i}]"), *c)),
    );
    for (p, code) in codes {
        if code > max {
            cx.issue(
                p,
                format!(
                    "0x{code:02X} does not fit in {} data bits: at most 0x{max:02X} (003 6.2.1)",
                    serial.data_bits.get()
                ),
            );
        }
    }
    if !a.prevent_overwrite && a.receive_buffer != 1 {
        cx.issue(
            format!("{path}.prevent_overwrite"),
            format!(
                "may be switched off only with receive_buffer = 1 (003 6.2.1 \"Prevent overwriting\"), found receive_buffer = {}",
                a.receive_buffer
            ),
        );
    }
    if a.end_criterion == EndCriterion::FixedLength && a.fixed_length > a.max_telegram_len {
        cx.issue(
            format!("{path}.fixed_length"),
            format!(
                "{} is longer than max_telegram_len = {}",
                a.fixed_length, a.max_telegram_len
            ),
        );
    }
}

/// An ASCII line's keys that only one end criterion or flow control reads (003 6.2.1; the V24
/// times 000 6.2.1), with their defaults (above): the rules by which `validate::ignored_keys`
/// finds them without effect in a file.
pub(crate) const ASCII_NEEDS: &[Needs] = &[
    needs(
        "end_chars",
        None,
        "end_criterion",
        &["end-chars"],
        "char-delay",
    ),
    needs(
        "fixed_length",
        Some("240"),
        "end_criterion",
        &["fixed-length"],
        "char-delay",
    ),
    needs(
        "xon_code",
        Some("17"),
        "flow_control",
        &["xon-xoff"],
        "none",
    ),
    needs(
        "xoff_code",
        Some("19"),
        "flow_control",
        &["xon-xoff"],
        "none",
    ),
    needs(
        "xon_wait",
        Some("20s"),
        "flow_control",
        &["xon-xoff", "rts-cts"],
        "none",
    ),
    needs(
        "rts_hold_time",
        Some("10ms"),
        "flow_control",
        &["auto-v24"],
        "none",
    ),
    needs(
        "data_output_wait",
        Some("10ms"),
        "flow_control",
        &["auto-v24"],
        "none",
    ),
];

#[cfg(test)]
mod tests {
    use super::*;

    fn baud(rate: u32) -> Baud {
        Baud::try_new(rate).expect("supported baud")
    }

    #[test]
    fn ascii_minimum_character_delay_by_baud() {
        // 003 6.2.1 table.
        for (rate, ms) in [
            (300, 130),
            (600, 65),
            (1200, 32),
            (2400, 16),
            (4800, 8),
            (9600, 4),
            (19200, 2),
            (38400, 2),
            (57600, 2),
            (76800, 2),
        ] {
            assert_eq!(
                min_ascii_character_delay(baud(rate)),
                Duration::from_millis(ms),
                "{rate} baud"
            );
        }
    }

    #[test]
    fn proc3964_minimum_times_by_baud() {
        // 003 6.3.3 tables (ZVZ and QVZ).
        for (rate, ms) in [
            (300, 60),
            (600, 40),
            (1200, 30),
            (2400, 20),
            (9600, 20),
            (76800, 20),
        ] {
            assert_eq!(
                min_3964_time(baud(rate)),
                Duration::from_millis(ms),
                "{rate} baud"
            );
        }
    }
}
