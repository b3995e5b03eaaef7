//! The CP 341 Modbus slave on a simulated line and clock: framing, broadcasts, ignored frames, line
//! faults and the answer timing here; the address conversion tables, write limits and exception
//! rules in `slave/memory.rs`.

#[path = "slave/memory.rs"]
mod memory;

use proptest::prelude::*;
use proto_core::cpmem::{
    locate_bits, locate_registers, AccessError, AddressMap, Area, BitMapping, BitTable, CpMemory,
    MemoryLayout, OperatingMode, RegisterLocation, RegisterTable, SlaveParams, WriteLimits,
    Written,
};
use proto_core::event::ids;
use proto_core::modbus::pdu::{ExceptionCode, FunctionCode};
use proto_core::modbus::rtu::{encode_frame, CharTiming};
use proto_core::modbus::slave::{DiscardReason, LineError, Outcome, Slave, SlaveEvent};
use proto_core::time::Instant;

/// 19200 bit/s, 8 data bits, even parity, 1 stop bit: 11 bits a character, t3.5 = 2005 us (the
/// CP's own table, 003 6.4.6: 19200 -> 2 ms).
fn timing() -> CharTiming {
    CharTiming::exact(19200, 11)
}

fn t35_micros() -> u64 {
    u64::try_from(timing().t35.as_micros()).expect("small")
}

fn at(micros: u64) -> Instant {
    Instant::from_micros(micros)
}

fn frame(address: u8, pdu: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    encode_frame(address, pdu, &mut out);
    out
}

fn params(address: u8, map: AddressMap) -> SlaveParams {
    SlaveParams::new(address, OperatingMode::Normal, 1, map).expect("valid parameters")
}

/// Everything writable that the manual's example map reaches.
fn open_limits() -> WriteLimits {
    WriteLimits {
        memory: Some((0, 2047)),
        outputs: Some((0, 2047)),
        data_blocks: Some((1, 65535)),
    }
}

fn slave_with(address: u8, map: AddressMap, memory: CpMemory) -> Slave {
    Slave::new(params(address, map), timing(), memory)
}

/// Steps the clock from deadline to deadline up to `until`; returns what was sent and when.
fn drive(slave: &mut Slave, until: Instant) -> Vec<(Instant, Vec<u8>)> {
    let mut sent = Vec::new();
    for _ in 0..1000 {
        while let Some(tx) = slave.poll_transmit() {
            sent.push((until, tx));
        }
        match slave.poll_timeout() {
            Some(deadline) if deadline <= until => {
                slave.handle_timeout(deadline);
                while let Some(tx) = slave.poll_transmit() {
                    sent.push((deadline, tx));
                }
            }
            _ => return sent,
        }
    }
    panic!("the slave keeps asking for timeouts: livelock");
}

fn drain(slave: &mut Slave) -> Vec<SlaveEvent> {
    std::iter::from_fn(|| slave.poll_event()).collect()
}

/// A slave on a simulated line whose clock only moves forward.
struct Line {
    slave: Slave,
    /// Microseconds on the simulated clock.
    now: u64,
}

impl Line {
    fn new(address: u8, map: AddressMap, memory: CpMemory) -> Self {
        Self {
            slave: slave_with(address, map, memory),
            now: 0,
        }
    }

    /// Sends one request a second after the previous one and returns the single answer, if any,
    /// once the line went quiet.
    fn exchange(&mut self, request: &[u8]) -> Option<Vec<u8>> {
        self.now += 1_000_000;
        self.slave.handle_rx(at(self.now), request);
        let mut sent = drive(&mut self.slave, at(self.now + 500_000));
        assert!(sent.len() <= 1, "one request, at most one answer");
        sent.pop().map(|(_, tx)| tx)
    }

    fn events(&mut self) -> Vec<SlaveEvent> {
        drain(&mut self.slave)
    }

    fn memory(&self) -> &CpMemory {
        self.slave.memory()
    }
}

fn exception(address: u8, function: u8, code: u8) -> Vec<u8> {
    frame(address, &[function | 0x80, code])
}

