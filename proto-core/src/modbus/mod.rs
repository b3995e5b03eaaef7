//! Modbus: the PDU codec, RTU and ASCII framing, and the master engine.
//!
//! Layers, each with its own error type:
//! - framing ([`rtu`], [`ascii`]): address, checksum, start and end characters; a bad frame is a
//!   [`FrameError`] (the CP 341 events 0E 57h, 0E 58h, 08 33h of 003 7.2);
//! - the PDU ([`pdu`]): function code and data; a request a server cannot decode is a
//!   [`pdu::PduError`] that maps to the exception it answers, a response that does not fit its
//!   request is a [`pdu::PduError`] that maps to the CP's events 0E 51h..0E 56h;
//! - the engines ([`master`], [`slave`]): timing, addresses, retries, events;
//! - [`tap`]: a listen-only station that pairs another master's requests with their answers.

pub mod ascii;
pub mod master;
pub mod pdu;
pub mod rtu;
pub mod slave;
mod table;
pub mod tap;

pub use table::Table;

/// Why a frame (RTU ADU or ASCII message) was rejected before its PDU was looked at.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// Fewer bytes (RTU) or characters (ASCII) than the smallest frame.
    #[error("frame too short: {len} bytes, at least {min} needed")]
    TooShort { len: usize, min: usize },
    /// More bytes or characters than the largest frame.
    #[error("frame too long: {len} bytes, at most {max} allowed")]
    TooLong { len: usize, max: usize },
    /// The CRC does not match (003 7.2, 0E 57h): `expected` is computed over the received address
    /// and PDU, `actual` is the CRC the frame carries.
    #[error("bad CRC: computed {expected:#06x}, frame carries {actual:#06x}")]
    BadCrc { expected: u16, actual: u16 },
    /// The LRC does not match (003 7.2, 0E 57h): `expected` is computed over the decoded address
    /// and PDU, `actual` is the LRC the frame carries.
    #[error("bad LRC: computed {expected:#04x}, frame carries {actual:#04x}")]
    BadLrc { expected: u8, actual: u8 },
    /// A character between ':' and CR LF that is not a hex digit (003 7.2, 0E 58h); `position` is
    /// its index in the frame.
    #[error("character {byte:#04x} at position {position} is not a hex digit")]
    BadHexDigit { position: usize, byte: u8 },
    /// An ASCII frame that does not start with ':' (003 7.2, 08 33h).
    #[error("frame does not start with ':'")]
    MissingStart,
    /// An ASCII frame that does not end with CR LF.
    #[error("frame does not end with CR LF")]
    MissingEnd,
    /// An odd number of hex digits between ':' and CR LF.
    #[error("odd number of hex digits")]
    OddHexLength,
}
