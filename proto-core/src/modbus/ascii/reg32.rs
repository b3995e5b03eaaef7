//! The CP 341's 32-bit register mode of the Modbus master ASCII (003 6.4.2.2 "with 32-Bit
//! Register", 6.4.4 "32bit access with Modbus Master ASCII"; 000 has the same text in German).
//!
//! How this module reads the manual:
//! - the user program selects 32-bit registers by setting bit 6 (40h) of the function code in its
//!   send DB: 43h for FC 03, 46h for FC 06, 50h for FC 16 (the table in 6.4.4); any other function
//!   with bit 6 set is refused (event 0E 4Ah, "only allowed with FC 03, 06, 16");
//! - "the function code, which is sent is not affected by the state of the 6. bit" (000: "dass der
//!   Zustand des 6. Bits den Funktionscode, welcher gesendet wird, nicht beeinflusst"): on the wire
//!   the frame carries the plain 03h, 06h or 10h. The bit only tells the master that every
//!   register is 4 bytes, and the slave has to be set to 32-bit access as well ("Please also
//!   regard to activate 32bit access in the slave, too"), since nothing in the frame says so;
//! - hence the quantity fields count 32-bit registers and byte counts are 4 x quantity; a 32-bit
//!   register travels high byte first (6.4.3 "word = high byte | low byte", extended to 4 bytes);
//! - limits (events 0E 45h, 0E 46h): 1..62 registers read (248 bytes, within the 250 data bytes of
//!   125 ASCII registers) and 1..61 registers written (244 bytes, within 123 x 2).

use crate::codec::{u32s_be, CodecError, Reader, Writer};
use crate::modbus::pdu::{ExceptionCode, ExceptionResponse, FunctionCode, PduError};

/// Bit 6 of the user's function code selects 32-bit registers (003 6.4.4).
pub const REG32_BIT: u8 = 0x40;
/// Most 32-bit registers one read may ask for (003 7.2, 0E 45h: "with 32bit 1...62").
pub const MAX_READ_REGISTERS: u16 = 62;
/// Most 32-bit registers one write may carry (003 7.2, 0E 46h: "with 32bit 1..61").
pub const MAX_WRITE_REGISTERS: u16 = 61;

/// The user-side function code for 32-bit FC 03 (43h), FC 06 (46h) and FC 16 (50h).
pub const fn user_function(wire: FunctionCode) -> FunctionCode {
    FunctionCode(wire.0 | REG32_BIT)
}

/// Splits a user-side function code into the code sent on the wire and whether it selects
/// 32-bit registers. Bit 6 on any function but 03, 06 and 16 is refused (003 7.2, 0E 4Ah) with
/// [`PduError::UnsupportedFunction`].
pub fn split_user_function(code: u8) -> Result<(FunctionCode, bool), PduError> {
    if code & REG32_BIT == 0 {
        return Ok((FunctionCode(code), false));
    }
    match FunctionCode(code & !REG32_BIT) {
        wire @ (FunctionCode::READ_HOLDING_REGISTERS
        | FunctionCode::WRITE_SINGLE_REGISTER
        | FunctionCode::WRITE_MULTIPLE_REGISTERS) => Ok((wire, true)),
        _ => Err(PduError::UnsupportedFunction(code)),
    }
}

/// A request on 32-bit registers.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Request32 {
    /// User FC 43h, sent as 03h: `quantity` 32-bit registers from `address`.
    ReadHoldingRegisters { address: u16, quantity: u16 },
    /// User FC 46h, sent as 06h with a 4-byte value.
    WriteSingleRegister { address: u16, value: u32 },
    /// User FC 50h, sent as 10h: quantity = `values.len()`, byte count 4 x quantity.
    WriteMultipleRegisters { address: u16, values: Vec<u32> },
}

/// A response on 32-bit registers.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Response32 {
    /// To FC 43h: the registers read.
    ReadHoldingRegisters(Vec<u32>),
    /// To FC 46h: the echo.
    WriteSingleRegister { address: u16, value: u32 },
    /// To FC 50h: the echo of address and quantity.
    WriteMultipleRegisters { address: u16, quantity: u16 },
}

fn quantity_of(len: usize) -> u16 {
    u16::try_from(len).unwrap_or(u16::MAX)
}

fn check_quantity(function: FunctionCode, quantity: u16, max: u16) -> Result<(), PduError> {
    if (1..=max).contains(&quantity) {
        Ok(())
    } else {
        Err(PduError::QuantityOutOfRange {
            function: function.0,
            quantity,
            min: 1,
            max,
        })
    }
}

