//! The frame monitor's protocol knowledge: where a line's frames end, and what a frame is.
//!
//! The runtime records every byte a line sends and receives with its time; it asks this module
//! where a received frame ends ([`FrameCutter`]: a silence of the line's gap ends every frame,
//! found by the RTU receivers' own [`SilenceFramer`], and the protocol's own end marks end it at
//! once) and, only when someone reads the monitor, what a frame is ([`describe`]: a verdict and a
//! one-line summary). Both are pure: bytes and times in, answers out; the cutter's
//! [`FrameCutter::deadline`] is one more deadline for the line's one timer.
//!
//! ```text
//!   Modbus RTU     a frame ends after t3.5 of silence (003 6.4.3)
//!   Modbus ASCII   ':' .. CR LF (003 6.4.2.2)
//!   3964(R)        STX, DLE and NAK are frames of their own; a telegram ends with DLE ETX and,
//!                  in 3964R, the BCC (003 6.3)
//!   ASCII          the end character(s), the fixed length, or the character delay time (003 6.2)
//! ```

use std::fmt::Write as _;
use std::time::Duration;

use crate::checksum::{bcc, crc16_modbus, lrc};
use crate::modbus::rtu::framer::Fault;
use crate::modbus::rtu::{CharTiming, SilenceFramer};
use crate::proc3964::frame::{Deframer, Progress};
use crate::proc3964::{Variant, DLE, ETX, NAK, STX};
use crate::telegram::EndCriterion;
use crate::time::Instant;

/// The shortest silence that ends a received frame: below it a port that delivers in bursts (a
/// pty, a USB adapter) would cut frames apart.
const MIN_GAP: Duration = Duration::from_micros(100);

/// Which way a frame went, seen from the gateway.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Received from the line.
    Rx,
    /// Sent by the gateway.
    Tx,
    /// Received on the first port of a listen-only line with two ports (a Y-cable tap of a
    /// point-to-point link): what partner A transmits.
    A,
    /// Received on the second port of such a line: what partner B transmits.
    B,
}

// === impl Direction ===

impl Direction {
    /// `"rx"` or `"tx"`.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Rx => "rx",
            Self::Tx => "tx",
            Self::A => "a",
            Self::B => "b",
        }
    }
}

/// Which side of a Modbus exchange the gateway is on: it says whether a frame is a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Role {
    /// The gateway sends the requests.
    Master,
    /// The gateway answers the requests.
    Slave,
    /// The gateway only listens: a frame is taken for a request when its shape says so.
    Listener,
}

/// How a line's frames are cut and described.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameKind {
    /// Bytes without a protocol: a frame ends by silence and is described by its length.
    Raw,
    /// Modbus RTU: a frame ends by a silence of t3.5 (003 6.4.3); CRC-16 at its end.
    ModbusRtu(Role),
    /// Modbus ASCII: `:` hex pairs, LRC, CR LF (003 6.4.2.2).
    ModbusAscii(Role),
    /// 3964(R): control characters and telegrams (003 6.3); `bcc`: 3964R, a block check
    /// character follows DLE ETX.
    Proc3964 {
        /// 3964R (with BCC) rather than 3964.
        bcc: bool,
    },
    /// An ASCII telegram line and how its telegrams end (003 6.2).
    Telegram(EndCriterion),
}

/// How the runtime cuts a line's received bytes into frames: the protocol and the silence that
/// ends any frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Framing {
    /// The protocol's frames.
    pub kind: FrameKind,
    /// A received frame ends after this much silence (`None`: 3.5 character times of the port).
    pub gap: Option<Duration>,
}

// === impl Framing ===

impl Framing {
    /// Bytes without a protocol, cut by 3.5 character times of silence.
    pub const RAW: Self = Self {
        kind: FrameKind::Raw,
        gap: None,
    };

    /// The silence that ends a received frame on a port whose characters take `char_time`:
    /// [`Self::gap`], else 3.5 character times (003 6.4.3), at least 100 µs.
    pub fn silence(&self, char_time: Duration) -> Duration {
        self.gap
            .unwrap_or_else(|| char_time.saturating_mul(7) / 2)
            .max(MIN_GAP)
    }
}

