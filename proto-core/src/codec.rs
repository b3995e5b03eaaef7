//! A cursor reader and writer that own every length check, so no decoder indexes a slice directly.
//!
//! [`Reader`] hands out fields front to back and fails with a typed [`CodecError`] when the bytes
//! end early ([`CodecError::TooShort`]) or when bytes remain that no field claimed
//! ([`CodecError::TrailingData`]). Positions in the errors are absolute (from the start of the
//! buffer the reader was made over), so a decoder can report "need 7 bytes, have 5" as is.
//!
//! [`Writer`] appends big-endian fields to a `Vec<u8>`; the helpers [`pack_bits`],
//! [`unpack_bits`] and [`bit_byte_count`] hold the coil packing rule of the Modbus Application
//! Protocol Specification V1.1b3 (6.1, 6.15: first coil in the LSB of the first byte, unused high
//! bits zero).

/// Why a [`Reader`] refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum CodecError {
    /// The buffer ends before the field does: `needed` bytes in total, `have` present.
    #[error("need {needed} bytes, have {have}")]
    TooShort { needed: usize, have: usize },
    /// `extra` bytes remain after the last field.
    #[error("{extra} trailing bytes")]
    TrailingData { extra: usize },
}

/// A cursor over untrusted bytes.
#[derive(Clone, Debug)]
pub struct Reader<'a> {
    /// The whole buffer, never shortened.
    buf: &'a [u8],
    /// How many bytes of `buf` have been handed out.
    offset: usize,
}

// === impl Reader ===

impl<'a> Reader<'a> {
    /// A reader at the start of `buf`.
    pub fn new(buf: &'a [u8]) -> Self {
        Self { buf, offset: 0 }
    }

    /// The next `n` bytes.
    pub fn take(&mut self, n: usize) -> Result<&'a [u8], CodecError> {
        let end = self.offset.checked_add(n).ok_or(CodecError::TooShort {
            needed: usize::MAX,
            have: self.buf.len(),
        })?;
        let bytes = self.buf.get(self.offset..end).ok_or(CodecError::TooShort {
            needed: end,
            have: self.buf.len(),
        })?;
        self.offset = end;
        Ok(bytes)
    }

    /// The next `N` bytes as an array.
    pub fn array<const N: usize>(&mut self) -> Result<[u8; N], CodecError> {
        let mut out = [0u8; N];
        out.copy_from_slice(self.take(N)?);
        Ok(out)
    }

    /// The next byte.
    pub fn u8(&mut self) -> Result<u8, CodecError> {
        let [b] = self.array::<1>()?;
        Ok(b)
    }

    /// The next two bytes, high byte first (003 6.4.3 "word = high byte | low byte").
    pub fn u16_be(&mut self) -> Result<u16, CodecError> {
        self.array::<2>().map(u16::from_be_bytes)
    }

    /// The next two bytes, low byte first (the RTU CRC, 003 6.4.3 "CRC-CHECK").
    pub fn u16_le(&mut self) -> Result<u16, CodecError> {
        self.array::<2>().map(u16::from_le_bytes)
    }

    /// The next four bytes, most significant first.
    pub fn u32_be(&mut self) -> Result<u32, CodecError> {
        self.array::<4>().map(u32::from_be_bytes)
    }

    /// The next byte without consuming it, if any.
    pub fn peek_u8(&self) -> Option<u8> {
        self.buf.get(self.offset).copied()
    }

    /// Everything not yet read (consumes it).
    pub fn rest(&mut self) -> &'a [u8] {
        let rest = self.buf.get(self.offset..).unwrap_or_default();
        self.offset = self.buf.len();
        rest
    }

    /// How many bytes are left.
    pub fn remaining(&self) -> usize {
        self.buf.len().saturating_sub(self.offset)
    }

    /// Whether every byte has been read.
    pub fn is_empty(&self) -> bool {
        self.remaining() == 0
    }

    /// How many bytes have been read.
    pub fn position(&self) -> usize {
        self.offset
    }

    /// Fails with [`CodecError::TrailingData`] unless every byte has been read.
    pub fn expect_end(&self) -> Result<(), CodecError> {
        match self.remaining() {
            0 => Ok(()),
            extra => Err(CodecError::TrailingData { extra }),
        }
    }

    /// Fails with [`CodecError::TooShort`] unless at least `n` bytes are left (a check before a
    /// loop, so the loop cannot stop half-way).
    pub fn require(&self, n: usize) -> Result<(), CodecError> {
        if self.remaining() >= n {
            Ok(())
        } else {
            Err(CodecError::TooShort {
                needed: self.offset.saturating_add(n),
                have: self.buf.len(),
            })
        }
    }
}

