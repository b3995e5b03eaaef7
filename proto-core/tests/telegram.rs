//! The ASCII telegram driver (manual 003 6.2; 000 5.4 and 6.2 for the RS232 signals) on a
//! simulated clock.

use core::time::Duration;
use std::collections::VecDeque;

use proptest::prelude::*;
use proto_core::event::{ids, EventId};
use proto_core::telegram::{
    Action, AsciiDriver, AsciiEvent, AsciiParams, AsciiSettings, ConfigError, EndCriterion,
    FlowControl, Interface, LineError, SendError, SendLength, Signals,
};
use proto_core::time::Instant;

const XON: u8 = 0x11;
const XOFF: u8 = 0x13;
const ETX: u8 = 0x03;

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn at(n: u64) -> Instant {
    Instant::from_millis(n)
}

fn driver(f: impl FnOnce(&mut AsciiSettings)) -> AsciiDriver {
    let mut settings = AsciiSettings::default();
    f(&mut settings);
    AsciiDriver::new(AsciiParams::try_new(settings).expect("valid settings"))
}

fn actions(d: &mut AsciiDriver) -> Vec<Action> {
    std::iter::from_fn(|| d.poll_action()).collect()
}

/// Every buffer the driver hands out, each confirmed as sent at `done`.
fn out(d: &mut AsciiDriver, done: Instant) -> Vec<Vec<u8>> {
    let mut buffers = Vec::new();
    while let Some(buf) = d.poll_transmit() {
        buffers.push(buf);
        d.handle_tx_done(done);
    }
    buffers
}

fn events(d: &mut AsciiDriver) -> Vec<AsciiEvent> {
    std::iter::from_fn(|| d.poll_event()).collect()
}

fn raised(events: &[AsciiEvent]) -> Vec<EventId> {
    events
        .iter()
        .filter_map(|e| match e {
            AsciiEvent::Raised { id } => Some(*id),
            _ => None,
        })
        .collect()
}

fn received(events: &[AsciiEvent]) -> Vec<Vec<u8>> {
    events
        .iter()
        .filter_map(|e| match e {
            AsciiEvent::Received { data } => Some(data.clone()),
            _ => None,
        })
        .collect()
}

#[test]
fn end_by_character_delay_time() {
    // 003 6.2.1: ZVZ default 4 ms (the minimum at 9600 bit/s).
    let mut d = driver(|_| {});
    d.handle_rx(at(10), b"AB");
    d.handle_rx(at(13), b"C");
    assert_eq!(d.poll_timeout(), Some(at(17)));
    d.handle_timeout(at(16));
    assert!(events(&mut d).is_empty());
    d.handle_timeout(at(17));
    assert_eq!(
        events(&mut d),
        [AsciiEvent::Received {
            data: b"ABC".to_vec()
        }]
    );
    assert_eq!(d.take_received(), Some(b"ABC".to_vec()));
    assert_eq!(d.poll_timeout(), None);
}

#[test]
fn end_by_fixed_length() {
    let mut d = driver(|s| s.end = EndCriterion::FixedLength(3));
    d.handle_rx(at(0), b"abcdefgh");
    assert_eq!(
        received(&events(&mut d)),
        [b"abc".to_vec(), b"def".to_vec()]
    );
    // The rest waits for its third character; the ZVZ gap discards it (7.2, 08 06h).
    d.handle_timeout(at(4));
    assert_eq!(raised(&events(&mut d)), [ids::CHARACTER_DELAY_EXCEEDED]);
    assert_eq!(d.received_len(), 2);
}