impl Default for Framing {
    fn default() -> Self {
        Self::RAW
    }
}

/// Where a received frame ends, byte by byte: the protocol's end marks at once, and a silence of
/// the line's gap ([`Framing::silence`]) after the last byte, found by the RTU receivers'
/// [`SilenceFramer`] (its t3.5 is the gap here). The caller owns the clock: it gives each byte
/// its time, waits until [`Self::deadline`] and calls [`Self::expire`].
#[derive(Debug)]
pub struct FrameCutter {
    kind: FrameKind,
    /// The silence after the last byte (or line error) that ends the frame.
    silence: SilenceFramer,
    /// Bytes of the current frame so far.
    len: usize,
    /// 3964(R): the frame is a telegram (data after the partner's STX was acknowledged, or
    /// bytes that are not a control character), whose end the protocol's own deframer finds.
    telegram: Option<Deframer>,
    /// 3964(R): the gateway acknowledged the partner's STX, so the next received bytes are a
    /// telegram even if they begin with a DLE.
    expect_telegram: bool,
    /// Modbus ASCII / ASCII end characters: the previous byte was the first end character.
    first_end_seen: bool,
}

// === impl FrameCutter ===

impl FrameCutter {
    /// A cutter for `kind` whose frames end after `gap` of silence, before any byte.
    pub const fn new(kind: FrameKind, gap: Duration) -> Self {
        // Only the silence is asked of the framer: t1.5 and the announced length are not checked
        // (the monitor keeps every frame; [`describe`] judges it when someone reads).
        let timing = CharTiming {
            char_time: gap,
            t15: gap,
            t35: gap,
        };
        Self {
            kind,
            silence: SilenceFramer::new(timing),
            len: 0,
            telegram: None,
            expect_telegram: false,
            first_end_seen: false,
        }
    }

    /// The frame ended (by silence, by a transmission, or by [`Self::push`]): the next byte
    /// begins a new one.
    pub fn reset(&mut self) {
        self.silence.clear();
        self.len = 0;
        self.telegram = None;
        self.first_end_seen = false;
    }

    /// The gateway sent `frame`: on a 3964(R) line, a lone DLE acknowledges the partner's STX
    /// (003 6.3 "Receiving data"), so the bytes that follow are its telegram.
    pub fn sent(&mut self, frame: &[u8]) {
        if let FrameKind::Proc3964 { .. } = self.kind {
            self.expect_telegram = frame == [DLE];
        }
    }

    /// When the frame being received ends by silence unless more bytes come.
    pub fn deadline(&self) -> Option<Instant> {
        self.silence.deadline()
    }

    /// Ends the frame being received if its silence has passed by `now`; true when it did.
    pub fn expire(&mut self, now: Instant) -> bool {
        let ended = self.silence.poll(now).is_some();
        if ended {
            self.reset();
        }
        ended
    }

    /// A line error at `at`: it belongs to the frame being received (or begins one), which ends
    /// a gap after it unless more bytes come.
    pub fn line_error(&mut self, at: Instant) {
        self.silence.fail(at, Fault::LineError);
    }

    /// One more received byte, arrived at `at`; true when the frame ends with it.
    pub fn push(&mut self, at: Instant, byte: u8) -> bool {
        self.silence.push(at, &[byte]);
        self.len += 1;
        let ends = match self.kind {
            FrameKind::Raw | FrameKind::ModbusRtu(_) => false,
            FrameKind::ModbusAscii(_) => {
                // 003 6.4.2.2: a frame ends with CR LF.
                let ends = self.first_end_seen && byte == b'\n';
                self.first_end_seen = byte == b'\r';
                ends
            }
            FrameKind::Proc3964 { bcc } => self.push_3964(byte, bcc),
            FrameKind::Telegram(end) => match end {
                EndCriterion::CharacterDelay => false,
                EndCriterion::FixedLength(n) => self.len >= usize::from(n),
                EndCriterion::EndChars { first, second } => match second {
                    None => byte == first,
                    Some(second) => {
                        let ends = self.first_end_seen && byte == second;
                        self.first_end_seen = byte == first;
                        ends
                    }
                },
            },
        };
        if ends {
            self.reset();
        }
        ends
    }

