//! Modbus RTU framing (manual 003, 6.4.3 "Message structure"; Modbus over Serial Line V1.02, 2.5.1).
//!
//! An RTU frame (ADU) is `address | PDU | CRC` with the CRC-16/Modbus low byte first. Frames are
//! delimited by silence: 3.5 character times end a frame (003 6.4.3), which [`CharTiming`]
//! computes. Where the function code and byte counts tell the frame's length,
//! [`expected_request_len`] and [`expected_response_len`] let a receiver check a frame ended by
//! silence against it: a frame longer than announced carries trailing bytes.

use core::time::Duration;

use super::FrameError;
use crate::checksum::crc16_modbus;
use crate::codec::Writer;

pub mod framer;

pub use framer::{DiscardReason, SilenceFramer};

/// The largest RTU ADU of the specification: 256 bytes (Modbus over Serial Line V1.02, 2.5.1.1:
/// address 1 + PDU 253 + CRC 2).
pub const MAX_ADU_LEN: usize = 256;

/// The largest frame [`decode_frame`] accepts: 264 bytes. The CP 341 master's limits (003 6.4.4:
/// 2040 coils, 127 registers) exceed the specification's 256 bytes: FC 15 with 2040 coils is
/// address 1 + function 1 + address 2 + quantity 2 + byte count 1 + 255 data + CRC 2 = 264 bytes,
/// and the answer to FC 03 with 127 registers is 1 + 1 + 1 + 254 + 2 = 259 bytes.
pub const MAX_FRAME_LEN: usize = 264;

/// The smallest RTU frame: address, function code and CRC.
pub const MIN_FRAME_LEN: usize = 4;

/// The end-of-frame silence above 19200 Bd (Modbus over Serial Line V1.02, 2.5.1.1: "a fixed value
/// of 1.75 ms for the inter-frame delay (t3.5)").
const FIXED_T35: Duration = Duration::from_micros(1750);
/// The inter-character timeout above 19200 Bd (same section: "750 µs for the inter-character
/// time-out (t1.5)").
const FIXED_T15: Duration = Duration::from_micros(750);
/// The baud rate above which the fixed values apply (same section).
const FIXED_TIMING_ABOVE_BAUD: u32 = 19_200;

/// The CP's "multiplier character delay time" range (003 6.4.2.1: 1 ... 10).
const MULTIPLIER_RANGE: core::ops::RangeInclusive<u8> = 1..=10;

/// The timing of a serial line in RTU mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CharTiming {
    /// The time one character takes on the wire (start, data, parity and stop bits).
    pub char_time: Duration,
    /// The longest silence allowed inside a frame (1.5 character times).
    pub t15: Duration,
    /// The silence that ends a frame (3.5 character times, times the CP multiplier).
    pub t35: Duration,
}

// === impl CharTiming ===

impl CharTiming {
    /// The timing the Modbus over Serial Line specification V1.02 (2.5.1.1) prescribes: 1.5 and
    /// 3.5 character times up to 19200 Bd, fixed 750 µs and 1.75 ms above.
    ///
    /// `bits_per_char` counts start, data, parity and stop bits (RTU: 1 + 8 + 1 + 1 = 11, 003
    /// 6.4.2.1). A zero baud rate or bit count is taken as 1, so the result is always defined.
    pub fn new(baud: u32, bits_per_char: u8) -> Self {
        let exact = Self::exact(baud, bits_per_char);
        if baud > FIXED_TIMING_ABOVE_BAUD {
            Self {
                char_time: exact.char_time,
                t15: FIXED_T15,
                t35: FIXED_T35,
            }
        } else {
            exact
        }
    }

    /// The inter-character timeout t1.5.
    pub const fn t1_5(&self) -> Duration {
        self.t15
    }

    /// The end-of-frame silence t3.5 (multiplier included).
    pub const fn t3_5(&self) -> Duration {
        self.t35
    }

    /// 1.5 and 3.5 character times at every baud rate, as the CP 341 computes them (003 6.4.3:
    /// "76800 -> 0.5 ms, 38400 -> 1 ms, 19200 -> 2 ms, 9600 -> 4 ms ... 300 -> 128 ms").
    pub fn exact(baud: u32, bits_per_char: u8) -> Self {
        let baud = u64::from(baud.max(1));
        let bits = u64::from(bits_per_char.max(1));
        let char_nanos = bits * 1_000_000_000 / baud;
        Self {
            char_time: Duration::from_nanos(char_nanos),
            t15: Duration::from_nanos(char_nanos * 3 / 2),
            t35: Duration::from_nanos(char_nanos * 7 / 2),
        }
    }