#[test]
fn end_by_one_or_two_end_characters() {
    let mut d = driver(|s| {
        s.end = EndCriterion::EndChars {
            first: ETX,
            second: None,
        }
    });
    d.handle_rx(at(0), b"ab\x03cd");
    d.handle_rx(at(1), b"\x03");
    assert_eq!(
        received(&events(&mut d)),
        [b"ab\x03".to_vec(), b"cd\x03".to_vec()]
    );
    let mut d = driver(|s| {
        s.end = EndCriterion::EndChars {
            first: b'\r',
            second: Some(b'\n'),
        }
    });
    d.handle_rx(at(0), b"x\ry\r");
    d.handle_rx(at(1), b"\nz\n");
    assert_eq!(received(&events(&mut d)), [b"x\ry\r\n".to_vec()]);
    d.handle_timeout(at(5));
    assert_eq!(raised(&events(&mut d)), [ids::CHARACTER_DELAY_EXCEEDED]);
}

#[test]
fn seven_data_bits_mask_and_refuse_the_eighth_bit() {
    let mut d = driver(|s| {
        s.data_bits = 7;
        s.end = EndCriterion::EndChars {
            first: ETX,
            second: None,
        };
    });
    d.handle_rx(at(0), &[0xC1, 0x42, 0x83]);
    assert_eq!(received(&events(&mut d)), [b"AB\x03".to_vec()]);
    assert_eq!(
        d.send(at(1), vec![0x41, 0x80]),
        Err(SendError::EighthBit {
            offset: 1,
            value: 0x80
        })
    );
}

#[test]
fn over_long_and_faulty_telegrams_are_discarded() {
    let mut d = driver(|_| {});
    d.handle_rx(at(0), &[0x55; 1025]);
    d.handle_timeout(at(4));
    // 7.2, 08 16h: "longer than the length agreed upon" (1024 bytes, 003 6.2.1).
    assert_eq!(raised(&events(&mut d)), [ids::FRAME_TOO_LONG]);
    d.handle_rx(at(10), b"ab");
    d.handle_line_error(at(10), LineError::Parity);
    d.handle_timeout(at(14));
    d.handle_rx(at(20), b"ab");
    d.handle_line_error(at(20), LineError::Break);
    assert_eq!(
        raised(&events(&mut d)),
        [ids::CHARACTER_ERROR, ids::LINE_BREAK]
    );
    assert_eq!(
        d.poll_timeout(),
        None,
        "the BREAK dropped the telegram in progress"
    );
    assert_eq!(d.received_len(), 0);
}

#[test]
fn a_full_buffer_drops_or_overwrites() {
    // 003 6.2.1 "Prevent overwriting": a full buffer drops the new telegram (7.2, 08 0Ah).
    let mut keep = driver(|s| {
        s.receive_buffers = 2;
        s.end = EndCriterion::FixedLength(1);
    });
    keep.handle_rx(at(0), b"123");
    let ev = events(&mut keep);
    assert_eq!(received(&ev), [b"1".to_vec(), b"2".to_vec()]);
    assert_eq!(raised(&ev), [ids::NO_FREE_RECEIVE_BUFFER]);
    assert_eq!(keep.take_received(), Some(b"1".to_vec()));
    assert_eq!(keep.take_received(), Some(b"2".to_vec()));
    // Overwriting allowed with one buffer: the newest telegram is kept.
    let mut latest = driver(|s| {
        s.receive_buffers = 1;
        s.prevent_overwrite = false;
        s.end = EndCriterion::FixedLength(1);
    });
    latest.handle_rx(at(0), b"123");
    assert!(raised(&events(&mut latest)).is_empty());
    assert_eq!(latest.take_received(), Some(b"3".to_vec()));
    assert_eq!(latest.take_received(), None);
}

#[test]
fn send_without_flow_control_and_the_transmission_pause() {
    let mut d = driver(|_| {});
    let first = d.send(at(0), b"one".to_vec()).expect("accepted");
    let second = d.send(at(0), b"two".to_vec()).expect("accepted");
    assert_eq!(out(&mut d, at(3)), [b"one".to_vec()]);
    assert_eq!(events(&mut d), [AsciiEvent::Sent { id: first }]);
    // 003 6.2.1 "Transmission pause": the line stays quiet for the ZVZ between telegrams.
    assert_eq!(d.poll_transmit(), None);
    assert_eq!(d.poll_timeout(), Some(at(7)));
    d.handle_timeout(at(7));
    assert_eq!(out(&mut d, at(10)), [b"two".to_vec()]);
    assert_eq!(events(&mut d), [AsciiEvent::Sent { id: second }]);
    assert!(d.is_idle());
    assert_eq!(d.send(at(20), Vec::new()), Err(SendError::Empty));
    assert_eq!(
        d.send(at(20), vec![0; 1025]),
        Err(SendError::TooLong {
            len: 1025,
            max: 1024
        })
    );
}