#[test]
fn broadcast_writes_are_applied_silently() {
    let map = AddressMap::manual_example()
        .with_limits(open_limits())
        .expect("valid");
    let mut line = Line::new(222, map, CpMemory::default());
    assert_eq!(
        line.exchange(&frame(0, &[0x06, 0x00, 0x05, 0xAB, 0xCD])),
        None
    );
    assert_eq!(line.memory().db(800).expect("DB 800")[5], 0xABCD);
    assert_eq!(
        line.exchange(&frame(0, &[0x0F, 0x04, 0x00, 0x00, 0x0A, 0x02, 0xFF, 0x03])),
        None
    );
    assert_eq!(&line.memory().q()[100..102], &[0xFF, 0x03]);
    let seen = line.events();
    assert!(seen.contains(&SlaveEvent::Written(Written {
        area: Area::Db(800),
        first: 5,
        len: 1
    })));
    assert!(seen.contains(&SlaveEvent::Written(Written {
        area: Area::Q,
        first: 100,
        len: 2
    })));
    let applied = seen.iter().filter(|e| {
        matches!(
            e,
            SlaveEvent::Request {
                address: 0,
                outcome: Outcome::BroadcastApplied,
                ..
            }
        )
    });
    assert_eq!(applied.count(), 2);

    // A broadcast read or a refused broadcast write is not answered either.
    assert_eq!(
        line.exchange(&frame(0, &[0x03, 0x00, 0x00, 0x00, 0x01])),
        None
    );
    assert_eq!(
        line.exchange(&frame(0, &[0x06, 0x08, 0x00, 0x00, 0x01])),
        None
    ); // DB 804 missing
    let refused: Vec<_> = line
        .events()
        .into_iter()
        .filter_map(|e| match e {
            SlaveEvent::Request {
                outcome: Outcome::BroadcastRefused(code),
                function,
                ..
            } => Some((function, code)),
            _ => None,
        })
        .collect();
    assert_eq!(
        refused,
        vec![
            (
                FunctionCode::READ_HOLDING_REGISTERS,
                ExceptionCode::IllegalFunction
            ),
            (
                FunctionCode::WRITE_SINGLE_REGISTER,
                ExceptionCode::IllegalDataAddress
            )
        ]
    );
}

#[test]
fn other_addresses_and_bad_crc_are_ignored() {
    let mut line = Line::new(17, AddressMap::manual_example(), CpMemory::default());
    assert_eq!(
        line.exchange(&frame(18, &[0x03, 0x00, 0x00, 0x00, 0x01])),
        None
    );
    let mut bad = frame(17, &[0x03, 0x00, 0x00, 0x00, 0x01]);
    bad[7] ^= 0xFF;
    assert_eq!(line.exchange(&bad), None);
    assert_eq!(line.exchange(&[0x11, 0x03]), None);
    assert_eq!(
        line.events(),
        vec![
            SlaveEvent::Discarded {
                reason: DiscardReason::OtherAddress(18),
                len: 8
            },
            SlaveEvent::Diagnostic(ids::MODBUS_CHECKSUM_ERROR),
            SlaveEvent::Discarded {
                reason: DiscardReason::BadCrc,
                len: 8
            },
            SlaveEvent::Discarded {
                reason: DiscardReason::TooShort,
                len: 2
            },
        ]
    );
    // The next good request is served.
    assert!(line
        .exchange(&frame(17, &[0x03, 0x00, 0x00, 0x00, 0x01]))
        .is_some());
}

#[test]
fn answer_not_before_t35() {
    let t35 = t35_micros();
    assert_eq!(t35, 2005);
    let mut slave = slave_with(222, AddressMap::manual_example(), CpMemory::default());
    let request = frame(222, &[0x03, 0x00, 0x00, 0x00, 0x02]);
    // Split over two chunks; the frame ends by the silence after its last byte at 1000 us.
    slave.handle_rx(at(0), &request[..3]);
    assert_eq!(slave.poll_timeout(), Some(at(t35)));
    slave.handle_rx(at(1000), &request[3..]);
    assert_eq!(slave.poll_timeout(), Some(at(1000 + t35)));
    slave.handle_timeout(at(1000 + t35 - 1));
    assert_eq!(slave.poll_transmit(), None, "not before t3.5");
    let sent = drive(&mut slave, at(10_000));
    assert_eq!(
        sent,
        vec![(at(1000 + t35), frame(222, &[0x03, 0x04, 0, 0, 0, 0]))]
    );
    assert_eq!(slave.poll_timeout(), None);

    // FC 08 0000h has no announced length: it ends after the silence and is answered then.
    let echo = frame(222, &[0x08, 0x00, 0x00, 0xA5, 0x5A]);
    slave.handle_rx(at(20_000), &echo);
    assert_eq!(slave.poll_timeout(), Some(at(20_000 + t35)));
    assert_eq!(
        drive(&mut slave, at(30_000)),
        vec![(at(20_000 + t35), echo)]
    );

    // A multiplier of 3 triples the wait (6.4.5.1).
    let slow = SlaveParams::new(222, OperatingMode::Normal, 3, AddressMap::manual_example())
        .expect("valid");
    let mut slave = Slave::new(slow, timing(), CpMemory::default());
    slave.handle_rx(at(0), &request);
    assert_eq!(slave.poll_timeout(), Some(at(3 * t35)));
}