    /// 003 6.3: STX (connection request), DLE (positive acknowledgement) and NAK (negative) are
    /// frames of one byte; a telegram's data has DLE doubled and ends with DLE ETX, followed by
    /// the BCC in 3964R: where it ends is the [`Deframer`]'s answer, the one the 3964(R) engine
    /// receives with (it keeps no user data here: only the end is wanted).
    fn push_3964(&mut self, byte: u8, with_bcc: bool) -> bool {
        if self.len == 1 && !self.expect_telegram && matches!(byte, STX | DLE | NAK) {
            return true;
        }
        self.expect_telegram = false;
        let variant = if with_bcc {
            Variant::P3964R
        } else {
            Variant::P3964
        };
        let telegram = self
            .telegram
            .get_or_insert_with(|| Deframer::new(variant, 0));
        telegram.push(byte) == Progress::Complete
    }
}

/// What a frame is worth.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Verdict {
    /// A well-formed frame with a good checksum (or one that has none).
    Ok,
    /// A Modbus exception answer (well-formed, CRC/LRC good).
    Exception,
    /// A protocol control character (3964(R) STX, DLE, NAK).
    Control,
    /// The CRC, LRC or BCC does not match.
    BadChecksum,
    /// Too short, no end mark, not hex: not a frame of the protocol.
    Malformed,
    /// The UART reported a parity or framing error, an overrun or a BREAK inside the frame.
    LineError,
    /// Bytes of a line without a protocol.
    Raw,
}

// === impl Verdict ===

impl Verdict {
    /// The verdict's name in the monitor's JSON and in capture comments.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Ok => "ok",
            Self::Exception => "exception",
            Self::Control => "control",
            Self::BadChecksum => "bad-checksum",
            Self::Malformed => "malformed",
            Self::LineError => "line-error",
            Self::Raw => "raw",
        }
    }
}

/// A frame's verdict and one-line summary.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Description {
    /// What the frame is worth.
    pub verdict: Verdict,
    /// What it says, e.g. `slave 1 read holding registers start 0 quantity 10, CRC ok`.
    pub summary: String,
}

/// Describes a frame of a line of `kind` that went `direction`; `line_errors` is how many line
/// errors the UART reported inside it (they make the verdict [`Verdict::LineError`]).
pub fn describe(
    kind: FrameKind,
    direction: Direction,
    bytes: &[u8],
    line_errors: usize,
) -> Description {
    let mut d = match kind {
        FrameKind::Raw => Description {
            verdict: Verdict::Raw,
            summary: format!("{} bytes", bytes.len()),
        },
        FrameKind::ModbusRtu(role) => describe_rtu(is_request(role, direction), bytes),
        FrameKind::ModbusAscii(role) => describe_ascii(is_request(role, direction), bytes),
        FrameKind::Proc3964 { bcc } => describe_3964(bytes, bcc),
        FrameKind::Telegram(end) => describe_telegram(end, bytes),
    };
    if line_errors > 0 {
        let _ = write!(d.summary, "; {line_errors} line error(s) inside");
        d.verdict = Verdict::LineError;
    }
    d
}

/// Whether a frame is a request: `Some` from the role, `None` when only its shape can tell.
const fn is_request(role: Role, direction: Direction) -> Option<bool> {
    match (role, direction) {
        (Role::Master, Direction::Tx) | (Role::Slave, Direction::Rx) => Some(true),
        (Role::Master, Direction::Rx) | (Role::Slave, Direction::Tx) => Some(false),
        (Role::Listener, _) | (_, Direction::A | Direction::B) => None,
    }
}

/// 003 6.4.3: address, function code and data, CRC-16 low byte first.
fn describe_rtu(request: Option<bool>, bytes: &[u8]) -> Description {
    let Some((body, crc)) = bytes
        .len()
        .checked_sub(2)
        .filter(|&n| n >= 2)
        .map(|n| bytes.split_at(n))
    else {
        return Description {
            verdict: Verdict::Malformed,
            summary: format!("{} bytes: too short for a Modbus RTU frame", bytes.len()),
        };
    };
    let good = crc16_modbus(body).to_le_bytes() == [crc[0], crc[1]];
    modbus_adu(request, body, if good { "CRC ok" } else { "CRC bad" }, good)
}