#[test]
fn xoff_pauses_and_xon_resumes() {
    let mut d = driver(|s| {
        s.flow = FlowControl::XON_XOFF;
        s.tx_chunk = 4;
    });
    let id = d.send(at(0), b"0123456789".to_vec()).expect("accepted");
    assert_eq!(d.poll_transmit(), Some(b"0123".to_vec()));
    d.handle_rx(at(1), &[XOFF]);
    d.handle_tx_done(at(4));
    assert_eq!(d.poll_transmit(), None, "held by XOFF");
    assert_eq!(
        d.poll_timeout(),
        Some(at(4) + ms(20_000)),
        "wait for XON: 20 000 ms"
    );
    d.handle_rx(at(500), &[XON]);
    assert_eq!(out(&mut d, at(504)), [b"4567".to_vec(), b"89".to_vec()]);
    assert_eq!(events(&mut d), [AsciiEvent::Sent { id }]);
    assert_eq!(d.received_len(), 0, "XON and XOFF are not data");
}

#[test]
fn no_xon_within_the_wait_time_fails_the_send() {
    let mut d = driver(|s| s.flow = FlowControl::XON_XOFF);
    d.handle_rx(at(0), &[XOFF]);
    let id = d.send(at(1), b"abc".to_vec()).expect("accepted");
    assert_eq!(d.poll_transmit(), None);
    d.handle_timeout(at(20_001));
    let ev = events(&mut d);
    // 7.2, 07 08h "The waiting time for XON respectively CTS = ON has elapsed."
    assert_eq!(
        ev,
        [
            AsciiEvent::Raised {
                id: ids::SEND_FLOW_CONTROL_TIMEOUT
            },
            AsciiEvent::SendFailed {
                id,
                event: ids::SEND_FLOW_CONTROL_TIMEOUT,
                first: ids::SEND_FLOW_CONTROL_TIMEOUT
            }
        ]
    );
    assert!(d.is_idle());
}

#[test]
fn a_full_buffer_sends_xoff_and_taking_sends_xon() {
    let mut d = driver(|s| {
        s.flow = FlowControl::XON_XOFF;
        s.receive_buffers = 2;
        s.end = EndCriterion::FixedLength(2);
    });
    d.handle_rx(at(0), b"abcd");
    assert_eq!(out(&mut d, at(1)), [vec![XOFF]]);
    assert_eq!(d.take_received(), Some(b"ab".to_vec()));
    assert_eq!(out(&mut d, at(2)), [vec![XON]]);
}

#[test]
fn rts_cts_waits_for_cts() {
    let mut d = driver(|s| {
        s.interface = Interface::Rs232;
        s.flow = FlowControl::RtsCts;
    });
    assert_eq!(actions(&mut d), [Action::SetRts(true)], "ready to receive");
    let id = d.send(at(0), b"abc".to_vec()).expect("accepted");
    assert_eq!(d.poll_transmit(), None, "CTS is off");
    d.handle_signals(
        at(5),
        Signals {
            cts: true,
            dsr: true,
        },
    );
    assert_eq!(out(&mut d, at(8)), [b"abc".to_vec()]);
    assert_eq!(events(&mut d), [AsciiEvent::Sent { id }]);
    d.handle_signals(
        at(9),
        Signals {
            cts: false,
            dsr: true,
        },
    );
    let id = d.send(at(20), b"x".to_vec()).expect("accepted");
    d.handle_timeout(at(20) + ms(20_000));
    assert!(events(&mut d).contains(&AsciiEvent::SendFailed {
        id,
        event: ids::SEND_FLOW_CONTROL_TIMEOUT,
        first: ids::SEND_FLOW_CONTROL_TIMEOUT
    }));
}

