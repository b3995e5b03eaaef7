//! The device simulators: every Altivar and KS vario frame of the seed manuals answered byte for
//! byte, through the model and over a real pty, plus the rules around them (other address, bad
//! CRC, broadcast, listen-only, limits, special values, faults).
//!
//! The frames are copied from the manuals (002 "Modbus-Protokoll", 001 chapter 4) as collected in
//! the project's vector list; the KS vario frames are printed there without CRC, which is added
//! here.

mod altivar;
mod ksvario;
mod pty;

use proto_core::checksum::crc16_modbus;

/// Bytes from hex pairs separated by spaces.
pub(crate) fn hex(text: &str) -> Vec<u8> {
    text.split_whitespace()
        .map(|pair| u8::from_str_radix(pair, 16).unwrap_or_else(|_| panic!("bad hex {pair:?}")))
        .collect()
}

/// A frame with its CRC-16/Modbus appended, low byte first.
pub(crate) fn with_crc(bytes: &[u8]) -> Vec<u8> {
    let mut frame = bytes.to_vec();
    frame.extend_from_slice(&crc16_modbus(bytes).to_le_bytes());
    frame
}

/// A frame from hex without CRC.
pub(crate) fn frame(text: &str) -> Vec<u8> {
    with_crc(&hex(text))
}