/// 003 6.4.2.2: `:`, address, function code and data as hex pairs, LRC, CR LF.
fn describe_ascii(request: Option<bool>, bytes: &[u8]) -> Description {
    let malformed = |why: &str| Description {
        verdict: Verdict::Malformed,
        summary: format!("{} bytes: {why}", bytes.len()),
    };
    let Some(hex) = bytes
        .strip_prefix(b":")
        .and_then(|rest| rest.strip_suffix(b"\r\n"))
    else {
        return malformed("not ':' .. CR LF");
    };
    if hex.len() % 2 != 0 {
        return malformed("an odd number of hex digits");
    }
    let mut binary = Vec::with_capacity(hex.len() / 2);
    for pair in hex.chunks_exact(2) {
        match (hex_digit(pair[0]), hex_digit(pair[1])) {
            (Some(hi), Some(lo)) => binary.push(hi << 4 | lo),
            _ => return malformed("not hex"),
        }
    }
    let Some((&sum, body)) = binary.split_last().filter(|(_, body)| body.len() >= 2) else {
        return malformed("too short for a Modbus ASCII frame");
    };
    let good = lrc(body) == sum;
    modbus_adu(request, body, if good { "LRC ok" } else { "LRC bad" }, good)
}

fn hex_digit(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'A'..=b'F' => Some(c - b'A' + 10),
        b'a'..=b'f' => Some(c - b'a' + 10),
        _ => None,
    }
}

/// Address and PDU (at least two bytes), with the checksum's word.
fn modbus_adu(request: Option<bool>, body: &[u8], check: &str, good: bool) -> Description {
    let (address, pdu) = (body[0], &body[1..]);
    let function = pdu[0];
    let data = &pdu[1..];
    let request = request.unwrap_or_else(|| looks_like_request(function, data));
    let mut summary = format!("slave {address} ");
    let exception = function & 0x80 != 0;
    if exception {
        let code = data.first().copied().unwrap_or(0);
        let _ = write!(
            summary,
            "{} exception {code:02X}h ({})",
            function_name(function & 0x7F),
            exception_name(code)
        );
    } else if request {
        request_summary(&mut summary, function, data);
    } else {
        response_summary(&mut summary, function, data);
    }
    let _ = write!(summary, ", {check}");
    let verdict = match (good, exception) {
        (false, _) => Verdict::BadChecksum,
        (true, true) => Verdict::Exception,
        (true, false) => Verdict::Ok,
    };
    Description { verdict, summary }
}

/// Without the role: a read request has exactly start and quantity; an answer has a byte count.
fn looks_like_request(function: u8, data: &[u8]) -> bool {
    match function {
        1..=4 => data.len() == 4,
        15 | 16 | 23 => data.len() > 4,
        _ => true,
    }
}

fn word(data: &[u8], at: usize) -> Option<u16> {
    Some(u16::from_be_bytes([*data.get(at)?, *data.get(at + 1)?]))
}

fn request_summary(out: &mut String, function: u8, data: &[u8]) {
    let name = function_name(function);
    let _ = match (function, word(data, 0), word(data, 2)) {
        (1..=4 | 15 | 16, Some(start), Some(quantity)) => {
            write!(out, "{name} start {start} quantity {quantity}")
        }
        (5 | 6, Some(address), Some(value)) => write!(out, "{name} address {address} value {value:04X}h"),
        (8, Some(sub), _) => write!(out, "{name} sub-function {sub}"),
        (23, Some(start), Some(quantity)) => match (word(data, 4), word(data, 6)) {
            (Some(wstart), Some(wquantity)) => write!(
                out,
                "{name} read start {start} quantity {quantity}, write start {wstart} quantity {wquantity}"
            ),
            _ => write!(out, "{name}, {} data bytes", data.len()),
        },
        _ => write!(out, "{name}, {} data bytes", data.len()),
    };
}