fn auto_v24() -> AsciiDriver {
    driver(|s| {
        s.interface = Interface::Rs232;
        s.flow = FlowControl::AUTO_V24;
    })
}

#[test]
fn automatic_v24_signal_handling() {
    // 000 5.4: RTS on, data output wait time (10 ms), CTS = ON, send, RTS off after the RTS hold
    // time (10 ms).
    let mut d = auto_v24();
    assert_eq!(
        actions(&mut d),
        [Action::SetRts(false), Action::SetDtr(true)]
    );
    d.handle_signals(
        at(0),
        Signals {
            cts: false,
            dsr: true,
        },
    );
    let id = d.send(at(0), b"abc".to_vec()).expect("accepted");
    assert_eq!(actions(&mut d), [Action::SetRts(true)]);
    assert_eq!(d.poll_transmit(), None);
    assert_eq!(d.poll_timeout(), Some(at(10)));
    d.handle_signals(
        at(4),
        Signals {
            cts: true,
            dsr: true,
        },
    );
    assert_eq!(d.poll_transmit(), None, "the data output wait time runs");
    d.handle_timeout(at(10));
    assert_eq!(out(&mut d, at(13)), [b"abc".to_vec()]);
    assert!(actions(&mut d).is_empty());
    assert_eq!(d.poll_timeout(), Some(at(23)));
    d.handle_timeout(at(23));
    assert_eq!(actions(&mut d), [Action::SetRts(false)]);
    assert_eq!(events(&mut d), [AsciiEvent::Sent { id }]);
}

#[test]
fn automatic_v24_does_not_start_a_send_while_dsr_is_off() {
    // 000 7.2 08 18h: DSR switched off by the partner before a send; RTS is not even raised.
    let mut d = auto_v24();
    actions(&mut d);
    let id = d.send(at(0), b"abc".to_vec()).expect("accepted");
    assert!(actions(&mut d).is_empty(), "RTS stays off");
    assert_eq!(d.poll_transmit(), None);
    assert_eq!(
        events(&mut d),
        [
            AsciiEvent::Raised {
                id: ids::DSR_OR_CTS_OFF
            },
            AsciiEvent::SendFailed {
                id,
                event: ids::DSR_OR_CTS_OFF,
                first: ids::DSR_OR_CTS_OFF
            }
        ]
    );
    // With DSR on, the next telegram goes out as usual.
    d.handle_signals(
        at(1),
        Signals {
            cts: true,
            dsr: true,
        },
    );
    d.send(at(1), b"abc".to_vec()).expect("accepted");
    assert_eq!(actions(&mut d), [Action::SetRts(true)]);
    d.handle_timeout(at(11));
    assert_eq!(out(&mut d, at(14)), [b"abc".to_vec()]);
}

#[test]
fn automatic_v24_without_cts_or_dsr() {
    let mut d = auto_v24();
    actions(&mut d);
    d.handle_signals(
        at(0),
        Signals {
            cts: false,
            dsr: true,
        },
    );
    let id = d.send(at(0), b"abc".to_vec()).expect("accepted");
    assert_eq!(actions(&mut d), [Action::SetRts(true)]);
    d.handle_timeout(at(10));
    assert_eq!(actions(&mut d), [Action::SetRts(false)]);
    assert!(events(&mut d).contains(&AsciiEvent::SendFailed {
        id,
        event: ids::SEND_FLOW_CONTROL_TIMEOUT,
        first: ids::SEND_FLOW_CONTROL_TIMEOUT
    }));
    // DSR off while sending aborts the send and the reception (7.2, 08 18h).
    d.handle_signals(
        at(20),
        Signals {
            cts: true,
            dsr: true,
        },
    );
    let id = d.send(at(20), vec![b'x'; 40]).expect("accepted");
    assert_eq!(actions(&mut d), [Action::SetRts(true)]);
    d.handle_timeout(at(30));
    assert_eq!(
        d.poll_transmit().map(|b| b.len()),
        Some(8),
        "sent in chunks"
    );
    d.handle_rx(at(31), b"partial");
    d.handle_signals(
        at(32),
        Signals {
            cts: true,
            dsr: false,
        },
    );
    assert_eq!(actions(&mut d), [Action::SetRts(false)]);
    assert_eq!(
        events(&mut d),
        [
            AsciiEvent::Raised {
                id: ids::DSR_OR_CTS_OFF
            },
            AsciiEvent::SendFailed {
                id,
                event: ids::DSR_OR_CTS_OFF,
                first: ids::DSR_OR_CTS_OFF
            }
        ]
    );
    assert_eq!(d.poll_timeout(), None, "the partial telegram is gone");
    // 000 5.4: reception needs DSR = ON.
    d.handle_rx(at(40), b"lost");
    assert_eq!(raised(&events(&mut d)), [ids::DSR_OR_CTS_OFF]);
}

