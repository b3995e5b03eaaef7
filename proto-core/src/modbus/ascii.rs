//! Modbus ASCII framing (manual 003, 6.4.2.2 and 6.4.4): ':' start, hex, LRC, CR LF.
//!
//! A frame is `':' hex(address PDU LRC) CR LF`, every byte as two hex characters, the LRC over the
//! binary address and PDU (Modbus over Serial Line V1.02, 2.5.2). [`encode_frame`] writes upper-case
//! hex, and [`decode_frame`] takes nothing else: 003 7.2 0E 58h names every character other than
//! 0-9 and A-F an invalid character. [`AsciiFrameAssembler`] cuts a byte stream into
//! frames and reports what it throws away: a wrong start character (003 7.2, 08 33h), a ':' inside
//! a frame (08 34h), a frame longer than the specification allows.
//!
//! The CP's optional 32-bit register mode (003 6.4.2.2 "with 32-Bit Register", 6.4.4) uses this
//! framing unchanged; its PDUs are in [`crate::modbus::master::Request32`].

use super::FrameError;
use crate::checksum::lrc;

/// The start character (003 6.4.2.2; Modbus over Serial Line V1.02, 2.5.2.1: ':' = 3Ah).
pub const COLON: u8 = b':';
/// The first end character (carriage return, 0Dh).
pub const CR: u8 = b'\r';
/// The second end character (line feed, 0Ah).
pub const LF: u8 = b'\n';

/// The longest ASCII frame in characters (Modbus over Serial Line V1.02, 2.5.2.1: 513, i.e.
/// ':' + 2 x 255 + CR LF).
pub const MAX_FRAME_CHARS: usize = 513;
/// The shortest ASCII frame: ':' + address, function code and LRC as hex + CR LF.
pub const MIN_FRAME_CHARS: usize = 9;

const HEX_DIGITS: &[u8; 16] = b"0123456789ABCDEF";

/// Appends the two upper-case hex characters of `byte`.
fn push_hex(out: &mut Vec<u8>, byte: u8) {
    for nibble in [byte >> 4, byte & 0x0F] {
        out.push(HEX_DIGITS.get(usize::from(nibble)).copied().unwrap_or(b'0'));
    }
}

/// The value of one hex character: 0-9 and A-F only (003 7.2 0E 58h: "A received character within
/// the reply message is not an ASCII character (0...9, A...F)"; lower case is such a character).
const fn hex_value(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'A'..=b'F' => Some(c - b'A' + 10),
        _ => None,
    }
}

/// Appends an ASCII frame: ':' + upper-case hex of address, PDU and LRC + CR LF.
pub fn encode_frame(address: u8, pdu: &[u8], out: &mut Vec<u8>) {
    // The LRC of the concatenation is the sum of the parts' LRCs (all modulo 256).
    let check = lrc(&[address]).wrapping_add(lrc(pdu));
    out.reserve(1 + 2 * (pdu.len() + 2) + 2);
    out.push(COLON);
    push_hex(out, address);
    for &byte in pdu {
        push_hex(out, byte);
    }
    push_hex(out, check);
    out.push(CR);
    out.push(LF);
}

/// Checks a complete frame (':' up to and including CR LF) and returns the address and the PDU.
///
/// Errors, in the order checked: length ([`FrameError::TooShort`], [`FrameError::TooLong`]),
/// [`FrameError::MissingStart`], [`FrameError::MissingEnd`], [`FrameError::BadHexDigit`] (with
/// its position in the frame), [`FrameError::OddHexLength`], [`FrameError::BadLrc`].
pub fn decode_frame(frame: &[u8]) -> Result<(u8, Vec<u8>), FrameError> {
    let len = frame.len();
    if len > MAX_FRAME_CHARS {
        return Err(FrameError::TooLong {
            len,
            max: MAX_FRAME_CHARS,
        });
    }
    let Some((&start, rest)) = frame.split_first() else {
        return Err(FrameError::TooShort {
            len,
            min: MIN_FRAME_CHARS,
        });
    };
    if start != COLON {
        return Err(FrameError::MissingStart);
    }
    let Some(hex) = rest.strip_suffix(&[CR, LF]) else {
        return Err(FrameError::MissingEnd);
    };
    let mut bytes = Vec::with_capacity(hex.len() / 2);
    for (i, pair) in hex.chunks(2).enumerate() {
        let position = 1 + 2 * i;
        let mut value = 0u8;
        for (j, &c) in pair.iter().enumerate() {
            let digit = hex_value(c).ok_or(FrameError::BadHexDigit {
                position: position + j,
                byte: c,
            })?;
            value = (value << 4) | digit;
        }
        if pair.len() != 2 {
            return Err(FrameError::OddHexLength);
        }
        bytes.push(value);
    }
    if len < MIN_FRAME_CHARS {
        return Err(FrameError::TooShort {
            len,
            min: MIN_FRAME_CHARS,
        });
    }
    let Some((&actual, body)) = bytes.split_last() else {
        return Err(FrameError::TooShort {
            len,
            min: MIN_FRAME_CHARS,
        });
    };
    let expected = lrc(body);
    if expected != actual {
        return Err(FrameError::BadLrc { expected, actual });
    }
    match body.split_first() {
        Some((&address, pdu)) => Ok((address, pdu.to_vec())),
        None => Err(FrameError::TooShort {
            len,
            min: MIN_FRAME_CHARS,
        }),
    }
}