fn echo(
    function: FunctionCode,
    field: &'static str,
    expected: u16,
    got: u16,
) -> Result<(), PduError> {
    if expected == got {
        Ok(())
    } else {
        Err(PduError::EchoMismatch {
            function: function.0,
            field,
            expected,
            got,
        })
    }
}

// === impl Request32 ===

impl Request32 {
    /// The code sent on the wire (03h, 06h, 10h).
    pub const fn wire_function(&self) -> FunctionCode {
        match self {
            Self::ReadHoldingRegisters { .. } => FunctionCode::READ_HOLDING_REGISTERS,
            Self::WriteSingleRegister { .. } => FunctionCode::WRITE_SINGLE_REGISTER,
            Self::WriteMultipleRegisters { .. } => FunctionCode::WRITE_MULTIPLE_REGISTERS,
        }
    }

    /// The user-side code (43h, 46h, 50h).
    pub const fn function(&self) -> FunctionCode {
        user_function(self.wire_function())
    }

    /// Checks the quantities against 1..62 (read) and 1..61 (write).
    pub fn validate(&self) -> Result<(), PduError> {
        match self {
            Self::ReadHoldingRegisters { quantity, .. } => {
                check_quantity(self.wire_function(), *quantity, MAX_READ_REGISTERS)
            }
            Self::WriteSingleRegister { .. } => Ok(()),
            Self::WriteMultipleRegisters { values, .. } => check_quantity(
                self.wire_function(),
                quantity_of(values.len()),
                MAX_WRITE_REGISTERS,
            ),
        }
    }

    /// Appends the PDU as sent: the plain function code and 4-byte registers. More than 63 values
    /// (what a one-byte byte count can describe) are cut; [`Request32::validate`] reports it first.
    pub fn encode(&self, out: &mut Vec<u8>) {
        let mut w = Writer::new(out);
        w.u8(self.wire_function().0);
        match self {
            Self::ReadHoldingRegisters { address, quantity } => {
                w.u16_be(*address).u16_be(*quantity);
            }
            Self::WriteSingleRegister { address, value } => {
                w.u16_be(*address).u32_be(*value);
            }
            Self::WriteMultipleRegisters { address, values } => {
                let values = values.get(..255 / 4).unwrap_or(values);
                w.u16_be(*address)
                    .u16_be(quantity_of(values.len()))
                    .count_u8(values.len() * 4);
                for &value in values {
                    w.u32_be(value);
                }
            }
        }
    }

    /// Decodes a request as a slave with 32-bit access enabled does (limits 1..62 / 1..61,
    /// byte count 4 x quantity). Other function codes are [`PduError::UnsupportedFunction`].
    pub fn decode(pdu: &[u8]) -> Result<Self, PduError> {
        let mut r = Reader::new(pdu);
        let function = FunctionCode(r.u8().map_err(|_| PduError::Empty)?);
        let err = |e: CodecError| PduError::from_codec(function.0, e);
        let request = match function {
            FunctionCode::READ_HOLDING_REGISTERS => {
                let address = r.u16_be().map_err(err)?;
                let quantity = r.u16_be().map_err(err)?;
                r.expect_end().map_err(err)?;
                check_quantity(function, quantity, MAX_READ_REGISTERS)?;
                Self::ReadHoldingRegisters { address, quantity }
            }
            FunctionCode::WRITE_SINGLE_REGISTER => {
                let address = r.u16_be().map_err(err)?;
                let value = r.u32_be().map_err(err)?;
                r.expect_end().map_err(err)?;
                Self::WriteSingleRegister { address, value }
            }
            FunctionCode::WRITE_MULTIPLE_REGISTERS => {
                let address = r.u16_be().map_err(err)?;
                let quantity = r.u16_be().map_err(err)?;
                let byte_count = r.u8().map_err(err)?;
                check_quantity(function, quantity, MAX_WRITE_REGISTERS)?;
                let expected = usize::from(quantity) * 4;
                if usize::from(byte_count) != expected {
                    return Err(PduError::ByteCountMismatch {
                        function: function.0,
                        byte_count,
                        expected,
                    });
                }
                let values = u32s_be(r.take(expected).map_err(err)?);
                r.expect_end().map_err(err)?;
                Self::WriteMultipleRegisters { address, values }
            }
            FunctionCode(other) => return Err(PduError::UnsupportedFunction(other)),
        };
        Ok(request)
    }
}

// === impl Response32 ===

impl Response32 {
    /// The code sent on the wire (03h, 06h, 10h).
    pub const fn wire_function(&self) -> FunctionCode {
        match self {
            Self::ReadHoldingRegisters(_) => FunctionCode::READ_HOLDING_REGISTERS,
            Self::WriteSingleRegister { .. } => FunctionCode::WRITE_SINGLE_REGISTER,
            Self::WriteMultipleRegisters { .. } => FunctionCode::WRITE_MULTIPLE_REGISTERS,
        }
    }