// --- two drivers on a simulated line ---

/// One end of a null-modem cable: our RTS is the partner's CTS, our DTR its DSR.
struct End {
    driver: AsciiDriver,
    free_at: Instant,
    inbox: VecDeque<(Instant, u8)>,
    received: Vec<Vec<u8>>,
    events: Vec<AsciiEvent>,
    rts: bool,
    dtr: bool,
    /// Whether the application takes received telegrams at once.
    takes: bool,
}

struct Pair {
    now: Instant,
    char_time: Duration,
    a: End,
    b: End,
    /// An extra instant the clock must stop at (the test's own schedule).
    wake: Option<Instant>,
}

impl Pair {
    fn new(a: AsciiDriver, b: AsciiDriver) -> Self {
        let end = |driver| End {
            driver,
            free_at: Instant::ZERO,
            inbox: VecDeque::new(),
            received: Vec::new(),
            events: Vec::new(),
            rts: false,
            dtr: false,
            takes: true,
        };
        let mut pair = Self {
            now: Instant::ZERO,
            char_time: Duration::from_micros(1146),
            a: end(a),
            b: end(b),
            wake: None,
        };
        for end in [&mut pair.a, &mut pair.b] {
            end.driver.handle_signals(Instant::ZERO, Signals::default());
        }
        pair
    }

    fn flush(now: Instant, char_time: Duration, from: &mut End, to: &mut End) {
        loop {
            let mut changed = false;
            while let Some(action) = from.driver.poll_action() {
                match action {
                    Action::SetRts(on) => from.rts = on,
                    Action::SetDtr(on) => from.dtr = on,
                }
                changed = true;
            }
            if changed {
                to.driver.handle_signals(
                    now,
                    Signals {
                        cts: from.rts,
                        dsr: from.dtr,
                    },
                );
            }
            let Some(buf) = from.driver.poll_transmit() else {
                break;
            };
            let start = from.free_at.max(now);
            for (i, &byte) in buf.iter().enumerate() {
                to.inbox.push_back((
                    start + char_time * u32::try_from(i + 1).expect("short"),
                    byte,
                ));
            }
            from.free_at = start + char_time * u32::try_from(buf.len()).expect("short");
            from.driver.handle_tx_done(from.free_at);
        }
        while let Some(event) = from.driver.poll_event() {
            from.events.push(event);
        }
        if from.takes {
            from.received
                .extend(std::iter::from_fn(|| from.driver.take_received()));
        }
    }

    fn step(&mut self) -> bool {
        let (now, ct) = (self.now, self.char_time);
        Self::flush(now, ct, &mut self.a, &mut self.b);
        Self::flush(now, ct, &mut self.b, &mut self.a);
        Self::flush(now, ct, &mut self.a, &mut self.b);
        let next = [
            self.a.inbox.front().map(|x| x.0),
            self.b.inbox.front().map(|x| x.0),
            self.a.driver.poll_timeout(),
            self.b.driver.poll_timeout(),
            self.wake,
        ]
        .into_iter()
        .flatten()
        .min();
        let Some(next) = next else { return false };
        self.now = self.now.max(next);
        for end in [&mut self.a, &mut self.b] {
            // Bytes arrive one character time apart: hand each over at its own instant.
            while let Some(&(when, byte)) = end.inbox.front().filter(|x| x.0 <= self.now) {
                end.inbox.pop_front();
                end.driver.handle_rx(when, &[byte]);
            }
            if end.driver.poll_timeout().is_some_and(|t| t <= self.now) {
                end.driver.handle_timeout(self.now);
            }
        }
        true
    }