    /// Multiplies the end-of-frame silence t3.5 by the CP's "multiplier character delay time"
    /// (003 6.4.2.1: range 1 ... 10, for partners that cannot meet the Modbus timing); values
    /// outside 1..=10 are clamped into it.
    #[must_use]
    pub fn with_multiplier(self, multiplier: u8) -> Self {
        let m = multiplier.clamp(*MULTIPLIER_RANGE.start(), *MULTIPLIER_RANGE.end());
        Self {
            t35: self.t35 * u32::from(m),
            ..self
        }
    }

    /// The time `bytes` characters take on the wire (an estimate of when a transmission ends).
    pub fn transmit_time(&self, bytes: usize) -> Duration {
        self.char_time
            .saturating_mul(u32::try_from(bytes).unwrap_or(u32::MAX))
    }
}

/// A decoded RTU frame, borrowing its PDU from the received bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RtuFrame<'a> {
    /// The slave address (0 = broadcast).
    pub address: u8,
    /// Function code and data, without address and CRC.
    pub pdu: &'a [u8],
}

/// Appends an RTU frame: `address`, `pdu`, CRC-16/Modbus low byte first (003 6.4.3 "CRC-CHECK").
pub fn encode_frame(address: u8, pdu: &[u8], out: &mut Vec<u8>) {
    let start = out.len();
    Writer::new(out).u8(address).bytes(pdu);
    let crc = crc16_modbus(out.get(start..).unwrap_or_default());
    Writer::new(out).u16_le(crc);
}

/// Checks the length and the CRC of a complete frame and splits it into address and PDU.
pub fn decode_frame(frame: &[u8]) -> Result<RtuFrame<'_>, FrameError> {
    let len = frame.len();
    if len < MIN_FRAME_LEN {
        return Err(FrameError::TooShort {
            len,
            min: MIN_FRAME_LEN,
        });
    }
    if len > MAX_FRAME_LEN {
        return Err(FrameError::TooLong {
            len,
            max: MAX_FRAME_LEN,
        });
    }
    let (body, crc) = frame.split_at(len - 2);
    let actual = match crc {
        [lo, hi] => u16::from_le_bytes([*lo, *hi]),
        _ => {
            return Err(FrameError::TooShort {
                len,
                min: MIN_FRAME_LEN,
            })
        }
    };
    let expected = crc16_modbus(body);
    if expected != actual {
        return Err(FrameError::BadCrc { expected, actual });
    }
    match body.split_first() {
        Some((&address, pdu)) => Ok(RtuFrame { address, pdu }),
        None => Err(FrameError::TooShort {
            len,
            min: MIN_FRAME_LEN,
        }),
    }
}

/// What the bytes received so far tell about the frame's total length.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameLen {
    /// At least this many bytes in total are needed before more can be said; always more than
    /// the bytes given.
    NeedMore(usize),
    /// The frame is this many bytes long, address and CRC included (the buffer may hold more:
    /// the rest belongs to the next frame or is noise).
    Complete(usize),
    /// The length cannot be derived (unknown function, FC 08 sub-function 00 with its free-length
    /// echo): the caller ends the frame after the t3.5 silence.
    Unknown,
}

/// Length of the frame at index `at` of `buf` plus `fixed`, or `NeedMore` up to `at`.
fn by_count(buf: &[u8], at: usize, fixed: usize) -> FrameLen {
    match buf.get(at) {
        Some(&count) => finish(buf, fixed + usize::from(count)),
        None => FrameLen::NeedMore(at + 1),
    }
}

/// `Complete(total)` when the buffer holds it, else `NeedMore(total)`.
fn finish(buf: &[u8], total: usize) -> FrameLen {
    if buf.len() >= total {
        FrameLen::Complete(total)
    } else {
        FrameLen::NeedMore(total)
    }
}