/// What [`AsciiFrameAssembler`] makes of the bytes fed to it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum AsciiEvent {
    /// A complete frame from ':' up to and including LF, for [`decode_frame`].
    Frame(Vec<u8>),
    /// A byte other than ':' where a frame should start (003 7.2, 08 33h). Reported once for the
    /// first byte of a run; the run up to the next ':' is dropped and counted in
    /// [`AsciiFrameAssembler::discarded`].
    WrongStart { byte: u8 },
    /// A ':' inside a frame (003 7.2, 08 34h): the first part (`discarded` characters) is thrown
    /// away and reception starts again with the new ':'.
    Restarted { discarded: usize },
    /// The frame grew past [`MAX_FRAME_CHARS`] without its LF: the `discarded` characters are
    /// thrown away and the assembler waits for the next ':'.
    Overflow { discarded: usize },
}

/// Cuts a stream of received bytes into ASCII frames: ':' starts (and restarts) a frame, LF ends
/// it. A frame ended by LF without CR is handed out all the same; [`decode_frame`] then reports
/// [`FrameError::MissingEnd`], so nothing is dropped without a word.
///
/// The character delay time (003 6.4.2.2) is the engine's: when it expires inside a frame, the
/// engine calls [`AsciiFrameAssembler::reset`].
#[derive(Clone, Debug, Default)]
pub struct AsciiFrameAssembler {
    /// The frame being received, from its ':'; empty between frames.
    buf: Vec<u8>,
    /// Whether the previous byte was a wrong start character (suppresses repeated reports).
    in_junk: bool,
    /// Bytes thrown away since creation, for every reason.
    discarded: u64,
}

// === impl AsciiFrameAssembler ===

impl AsciiFrameAssembler {
    /// An assembler waiting for ':'.
    pub fn new() -> Self {
        Self::default()
    }

    /// Takes one byte; returns what it completed or threw away, if anything.
    pub fn push(&mut self, byte: u8) -> Option<AsciiEvent> {
        if byte == COLON {
            self.in_junk = false;
            let discarded = self.buf.len();
            self.buf.clear();
            self.buf.push(COLON);
            if discarded > 0 {
                self.count(discarded);
                return Some(AsciiEvent::Restarted { discarded });
            }
            return None;
        }
        if self.buf.is_empty() {
            self.count(1);
            if self.in_junk {
                return None;
            }
            self.in_junk = true;
            return Some(AsciiEvent::WrongStart { byte });
        }
        self.buf.push(byte);
        if byte == LF {
            return Some(AsciiEvent::Frame(core::mem::take(&mut self.buf)));
        }
        if self.buf.len() >= MAX_FRAME_CHARS {
            let discarded = self.buf.len();
            self.buf.clear();
            self.count(discarded);
            // The rest of the overlong frame is junk up to the next ':', reported here once.
            self.in_junk = true;
            return Some(AsciiEvent::Overflow { discarded });
        }
        None
    }

    /// Takes a chunk of bytes and appends the events to `events`.
    pub fn feed(&mut self, bytes: &[u8], events: &mut Vec<AsciiEvent>) {
        events.extend(bytes.iter().filter_map(|&b| self.push(b)));
    }

    /// Drops a partial frame (the character delay time expired) and returns how many characters
    /// it held.
    pub fn reset(&mut self) -> usize {
        let discarded = self.buf.len();
        self.buf.clear();
        self.in_junk = false;
        self.count(discarded);
        discarded
    }

