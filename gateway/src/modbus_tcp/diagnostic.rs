//! The diagnostic unit: the gateway's own health as read-only registers under one unit id
//! (`[modbus_tcp] diagnostic_unit`), for SCADA systems that read Modbus but not Prometheus.
//!
//! The layout (docs/diagnostics.md has it with a worked example) is a header, then one block per
//! line in the order of the lines' names, then one block per polled device (Modbus master lines,
//! in line order, each line's devices in the order of their names). FC 03 and FC 04 read the same
//! registers; 32-bit counters are high word first and stop at 4294967295.
//!
//! | block | offset | meaning |
//! |---|---|---|
//! | header | 0 | layout version (1) |
//! | header | 1 | lines |
//! | header | 2 | devices |
//! | header | 3 | header size (16) |
//! | header | 4 | line block size (32) |
//! | header | 5 | device block size (8) |
//! | header | 6 | address of the first line block (16) |
//! | header | 7 | address of the first device block (16 + 32 x lines) |
//! | header | 8 | event classes counted in a line block (10) |
//! | header | 9..15 | reserved, 0 |
//! | line | 0 | STATUS word of the line's newest event (003 7.2: bits 12..8 class, 7..0 number; 0 = none) |
//! | line | 1 | port open: 1, closed: 0 |
//! | line | 2 | devices online |
//! | line | 3 | devices polled |
//! | line | 4..5 | frames (telegrams) sent |
//! | line | 6..7 | frames (telegrams) received complete and valid |
//! | line | 8..9 | errors: events of every class but 00h "CP start-up" |
//! | line | 10..11 | commands failed |
//! | line | 12..31 | events per class (003 7.2), two registers each: 00h, 01h, 02h, 03h, 04h, 05h, 07h, 08h, 0Eh, 1Eh |
//! | device | 0 | online: 1, backed off: 0 |
//! | device | 1 | age of its oldest polled value in 100 ms steps, 65535 at and above 6553.5 s or before the first poll |
//! | device | 2 | exception code of the newest poll it answered with an exception (0 = none) |
//! | device | 3 | its line: the line block's number, 0 for the first |
//! | device | 4 | its unit id |
//! | device | 5 | its slave address |
//! | device | 6..7 | polls without a valid answer |
//!
//! Nothing here can be written: the unit has no writable register, so every function but FC 03
//! and FC 04 (writes included) is answered with exception 01 "illegal function" (Modbus
//! Application Protocol V1.1b3, 7: the function "is not an allowable action for the server");
//! 02 "illegal data address" is kept for reads past the last register.

use std::future::ready;
use std::time::Duration;

use proto_core::event::{self, EventId};
use proto_core::modbus::pdu::{ExceptionCode, Request, Response};
use tokio::time::Instant;

use crate::image::ProcessImage;
use crate::line::LineHandle;
use crate::mailbox::layout::counter_word;
use crate::unit::{UnitFuture, UnitResult, UnitService};

/// Version of the layout; raised when a register changes its meaning.
pub const VERSION: u16 = 1;
/// Registers of the header.
pub const HEADER_SIZE: u16 = 16;
/// Event classes counted per line: the classes of 003 7.2.
pub const CLASSES: u16 = 10;
/// Registers of a line block.
pub const LINE_BLOCK: u16 = 12 + 2 * CLASSES;
/// Registers of a device block.
pub const DEVICE_BLOCK: u16 = 8;
/// The age register's unit.
pub const AGE_STEP: Duration = Duration::from_millis(100);

/// One line as the layout shows it.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LineDiag {
    /// STATUS word of the newest event.
    pub status_word: u16,
    pub port_open: bool,
    pub devices_online: u16,
    pub devices_total: u16,
    pub frames_sent: u64,
    pub frames_received: u64,
    /// Events of every class but 00h.
    pub errors: u64,
    pub commands_failed: u64,
    /// Events counted per class, in the order of [`event::classes`].
    pub classes: [u64; CLASSES as usize],
}

