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
//! range would be half a slave register and is refused ([`SubmitError::HalfRegister`]), as is a
//! read of an odd range. The other tables keep their 16-bit or bit access.

use super::types::{MasterEvent, Outcome, SubmitError};
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

    /// The job a 16-bit request to the holding registers stands for on a line with `registers32`
    /// (see the module documentation); `None` for a request the mode leaves alone (every table but
    /// the holding registers, FC 23), an error for a range that splits a 32-bit register.
    pub fn from_16bit(request: &Request) -> Option<Result<Self, SubmitError>> {
        to_32bit(request)
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

/// The 32-bit job for a 16-bit request; `None` for a request the mode leaves alone (every table
/// but the holding registers, FC 23).
pub(super) fn to_32bit(request: &Request) -> Option<Result<Request32, SubmitError>> {
    let half = |address: u16, quantity: u16| SubmitError::HalfRegister { address, quantity };
    let slave_address = |address: u16, quantity: u16| {
        if address % IMAGE_WORDS != 0 || quantity % IMAGE_WORDS != 0 || quantity == 0 {
            Err(half(address, quantity))
        } else {
            Ok(address / IMAGE_WORDS)
        }
    };
    Some(match request {
        Request::ReadHoldingRegisters { address, quantity } => slave_address(*address, *quantity)
            .map(|address| Request32::ReadHoldingRegisters {
                address,
                quantity: quantity / IMAGE_WORDS,
            }),
        Request::WriteSingleRegister { address, .. } => Err(half(*address, 1)),
        Request::WriteMultipleRegisters { address, values } => {
            let quantity = u16::try_from(values.len()).unwrap_or(u16::MAX);
            slave_address(*address, quantity).map(|address| {
                let mut joined: Vec<u32> = values
                    .chunks_exact(usize::from(IMAGE_WORDS))
                    .map(|pair| match pair {
                        [high, low] => u32::from(*high) << 16 | u32::from(*low),
                        _ => 0,
                    })
                    .collect();
                match (joined.pop(), joined.is_empty()) {
                    (Some(value), true) => Request32::WriteSingleRegister { address, value },
                    (last, _) => {
                        joined.extend(last);
                        Request32::WriteMultipleRegisters {
                            address,
                            values: joined,
                        }
                    }
                }
            })
        }
        _ => return None,
    })
}

/// A master event with a finished 32-bit job turned into the completion of the 16-bit request it
/// was made from (the answer's registers split high word first), and the function code of the job
/// (43h, 46h, 50h). Other events pass unchanged with `None`.
pub(super) fn as_16bit(event: MasterEvent) -> (MasterEvent, Option<u8>) {
    let MasterEvent::Completed32 {
        id,
        slave,
        request,
        outcome,
    } = event
    else {
        return (event, None);
    };
    let function = request.job_function();
    let image = |address: u16| address.saturating_mul(IMAGE_WORDS);
    let split = |value: u32| [(value >> 16) as u16, value as u16];
    let request16 = match &request {
        Request32::ReadHoldingRegisters { address, quantity } => Request::ReadHoldingRegisters {
            address: image(*address),
            quantity: quantity.saturating_mul(IMAGE_WORDS),
        },
        Request32::WriteSingleRegister { address, value } => Request::WriteMultipleRegisters {
            address: image(*address),
            values: split(*value).to_vec(),
        },
        Request32::WriteMultipleRegisters { address, values } => Request::WriteMultipleRegisters {
            address: image(*address),
            values: values.iter().flat_map(|v| split(*v)).collect(),
        },
    };
    let outcome = match outcome {
        Outcome::Response(response) => Outcome::Response(match response {
            Response32::ReadHoldingRegisters(values) => {
                Response::ReadHoldingRegisters(values.into_iter().flat_map(split).collect())
            }
            Response32::WriteSingleRegister { address, .. } => Response::WriteMultipleRegisters {
                address: image(address),
                quantity: IMAGE_WORDS,
            },
            Response32::WriteMultipleRegisters { address, quantity } => {
                Response::WriteMultipleRegisters {
                    address: image(address),
                    quantity: quantity.saturating_mul(IMAGE_WORDS),
                }
            }
        }),
        Outcome::Exception(code) => Outcome::Exception(code),
        Outcome::Broadcast => Outcome::Broadcast,
        Outcome::Failed(event) => Outcome::Failed(event),
    };
    (
        MasterEvent::Completed {
            id,
            slave,
            request: request16,
            outcome,
        },
        Some(function),
    )
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::modbus::master::RequestId;

    fn job(request: Request) -> Request32 {
        match to_32bit(&request) {
            Some(Ok(job)) => job,
            other => panic!("{request:?} gave {other:?}"),
        }
    }

    /// An on-demand read of part of a 32-bit register reads all of it, and the client gets the
    /// part it asked for.
    #[test]
    fn a_read_of_half_a_register_reads_the_whole_and_answers_the_half() {
        let read = |address, quantity| Request::ReadHoldingRegisters { address, quantity };
        assert_eq!(widen_read(&read(4, 2)), None, "whole registers");
        assert_eq!(widen_read(&read(5, 1)), Some(read(4, 2)));
        assert_eq!(widen_read(&read(4, 1)), Some(read(4, 2)));
        assert_eq!(widen_read(&read(3, 4)), Some(read(2, 6)));
        assert_eq!(widen_read(&read(65_535, 1)), Some(read(65_534, 2)));
        assert_eq!(
            widen_read(&Request::ReadInputRegisters {
                address: 5,
                quantity: 1
            }),
            None,
            "only holding registers are 32 bits wide"
        );
        let answer = Response::ReadHoldingRegisters(vec![0xA, 0xB, 0xC, 0xD, 0xE, 0xF]);
        assert_eq!(
            narrow(&read(3, 4), &read(2, 6), answer.clone()),
            Response::ReadHoldingRegisters(vec![0xB, 0xC, 0xD, 0xE])
        );
        assert_eq!(
            narrow(
                &read(5, 1),
                &read(4, 2),
                Response::ReadHoldingRegisters(vec![1, 2])
            ),
            Response::ReadHoldingRegisters(vec![2])
        );
        assert_eq!(narrow(&read(2, 6), &read(2, 6), answer.clone()), answer);
    }

    #[test]
    fn image_ranges_map_to_slave_registers() {
        assert_eq!(
            job(Request::ReadHoldingRegisters {
                address: 10,
                quantity: 4
            }),
            Request32::ReadHoldingRegisters {
                address: 5,
                quantity: 2
            }
        );
        assert_eq!(
            job(Request::WriteMultipleRegisters {
                address: 2,
                values: vec![0xDEAD, 0xBEEF]
            }),
            Request32::WriteSingleRegister {
                address: 1,
                value: 0xDEAD_BEEF
            }
        );
        assert_eq!(
            job(Request::WriteMultipleRegisters {
                address: 0,
                values: vec![1, 2, 3, 4]
            }),
            Request32::WriteMultipleRegisters {
                address: 0,
                values: vec![0x0001_0002, 0x0003_0004]
            }
        );
        for half in [
            Request::ReadHoldingRegisters {
                address: 1,
                quantity: 2,
            },
            Request::ReadHoldingRegisters {
                address: 0,
                quantity: 3,
            },
            Request::WriteSingleRegister {
                address: 0,
                value: 1,
            },
        ] {
            assert!(matches!(
                to_32bit(&half),
                Some(Err(SubmitError::HalfRegister { .. }))
            ));
        }
        assert!(to_32bit(&Request::ReadInputRegisters {
            address: 1,
            quantity: 1
        })
        .is_none());
    }

    #[test]
    fn a_finished_read_is_the_16_bit_read_high_word_first() {
        let (event, function) = as_16bit(MasterEvent::Completed32 {
            id: RequestId(7),
            slave: 5,
            request: Request32::ReadHoldingRegisters {
                address: 1,
                quantity: 2,
            },
            outcome: Outcome::Response(Response32::ReadHoldingRegisters(vec![
                0x1234_5678,
                0x435E_0000,
            ])),
        });
        assert_eq!(function, Some(0x43));
        assert_eq!(
            event,
            MasterEvent::Completed {
                id: RequestId(7),
                slave: 5,
                request: Request::ReadHoldingRegisters {
                    address: 2,
                    quantity: 4
                },
                outcome: Outcome::Response(Response::ReadHoldingRegisters(vec![
                    0x1234, 0x5678, 0x435E, 0
                ])),
            }
        );
    }

    #[test]
    fn read_round_trip() {
        let request = Request32::ReadHoldingRegisters {
            address: 0x0010,
            quantity: 2,
        };
        let mut pdu = Vec::new();
        request.encode(&mut pdu);
        assert_eq!(pdu, [0x03, 0x00, 0x10, 0x00, 0x02]);
        let answer = [0x03, 0x08, 0x12, 0x34, 0x56, 0x78, 0x00, 0x00, 0x00, 0x01];
        assert_eq!(
            request.decode_response(&answer),
            Ok(Response32::ReadHoldingRegisters(vec![0x1234_5678, 1]))
        );
        assert!(matches!(
            request.decode_response(&answer[..9]),
            Err(PduError::TooShort { .. })
        ));
        assert!(matches!(
            request.decode_response(&[0x03, 0x04, 0, 0, 0, 0]),
            Err(PduError::ByteCountTooSmall {
                byte_count: 4,
                expected: 8,
                ..
            })
        ));
        assert!(matches!(
            request.decode_response(&[0x04, 0x00]),
            Err(PduError::FunctionMismatch { .. })
        ));
        assert_eq!(request.decode_response(&[]), Err(PduError::Empty));
    }

    #[test]
    fn writes_encode_and_check_the_echo() {
        let single = Request32::WriteSingleRegister {
            address: 7,
            value: 0xDEAD_BEEF,
        };
        let mut pdu = Vec::new();
        single.encode(&mut pdu);
        assert_eq!(pdu, [0x06, 0x00, 0x07, 0xDE, 0xAD, 0xBE, 0xEF]);
        assert_eq!(
            single.decode_response(&pdu),
            Ok(Response32::WriteSingleRegister {
                address: 7,
                value: 0xDEAD_BEEF
            })
        );
        assert!(matches!(
            single.decode_response(&[0x06, 0x00, 0x07, 0xDE, 0xAD, 0xBE, 0xEE]),
            Err(PduError::EchoMismatch { field: "value", .. })
        ));
        let multiple = Request32::WriteMultipleRegisters {
            address: 1,
            values: vec![1, 2],
        };
        pdu.clear();
        multiple.encode(&mut pdu);
        assert_eq!(
            pdu,
            [0x10, 0x00, 0x01, 0x00, 0x02, 0x08, 0, 0, 0, 1, 0, 0, 0, 2]
        );
        assert_eq!(
            multiple.decode_response(&[0x10, 0x00, 0x01, 0x00, 0x02]),
            Ok(Response32::WriteMultipleRegisters {
                address: 1,
                quantity: 2
            })
        );
        assert!(matches!(
            multiple.decode_response(&[0x10, 0x00, 0x01, 0x00, 0x03]),
            Err(PduError::EchoMismatch {
                field: "quantity",
                ..
            })
        ));
        assert!(matches!(
            multiple.decode_response(&[0x10, 0x00, 0x01, 0x00, 0x02, 0x00]),
            Err(PduError::TrailingData { .. })
        ));
    }

    #[test]
    fn job_functions_have_bit_6_set_and_the_wire_keeps_the_plain_code() {
        // 003 6.4.4: the send DB carries 43h / 46h / 50h, the wire 03h / 06h / 10h.
        let jobs = [
            Request32::ReadHoldingRegisters {
                address: 0,
                quantity: 1,
            },
            Request32::WriteSingleRegister {
                address: 0,
                value: 0,
            },
            Request32::WriteMultipleRegisters {
                address: 0,
                values: vec![0],
            },
        ];
        let codes: Vec<_> = jobs
            .iter()
            .map(|j| (j.job_function(), j.function().0))
            .collect();
        assert_eq!(codes, [(0x43, 0x03), (0x46, 0x06), (0x50, 0x10)]);
        for (job, wire) in codes {
            assert_eq!(job & !0x40, wire);
        }
    }

    #[test]
    fn read_of_two_floats_over_ascii() {
        // 222.0 and 333.0 as IEEE-754 (001 4.4 example values), framed as ASCII.
        let request = Request32::ReadHoldingRegisters {
            address: 0x0100,
            quantity: 2,
        };
        let mut pdu = Vec::new();
        request.encode(&mut pdu);
        let mut frame = Vec::new();
        crate::modbus::ascii::encode_frame(0x11, &pdu, &mut frame);
        let (address, decoded) = crate::modbus::ascii::decode_frame(&frame).expect("frame");
        assert_eq!(
            (address, decoded.as_slice()),
            (0x11, &[0x03, 0x01, 0x00, 0x00, 0x02][..])
        );
        let answer = [0x03, 0x08, 0x43, 0x5E, 0x00, 0x00, 0x43, 0xA6, 0x80, 0x00];
        let Ok(Response32::ReadHoldingRegisters(values)) = request.decode_response(&answer) else {
            panic!("a read answer");
        };
        let floats: Vec<f32> = values.into_iter().map(f32::from_bits).collect();
        assert_eq!(floats, [222.0, 333.0]);
    }
}
