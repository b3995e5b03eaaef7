//! MBAP framing: the 7-byte header in front of every Modbus TCP PDU, and a check-then-parse frame
//! reader over a byte buffer.
//!
//! The seeds cover serial Modbus only; this module follows the Modbus Messaging on TCP/IP
//! Implementation Guide V1.0b (section 3.1.3, "MBAP Header description") and the Modbus Application
//! Protocol Specification V1.1b3 (section 4.1, PDU size):
//!
//! ```text
//! +----------------+-------------+--------+---------+--------------------+
//! | transaction id | protocol id | length | unit id | PDU (1..253 bytes) |
//! |    2 bytes     |   2 bytes   | 2 bytes| 1 byte  |                    |
//! +----------------+-------------+--------+---------+--------------------+
//!                                  length counts the unit id and the PDU
//! ```
//!
//! The reader checks a header field as soon as its bytes are present: a protocol id other than 0
//! is refused after 4 bytes, a length of 0 or above 254 after 6 bytes. A bad header is never
//! skipped over (the stream has no way to find the next frame); the connection closes.

use thiserror::Error;

/// Size of the MBAP header: transaction id, protocol id, length, unit id (guide 3.1.3).
pub const HEADER_LEN: usize = 7;

/// The protocol id of Modbus (guide 3.1.3: "0 = MODBUS protocol").
pub const PROTOCOL_ID_MODBUS: u16 = 0;

/// Largest PDU (Modbus Application Protocol V1.1b3, 4.1: 256-byte serial ADU minus address and CRC).
pub const MAX_PDU_LEN: usize = 253;

/// Largest value of the length field: the unit id plus the largest PDU.
pub const MAX_LENGTH_FIELD: u16 = 1 + MAX_PDU_LEN as u16;

/// Largest Modbus TCP ADU: header plus largest PDU (V1.1b3, 4.1: "TCP MODBUS ADU = 253 + 7 = 260").
pub const MAX_ADU_LEN: usize = HEADER_LEN + MAX_PDU_LEN;

/// Why a header was refused. Each case closes the connection.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Error)]
pub enum MbapError {
    /// The protocol id is not 0.
    #[error("MBAP protocol id {0} is not 0 (Modbus)")]
    ProtocolId(u16),
    /// The length field is 0 or above 254.
    #[error("MBAP length {0} outside 1..=254")]
    Length(u16),
}

// === impl MbapError ===

impl MbapError {
    /// A stable label for counters and logs (bounded set).
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::ProtocolId(_) => "protocol_id",
            Self::Length(_) => "length",
        }
    }
}

/// A checked MBAP header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MbapHeader {
    /// Chosen by the client, echoed in the response.
    pub transaction_id: u16,
    /// The unit id ("slave address" behind a gateway), echoed in the response.
    pub unit_id: u8,
    /// Bytes of the PDU that follow the header (0..=253; 0 means the client sent no function code).
    pub pdu_len: usize,
}

// === impl MbapHeader ===

impl MbapHeader {
    /// Checks the header bytes present in `buf` (any number, also fewer than 7).
    ///
    /// Returns `Ok(None)` while the bytes present are valid but the header is incomplete, and an
    /// error as soon as a present field is invalid.
    pub fn check(buf: &[u8]) -> Result<Option<Self>, MbapError> {
        if let Some(protocol_id) = be_u16(buf, 2) {
            if protocol_id != PROTOCOL_ID_MODBUS {
                return Err(MbapError::ProtocolId(protocol_id));
            }
        }
        if let Some(length) = be_u16(buf, 4) {
            if length == 0 || length > MAX_LENGTH_FIELD {
                return Err(MbapError::Length(length));
            }
        }
        let (Some(transaction_id), Some(length), Some(&unit_id)) =
            (be_u16(buf, 0), be_u16(buf, 4), buf.get(HEADER_LEN - 1))
        else {
            return Ok(None);
        };
        Ok(Some(Self {
            transaction_id,
            unit_id,
            pdu_len: usize::from(length) - 1,
        }))
    }

    /// The header of the response to this request carrying `pdu_len` PDU bytes, or `None` when
    /// such a PDU is longer than an ADU allows.
    pub fn reply(self, pdu_len: usize) -> Option<Self> {
        (pdu_len <= MAX_PDU_LEN).then_some(Self { pdu_len, ..self })
    }

    /// Size of the whole frame: header and PDU.
    pub const fn frame_len(self) -> usize {
        HEADER_LEN + self.pdu_len
    }

    /// The 7 header bytes.
    pub fn to_bytes(self) -> [u8; HEADER_LEN] {
        // `pdu_len` <= 253 for every header built by `check` or `reply`; saturate otherwise.
        let length = u16::try_from(self.pdu_len + 1).unwrap_or(u16::MAX);
        let [t0, t1] = self.transaction_id.to_be_bytes();
        let [p0, p1] = PROTOCOL_ID_MODBUS.to_be_bytes();
        let [l0, l1] = length.to_be_bytes();
        [t0, t1, p0, p1, l0, l1, self.unit_id]
    }

