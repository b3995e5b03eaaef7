//! The 16-bit image's side of 32-bit registers (manual 003, 6.4.4): a 16-bit holding-register
//! request of the master's callers becomes the 32-bit job the slave understands, and the job's
//! completion the completion of that 16-bit request (each slave register is two image registers,
//! the high word first; see `registers32` for the wire format).

use super::registers32::{Request32, Response32, IMAGE_WORDS};
use super::types::{MasterEvent, Outcome, SubmitError};
use crate::modbus::pdu::{Request, Response};

// === impl Request32 ===

impl Request32 {
    /// The job a 16-bit request to the holding registers stands for on a line with `registers32`
    /// (see the module documentation); `None` for a request the mode leaves alone (every table but
    /// the holding registers, FC 23), an error for a range that splits a 32-bit register.
    pub fn from_16bit(request: &Request) -> Option<Result<Self, SubmitError>> {
        to_32bit(request)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::modbus::master::registers32::{narrow, widen_read};
    use crate::modbus::master::RequestId;
    use crate::modbus::pdu::PduError;

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