    fn drive(&mut self) {
        for _ in 0..200_000 {
            if !self.step() {
                return;
            }
        }
        panic!("no rest after 200000 steps");
    }
}

#[test]
fn the_transmission_pause_separates_telegrams_on_the_line() {
    let mut pair = Pair::new(driver(|_| {}), driver(|_| {}));
    for t in [b"first".to_vec(), b"second".to_vec(), b"third".to_vec()] {
        pair.a.driver.send(at(0), t).expect("accepted");
    }
    pair.drive();
    assert_eq!(
        pair.b.received,
        [b"first".to_vec(), b"second".to_vec(), b"third".to_vec()]
    );
    let no_pause = |s: &mut AsciiSettings| s.send_pause = false;
    let mut pair = Pair::new(driver(no_pause), driver(|_| {}));
    for t in [b"first".to_vec(), b"second".to_vec()] {
        pair.a.driver.send(at(0), t).expect("accepted");
    }
    pair.drive();
    assert_eq!(
        pair.b.received,
        [b"firstsecond".to_vec()],
        "without the pause they merge"
    );
}

/// A sender with five telegrams against a receiver with one buffer whose application takes a
/// telegram every 50 ms; runs one simulated second. Returns what the receiver's application got
/// and the events both sides raised.
fn slow_receiver(flow: FlowControl) -> (Vec<Vec<u8>>, Vec<EventId>, Vec<EventId>) {
    let settings = |s: &mut AsciiSettings| {
        s.interface = Interface::Rs232;
        s.flow = flow;
        s.end = EndCriterion::EndChars {
            first: ETX,
            second: None,
        };
        s.receive_buffers = 1;
        s.tx_chunk = 1;
    };
    let mut pair = Pair::new(driver(settings), driver(settings));
    pair.b.takes = false;
    for i in 0..5u8 {
        pair.a
            .driver
            .send(at(0), vec![b'a' + i, b'b' + i, ETX])
            .expect("accepted");
    }
    let mut next_take = at(50);
    while pair.now < at(1000) {
        pair.wake = Some(next_take);
        pair.step();
        if pair.now >= next_take {
            pair.b.received.extend(pair.b.driver.take_received());
            next_take = pair.now + ms(50);
        }
    }
    assert!(pair.a.driver.is_idle());
    (
        pair.b.received,
        raised(&pair.b.events),
        raised(&pair.a.events),
    )
}

#[test]
fn flow_control_keeps_a_slow_receiver_from_losing_telegrams() {
    let telegrams: Vec<Vec<u8>> = (0..5u8).map(|i| vec![b'a' + i, b'b' + i, ETX]).collect();
    for flow in [FlowControl::XON_XOFF, FlowControl::RtsCts] {
        let (got, raised_b, raised_a) = slow_receiver(flow);
        assert_eq!(got, telegrams, "{flow:?}");
        assert!(
            raised_b.is_empty() && raised_a.is_empty(),
            "{flow:?}: {raised_b:?} {raised_a:?}"
        );
    }
    // Without flow control the same receiver loses telegrams, each with 08 0Ah.
    let (got, raised_b, _) = slow_receiver(FlowControl::None);
    assert_eq!(got.len() + raised_b.len(), 5);
    assert!(!raised_b.is_empty() && raised_b.iter().all(|&e| e == ids::NO_FREE_RECEIVE_BUFFER));
}

/// One thing that can happen to a driver.
#[derive(Clone, Debug)]
enum Op {
    Rx(Vec<u8>),
    LineError(LineError),
    Signals(bool, bool),
    Send(Vec<u8>),
    Take,
    Wait(u16),
}