/// One polled device as the layout shows it.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct DeviceDiag {
    pub online: bool,
    /// Age of the oldest polled value; `None` before the first poll.
    pub age: Option<Duration>,
    /// Exception code of the newest poll answered with an exception.
    pub last_exception: Option<u8>,
    /// Index of its line in the line blocks.
    pub line: u16,
    pub unit_id: u8,
    pub slave: u8,
    pub polls_failed: u64,
}

// === impl LineDiag ===

impl LineDiag {
    /// Event counts by id folded into the per-class counters and the error count.
    pub fn count_events<'a>(&mut self, counts: impl IntoIterator<Item = (&'a EventId, &'a u64)>) {
        for (id, n) in counts {
            if let Some(i) = event::classes().iter().position(|(c, _)| *c == id.class) {
                if let Some(slot) = self.classes.get_mut(i) {
                    *slot = slot.saturating_add(*n);
                }
            }
            if id.class != 0 {
                self.errors = self.errors.saturating_add(*n);
            }
        }
    }
}

/// A count as a register (saturating).
fn reg(n: usize) -> u16 {
    u16::try_from(n).unwrap_or(u16::MAX)
}

fn push_u32(out: &mut Vec<u16>, value: u64) {
    out.push(counter_word(value, true));
    out.push(counter_word(value, false));
}

/// The age register: 100 ms steps, saturating; 65535 before the first poll.
pub fn age_steps(age: Option<Duration>) -> u16 {
    age.map_or(u16::MAX, |age| {
        u16::try_from(age.as_millis() / AGE_STEP.as_millis()).unwrap_or(u16::MAX)
    })
}

/// Every register of the unit, from address 0.
pub fn registers(lines: &[LineDiag], devices: &[DeviceDiag]) -> Vec<u16> {
    let line_start = HEADER_SIZE;
    let device_start = usize::from(HEADER_SIZE) + lines.len() * usize::from(LINE_BLOCK);
    let mut out = Vec::with_capacity(device_start + devices.len() * usize::from(DEVICE_BLOCK));
    out.extend([
        VERSION,
        reg(lines.len()),
        reg(devices.len()),
        HEADER_SIZE,
        LINE_BLOCK,
        DEVICE_BLOCK,
        line_start,
        reg(device_start),
        CLASSES,
    ]);
    out.resize(usize::from(HEADER_SIZE), 0);
    for line in lines {
        out.extend([
            line.status_word,
            u16::from(line.port_open),
            line.devices_online,
            line.devices_total,
        ]);
        for n in [
            line.frames_sent,
            line.frames_received,
            line.errors,
            line.commands_failed,
        ] {
            push_u32(&mut out, n);
        }
        for n in line.classes {
            push_u32(&mut out, n);
        }
    }
    for device in devices {
        out.extend([
            u16::from(device.online),
            age_steps(device.age),
            u16::from(device.last_exception.unwrap_or(0)),
            device.line,
            u16::from(device.unit_id),
            u16::from(device.slave),
        ]);
        push_u32(&mut out, device.polls_failed);
    }
    out
}

/// `quantity` registers from `address` of `registers`, or exception 02 when the range runs past
/// the last one.
pub fn read(registers: &[u16], address: u16, quantity: u16) -> Result<Vec<u16>, ExceptionCode> {
    let start = usize::from(address);
    registers
        .get(start..start + usize::from(quantity))
        .map(<[u16]>::to_vec)
        .ok_or(ExceptionCode::IllegalDataAddress)
}

/// The diagnostic unit of a set of running lines.
#[derive(Clone, Debug)]
pub struct DiagnosticUnit {
    lines: Vec<LineHandle>,
    image: ProcessImage,
}

// === impl DiagnosticUnit ===

impl DiagnosticUnit {
    /// The unit of `lines` (in the order of their blocks) with the devices' values in `image`.
    pub fn new(lines: Vec<LineHandle>, image: ProcessImage) -> Self {
        Self { lines, image }
    }