/// An appending writer of big-endian fields.
#[derive(Debug)]
pub struct Writer<'a> {
    /// The buffer appended to; bytes already in it are kept.
    out: &'a mut Vec<u8>,
}

// === impl Writer ===

impl<'a> Writer<'a> {
    /// A writer appending to `out`.
    pub fn new(out: &'a mut Vec<u8>) -> Self {
        Self { out }
    }

    /// Appends one byte.
    pub fn u8(&mut self, value: u8) -> &mut Self {
        self.out.push(value);
        self
    }

    /// Appends two bytes, high byte first.
    pub fn u16_be(&mut self, value: u16) -> &mut Self {
        self.out.extend_from_slice(&value.to_be_bytes());
        self
    }

    /// Appends two bytes, low byte first (the RTU CRC).
    pub fn u16_le(&mut self, value: u16) -> &mut Self {
        self.out.extend_from_slice(&value.to_le_bytes());
        self
    }

    /// Appends four bytes, most significant first.
    pub fn u32_be(&mut self, value: u32) -> &mut Self {
        self.out.extend_from_slice(&value.to_be_bytes());
        self
    }

    /// Appends bytes as they are.
    pub fn bytes(&mut self, bytes: &[u8]) -> &mut Self {
        self.out.extend_from_slice(bytes);
        self
    }

    /// Appends a one-byte count, saturated at 255 (callers keep their payloads within the limits;
    /// a saturated count makes the peer reject the frame rather than misread it).
    pub fn count_u8(&mut self, count: usize) -> &mut Self {
        self.u8(u8::try_from(count).unwrap_or(u8::MAX))
    }

    /// Appends coil states packed eight a byte, first coil in the LSB of the first byte.
    pub fn bits(&mut self, bits: &[bool]) -> &mut Self {
        pack_bits(bits, self.out);
        self
    }

    /// How many bytes the underlying buffer holds (including those it held before).
    pub fn len(&self) -> usize {
        self.out.len()
    }

    /// Whether the underlying buffer is empty.
    pub fn is_empty(&self) -> bool {
        self.out.is_empty()
    }
}

/// The bytes needed for `quantity` packed bits: ceil(quantity / 8).
pub const fn bit_byte_count(quantity: usize) -> usize {
    quantity.div_ceil(8)
}

/// Packs `bits` eight a byte, first bit in the LSB of the first byte, unused high bits zero
/// (Modbus Application Protocol V1.1b3, 6.1 and 6.11).
pub fn pack_bits(bits: &[bool], out: &mut Vec<u8>) {
    out.extend(bits.chunks(8).map(|chunk| {
        chunk.iter().enumerate().fold(
            0u8,
            |byte, (i, &on)| if on { byte | (1 << i) } else { byte },
        )
    }));
}

/// Unpacks the first `quantity` bits of `bytes` (LSB of the first byte first); bits beyond the
/// bytes present are not produced, so the result is at most `8 * bytes.len()` long.
pub fn unpack_bits(bytes: &[u8], quantity: usize) -> Vec<bool> {
    bytes
        .iter()
        .flat_map(|&byte| (0..8).map(move |i| byte & (1 << i) != 0))
        .take(quantity)
        .collect()
}