fn response_summary(out: &mut String, function: u8, data: &[u8]) {
    let name = function_name(function);
    let _ = match (function, data.first()) {
        (3 | 4 | 23, Some(&count)) => write!(out, "{name} answer, {} registers", count / 2),
        (1 | 2, Some(&count)) => write!(out, "{name} answer, {count} bytes of bits"),
        (5 | 6 | 15 | 16, _) => match (word(data, 0), word(data, 2)) {
            (Some(a), Some(b)) => write!(out, "{name} answer, {a} / {b}"),
            _ => write!(out, "{name} answer, {} data bytes", data.len()),
        },
        _ => write!(out, "{name} answer, {} data bytes", data.len()),
    };
}

/// The public function codes' names (Modbus Application Protocol V1.1b3, 6).
fn function_name(function: u8) -> String {
    let name = match function {
        1 => "read coils",
        2 => "read discrete inputs",
        3 => "read holding registers",
        4 => "read input registers",
        5 => "write single coil",
        6 => "write single register",
        8 => "diagnostics",
        15 => "write multiple coils",
        16 => "write multiple registers",
        23 => "read/write multiple registers",
        other => return format!("function {other}"),
    };
    name.into()
}

/// The exception codes' names (Modbus Application Protocol V1.1b3, 7).
const fn exception_name(code: u8) -> &'static str {
    match code {
        1 => "illegal function",
        2 => "illegal data address",
        3 => "illegal data value",
        4 => "server device failure",
        5 => "acknowledge",
        6 => "server device busy",
        10 => "gateway path unavailable",
        11 => "gateway target failed to respond",
        _ => "unknown",
    }
}

/// 003 6.3: a control character, or a telegram (DLE doubled) ending DLE ETX [BCC].
fn describe_3964(bytes: &[u8], with_bcc: bool) -> Description {
    let control = |name: &str| Description {
        verdict: Verdict::Control,
        summary: name.into(),
    };
    match bytes {
        [STX] => return control("STX (connection request)"),
        [DLE] => return control("DLE (positive acknowledgement)"),
        [NAK] => return control("NAK (negative acknowledgement)"),
        _ => {}
    }
    let (frame, sum) = if with_bcc {
        match bytes.split_last() {
            Some((&sum, frame)) => (frame, Some(sum)),
            None => (bytes, None),
        }
    } else {
        (bytes, None)
    };
    let Some(data) = frame.strip_suffix(&[DLE, ETX]) else {
        return Description {
            verdict: Verdict::Malformed,
            summary: format!("{} bytes without DLE ETX (ended by silence)", bytes.len()),
        };
    };
    let len = undoubled_len(data);
    match sum {
        None => Description {
            verdict: Verdict::Ok,
            summary: format!("telegram, {len} data bytes"),
        },
        Some(sum) => {
            let expected = bcc(frame);
            if sum == expected {
                Description {
                    verdict: Verdict::Ok,
                    summary: format!("telegram, {len} data bytes, BCC ok"),
                }
            } else {
                Description {
                    verdict: Verdict::BadChecksum,
                    summary: format!(
                        "telegram, {len} data bytes, BCC bad ({sum:02X}h, expected {expected:02X}h)"
                    ),
                }
            }
        }
    }
}

/// Data bytes of a telegram body with each doubled DLE counted once.
fn undoubled_len(data: &[u8]) -> usize {
    let mut len = 0;
    let mut dle = false;
    for &b in data {
        if dle {
            dle = false;
            continue;
        }
        dle = b == DLE;
        len += 1;
    }
    len
}

/// 003 6.2: a telegram and how it ended.
fn describe_telegram(end: EndCriterion, bytes: &[u8]) -> Description {
    let ended = match end {
        EndCriterion::CharacterDelay => "ended by the character delay time",
        EndCriterion::FixedLength(n) if bytes.len() >= usize::from(n) => {
            "ended at its fixed length"
        }
        EndCriterion::FixedLength(_) => "shorter than its fixed length (ended by silence)",
        EndCriterion::EndChars { first, second } => {
            let by_end = match second {
                None => bytes.last() == Some(&first),
                Some(second) => bytes.ends_with(&[first, second]),
            };
            if by_end {
                "ended by its end character(s)"
            } else {
                "no end character (ended by silence)"
            }
        }
    };
    let verdict = if ended.contains("silence") {
        Verdict::Malformed
    } else {
        Verdict::Ok
    };
    Description {
        verdict,
        summary: format!(
            "telegram, {} bytes, {ended}: {}",
            bytes.len(),
            printable(bytes)
        ),
    }
}