fn op() -> impl Strategy<Value = Op> {
    let byte = prop_oneof![Just(XON), Just(XOFF), Just(ETX), any::<u8>()];
    prop_oneof![
        4 => prop::collection::vec(byte, 1..12).prop_map(Op::Rx),
        1 => prop_oneof![Just(LineError::Overrun), Just(LineError::Break)].prop_map(Op::LineError),
        1 => (any::<bool>(), any::<bool>()).prop_map(|(c, d)| Op::Signals(c, d)),
        1 => prop::collection::vec(0u8..0x80, 0..40).prop_map(Op::Send),
        1 => Just(Op::Take),
        2 => (0u16..30_000).prop_map(Op::Wait),
    ]
}

fn flows() -> impl Strategy<Value = FlowControl> {
    prop_oneof![
        Just(FlowControl::None),
        Just(FlowControl::XON_XOFF),
        Just(FlowControl::RtsCts),
        Just(FlowControl::AUTO_V24)
    ]
}

fn criteria() -> impl Strategy<Value = EndCriterion> {
    prop_oneof![
        (1u16..20).prop_map(EndCriterion::FixedLength),
        Just(EndCriterion::EndChars {
            first: ETX,
            second: None
        }),
        Just(EndCriterion::EndChars {
            first: b'\r',
            second: Some(b'\n')
        }),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn chunking_does_not_change_the_telegrams(
        end in criteria(),
        bytes in prop::collection::vec(prop_oneof![Just(ETX), Just(b'\r'), Just(b'\n'), any::<u8>()], 0..200),
        cuts in prop::collection::vec(any::<prop::sample::Index>(), 0..10),
        spread in any::<bool>(),
    ) {
        let mut points: Vec<usize> = cuts.iter().map(|c| c.index(bytes.len() + 1)).collect();
        points.extend([0, bytes.len()]);
        points.sort_unstable();
        let run = |chunks: Vec<&[u8]>, spread: bool| {
            let mut d = driver(|s| s.end = end);
            for (i, chunk) in chunks.iter().enumerate() {
                // Within one ZVZ of each other (4 ms): 1 ms apart, or all at once.
                d.handle_rx(if spread { at(i as u64) } else { at(0) }, chunk);
            }
            d.handle_timeout(at(1000));
            events(&mut d)
        };
        let chunks: Vec<&[u8]> = points.windows(2).filter_map(|w| bytes.get(w[0]..w[1])).collect();
        prop_assert_eq!(run(chunks, spread), run(vec![&bytes], false));
    }

    #[test]
    fn any_input_comes_to_rest(ops in prop::collection::vec(op(), 0..40), flow in flows(), end in criteria()) {
        let mut d = driver(|s| {
            s.interface = Interface::Rs232;
            s.flow = flow;
            s.end = end;
            s.receive_buffers = 2;
        });
        let mut now = at(0);
        let drain = |d: &mut AsciiDriver, now: Instant| {
            actions(d);
            out(d, now);
            events(d);
        };
        for op in ops {
            match op {
                Op::Rx(bytes) => d.handle_rx(now, &bytes),
                Op::LineError(e) => d.handle_line_error(now, e),
                Op::Signals(cts, dsr) => d.handle_signals(now, Signals { cts, dsr }),
                Op::Send(data) => { let _ = d.send(now, data); }
                Op::Take => { d.take_received(); }
                Op::Wait(n) => {
                    now += ms(n.into());
                    if d.poll_timeout().is_some_and(|t| t <= now) { d.handle_timeout(now); }
                }
            }
            drain(&mut d, now);
        }
        for _ in 0..10_000 {
            drain(&mut d, now);
            match d.poll_timeout() {
                Some(t) => {
                    now = now.max(t);
                    d.handle_timeout(now);
                }
                None => break,
            }
        }
        prop_assert!(d.is_idle());
        prop_assert_eq!(d.poll_timeout(), None);
    }

    #[test]
    fn character_delay_cuts_where_the_gaps_are(
        telegrams in prop::collection::vec(prop::collection::vec(any::<u8>(), 1..50), 1..6),
    ) {
        let mut d = driver(|_| {});
        let mut now = at(0);
        for t in &telegrams {
            for &b in t {
                d.handle_rx(now, &[b]);
                now += Duration::from_micros(1146);
            }
            now += ms(4);
            d.handle_timeout(now);
        }
        prop_assert_eq!(received(&events(&mut d)), telegrams);
    }
}

#[test]
fn send_with_end_character_cuts_the_telegram_after_its_end_characters() {
    // 003 6.2.1 "Send with end character": "the length of the respective telegram is limited by
    // an end character"; the default sends the length given.
    let crlf = |s: &mut AsciiSettings| {
        s.end = EndCriterion::EndChars {
            first: b'\r',
            second: Some(b'\n'),
        };
    };
    let mut settings = AsciiSettings::default();
    crlf(&mut settings);
    let params = AsciiParams::try_new(settings.clone()).expect("valid");
    assert_eq!(params.send_length(), SendLength::AsGiven);
    let up_to = params
        .with_send_length(SendLength::UpToEndChars)
        .expect("valid with end characters");
    let mut d = AsciiDriver::new(up_to);
    d.send(at(0), b"12\r3\r\nrest\r\n".to_vec())
        .expect("accepted");
    assert_eq!(out(&mut d, at(10)), [b"12\r3\r\n".to_vec()]);
    // Without its end characters the telegram goes out as given.
    d.send(at(20), b"no end".to_vec()).expect("accepted");
    assert_eq!(out(&mut d, at(30)), [b"no end".to_vec()]);
    // As given by default.
    let mut plain = AsciiDriver::new(AsciiParams::try_new(settings).expect("valid"));
    plain.send(at(0), b"a\r\nb".to_vec()).expect("accepted");
    assert_eq!(out(&mut plain, at(10)), [b"a\r\nb".to_vec()]);
    // One end character.
    let etx = AsciiParams::try_new(AsciiSettings {
        end: EndCriterion::EndChars {
            first: 0x03,
            second: None,
        },
        ..AsciiSettings::default()
    })
    .and_then(|p| p.with_send_length(SendLength::UpToEndChars))
    .expect("valid");
    let mut d = AsciiDriver::new(etx);
    d.send(at(0), b"AB\x03CD\x03".to_vec()).expect("accepted");
    assert_eq!(out(&mut d, at(10)), [b"AB\x03".to_vec()]);
    // Only "as soon as 'End character' is activated at the end ID".
    assert_eq!(
        AsciiParams::default().with_send_length(SendLength::UpToEndChars),
        Err(ConfigError::SendLengthNeedsEndChars)
    );
}

#[test]
fn full_duplex_the_character_delay_runs_on_the_received_bytes_own_arrival() {
    // 003 6.2.1 "Full-duplex (RS422)": "data may be sent and received at the same time"; 6.2:
    // telegrams are separated by the character delay time between received characters. Our own
    // long transmission does not stretch it.
    let mut d = driver(|_| {});
    let zvz = d.params().settings().zvz;
    let id = d.send(at(0), vec![b'x'; 200]).expect("accepted");
    let sending = d.poll_transmit().expect("the telegram goes out");
    assert_eq!(sending.len(), 200);
    // At 9600 bit/s the 200 bytes take about 230 ms; the partner sends two telegrams meanwhile.
    d.handle_rx(at(10), b"AB");
    assert_eq!(d.poll_timeout(), Some(at(10) + zvz));
    d.handle_timeout(at(10) + zvz);
    d.handle_rx(at(50), b"CD");
    d.handle_timeout(at(50) + zvz);
    assert_eq!(received(&events(&mut d)), [b"AB".to_vec(), b"CD".to_vec()]);
    d.handle_tx_done(at(230));
    assert_eq!(events(&mut d), [AsciiEvent::Sent { id }]);
}
