//! The Modbus slave RTU engine entry point.

use crate::cpmem::{AddressMap, CpMemory, OperatingMode, SlaveParams, WriteLimits};
use crate::modbus::rtu::{self, CharTiming};
use crate::modbus::slave::{LineError, Outcome, Slave, SlaveEvent};
use crate::time::Instant;

/// The most deadlines [`fuzz_slave`] follows after the script before calling it a livelock.
const MAX_DRIVE_STEPS: usize = 10_000;

/// The Modbus slave RTU engine fed a script of received chunks, pauses, timeouts and line faults.
///
/// Input: byte 0 the slave address (0 is taken as 1), byte 1 the setup (bits 0..3 the t3.5
/// multiplier 1..10, bit 4 interference suppression, bits 5..7 the baud rate index into
/// [`SlaveParams::BAUD_RATES`]), then operations of one byte each, `op & 3` saying which and
/// `op >> 2` its argument `a`:
/// - 0: receive the next `a + 1` bytes of the input;
/// - 1: wait `a` half character times;
/// - 2: wait until the engine's deadline (if any) or `a` milliseconds, then `handle_timeout`;
/// - 3: a line fault (a BREAK if `a` is odd, else a character error).
///
/// Checked after every step: after a `handle_*` call the deadline lies in the future (a driver
/// following it does not spin), every frame sent is a good RTU frame from the own address, and
/// one is sent for every request answered (never for a broadcast). After the script, following
/// the deadlines ends in an idle engine.
pub fn fuzz_slave(data: &[u8]) {
    run_slave_script(data);
}

/// [`fuzz_slave`]; returns how many frames the slave sent.
pub(super) fn run_slave_script(data: &[u8]) -> usize {
    let [address, setup, ref script @ ..] = *data else {
        return 0;
    };
    let address = address.max(1);
    let multiplier = setup % 16 % 10 + 1;
    let mode = if setup & 0x10 == 0 {
        OperatingMode::Normal
    } else {
        OperatingMode::InterferenceSuppression
    };
    let baud = SlaveParams::BAUD_RATES
        .get(usize::from(setup >> 5))
        .copied()
        .unwrap_or(SlaveParams::DEFAULT_BAUD_RATE);
    let map = AddressMap::manual_example()
        .with_limits(WriteLimits {
            memory: Some((0, 2047)),
            outputs: Some((0, 2047)),
            data_blocks: Some((1, 65535)),
        })
        .unwrap_or_default();
    let Ok(params) = SlaveParams::new(address, mode, multiplier, map) else {
        return 0;
    };
    let timing = CharTiming::exact(baud, 11);
    let mut slave = SlaveRun {
        slave: Slave::new(params, timing, CpMemory::default()),
        now: Instant::from_millis(1),
        address,
        answers_due: 0,
        sent: 0,
    };
    let half_char = u64::try_from(timing.char_time.as_micros() / 2).unwrap_or(1);

    let mut ops = script.iter();
    while let Some(&op) = ops.next() {
        let arg = u64::from(op >> 2);
        match op & 3 {
            0 => {
                let chunk: Vec<u8> = ops
                    .by_ref()
                    .take(usize::from(op >> 2) + 1)
                    .copied()
                    .collect();
                let now = slave.now;
                slave.slave.handle_rx(now, &chunk);
            }
            1 => slave.now += core::time::Duration::from_micros(arg * half_char),
            2 => {
                let at = slave
                    .slave
                    .poll_timeout()
                    .unwrap_or(slave.now + core::time::Duration::from_millis(arg));
                slave.now = slave.now.max(at);
                let now = slave.now;
                slave.slave.handle_timeout(now);
            }
            _ => {
                let fault = if arg % 2 == 1 {
                    LineError::Break
                } else {
                    LineError::ParityOrFraming
                };
                let now = slave.now;
                slave.slave.handle_line_error(now, fault);
            }
        }
        // A wait tells the engine nothing: its deadline may pass unnoticed (a late wake-up).
        slave.check(op & 3 != 1);
    }
    for _ in 0..MAX_DRIVE_STEPS {
        let Some(deadline) = slave.slave.poll_timeout() else {
            assert_eq!(slave.answers_due, 0, "answers announced but not sent");
            return slave.sent;
        };
        slave.now = deadline;
        slave.slave.handle_timeout(deadline);
        slave.check(true);
    }
    panic!("the slave still has deadlines after {MAX_DRIVE_STEPS} steps: livelock");
}

/// A slave under test with its clock.
struct SlaveRun {
    slave: Slave,
    now: Instant,
    address: u8,
    /// Answers announced by events and not yet seen in `poll_transmit`.
    answers_due: i64,
    /// Frames sent.
    sent: usize,
}

impl SlaveRun {
    /// Drains events and frames and checks them, and (after a `handle_*` call at `self.now`) that
    /// the next deadline is in the future.
    fn check(&mut self, handled: bool) {
        while let Some(event) = self.slave.poll_event() {
            if let SlaveEvent::Request {
                address, outcome, ..
            } = event
            {
                match outcome {
                    Outcome::Answered | Outcome::Exception(_) => {
                        assert_eq!(address, self.address, "answered another address");
                        self.answers_due += 1;
                    }
                    Outcome::BroadcastApplied | Outcome::BroadcastRefused(_) => {
                        assert_eq!(address, 0, "broadcast outcome for a unicast");
                    }
                }
            }
        }
        while let Some(frame) = self.slave.poll_transmit() {
            let decoded = rtu::decode_frame(&frame);
            assert!(decoded.is_ok(), "the slave sent a bad frame {frame:02x?}");
            if let Ok(decoded) = decoded {
                assert_eq!(decoded.address, self.address, "answer from another address");
                assert!(!decoded.pdu.is_empty(), "empty answer");
            }
            self.answers_due -= 1;
            self.sent += 1;
        }
        assert_eq!(self.answers_due, 0, "answers and events disagree");
        if let Some(deadline) = self.slave.poll_timeout().filter(|_| handled) {
            assert!(
                deadline > self.now,
                "deadline {deadline:?} not after {:?}",
                self.now
            );
        }
    }
}