#[test]
fn silence_between_chunks_splits_frames() {
    let t35 = t35_micros();
    let mut slave = slave_with(222, AddressMap::manual_example(), CpMemory::default());
    let request = frame(222, &[0x03, 0x00, 0x00, 0x00, 0x01]);
    // A pause of t3.5 inside the request ends it: both halves are dropped.
    slave.handle_rx(at(0), &request[..4]);
    slave.handle_rx(at(t35), &request[4..]);
    assert!(drive(&mut slave, at(100_000)).is_empty());
    let discarded = drain(&mut slave)
        .into_iter()
        .filter(|e| matches!(e, SlaveEvent::Discarded { .. }))
        .count();
    assert_eq!(discarded, 2);
    // Two requests without a silence between them are one frame (003 6.4.6: the frame ends by
    // silence only): a request with trailing bytes, discarded and counted, not answered.
    let second = frame(222, &[0x01, 0x00, 0x00, 0x00, 0x01]);
    let both: Vec<u8> = request.iter().chain(second.iter()).copied().collect();
    slave.handle_rx(at(200_000), &both);
    assert!(drive(&mut slave, at(300_000)).is_empty());
    assert_eq!(
        drain(&mut slave),
        vec![SlaveEvent::Discarded {
            reason: DiscardReason::TrailingData,
            len: both.len()
        }]
    );
    // The same two with t3.5 of silence between them are both answered, in order.
    slave.handle_rx(at(400_000), &request);
    slave.handle_rx(at(400_000 + t35), &second);
    let sent: Vec<Vec<u8>> = drive(&mut slave, at(500_000))
        .into_iter()
        .map(|(_, tx)| tx)
        .collect();
    assert_eq!(
        sent,
        vec![
            frame(222, &[0x03, 0x02, 0, 0]),
            frame(222, &[0x01, 0x01, 0])
        ]
    );
}

#[test]
fn a_request_with_trailing_bytes_is_discarded_and_counted() {
    let t35 = t35_micros();
    let mut slave = slave_with(222, AddressMap::manual_example(), CpMemory::default());
    let request = frame(222, &[0x03, 0x00, 0x00, 0x00, 0x01]);
    // One trailing byte 1 ms after the request, inside t3.5: part of the frame.
    slave.handle_rx(at(0), &request);
    slave.handle_rx(at(1000), &[0x00]);
    assert_eq!(slave.poll_timeout(), Some(at(1000 + t35)));
    assert!(drive(&mut slave, at(50_000)).is_empty(), "not answered");
    assert_eq!(
        drain(&mut slave),
        vec![SlaveEvent::Discarded {
            reason: DiscardReason::TrailingData,
            len: request.len() + 1
        }]
    );
    assert_eq!(DiscardReason::TrailingData.as_str(), "trailing_data");
    // The line goes on: the next request after the silence is answered at t3.5 after it.
    slave.handle_rx(at(60_000), &request);
    assert_eq!(
        drive(&mut slave, at(70_000)),
        vec![(at(60_000 + t35), frame(222, &[0x03, 0x02, 0, 0]))]
    );
}