/// The big-endian 16-bit words of `bytes` (a trailing odd byte is not a word and is left out).
pub fn u16s_be(bytes: &[u8]) -> Vec<u16> {
    bytes
        .chunks_exact(2)
        .filter_map(|pair| <[u8; 2]>::try_from(pair).ok())
        .map(u16::from_be_bytes)
        .collect()
}

/// The big-endian 32-bit words of `bytes` (trailing bytes short of a word are left out).
pub fn u32s_be(bytes: &[u8]) -> Vec<u32> {
    bytes
        .chunks_exact(4)
        .filter_map(|quad| <[u8; 4]>::try_from(quad).ok())
        .map(u32::from_be_bytes)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reader_hands_out_fields_in_order() {
        let mut r = Reader::new(&[0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07, 0x08, 0x09]);
        assert_eq!(r.u8(), Ok(0x01));
        assert_eq!(r.u16_be(), Ok(0x0203));
        assert_eq!(r.u16_le(), Ok(0x0504));
        assert_eq!(r.position(), 5);
        assert_eq!(r.peek_u8(), Some(0x06));
        assert_eq!(r.u32_be(), Ok(0x0607_0809));
        assert!(r.is_empty());
        assert_eq!(r.expect_end(), Ok(()));
        assert_eq!(r.peek_u8(), None);
    }

    #[test]
    fn reader_reports_absolute_lengths() {
        let mut r = Reader::new(&[0x01, 0x02, 0x03]);
        assert_eq!(r.u8(), Ok(0x01));
        assert_eq!(r.u32_be(), Err(CodecError::TooShort { needed: 5, have: 3 }));
        // A failed read consumes nothing.
        assert_eq!(r.remaining(), 2);
        assert_eq!(
            r.require(3),
            Err(CodecError::TooShort { needed: 4, have: 3 })
        );
        assert_eq!(r.require(2), Ok(()));
        assert_eq!(r.expect_end(), Err(CodecError::TrailingData { extra: 2 }));
        assert_eq!(
            r.take(usize::MAX),
            Err(CodecError::TooShort {
                needed: usize::MAX,
                have: 3
            })
        );
        assert_eq!(r.rest(), &[0x02, 0x03]);
        assert_eq!(r.rest(), &[] as &[u8]);
    }

    #[test]
    fn writer_appends() {
        let mut out = vec![0xAA];
        let mut w = Writer::new(&mut out);
        w.u8(1)
            .u16_be(0x0203)
            .u16_le(0x0504)
            .u32_be(0x0607_0809)
            .bytes(&[0x0A])
            .count_u8(300);
        assert_eq!(w.len(), 12);
        assert!(!w.is_empty());
        assert_eq!(out, [0xAA, 1, 2, 3, 4, 5, 6, 7, 8, 9, 0x0A, 0xFF]);
    }

    #[test]
    fn bits_pack_lsb_first() {
        // Modbus Application Protocol V1.1b3, 6.11 example: coils 20..29 = CD 01.
        let bits = [
            true, false, true, true, false, false, true, true, true, false,
        ];
        let mut out = Vec::new();
        Writer::new(&mut out).bits(&bits);
        assert_eq!(out, [0xCD, 0x01]);
        assert_eq!(unpack_bits(&out, bits.len()), bits);
        assert_eq!(unpack_bits(&out, 100).len(), 16);
        assert_eq!(bit_byte_count(0), 0);
        assert_eq!(bit_byte_count(1), 1);
        assert_eq!(bit_byte_count(8), 1);
        assert_eq!(bit_byte_count(9), 2);
        assert_eq!(bit_byte_count(2040), 255);
    }

    #[test]
    fn words_big_endian() {
        assert_eq!(u16s_be(&[0x00, 0x28, 0x02, 0x58, 0xFF]), [0x0028, 0x0258]);
        assert_eq!(
            u32s_be(&[0x43, 0x5E, 0x00, 0x00, 0x43, 0xA6, 0x80, 0x00, 0x01]),
            [0x435E_0000, 0x43A6_8000]
        );
    }
}