    /// Appends the PDU as a slave sends it (at most 63 registers fit the byte count).
    pub fn encode(&self, out: &mut Vec<u8>) {
        let mut w = Writer::new(out);
        w.u8(self.wire_function().0);
        match self {
            Self::ReadHoldingRegisters(values) => {
                let values = values.get(..255 / 4).unwrap_or(values);
                w.count_u8(values.len() * 4);
                for &value in values {
                    w.u32_be(value);
                }
            }
            Self::WriteSingleRegister { address, value } => {
                w.u16_be(*address).u32_be(*value);
            }
            Self::WriteMultipleRegisters { address, quantity } => {
                w.u16_be(*address).u16_be(*quantity);
            }
        }
    }

    /// Decodes the answer to `request`, with the same checks and errors as
    /// [`crate::modbus::pdu::Response::decode_for`].
    pub fn decode_for(
        request: &Request32,
        pdu: &[u8],
    ) -> Result<Result<Self, ExceptionResponse>, PduError> {
        let mut r = Reader::new(pdu);
        let function = request.wire_function();
        let err = |e: CodecError| PduError::from_codec(function.0, e);
        let got = r.u8().map_err(|_| PduError::Empty)?;
        if got == function.to_exception() {
            let code = r.u8().map_err(|e| PduError::from_codec(got, e))?;
            r.expect_end().map_err(|e| PduError::from_codec(got, e))?;
            return Ok(Err(ExceptionResponse {
                function,
                code: ExceptionCode::from(code),
            }));
        }
        if got != function.0 {
            return Err(PduError::FunctionMismatch {
                expected: function.0,
                got,
            });
        }
        let response = match request {
            Request32::ReadHoldingRegisters { quantity, .. } => {
                let byte_count = r.u8().map_err(err)?;
                let expected = usize::from(*quantity) * 4;
                if usize::from(byte_count) < expected {
                    return Err(PduError::ByteCountTooSmall {
                        function: function.0,
                        byte_count,
                        expected,
                    });
                }
                if usize::from(byte_count) > expected {
                    return Err(PduError::ByteCountMismatch {
                        function: function.0,
                        byte_count,
                        expected,
                    });
                }
                let values = u32s_be(r.take(expected).map_err(err)?);
                r.expect_end().map_err(err)?;
                Self::ReadHoldingRegisters(values)
            }
            Request32::WriteSingleRegister { address, value } => {
                let got_address = r.u16_be().map_err(err)?;
                let got_value = r.u32_be().map_err(err)?;
                r.expect_end().map_err(err)?;
                echo(function, "address", *address, got_address)?;
                if got_value != *value {
                    // Report the differing half, so the error stays within 16 bits.
                    let (sent, got) = if got_value >> 16 == value >> 16 {
                        (*value & 0xFFFF, got_value & 0xFFFF)
                    } else {
                        (*value >> 16, got_value >> 16)
                    };
                    let narrow = |v: u32| u16::try_from(v).unwrap_or(u16::MAX);
                    return Err(PduError::EchoMismatch {
                        function: function.0,
                        field: "value",
                        expected: narrow(sent),
                        got: narrow(got),
                    });
                }
                Self::WriteSingleRegister {
                    address: got_address,
                    value: got_value,
                }
            }
            Request32::WriteMultipleRegisters { address, values } => {
                let got_address = r.u16_be().map_err(err)?;
                let got_quantity = r.u16_be().map_err(err)?;
                r.expect_end().map_err(err)?;
                echo(function, "address", *address, got_address)?;
                echo(
                    function,
                    "quantity",
                    quantity_of(values.len().min(255 / 4)),
                    got_quantity,
                )?;
                Self::WriteMultipleRegisters {
                    address: got_address,
                    quantity: got_quantity,
                }
            }
        };
        Ok(Ok(response))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::modbus::ascii::{decode_frame, encode_frame};

    #[test]
    fn user_function_codes() {
        assert_eq!(split_user_function(0x43), Ok((FunctionCode(0x03), true)));
        assert_eq!(split_user_function(0x46), Ok((FunctionCode(0x06), true)));
        assert_eq!(split_user_function(0x50), Ok((FunctionCode(0x10), true)));
        assert_eq!(split_user_function(0x03), Ok((FunctionCode(0x03), false)));
        assert_eq!(
            split_user_function(0x41),
            Err(PduError::UnsupportedFunction(0x41))
        );
        assert_eq!(
            Request32::ReadHoldingRegisters {
                address: 0,
                quantity: 1
            }
            .function(),
            FunctionCode(0x43)
        );
    }

    #[test]
    fn read_roundtrip_over_ascii() {
        let request = Request32::ReadHoldingRegisters {
            address: 0x0100,
            quantity: 2,
        };
        let mut pdu = Vec::new();
        request.encode(&mut pdu);
        assert_eq!(pdu, [0x03, 0x01, 0x00, 0x00, 0x02]);
        let mut frame = Vec::new();
        encode_frame(0x11, &pdu, &mut frame);
        let (address, decoded) = decode_frame(&frame).unwrap();
        assert_eq!(address, 0x11);
        assert_eq!(Request32::decode(&decoded), Ok(request.clone()));

        // 222.0 and 333.0 as IEEE-754 (001 4.4 example values).
        let response = Response32::ReadHoldingRegisters(vec![0x435E_0000, 0x43A6_8000]);
        let mut pdu = Vec::new();
        response.encode(&mut pdu);
        assert_eq!(
            pdu,
            [0x03, 0x08, 0x43, 0x5E, 0x00, 0x00, 0x43, 0xA6, 0x80, 0x00]
        );
        assert_eq!(Response32::decode_for(&request, &pdu), Ok(Ok(response)));
        assert_eq!(
            Response32::decode_for(&request, &[0x03, 0x04, 0x43, 0x5E, 0x00, 0x00]),
            Err(PduError::ByteCountTooSmall {
                function: 3,
                byte_count: 4,
                expected: 8
            })
        );
        assert_eq!(
            Response32::decode_for(&request, &[0x83, 0x02]),
            Ok(Err(ExceptionResponse {
                function: FunctionCode(3),
                code: ExceptionCode::IllegalDataAddress
            }))
        );
    }

    #[test]
    fn writes_and_limits() {
        let single = Request32::WriteSingleRegister {
            address: 7,
            value: 0x0102_0304,
        };
        let pdu = {
            let mut v = Vec::new();
            single.encode(&mut v);
            v
        };
        assert_eq!(pdu, [0x06, 0x00, 0x07, 0x01, 0x02, 0x03, 0x04]);
        assert_eq!(Request32::decode(&pdu), Ok(single.clone()));
        assert_eq!(
            Response32::decode_for(&single, &pdu),
            Ok(Ok(Response32::WriteSingleRegister {
                address: 7,
                value: 0x0102_0304
            }))
        );
        assert_eq!(
            Response32::decode_for(&single, &[0x06, 0x00, 0x07, 0x01, 0x02, 0x03, 0x05]),
            Err(PduError::EchoMismatch {
                function: 6,
                field: "value",
                expected: 0x0304,
                got: 0x0305
            })
        );

        let multi = Request32::WriteMultipleRegisters {
            address: 9,
            values: vec![1, 2],
        };
        let mut pdu = Vec::new();
        multi.encode(&mut pdu);
        assert_eq!(pdu, [0x10, 0, 9, 0, 2, 8, 0, 0, 0, 1, 0, 0, 0, 2]);
        assert_eq!(Request32::decode(&pdu), Ok(multi.clone()));
        assert_eq!(
            Response32::decode_for(&multi, &[0x10, 0, 9, 0, 2]),
            Ok(Ok(Response32::WriteMultipleRegisters {
                address: 9,
                quantity: 2
            }))
        );
        assert_eq!(
            Request32::decode(&[0x10, 0, 9, 0, 2, 4, 0, 0, 0, 1]),
            Err(PduError::ByteCountMismatch {
                function: 0x10,
                byte_count: 4,
                expected: 8
            })
        );

        assert!(Request32::ReadHoldingRegisters {
            address: 0,
            quantity: 62
        }
        .validate()
        .is_ok());
        assert_eq!(
            Request32::ReadHoldingRegisters {
                address: 0,
                quantity: 63
            }
            .validate(),
            Err(PduError::QuantityOutOfRange {
                function: 3,
                quantity: 63,
                min: 1,
                max: 62
            })
        );
        assert!(Request32::WriteMultipleRegisters {
            address: 0,
            values: vec![0; 61]
        }
        .validate()
        .is_ok());
        assert!(Request32::WriteMultipleRegisters {
            address: 0,
            values: vec![0; 62]
        }
        .validate()
        .is_err());
        assert!(Request32::WriteMultipleRegisters {
            address: 0,
            values: vec![]
        }
        .validate()
        .is_err());
        assert_eq!(
            Request32::decode(&[0x03, 0, 0, 0, 63])
                .unwrap_err()
                .function(),
            Some(3)
        );
        assert_eq!(
            Request32::decode(&[0x04, 0, 0, 0, 1]),
            Err(PduError::UnsupportedFunction(4))
        );
    }
}