    /// Whether a frame has started and not yet ended.
    pub fn in_frame(&self) -> bool {
        !self.buf.is_empty()
    }

    /// How many characters the partial frame holds.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }

    /// Bytes thrown away since creation (wrong start characters, restarted, overlong and reset
    /// frames).
    pub fn discarded(&self) -> u64 {
        self.discarded
    }

    fn count(&mut self, n: usize) {
        self.discarded = self
            .discarded
            .saturating_add(u64::try_from(n).unwrap_or(u64::MAX));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encodes_spec_example() {
        // Modbus over Serial Line V1.02 style: slave 11h, FC03, 006Bh, 3 registers, LRC 7E.
        let mut out = Vec::new();
        encode_frame(0x11, &[0x03, 0x00, 0x6B, 0x00, 0x03], &mut out);
        assert_eq!(out, b":1103006B00037E\r\n");
        assert_eq!(
            decode_frame(&out),
            Ok((0x11, vec![0x03, 0x00, 0x6B, 0x00, 0x03]))
        );
        // Lower-case hex is an invalid character (003 7.2 0E 58h).
        assert_eq!(
            decode_frame(b":1103006b00037e\r\n"),
            Err(FrameError::BadHexDigit {
                position: 8,
                byte: b'b'
            })
        );
    }

    #[test]
    fn decode_errors() {
        assert_eq!(
            decode_frame(b""),
            Err(FrameError::TooShort { len: 0, min: 9 })
        );
        assert_eq!(
            decode_frame(b"1103006B00037E\r\n"),
            Err(FrameError::MissingStart)
        );
        assert_eq!(
            decode_frame(b":1103006B00037E\r"),
            Err(FrameError::MissingEnd)
        );
        assert_eq!(
            decode_frame(b":1103006B00037E\n"),
            Err(FrameError::MissingEnd)
        );
        assert_eq!(
            decode_frame(b":1103006G00037E\r\n"),
            Err(FrameError::BadHexDigit {
                position: 8,
                byte: b'G'
            })
        );
        assert_eq!(
            decode_frame(b":1103006b00037E\r\n"),
            Err(FrameError::BadHexDigit {
                position: 8,
                byte: b'b'
            })
        );
        assert_eq!(
            decode_frame(b":1103006B00037\r\n"),
            Err(FrameError::OddHexLength)
        );
        assert_eq!(
            decode_frame(b":1103006B00037F\r\n"),
            Err(FrameError::BadLrc {
                expected: 0x7E,
                actual: 0x7F
            })
        );
        assert_eq!(
            decode_frame(b":1100\r\n"),
            Err(FrameError::TooShort { len: 7, min: 9 })
        );
        let mut long = vec![COLON];
        long.extend(std::iter::repeat_n(b'0', 512));
        long.extend([CR, LF]);
        assert_eq!(
            decode_frame(&long),
            Err(FrameError::TooLong { len: 515, max: 513 })
        );
    }

    #[test]
    fn assembler_cuts_frames_and_reports_junk() {
        let mut a = AsciiFrameAssembler::new();
        let mut events = Vec::new();
        a.feed(b"xy:11\r\n:0102:1103006B00037E\r", &mut events);
        assert!(a.in_frame());
        a.feed(b"\n", &mut events);
        assert_eq!(
            events,
            [
                AsciiEvent::WrongStart { byte: b'x' },
                AsciiEvent::Frame(b":11\r\n".to_vec()),
                AsciiEvent::Restarted { discarded: 5 },
                AsciiEvent::Frame(b":1103006B00037E\r\n".to_vec()),
            ]
        );
        assert!(!a.in_frame());
        assert_eq!(a.discarded(), 2 + 5);
        a.feed(b":12", &mut events);
        assert_eq!(a.pending(), 3);
        assert_eq!(a.reset(), 3);
        assert_eq!(a.discarded(), 10);
    }

    #[test]
    fn assembler_bounds_a_frame() {
        let mut a = AsciiFrameAssembler::new();
        let mut events = Vec::new();
        a.push(COLON);
        a.feed(&[b'0'; 600], &mut events);
        assert_eq!(events, [AsciiEvent::Overflow { discarded: 513 }]);
        assert!(!a.in_frame());
        assert_eq!(a.discarded(), 600 + 1);
    }
}
