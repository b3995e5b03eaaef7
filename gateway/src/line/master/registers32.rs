//! The 32-bit register mode of a Modbus master ASCII line (003 6.4.4 "32bit access with Modbus
//! Master ASCII", parameter "with 32-Bit Register" of 6.4.2.2).
//!
//! With `registers32 = true` the slave's holding registers are 32 bits wide and the CP reaches
//! them with the function codes 43h (read), 46h (write one) and 50h (write several): bit 6 set in
//! the send DB, 03h / 06h / 10h on the wire, every register 4 bytes, most significant byte first.
//! The other tables (coils, discrete inputs, input registers) keep their 16-bit or bit access: the
//! manual allows the 32-bit form for 03, 06 and 16 only (003 7.2, event 0E 4Ah).
//!
//! The gateway's image and Modbus TCP stay 16-bit, so each 32-bit register of the slave is two
//! image registers, the high word first:
//!
//! ```text
//! slave register n (32 bits)  <->  image / Modbus TCP holding registers 2n (high), 2n + 1 (low)
//! ```
//!
//! A poll range or tag of such a device therefore starts at an even image address and covers an
//! even count (an `u32`, `i32` or `f32` tag with `word_order = "high-first"` is one slave
//! register). A read of image registers `2n .. 2n + 2k` goes out as 43h for `k` registers from
//! `n`; a write of two image registers (FC 16) as 46h, of more as 50h. A write of a single image
//! register (FC 06) or of an odd range would be half a slave register and is refused, as is a
//! read of an odd range.
//!
//! The line's master submits through [`submit`] and turns the 32-bit completion back into the
//! 16-bit request and answer the rest of the line handles with [`as_16bit`].

use std::fmt;

use proto_core::modbus::master::{
    Attempts, Master, MasterEvent, Outcome, Request32, RequestId, Response32, SubmitError,
};
use proto_core::modbus::pdu::{Request, Response};
use proto_core::profiles::BitUpdate;
use proto_core::time::Instant;

use super::plan::DeviceLimits;

/// Most 32-bit registers one 43h read carries (003 7.2, 0E 45h "with 32bit 1...62").
pub(crate) const MAX_READ_32: u16 = 62;
/// Most 32-bit registers one 50h write carries (003 7.2, 0E 46h "with 32bit 1..61").
pub(crate) const MAX_WRITE_32: u16 = 61;

/// Image registers one 32-bit register of the slave occupies.
const IMAGE_WORDS: u16 = 2;

/// Why a request cannot go out as a 32-bit register job.
#[derive(Debug)]
pub(crate) enum Submit32Error {
    /// The range starts or ends inside a 32-bit register (odd image address or count).
    HalfRegister { address: u16, quantity: u16 },
    /// The master refused the job.
    Master(SubmitError),
}

impl fmt::Display for Submit32Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::HalfRegister { address, quantity } => write!(
                f,
                "holding registers {address}+{quantity} split a 32-bit register of the slave \
                 (registers32: each is two image registers from an even address)"
            ),
            Self::Master(e) => e.fmt(f),
        }
    }
}

/// Whether the line's master runs the 32-bit register mode.
pub(crate) fn enabled(master: &proto_core::modbus::master::MasterConfig) -> bool {
    matches!(
        master.framing,
        proto_core::modbus::master::Framing::Ascii {
            registers32: true,
            ..
        }
    )
}

/// The line's devices, with [`limits`] applied when the line runs the 32-bit register mode.
pub(crate) fn line_devices(
    master: &proto_core::modbus::master::MasterConfig,
    devices: Vec<std::sync::Arc<super::DeviceSettings>>,
) -> Vec<std::sync::Arc<super::DeviceSettings>> {
    if !enabled(master) {
        return devices;
    }
    devices
        .into_iter()
        .map(|d| {
            let mut d = (*d).clone();
            d.limits = limits(d.limits);
            std::sync::Arc::new(d)
        })
        .collect()
}

/// A device's limits on a 32-bit line, in image registers: at most 62 slave registers a read, 61
/// a write, and always an even number so that a split read does not cut a register in two.
pub(crate) fn limits(mut limits: DeviceLimits) -> DeviceLimits {
    let even = |n: u16, max32: u16| (n.min(max32 * IMAGE_WORDS) / IMAGE_WORDS * IMAGE_WORDS).max(2);
    limits.max_read_regs = even(limits.max_read_regs, MAX_READ_32);
    limits.max_write_regs = even(limits.max_write_regs, MAX_WRITE_32);
    limits
}

/// The read of a read-modify-write of a bit on a 32-bit line: the two image registers of the
/// 32-bit register the bit's register is half of (one 43h read of it).
pub(crate) fn bit_update_read(update: BitUpdate) -> Request {
    Request::ReadHoldingRegisters {
        address: update.address & !1,
        quantity: IMAGE_WORDS,
    }
}

