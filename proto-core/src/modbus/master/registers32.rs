//! 32-bit register jobs of the Modbus master ASCII (manual 003, 6.4.4 "32bit access with Modbus
//! Master ASCII", 6.4.2.2 "with 32-Bit Register").
//!
//! The CP's user program asks for a 32-bit access by setting bit 6 of the function code in its
//! send DB (43h, 46h, 50h instead of 03h, 06h, 10h). "The function code, which is sent is not
//! affected by the state of the 6. bit. This serves for master information, which data size to be
//! handled": on the wire the request carries 03h, 06h or 10h, and every register is 4 bytes long,
//! most significant byte first (003 6.4.3 "word = high byte | low byte", extended to the double
//! word). The slave must be set to 32-bit access too.
//!
//! Wire format (a register counts 4 bytes, quantities count registers):
//! - read: `03 addr qty` -> `03 bytecount(4*qty) value32*qty`;
//! - write single: `06 addr value32` -> the same echoed;
//! - write multiple: `10 addr qty bytecount(4*qty) value32*qty` -> `10 addr qty`.
//!
//! The master's callers (the gateway's image, Modbus TCP) stay 16-bit, so on a line with
//! `registers32` the master takes the 16-bit request and answers with the 16-bit completion
//! itself: each 32-bit register of the slave is two 16-bit registers, the high word first.
//!
//! ```text
//! slave register n (32 bits)  <->  16-bit holding registers 2n (high), 2n + 1 (low)
//! ```
//!
//! A read of registers `2n .. 2n + 2k` goes out as 43h for `k` registers from `n`; a write of two
//! registers (FC 16) as 46h, of more as 50h. A write of a single register (FC 06) or of an odd
//! range would be half a slave register and is refused (`SubmitError::HalfRegister`, see `image16`), as is a
//! read of an odd range. The other tables keep their 16-bit or bit access.

use crate::codec::{Reader, Writer};
use crate::modbus::pdu::{FunctionCode, PduError, Request, Response};

/// The bytes of one 32-bit register.
const REGISTER_BYTES: usize = 4;

/// The function code the user program sets for a 32-bit read (003 6.4.4 table: 43h).
pub const FC_READ_32: u8 = 0x43;
/// The function code for a 32-bit single write (003 6.4.4 table: 46h).
pub const FC_WRITE_SINGLE_32: u8 = 0x46;
/// The function code for a 32-bit multiple write (003 6.4.4 table: 50h).
pub const FC_WRITE_MULTIPLE_32: u8 = 0x50;

/// The 16-bit registers one 32-bit register of the slave occupies.
pub const IMAGE_WORDS: u16 = 2;

/// A 32-bit register job (only FC 03, 06 and 16 exist in 32-bit form, 003 7.2 event 0E 4Ah).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Request32 {
    /// FC 03 with bit 6 set (43h): read 1..62 registers of 4 bytes (003 7.2, 0E 45h).
    ReadHoldingRegisters { address: u16, quantity: u16 },
    /// FC 06 with bit 6 set (46h): write one register of 4 bytes.
    WriteSingleRegister { address: u16, value: u32 },
    /// FC 16 with bit 6 set (50h): write 1..61 registers of 4 bytes (003 7.2, 0E 46h).
    WriteMultipleRegisters { address: u16, values: Vec<u32> },
}

/// The answer to a [`Request32`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Response32 {
    /// The registers read.
    ReadHoldingRegisters(Vec<u32>),
    /// The echo of a single write.
    WriteSingleRegister { address: u16, value: u32 },
    /// The echo of a multiple write.
    WriteMultipleRegisters { address: u16, quantity: u16 },
}

// === impl Request32 ===

impl Request32 {
    /// The function code sent on the wire (bit 6 cleared).
    pub const fn function(&self) -> FunctionCode {
        match self {
            Self::ReadHoldingRegisters { .. } => FunctionCode::READ_HOLDING_REGISTERS,
            Self::WriteSingleRegister { .. } => FunctionCode::WRITE_SINGLE_REGISTER,
            Self::WriteMultipleRegisters { .. } => FunctionCode::WRITE_MULTIPLE_REGISTERS,
        }
    }

    /// The function code of the CP's send DB (bit 6 set: 43h, 46h, 50h).
    pub const fn job_function(&self) -> u8 {
        match self {
            Self::ReadHoldingRegisters { .. } => FC_READ_32,
            Self::WriteSingleRegister { .. } => FC_WRITE_SINGLE_32,
            Self::WriteMultipleRegisters { .. } => FC_WRITE_MULTIPLE_32,
        }
    }