    /// Appends the 7 header bytes to `out`.
    pub fn encode(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_bytes());
    }
}

/// One complete frame borrowed from the reader's buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frame<'a> {
    /// The checked header.
    pub header: MbapHeader,
    /// The PDU: function code and data (empty when the length field is 1).
    pub pdu: &'a [u8],
}

/// Checks the start of `buf` for a frame: `Ok(Some(len))` when a complete frame of `len` bytes is
/// there, `Ok(None)` when more bytes are needed, an error when the header is invalid.
pub fn check_frame(buf: &[u8]) -> Result<Option<usize>, MbapError> {
    Ok(MbapHeader::check(buf)?
        .map(MbapHeader::frame_len)
        .filter(|&len| buf.len() >= len))
}

/// Appends a complete response ADU (header and `pdu`) to `out`; `false` (nothing appended) when
/// `pdu` is longer than [`MAX_PDU_LEN`].
pub fn encode_frame(request: MbapHeader, pdu: &[u8], out: &mut Vec<u8>) -> bool {
    let Some(header) = request.reply(pdu.len()) else {
        return false;
    };
    header.encode(out);
    out.extend_from_slice(pdu);
    true
}

/// Completes a response ADU built in place: `adu` holds [`HEADER_LEN`] bytes of room, then the
/// PDU; writes the reply header to `request` into the room. `false` (nothing changed) when the
/// PDU is longer than [`MAX_PDU_LEN`] or there is no room.
pub fn complete_frame(request: MbapHeader, adu: &mut [u8]) -> bool {
    let Some(header) = adu
        .len()
        .checked_sub(HEADER_LEN)
        .and_then(|pdu_len| request.reply(pdu_len))
    else {
        return false;
    };
    match adu.get_mut(..HEADER_LEN) {
        Some(room) => {
            room.copy_from_slice(&header.to_bytes());
            true
        }
        None => false,
    }
}

/// Collects the bytes of one connection and cuts them into frames (check, then parse).
///
/// Bounded: the owner reads more bytes only when [`FrameReader::next_frame`] gives `Ok(None)`, so
/// the buffer holds at most one incomplete frame plus one read.
#[derive(Debug, Default)]
pub struct FrameReader {
    /// Received bytes; `buf[start..]` is not consumed yet.
    buf: Vec<u8>,
    /// Offset of the first unconsumed byte.
    start: usize,
}

// === impl FrameReader ===

impl FrameReader {
    /// An empty reader.
    pub fn new() -> Self {
        Self {
            buf: Vec::with_capacity(2 * MAX_ADU_LEN),
            start: 0,
        }
    }

    /// Adds received bytes.
    pub fn extend(&mut self, bytes: &[u8]) {
        if self.start > 0 {
            self.buf.drain(..self.start);
            self.start = 0;
        }
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes received and not yet consumed as a frame.
    pub fn buffered(&self) -> usize {
        self.buf.len().saturating_sub(self.start)
    }

    /// The next complete frame, consumed; `Ok(None)` when more bytes are needed. After an error
    /// the reader stays in error: the stream cannot be resynchronised.
    pub fn next_frame(&mut self) -> Result<Option<Frame<'_>>, MbapError> {
        let rest = self.buf.get(self.start..).unwrap_or_default();
        let Some(header) = MbapHeader::check(rest)? else {
            return Ok(None);
        };
        let Some(pdu) = rest.get(HEADER_LEN..header.frame_len()) else {
            return Ok(None);
        };
        self.start += header.frame_len();
        Ok(Some(Frame { header, pdu }))
    }
}

