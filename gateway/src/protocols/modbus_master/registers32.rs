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
//! proto-core's master does the translation itself: on such a line it takes the 16-bit request,
//! sends the 32-bit job and completes with the 16-bit request and answer
//! (`Master::submit_with`). What stays here needs the line: the devices' limits, the
//! read-modify-write of a bit (its `BitUpdate` is a profile's, which proto-core's modbus module does
//! not know).

use proto_core::modbus::master::IMAGE_WORDS;
use proto_core::modbus::pdu::Request;
use proto_core::profiles::BitUpdate;

use super::plan::DeviceLimits;

/// Most 32-bit registers one 43h read carries (003 7.2, 0E 45h "with 32bit 1...62").
pub(crate) const MAX_READ_32: u16 = 62;
/// Most 32-bit registers one 50h write carries (003 7.2, 0E 46h "with 32bit 1..61").
pub(crate) const MAX_WRITE_32: u16 = 61;

/// Whether the line's master runs the 32-bit register mode.
pub(crate) fn enabled(master: &proto_core::modbus::master::MasterConfig) -> bool {
    master.framing.registers32()
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

#[cfg(test)]
mod tests {
    use super::*;
    use proto_core::modbus::master::Request32;

    fn job(request: Request) -> Request32 {
        match Request32::from_16bit(&request) {
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