    /// Appends the request PDU.
    pub fn encode(&self, out: &mut Vec<u8>) {
        let mut w = Writer::new(out);
        w.u8(self.function().0);
        match self {
            Self::ReadHoldingRegisters { address, quantity } => {
                w.u16_be(*address).u16_be(*quantity);
            }
            Self::WriteSingleRegister { address, value } => {
                w.u16_be(*address).u32_be(*value);
            }
            Self::WriteMultipleRegisters { address, values } => {
                w.u16_be(*address)
                    .u16_be(u16::try_from(values.len()).unwrap_or(u16::MAX))
                    .count_u8(values.len().saturating_mul(REGISTER_BYTES));
                for value in values {
                    w.u32_be(*value);
                }
            }
        }
    }

    /// Decodes the normal (non-exception) answer to this request; the function code has been
    /// checked by the caller but is checked again here.
    pub fn decode_response(&self, pdu: &[u8]) -> Result<Response32, PduError> {
        let function = self.function().0;
        let codec = |e| PduError::from_codec(function, e);
        let mut r = Reader::new(pdu);
        let got = r.u8().map_err(|_| PduError::Empty)?;
        if got != function {
            return Err(PduError::FunctionMismatch {
                expected: function,
                got,
            });
        }
        let response = match self {
            Self::ReadHoldingRegisters { quantity, .. } => {
                let expected = usize::from(*quantity) * REGISTER_BYTES;
                let byte_count = r.u8().map_err(codec)?;
                if usize::from(byte_count) < expected {
                    return Err(PduError::ByteCountTooSmall {
                        function,
                        byte_count,
                        expected,
                    });
                }
                if usize::from(byte_count) != expected {
                    return Err(PduError::ByteCountMismatch {
                        function,
                        byte_count,
                        expected,
                    });
                }
                r.require(expected).map_err(codec)?;
                let mut values = Vec::with_capacity(usize::from(*quantity));
                for _ in 0..*quantity {
                    values.push(r.u32_be().map_err(codec)?);
                }
                Response32::ReadHoldingRegisters(values)
            }
            Self::WriteSingleRegister { address, value } => {
                let got_address = r.u16_be().map_err(codec)?;
                let got_value = r.u32_be().map_err(codec)?;
                check_echo(function, "address", *address, got_address)?;
                if got_value != *value {
                    // The echo field is 32 bits wide; the error reports the first differing half.
                    let (sent, got) = if got_value >> 16 != value >> 16 {
                        (value >> 16, got_value >> 16)
                    } else {
                        (value & 0xFFFF, got_value & 0xFFFF)
                    };
                    check_echo(function, "value", sent as u16, got as u16)?;
                }
                Response32::WriteSingleRegister {
                    address: got_address,
                    value: got_value,
                }
            }
            Self::WriteMultipleRegisters { address, values } => {
                let got_address = r.u16_be().map_err(codec)?;
                let got_quantity = r.u16_be().map_err(codec)?;
                check_echo(function, "address", *address, got_address)?;
                check_echo(
                    function,
                    "quantity",
                    u16::try_from(values.len()).unwrap_or(u16::MAX),
                    got_quantity,
                )?;
                Response32::WriteMultipleRegisters {
                    address: got_address,
                    quantity: got_quantity,
                }
            }
        };
        r.expect_end().map_err(codec)?;
        Ok(response)
    }
}

/// A read of holding registers that starts or ends inside a 32-bit register of the slave, widened
/// to the whole 32-bit registers it touches (a slave register cannot be read by halves, 003
/// 6.4.4); `None` when it needs no widening (or is no such read).
pub fn widen_read(request: &Request) -> Option<Request> {
    let Request::ReadHoldingRegisters { address, quantity } = *request else {
        return None;
    };
    if address % IMAGE_WORDS == 0 && quantity % IMAGE_WORDS == 0 {
        return None;
    }
    let start = address & !1;
    let end = (u32::from(address) + u32::from(quantity)).next_multiple_of(u32::from(IMAGE_WORDS));
    Some(Request::ReadHoldingRegisters {
        address: start,
        quantity: u16::try_from(end - u32::from(start)).ok()?,
    })
}

/// The answer to the read a client `asked` for, out of the answer to the read `sent` for it
/// ([`widen_read`]); any other answer as it is.
pub fn narrow(asked: &Request, sent: &Request, response: Response) -> Response {
    let (
        Request::ReadHoldingRegisters { address, quantity },
        Request::ReadHoldingRegisters { address: from, .. },
        Response::ReadHoldingRegisters(words),
    ) = (asked, sent, &response)
    else {
        return response;
    };
    let offset = usize::from(address.saturating_sub(*from));
    match words.get(offset..offset + usize::from(*quantity)) {
        Some(part) if part.len() != words.len() => Response::ReadHoldingRegisters(part.to_vec()),
        _ => response,
    }
}

fn check_echo(function: u8, field: &'static str, expected: u16, got: u16) -> Result<(), PduError> {
    if expected == got {
        Ok(())
    } else {
        Err(PduError::EchoMismatch {
            function,
            field,
            expected,
            got,
        })
    }
}