#[test]
fn overlong_frames_and_line_faults() {
    let t35 = t35_micros();
    let mut line = Line::new(222, AddressMap::manual_example(), CpMemory::default());
    // 300 bytes of noise with an unknown function code: dropped as too long, then recovery.
    let mut noise = vec![222, 0x64];
    noise.resize(300, 0x55);
    assert_eq!(line.exchange(&noise), None);
    let seen = line.events();
    assert_eq!(
        seen,
        vec![
            SlaveEvent::Diagnostic(ids::FRAME_TOO_LONG),
            // Every byte of the noise: the 265 of the overlong frame and the 35 after it.
            SlaveEvent::Discarded {
                reason: DiscardReason::TooLong,
                len: 300
            }
        ]
    );
    assert_eq!(
        line.exchange(&frame(222, &[0x03, 0x00, 0x00, 0x00, 0x01]))
            .map(|f| f.len()),
        Some(7)
    );
    line.events();

    // A parity error inside a frame drops it; in idle it is still reported in normal operation.
    let request = frame(222, &[0x03, 0x00, 0x00, 0x00, 0x01]);
    let t0 = line.now + 1_000_000;
    line.slave.handle_rx(at(t0), &request[..3]);
    line.slave
        .handle_line_error(at(t0 + 100), LineError::ParityOrFraming);
    line.slave.handle_rx(at(t0 + 200), &request[3..]);
    assert!(drive(&mut line.slave, at(t0 + 200 + 2 * t35)).is_empty());
    line.slave
        .handle_line_error(at(t0 + 100_000), LineError::Break);
    assert_eq!(
        line.events(),
        vec![
            SlaveEvent::Diagnostic(ids::CHARACTER_ERROR),
            // The 3 bytes before the fault and the 5 after it, up to the silence.
            SlaveEvent::Discarded {
                reason: DiscardReason::LineError,
                len: 8
            },
            SlaveEvent::Diagnostic(ids::LINE_BREAK)
        ]
    );

    // With interference suppression an idle fault is ignored, a fault inside a frame is not.
    let quiet = SlaveParams::new(
        222,
        OperatingMode::InterferenceSuppression,
        1,
        AddressMap::manual_example(),
    );
    let mut slave = Slave::new(quiet.expect("valid"), timing(), CpMemory::default());
    slave.handle_line_error(at(0), LineError::Break);
    assert_eq!(slave.poll_event(), None);
    slave.handle_rx(at(10), &request[..2]);
    slave.handle_line_error(at(20), LineError::ParityOrFraming);
    assert_eq!(
        slave.poll_event(),
        Some(SlaveEvent::Diagnostic(ids::CHARACTER_ERROR))
    );
}

proptest! {
    /// Feeding the same request in any chunking, with gaps below t3.5, gives the same answer at
    /// the same time: t3.5 after the last byte.
    #[test]
    fn chunking_does_not_change_the_answer(
        quantity in 1u16..=127,
        start in 0u16..385,
        cuts in proptest::collection::vec(1usize..8, 0..8),
        gap in 0u64..2000,
    ) {
        let mut mem = CpMemory::default();
        for (k, word) in mem.db_mut(800).expect("DB 800").iter_mut().enumerate() {
            *word = u16::try_from(k).expect("512 words") * 3;
        }
        let mut slave = slave_with(222, AddressMap::manual_example(), mem);
        let [sh, sl] = start.to_be_bytes();
        let [qh, ql] = quantity.to_be_bytes();
        let request = frame(222, &[0x03, sh, sl, qh, ql]);
        let mut now = 0;
        let mut last = 0;
        let mut rest: &[u8] = &request;
        for cut in cuts {
            let (chunk, tail) = rest.split_at(cut.min(rest.len()));
            slave.handle_rx(at(now), chunk);
            if !chunk.is_empty() {
                last = now;
            }
            rest = tail;
            now += gap;
        }
        if !rest.is_empty() {
            slave.handle_rx(at(now), rest);
            last = now;
        }
        let sent = drive(&mut slave, at(1_000_000));
        let mut data = vec![0x03, u8::try_from(quantity * 2).expect("<= 254")];
        for k in start..start + quantity {
            data.extend_from_slice(&(k * 3).to_be_bytes());
        }
        prop_assert_eq!(sent.len(), 1);
        prop_assert_eq!(&sent[0].1, &frame(222, &data));
        prop_assert!(sent[0].0 >= at(last + t35_micros()));
    }

    /// Arbitrary bytes never panic and never make the slave answer more than once per frame.
    #[test]
    fn noise_never_panics(chunks in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..40), 0..20)) {
        let mut slave = slave_with(1, AddressMap::manual_example(), CpMemory::default());
        let mut now = 0;
        for chunk in chunks {
            slave.handle_rx(at(now), &chunk);
            now += 1500;
            drive(&mut slave, at(now));
        }
        drive(&mut slave, at(now + 1_000_000));
        prop_assert_eq!(slave.poll_timeout(), None);
    }
}