/// The total length of the request frame that starts `buf`, as a slave sees it (address, function
/// code and the fields that carry lengths; Modbus Application Protocol V1.1b3, 6).
pub fn expected_request_len(buf: &[u8]) -> FrameLen {
    let Some(&function) = buf.get(1) else {
        return FrameLen::NeedMore(2);
    };
    match function {
        // address, function, 2 x 2 bytes, CRC
        0x01..=0x06 => finish(buf, 8),
        0x07 | 0x0B | 0x0C | 0x11 => finish(buf, 4),
        0x08 => match (buf.get(2), buf.get(3)) {
            (Some(0), Some(0)) => FrameLen::Unknown,
            (Some(_), Some(_)) => finish(buf, 8),
            _ => FrameLen::NeedMore(4),
        },
        // address, function, start, quantity, byte count at index 6, data, CRC
        0x0F | 0x10 => by_count(buf, 6, 9),
        // address, function, read start, read quantity, write start, write quantity, byte count at 10
        0x17 => by_count(buf, 10, 13),
        0x2B => match buf.get(2) {
            Some(&0x0E) => finish(buf, 7),
            Some(_) => FrameLen::Unknown,
            None => FrameLen::NeedMore(3),
        },
        _ => FrameLen::Unknown,
    }
}

/// The total length of the response frame that starts `buf`, as a master sees it.
pub fn expected_response_len(buf: &[u8]) -> FrameLen {
    let Some(&function) = buf.get(1) else {
        return FrameLen::NeedMore(2);
    };
    match function {
        // address, function, byte count, data, CRC
        0x01..=0x04 | 0x0C | 0x11 | 0x17 => by_count(buf, 2, 5),
        0x05 | 0x06 | 0x0B | 0x0F | 0x10 => finish(buf, 8),
        0x07 => finish(buf, 5),
        0x08 => match (buf.get(2), buf.get(3)) {
            (Some(0), Some(0)) => FrameLen::Unknown,
            (Some(_), Some(_)) => finish(buf, 8),
            _ => FrameLen::NeedMore(4),
        },
        0x2B => device_identification_len(buf),
        // The Altivar's FC 43 exception carries the MEI type (002): AB 0E code.
        0xAB => match buf.get(2) {
            Some(&0x0E) => finish(buf, 6),
            Some(_) => finish(buf, 5),
            None => FrameLen::NeedMore(3),
        },
        // address, function | 80h, exception code, CRC
        f if f & 0x80 != 0 => finish(buf, 5),
        _ => FrameLen::Unknown,
    }
}