/// Up to 32 bytes as text, other bytes as `<hh>`.
fn printable(bytes: &[u8]) -> String {
    let mut out = String::new();
    for &b in bytes.iter().take(32) {
        if b.is_ascii_graphic() || b == b' ' {
            out.push(char::from(b));
        } else {
            let _ = write!(out, "<{b:02X}>");
        }
    }
    if bytes.len() > 32 {
        out.push_str("...");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rtu(body: &[u8]) -> Vec<u8> {
        let mut frame = body.to_vec();
        frame.extend_from_slice(&crc16_modbus(body).to_le_bytes());
        frame
    }

    #[test]
    fn rtu_read_request_and_answer_as_the_master_sees_them() {
        // Modbus Application Protocol 6.3: read holding registers 108..110 of slave 17.
        let request = [0x11, 0x03, 0x00, 0x6B, 0x00, 0x03, 0x76, 0x87];
        let d = describe(
            FrameKind::ModbusRtu(Role::Master),
            Direction::Tx,
            &request,
            0,
        );
        assert_eq!(d.verdict, Verdict::Ok);
        assert_eq!(
            d.summary,
            "slave 17 read holding registers start 107 quantity 3, CRC ok"
        );

        let answer = rtu(&[0x11, 0x03, 0x06, 0x02, 0x2B, 0x00, 0x00, 0x00, 0x64]);
        let d = describe(
            FrameKind::ModbusRtu(Role::Master),
            Direction::Rx,
            &answer,
            0,
        );
        assert_eq!(d.verdict, Verdict::Ok);
        assert_eq!(
            d.summary,
            "slave 17 read holding registers answer, 3 registers, CRC ok"
        );
    }

    #[test]
    fn rtu_exception_bad_crc_and_short_frames() {
        let exception = rtu(&[0x01, 0x83, 0x02]);
        let d = describe(
            FrameKind::ModbusRtu(Role::Master),
            Direction::Rx,
            &exception,
            0,
        );
        assert_eq!(d.verdict, Verdict::Exception);
        assert_eq!(
            d.summary,
            "slave 1 read holding registers exception 02h (illegal data address), CRC ok"
        );

        let mut bad = rtu(&[0x01, 0x06, 0x00, 0x10, 0x12, 0x34]);
        bad[5] ^= 0xFF;
        let d = describe(FrameKind::ModbusRtu(Role::Slave), Direction::Rx, &bad, 0);
        assert_eq!(d.verdict, Verdict::BadChecksum);
        assert_eq!(
            d.summary,
            "slave 1 write single register address 16 value 12CBh, CRC bad"
        );

        let d = describe(
            FrameKind::ModbusRtu(Role::Master),
            Direction::Rx,
            &[0x01, 0x03, 0x00],
            0,
        );
        assert_eq!(d.verdict, Verdict::Malformed);
        let d = describe(FrameKind::ModbusRtu(Role::Master), Direction::Rx, &[], 0);
        assert_eq!(d.verdict, Verdict::Malformed);
    }

    #[test]
    fn a_listener_tells_requests_from_answers_by_their_shape() {
        let request = rtu(&[0x02, 0x04, 0x00, 0x00, 0x00, 0x02]);
        let answer = rtu(&[0x02, 0x04, 0x04, 0x00, 0x01, 0x00, 0x02]);
        let kind = FrameKind::ModbusRtu(Role::Listener);
        assert_eq!(
            describe(kind, Direction::Rx, &request, 0).summary,
            "slave 2 read input registers start 0 quantity 2, CRC ok"
        );
        assert_eq!(
            describe(kind, Direction::Rx, &answer, 0).summary,
            "slave 2 read input registers answer, 2 registers, CRC ok"
        );
    }

    #[test]
    fn a_line_error_inside_a_frame_is_the_verdict() {
        let request = rtu(&[0x01, 0x03, 0x00, 0x00, 0x00, 0x01]);
        let d = describe(
            FrameKind::ModbusRtu(Role::Master),
            Direction::Rx,
            &request,
            1,
        );
        assert_eq!(d.verdict, Verdict::LineError);
        assert!(
            d.summary.ends_with("CRC ok; 1 line error(s) inside"),
            "{}",
            d.summary
        );
    }

    #[test]
    fn modbus_ascii_frames_with_good_and_bad_lrc() {
        // Slave 1, read holding registers 0..1: 01 03 00 00 00 01, LRC FB.
        let good = b":010300000001FB\r\n";
        let d = describe(FrameKind::ModbusAscii(Role::Master), Direction::Tx, good, 0);
        assert_eq!(d.verdict, Verdict::Ok);
        assert_eq!(
            d.summary,
            "slave 1 read holding registers start 0 quantity 1, LRC ok"
        );
        let bad = b":010300000001FC\r\n";
        let d = describe(FrameKind::ModbusAscii(Role::Master), Direction::Tx, bad, 0);
        assert_eq!(d.verdict, Verdict::BadChecksum);
        let d = describe(
            FrameKind::ModbusAscii(Role::Master),
            Direction::Tx,
            b":01G3\r\n",
            0,
        );
        assert_eq!(d.verdict, Verdict::Malformed);
    }

    #[test]
    fn proc3964_control_characters_and_telegrams() {
        let kind = FrameKind::Proc3964 { bcc: true };
        assert_eq!(
            describe(kind, Direction::Rx, &[STX], 0).verdict,
            Verdict::Control
        );
        assert_eq!(
            describe(kind, Direction::Tx, &[DLE], 0).summary,
            "DLE (positive acknowledgement)"
        );
        assert_eq!(
            describe(kind, Direction::Rx, &[NAK], 0).verdict,
            Verdict::Control
        );

        // "A" DLE "B" with the DLE doubled, DLE ETX, BCC over all of it.
        let mut telegram = vec![b'A', DLE, DLE, b'B', DLE, ETX];
        telegram.push(bcc(&telegram));
        let d = describe(kind, Direction::Rx, &telegram, 0);
        assert_eq!(d.verdict, Verdict::Ok);
        assert_eq!(d.summary, "telegram, 3 data bytes, BCC ok");

        let last = telegram.len() - 1;
        telegram[last] ^= 0x01;
        let d = describe(kind, Direction::Rx, &telegram, 0);
        assert_eq!(d.verdict, Verdict::BadChecksum);

        let d = describe(
            FrameKind::Proc3964 { bcc: false },
            Direction::Rx,
            b"AB\x10\x03",
            0,
        );
        assert_eq!(d.summary, "telegram, 2 data bytes");
        let d = describe(kind, Direction::Rx, b"AB", 0);
        assert_eq!(d.verdict, Verdict::Malformed);
    }

    #[test]
    fn ascii_telegrams_and_how_they_ended() {
        let end = EndCriterion::EndChars {
            first: b'\r',
            second: Some(b'\n'),
        };
        let d = describe(FrameKind::Telegram(end), Direction::Rx, b"T=21.5\r\n", 0);
        assert_eq!(d.verdict, Verdict::Ok);
        assert_eq!(
            d.summary,
            "telegram, 8 bytes, ended by its end character(s): T=21.5<0D><0A>"
        );
        let d = describe(FrameKind::Telegram(end), Direction::Rx, b"T=21", 0);
        assert_eq!(d.verdict, Verdict::Malformed);
        let d = describe(
            FrameKind::Telegram(EndCriterion::FixedLength(4)),
            Direction::Rx,
            b"ABCD",
            0,
        );
        assert_eq!(
            d.summary,
            "telegram, 4 bytes, ended at its fixed length: ABCD"
        );
    }

    /// A byte every 100 µs, well inside the cutters' gap.
    fn cut(cutter: &mut FrameCutter, bytes: &[u8]) -> Vec<usize> {
        bytes
            .iter()
            .enumerate()
            .filter_map(|(i, &b)| {
                let at = Instant::from_micros(100 * i as u64);
                cutter.push(at, b).then_some(i)
            })
            .collect()
    }

    const GAP: Duration = Duration::from_millis(2);

    #[test]
    fn the_3964r_cutter_ends_control_characters_and_telegrams() {
        let mut c = FrameCutter::new(FrameKind::Proc3964 { bcc: true }, GAP);
        // The partner's STX is a frame; after our DLE its telegram (starting with a doubled
        // DLE) ends after DLE ETX BCC.
        assert_eq!(cut(&mut c, &[STX]), [0]);
        c.sent(&[DLE]);
        let mut telegram = vec![DLE, DLE, b'x', DLE, ETX];
        telegram.push(bcc(&telegram));
        assert_eq!(cut(&mut c, &telegram), [5]);
        // The partner's acknowledgements of our STX and our telegram, and a NAK.
        c.sent(&[STX]);
        assert_eq!(cut(&mut c, &[DLE, NAK]), [0, 1]);
    }

    #[test]
    fn the_3964_cutter_without_bcc_ends_at_dle_etx() {
        let mut c = FrameCutter::new(FrameKind::Proc3964 { bcc: false }, GAP);
        assert_eq!(cut(&mut c, b"ab\x10\x03cd\x10\x03"), [3, 7]);
    }

    #[test]
    fn modbus_ascii_and_end_character_cutters() {
        let mut c = FrameCutter::new(FrameKind::ModbusAscii(Role::Master), GAP);
        assert_eq!(cut(&mut c, b":0103\r\n:01\r\n"), [6, 11]);
        let end = EndCriterion::EndChars {
            first: b'\r',
            second: None,
        };
        let mut c = FrameCutter::new(FrameKind::Telegram(end), GAP);
        assert_eq!(cut(&mut c, b"ab\rcd\r"), [2, 5]);
        let mut c = FrameCutter::new(FrameKind::Telegram(EndCriterion::FixedLength(3)), GAP);
        assert_eq!(cut(&mut c, b"abcdefg"), [2, 5]);
    }

    #[test]
    fn a_frame_ends_a_gap_after_its_last_byte_or_line_error() {
        let at = Instant::from_micros;
        let mut c = FrameCutter::new(FrameKind::ModbusRtu(Role::Master), GAP);
        assert_eq!(c.deadline(), None);
        assert!(!c.push(at(1000), 1));
        assert!(!c.push(at(1500), 3));
        assert_eq!(c.deadline(), Some(at(1500) + GAP));
        assert!(!c.expire(at(1499) + GAP));
        assert!(c.expire(at(1500) + GAP));
        assert_eq!(c.deadline(), None);
        // A line error begins a frame of its own, ended by the same silence.
        c.line_error(at(10_000));
        assert_eq!(c.deadline(), Some(at(10_000) + GAP));
        // An end mark ends the frame at once: no silence is waited for.
        let mut c = FrameCutter::new(FrameKind::ModbusAscii(Role::Master), GAP);
        assert!(!c.push(at(0), b'\r'));
        assert!(c.push(at(100), b'\n'));
        assert_eq!(c.deadline(), None);
    }

    #[test]
    fn the_gap_is_the_framings_or_three_and_a_half_characters() {
        let char_time = Duration::from_micros(1146); // 9600 Bd, 11 bits
        assert_eq!(Framing::RAW.silence(char_time), Duration::from_micros(4011));
        let framing = Framing {
            kind: FrameKind::Raw,
            gap: Some(Duration::from_millis(50)),
        };
        assert_eq!(framing.silence(char_time), Duration::from_millis(50));
        assert_eq!(
            Framing::RAW.silence(Duration::from_micros(10)),
            Duration::from_micros(100)
        );
    }

    #[test]
    fn rtu_and_raw_frames_end_only_by_silence() {
        let mut c = FrameCutter::new(FrameKind::ModbusRtu(Role::Master), GAP);
        assert!(cut(&mut c, &[1, 3, 0, 0, 0, 1, 0x84, 0x0A]).is_empty());
        let mut c = FrameCutter::new(FrameKind::Raw, GAP);
        assert!(cut(&mut c, b"\r\n\x10\x03").is_empty());
    }
}