    /// The blocks as they are now.
    pub fn snapshot(&self) -> (Vec<LineDiag>, Vec<DeviceDiag>) {
        let now = Instant::now();
        let mut lines = Vec::with_capacity(self.lines.len());
        let mut devices = Vec::new();
        for (index, handle) in self.lines.iter().enumerate() {
            let status = handle.status();
            let traffic = handle.traffic();
            let mut line = LineDiag {
                status_word: status.status_word,
                port_open: status.port_open,
                devices_online: reg(status.devices.iter().filter(|d| d.online).count()),
                devices_total: reg(status.devices.len()),
                frames_sent: traffic.frames_sent,
                frames_received: traffic.frames_received,
                errors: 0,
                commands_failed: traffic.commands_failed,
                classes: [0; CLASSES as usize],
            };
            line.count_events(&status.event_counts);
            lines.push(line);
            for d in &status.devices {
                devices.push(DeviceDiag {
                    online: d.online,
                    age: self
                        .image
                        .oldest_polled(d.unit_id)
                        .map(|at| now.saturating_duration_since(at)),
                    last_exception: d.last_exception,
                    line: reg(index),
                    unit_id: d.unit_id,
                    slave: d.slave,
                    polls_failed: d.polls_failed,
                });
            }
        }
        (lines, devices)
    }

    /// Answers one request: FC 03 and FC 04 read, anything else is exception 01.
    pub fn answer(&self, request: &Request) -> UnitResult {
        let (address, quantity) = match request {
            Request::ReadHoldingRegisters { address, quantity }
            | Request::ReadInputRegisters { address, quantity } => (*address, *quantity),
            _ => return Err(ExceptionCode::IllegalFunction),
        };
        let (lines, devices) = self.snapshot();
        let values = read(&registers(&lines, &devices), address, quantity)?;
        Ok(match request {
            Request::ReadInputRegisters { .. } => Response::ReadInputRegisters(values),
            _ => Response::ReadHoldingRegisters(values),
        })
    }
}

impl UnitService for DiagnosticUnit {
    fn call(&self, request: Request) -> UnitFuture {
        Box::pin(ready(self.answer(&request)))
    }