/// Walks the objects of an FC 43/14 response: address, 2B, 0E, code, conformity, more follows,
/// next object id, object count, then per object id, length, value (Modbus Application Protocol
/// V1.1b3, 6.21).
fn device_identification_len(buf: &[u8]) -> FrameLen {
    match buf.get(2) {
        None => return FrameLen::NeedMore(3),
        Some(&0x0E) => {}
        Some(_) => return FrameLen::Unknown,
    }
    let Some(&count) = buf.get(7) else {
        return FrameLen::NeedMore(8);
    };
    let mut at = 8;
    for _ in 0..count {
        let Some(&len) = buf.get(at + 1) else {
            return FrameLen::NeedMore(at + 2);
        };
        at += 2 + usize::from(len);
        if at > MAX_FRAME_LEN {
            // Longer than any frame: the caller's length limit takes over.
            return finish(buf, at + 2);
        }
    }
    finish(buf, at + 2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timing_follows_the_spec_and_the_cp_table() {
        let t = CharTiming::new(9600, 11);
        assert_eq!(t.char_time, Duration::from_nanos(1_145_833));
        assert_eq!(t.t35.as_micros(), 4010); // 003 6.4.3: 9600 -> 4 ms
        assert_eq!(t.t15.as_micros(), 1718);
        assert_eq!(CharTiming::new(19200, 11).t35.as_micros(), 2005); // 19200 -> 2 ms
        assert_eq!(CharTiming::new(38400, 11).t35, Duration::from_micros(1750));
        assert_eq!(CharTiming::new(115_200, 11).t15, Duration::from_micros(750));
        assert_eq!(CharTiming::exact(76800, 11).t35.as_micros(), 501); // 76800 -> 0.5 ms
        assert_eq!(CharTiming::exact(300, 11).t35.as_millis(), 128); // 300 -> 128 ms
        assert_eq!(CharTiming::new(0, 0).char_time, Duration::from_secs(1));
    }

    #[test]
    fn multiplier_scales_t35_only() {
        let t = CharTiming::new(9600, 11);
        let m = t.with_multiplier(3);
        assert_eq!(m.t35, t.t35 * 3);
        assert_eq!(m.t15, t.t15);
        assert_eq!(t.with_multiplier(0), t);
        assert_eq!(t.with_multiplier(200).t35, t.t35 * 10);
        assert_eq!(t.transmit_time(8), t.char_time * 8);
    }

    #[test]
    fn frame_roundtrip() {
        let mut out = vec![0xEE];
        encode_frame(0x02, &[0x03, 0x0C, 0x1E, 0x00, 0x04], &mut out);
        assert_eq!(out, [0xEE, 0x02, 0x03, 0x0C, 0x1E, 0x00, 0x04, 0x27, 0x6C]);
        let frame = decode_frame(&out[1..]).unwrap();
        assert_eq!(
            frame,
            RtuFrame {
                address: 2,
                pdu: &[0x03, 0x0C, 0x1E, 0x00, 0x04]
            }
        );
    }

    #[test]
    fn frame_errors() {
        assert_eq!(
            decode_frame(&[1, 2, 3]),
            Err(FrameError::TooShort { len: 3, min: 4 })
        );
        assert_eq!(
            decode_frame(&[0; 265]),
            Err(FrameError::TooLong { len: 265, max: 264 })
        );
        assert_eq!(
            decode_frame(&[0x02, 0x03, 0x0C, 0x1E, 0x00, 0x04, 0x27, 0x6D]),
            Err(FrameError::BadCrc {
                expected: 0x6C27,
                actual: 0x6D27
            })
        );
    }

    #[test]
    fn request_lengths() {
        assert_eq!(expected_request_len(&[]), FrameLen::NeedMore(2));
        assert_eq!(expected_request_len(&[2, 3]), FrameLen::NeedMore(8));
        assert_eq!(
            expected_request_len(&[2, 3, 0, 0, 0, 1, 0, 0, 9]),
            FrameLen::Complete(8)
        );
        assert_eq!(
            expected_request_len(&[2, 0x10, 0, 0, 0, 2]),
            FrameLen::NeedMore(7)
        );
        assert_eq!(
            expected_request_len(&[2, 0x10, 0, 0, 0, 2, 4]),
            FrameLen::NeedMore(13)
        );
        assert_eq!(
            expected_request_len(&[2, 0x17, 0, 0, 0, 1, 0, 0, 0, 1, 2]),
            FrameLen::NeedMore(15)
        );
        assert_eq!(expected_request_len(&[2, 0x08, 0, 0]), FrameLen::Unknown);
        assert_eq!(
            expected_request_len(&[2, 0x08, 0, 0x0B]),
            FrameLen::NeedMore(8)
        );
        assert_eq!(
            expected_request_len(&[2, 0x2B, 0x0E]),
            FrameLen::NeedMore(7)
        );
        assert_eq!(expected_request_len(&[2, 0x11]), FrameLen::NeedMore(4));
        assert_eq!(expected_request_len(&[2, 0x45]), FrameLen::Unknown);
    }

    #[test]
    fn response_lengths() {
        assert_eq!(expected_response_len(&[2, 3]), FrameLen::NeedMore(3));
        assert_eq!(expected_response_len(&[2, 3, 8]), FrameLen::NeedMore(13));
        assert_eq!(expected_response_len(&[2, 0x83]), FrameLen::NeedMore(5));
        assert_eq!(
            expected_response_len(&[2, 0xAB, 0x0E]),
            FrameLen::NeedMore(6)
        );
        assert_eq!(expected_response_len(&[2, 0x07]), FrameLen::NeedMore(5));
        assert_eq!(
            expected_response_len(&[2, 0x2B, 0x0E, 1, 2, 0, 0, 1, 0]),
            FrameLen::NeedMore(10)
        );
        assert_eq!(
            expected_response_len(&[2, 0x2B, 0x0E, 1, 2, 0, 0, 1, 0, 3]),
            FrameLen::NeedMore(15)
        );
        assert_eq!(
            expected_response_len(&[2, 0x2B, 0x0E, 1, 2, 0, 0, 0]),
            FrameLen::NeedMore(10)
        );
        assert_eq!(expected_response_len(&[2, 0x42]), FrameLen::Unknown);
    }
}