/// The write of a read-modify-write from what its read returned, `None` when the read did not
/// return what it asked for: on a 16-bit line the changed register (FC 06); on a 32-bit line
/// (`registers32`) the whole 32-bit register with the changed half (two image registers from
/// the even address: 46h), since half of one cannot be written.
pub(crate) fn bit_update_write(
    update: BitUpdate,
    words: &[u16],
    registers32: bool,
) -> Option<Request> {
    match (registers32, words) {
        (false, [current]) => Some(Request::WriteSingleRegister {
            address: update.address,
            value: update.apply(*current),
        }),
        (true, [high, low]) => {
            let (high, low) = if update.address % 2 == 0 {
                (update.apply(*high), *low)
            } else {
                (*high, update.apply(*low))
            };
            Some(Request::WriteMultipleRegisters {
                address: update.address & !1,
                values: vec![high, low],
            })
        }
        _ => None,
    }
}

/// A read of holding registers that starts or ends inside a 32-bit register of the slave, widened
/// to the whole 32-bit registers it touches (a slave register cannot be read by halves, 003
/// 6.4.4); `None` when it needs no widening (or is no such read).
pub(crate) fn widen_read(request: &Request) -> Option<Request> {
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
pub(crate) fn narrow(asked: &Request, sent: &Request, response: Response) -> Response {
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

/// The 32-bit job for a request of the 16-bit image; `None` for a request the mode leaves alone
/// (every table but the holding registers, FC 23).
fn to_32bit(request: &Request) -> Option<Result<Request32, Submit32Error>> {
    let half = |address: u16, quantity: u16| Submit32Error::HalfRegister { address, quantity };
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

/// Submits `request` to the line's master: as a 32-bit register job when the line runs the mode
/// and the request reaches holding registers, else as it is with `attempts`.
pub(crate) fn submit(
    master: &mut Master,
    registers32: bool,
    now: Instant,
    slave: u8,
    request: Request,
    attempts: Attempts,
) -> Result<RequestId, Submit32Error> {
    match to_32bit(&request).filter(|_| registers32) {
        Some(Ok(job)) => master
            .submit_registers32(now, slave, job)
            .map_err(Submit32Error::Master),
        Some(Err(e)) => Err(e),
        None => master
            .submit_with(now, slave, request, attempts)
            .map_err(Submit32Error::Master),
    }
}

/// A master event with a finished 32-bit job turned into the completion of the 16-bit request it
/// was made from (the answer's registers split high word first), and the function code to count
/// it under (43h, 46h, 50h). Other events pass unchanged with `None`.
pub(crate) fn as_16bit(event: MasterEvent) -> (MasterEvent, Option<u8>) {
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

    fn job(request: Request) -> Request32 {
        match to_32bit(&request) {
            Some(Ok(job)) => job,
            other => panic!("{request:?} gave {other:?}"),
        }
    }

    /// A bit of image register 5 (the low half of slave register 2): the whole 32-bit register
    /// is read and written back with only that half changed; a 16-bit line writes the register.
    #[test]
    fn a_bit_write_reads_and_writes_the_whole_32_bit_register() {
        let set_bit_3 = |address| BitUpdate {
            address,
            and: !0x0008,
            or: 0x0008,
        };
        let read = bit_update_read(set_bit_3(5));
        assert_eq!(
            read,
            Request::ReadHoldingRegisters {
                address: 4,
                quantity: 2
            }
        );
        assert_eq!(
            job(read),
            Request32::ReadHoldingRegisters {
                address: 2,
                quantity: 1
            }
        );
        let write = bit_update_write(set_bit_3(5), &[0x1234, 0x0001], true).expect("a write");
        assert_eq!(
            write,
            Request::WriteMultipleRegisters {
                address: 4,
                values: vec![0x1234, 0x0009]
            }
        );
        assert_eq!(
            job(write),
            Request32::WriteSingleRegister {
                address: 2,
                value: 0x1234_0009
            }
        );
        // The high half, from an even address.
        assert_eq!(
            bit_update_write(set_bit_3(4), &[0x1234, 0x0001], true),
            Some(Request::WriteMultipleRegisters {
                address: 4,
                values: vec![0x123C, 0x0001]
            })
        );
        // A 16-bit line: one register; a read that returned something else: no write.
        assert_eq!(
            bit_update_write(set_bit_3(5), &[0x0001], false),
            Some(Request::WriteSingleRegister {
                address: 5,
                value: 0x0009
            })
        );
        assert_eq!(bit_update_write(set_bit_3(5), &[0x0001], true), None);
        assert_eq!(bit_update_write(set_bit_3(5), &[1, 2], false), None);
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
                Some(Err(Submit32Error::HalfRegister { .. }))
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
    fn limits_are_even_and_within_the_32_bit_ranges() {
        let l = limits(DeviceLimits::CP341);
        assert_eq!((l.max_read_regs, l.max_write_regs), (124, 122));
        let l = limits(DeviceLimits {
            max_read_regs: 63,
            max_write_regs: 1,
            ..DeviceLimits::CP341
        });
        assert_eq!((l.max_read_regs, l.max_write_regs), (62, 2));
    }
}