    fn answer_now(
        &self,
        request: &Request,
        out: &mut Vec<u8>,
    ) -> Option<Result<(), ExceptionCode>> {
        Some(self.answer(request).map(|response| response.encode(out)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(status_word: u16) -> LineDiag {
        LineDiag {
            status_word,
            port_open: true,
            devices_online: 1,
            devices_total: 2,
            frames_sent: 70_000,
            frames_received: 69_999,
            errors: 3,
            commands_failed: 1,
            classes: [1, 0, 0, 0, 0, 0, 0, 3, 0, 0],
        }
    }

    #[test]
    fn the_block_sizes_follow_the_catalog() {
        assert_eq!(usize::from(CLASSES), event::classes().len());
        assert_eq!(LINE_BLOCK, 32);
        assert_eq!(DEVICE_BLOCK, 8);
    }

    #[test]
    fn header_then_line_blocks_then_device_blocks() {
        let lines = [line(0x0830), line(0x0003)];
        let devices = [
            DeviceDiag {
                online: true,
                age: Some(Duration::from_millis(1_299)),
                last_exception: Some(2),
                line: 0,
                unit_id: 2,
                slave: 2,
                polls_failed: 5,
            },
            DeviceDiag {
                online: false,
                age: None,
                last_exception: None,
                line: 1,
                unit_id: 17,
                slave: 17,
                polls_failed: u64::MAX,
            },
        ];
        let regs = registers(&lines, &devices);
        assert_eq!(regs.len(), 16 + 2 * 32 + 2 * 8);
        assert_eq!(
            regs[..16],
            [1, 2, 2, 16, 32, 8, 16, 80, 10, 0, 0, 0, 0, 0, 0, 0]
        );
        // The first line block.
        assert_eq!(
            regs[16..28],
            [0x0830, 1, 1, 2, 1, 0x1170, 1, 0x116F, 0, 3, 0, 1]
        );
        // Class 00h and class 08h (the eighth class of the catalog).
        assert_eq!(regs[28..30], [0, 1]);
        assert_eq!(regs[28 + 2 * 7..28 + 2 * 8], [0, 3]);
        assert_eq!(regs[48], 0x0003);
        // The device blocks.
        assert_eq!(regs[80..88], [1, 12, 2, 0, 2, 2, 0, 5]);
        assert_eq!(regs[88..96], [0, 65535, 0, 1, 17, 17, 0xFFFF, 0xFFFF]);
    }

    #[test]
    fn an_empty_gateway_has_a_header_only() {
        let regs = registers(&[], &[]);
        assert_eq!(regs[..9], [1, 0, 0, 16, 32, 8, 16, 16, 10]);
        assert_eq!(regs.len(), 16);
    }

    #[test]
    fn the_age_saturates_in_100_ms_steps() {
        assert_eq!(age_steps(Some(Duration::ZERO)), 0);
        assert_eq!(age_steps(Some(Duration::from_millis(99))), 0);
        assert_eq!(age_steps(Some(Duration::from_millis(100))), 1);
        assert_eq!(age_steps(Some(Duration::from_millis(6_553_499))), 65_534);
        assert_eq!(age_steps(Some(Duration::from_secs(86_400))), 65_535);
        assert_eq!(age_steps(None), 65_535);
    }

    #[test]
    fn events_count_by_class_and_start_up_is_no_error() {
        let mut l = LineDiag::default();
        let counts = [
            (EventId::new(0x00, 0x03), 2),
            (EventId::new(0x08, 0x30), 4),
            (EventId::new(0x08, 0x0A), 1),
            (EventId::new(0x1E, 0x0D), 1),
        ];
        l.count_events(counts.iter().map(|(id, n)| (id, n)));
        assert_eq!(l.classes, [2, 0, 0, 0, 0, 0, 0, 5, 0, 1]);
        assert_eq!(l.errors, 6);
    }

    #[test]
    fn reads_past_the_end_are_refused_and_writes_are_illegal_functions() {
        let regs = registers(&[line(0)], &[]);
        assert_eq!(read(&regs, 0, 3), Ok(vec![1, 1, 0]));
        assert_eq!(read(&regs, 47, 1).map(|v| v.len()), Ok(1));
        assert_eq!(read(&regs, 47, 2), Err(ExceptionCode::IllegalDataAddress));
        assert_eq!(
            read(&regs, 65_535, 125),
            Err(ExceptionCode::IllegalDataAddress)
        );

        let unit = DiagnosticUnit::new(Vec::new(), ProcessImage::default());
        for request in [
            Request::WriteSingleRegister {
                address: 0,
                value: 1,
            },
            Request::WriteMultipleRegisters {
                address: 0,
                values: vec![1],
            },
            Request::WriteSingleCoil {
                address: 0,
                value: true,
            },
            Request::ReadCoils {
                address: 0,
                quantity: 1,
            },
            Request::ReadWriteMultipleRegisters {
                read_address: 0,
                read_quantity: 1,
                write_address: 0,
                values: vec![1],
            },
        ] {
            assert_eq!(
                unit.answer(&request),
                Err(ExceptionCode::IllegalFunction),
                "{request:?}"
            );
        }
        assert_eq!(
            unit.answer(&Request::ReadInputRegisters {
                address: 0,
                quantity: 3
            }),
            Ok(Response::ReadInputRegisters(vec![1, 0, 0]))
        );
        assert_eq!(
            unit.answer(&Request::ReadHoldingRegisters {
                address: 1,
                quantity: 2
            }),
            Ok(Response::ReadHoldingRegisters(vec![0, 0]))
        );
        let mut out = Vec::new();
        assert_eq!(
            unit.answer_now(
                &Request::ReadHoldingRegisters {
                    address: 0,
                    quantity: 1
                },
                &mut out
            ),
            Some(Ok(()))
        );
        assert_eq!(out, [0x03, 2, 0, 1]);
    }
}
