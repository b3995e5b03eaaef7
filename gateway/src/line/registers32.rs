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