/// The big-endian `u16` at `at`, if both bytes are present.
fn be_u16(buf: &[u8], at: usize) -> Option<u16> {
    let bytes = buf.get(at..at.checked_add(2)?)?;
    let pair: [u8; 2] = bytes.try_into().ok()?;
    Some(u16::from_be_bytes(pair))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// FC03 read 2 registers at 0x0010 of unit 1, transaction 0x1234.
    const READ_REQUEST: [u8; 12] = [0x12, 0x34, 0, 0, 0, 6, 1, 0x03, 0x00, 0x10, 0x00, 0x02];

    #[test]
    fn parses_a_complete_frame() {
        let mut reader = FrameReader::new();
        reader.extend(&READ_REQUEST);
        let frame = reader.next_frame().expect("valid").expect("complete");
        assert_eq!(
            frame.header,
            MbapHeader {
                transaction_id: 0x1234,
                unit_id: 1,
                pdu_len: 5
            }
        );
        assert_eq!(frame.pdu, &[0x03, 0x00, 0x10, 0x00, 0x02]);
        assert_eq!(reader.next_frame(), Ok(None));
        assert_eq!(reader.buffered(), 0);
    }

    #[test]
    fn byte_by_byte_gives_the_same_frame() {
        let mut reader = FrameReader::new();
        for (i, byte) in READ_REQUEST.iter().enumerate() {
            if i + 1 < READ_REQUEST.len() {
                reader.extend(std::slice::from_ref(byte));
                assert_eq!(reader.next_frame(), Ok(None), "after {} bytes", i + 1);
            } else {
                reader.extend(std::slice::from_ref(byte));
                let frame = reader.next_frame().expect("valid").expect("complete");
                assert_eq!(frame.pdu, &READ_REQUEST[7..]);
            }
        }
    }

    #[test]
    fn pipelined_frames_come_out_in_order() {
        let mut reader = FrameReader::new();
        let mut bytes = Vec::new();
        for id in 0..10u16 {
            let mut frame = READ_REQUEST;
            frame[..2].copy_from_slice(&id.to_be_bytes());
            bytes.extend_from_slice(&frame);
        }
        // Half a frame more at the end stays buffered.
        bytes.extend_from_slice(&READ_REQUEST[..5]);
        reader.extend(&bytes);
        for id in 0..10u16 {
            let frame = reader.next_frame().expect("valid").expect("complete");
            assert_eq!(frame.header.transaction_id, id);
        }
        assert_eq!(reader.next_frame(), Ok(None));
        assert_eq!(reader.buffered(), 5);
    }

    #[test]
    fn protocol_id_is_refused_after_four_bytes() {
        assert_eq!(check_frame(&[0, 1, 0, 1]), Err(MbapError::ProtocolId(1)));
        assert_eq!(check_frame(&[0, 1, 0]), Ok(None));
    }

    #[test]
    fn length_0_and_above_254_are_refused_after_six_bytes() {
        assert_eq!(check_frame(&[0, 1, 0, 0, 0, 0]), Err(MbapError::Length(0)));
        assert_eq!(
            check_frame(&[0, 1, 0, 0, 0xFF, 0xFF]),
            Err(MbapError::Length(0xFFFF))
        );
        assert_eq!(
            check_frame(&[0, 1, 0, 0, 0, 255]),
            Err(MbapError::Length(255))
        );
        assert_eq!(check_frame(&[0, 1, 0, 0, 0, 254]), Ok(None));
        assert_eq!(check_frame(&[0, 1, 0, 0, 0, 1]), Ok(None));
    }

    #[test]
    fn largest_frame_is_260_bytes() {
        let mut frame = vec![0, 1, 0, 0, 0, 254, 9];
        frame.resize(MAX_ADU_LEN, 0x10);
        assert_eq!(check_frame(&frame), Ok(Some(MAX_ADU_LEN)));
        assert_eq!(check_frame(&frame[..MAX_ADU_LEN - 1]), Ok(None));
    }

    #[test]
    fn length_1_is_a_frame_without_pdu() {
        let mut reader = FrameReader::new();
        reader.extend(&[0, 7, 0, 0, 0, 1, 3]);
        let frame = reader.next_frame().expect("valid").expect("complete");
        assert_eq!(frame.header.pdu_len, 0);
        assert!(frame.pdu.is_empty());
    }

    #[test]
    fn reply_echoes_transaction_and_unit() {
        let request = MbapHeader {
            transaction_id: 0xBEEF,
            unit_id: 17,
            pdu_len: 5,
        };
        let mut out = Vec::new();
        assert!(encode_frame(request, &[0x83, 0x02], &mut out));
        assert_eq!(out, [0xBE, 0xEF, 0, 0, 0, 3, 17, 0x83, 0x02]);
    }

    #[test]
    fn a_frame_built_in_place_is_the_frame_encoded() {
        let request = MbapHeader {
            transaction_id: 0xBEEF,
            unit_id: 17,
            pdu_len: 5,
        };
        let pdu = [0x03, 4, 0, 1, 0, 2];
        let mut encoded = Vec::new();
        assert!(encode_frame(request, &pdu, &mut encoded));
        let mut in_place = vec![0u8; HEADER_LEN];
        in_place.extend_from_slice(&pdu);
        assert!(complete_frame(request, &mut in_place));
        assert_eq!(in_place, encoded);
        let mut too_long = vec![0u8; HEADER_LEN + MAX_PDU_LEN + 1];
        assert!(!complete_frame(request, &mut too_long));
        assert!(too_long.iter().all(|&b| b == 0));
        assert!(!complete_frame(request, &mut [0u8; HEADER_LEN - 1]));
    }

    #[test]
    fn reply_longer_than_an_adu_is_refused() {
        let request = MbapHeader {
            transaction_id: 1,
            unit_id: 1,
            pdu_len: 5,
        };
        let mut out = Vec::new();
        assert!(!encode_frame(request, &[0u8; MAX_PDU_LEN + 1], &mut out));
        assert!(out.is_empty());
        assert!(encode_frame(request, &[0u8; MAX_PDU_LEN], &mut out));
        assert_eq!(out.len(), MAX_ADU_LEN);
    }

    #[test]
    fn errors_stay_errors() {
        let mut reader = FrameReader::new();
        reader.extend(&[0, 1, 0, 0, 0, 0, 1]);
        assert_eq!(reader.next_frame(), Err(MbapError::Length(0)));
        reader.extend(&READ_REQUEST);
        assert_eq!(reader.next_frame(), Err(MbapError::Length(0)));
    }
}
