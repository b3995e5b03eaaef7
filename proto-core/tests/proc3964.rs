//! The 3964(R) procedure (manual 003 6.3, 000 6.3; events 7.2) on a simulated clock.
//!
//! Frames of the 3964(R) table in the project's vectors (from both CP 341 manuals, 6.3) are
//! copied here byte for byte.

use core::time::Duration;
use std::collections::VecDeque;

use proptest::prelude::*;
use proto_core::event::{ids, EventId};
use proto_core::proc3964::frame::{encode, Deframer, Progress};
use proto_core::proc3964::{
    Event3964, LineError, Params3964, Priority, Proc3964, SendError, Settings3964, Variant, DLE,
    ETX, NAK, STX,
};
use proto_core::time::Instant;

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn at(n: u64) -> Instant {
    Instant::from_millis(n)
}

fn station(f: impl FnOnce(&mut Settings3964)) -> Proc3964 {
    let mut settings = Settings3964::default();
    f(&mut settings);
    Proc3964::new(Params3964::try_new(settings).expect("valid settings"))
}

/// Everything the station wants to write, each buffer confirmed as sent at `done`.
fn out(p: &mut Proc3964, done: Instant) -> Vec<u8> {
    let mut bytes = Vec::new();
    while let Some(buf) = p.poll_transmit() {
        bytes.extend_from_slice(&buf);
        p.handle_tx_done(done);
    }
    bytes
}

fn events(p: &mut Proc3964) -> Vec<Event3964> {
    std::iter::from_fn(|| p.poll_event()).collect()
}

fn raised(events: &[Event3964]) -> Vec<EventId> {
    events
        .iter()
        .filter_map(|e| match e {
            Event3964::Raised { id } => Some(*id),
            _ => None,
        })
        .collect()
}

/// vectors/README.md "3964(R)": (variant, user data, bytes the active side sends after DLE).
const VECTORS: [(Variant, &[u8], &[u8]); 3] = [
    (
        Variant::P3964R,
        b"ABC",
        &[0x41, 0x42, 0x43, 0x10, 0x03, 0x53],
    ),
    (
        Variant::P3964R,
        &[0x10, 0x20],
        &[0x10, 0x10, 0x20, 0x10, 0x03, 0x33],
    ),
    (Variant::P3964, b"ABC", &[0x41, 0x42, 0x43, 0x10, 0x03]),
];

#[test]
fn active_side_sends_the_manual_frames() {
    for (variant, data, frame) in VECTORS {
        let mut a = station(|s| *s = Settings3964::new(variant));
        let id = a.send(at(0), data.to_vec()).expect("accepted");
        assert_eq!(out(&mut a, at(1)), [STX]);
        a.handle_rx(at(5), &[DLE]);
        assert_eq!(out(&mut a, at(10)), frame, "{variant:?} {data:02X?}");
        assert!(events(&mut a).is_empty());
        a.handle_rx(at(12), &[DLE]);
        assert_eq!(events(&mut a), [Event3964::Sent { id }]);
        assert!(a.is_idle());
        assert_eq!(a.poll_timeout(), None);
    }
}

#[test]
fn passive_side_accepts_the_manual_frames() {
    for (variant, data, frame) in VECTORS {
        let mut p = station(|s| *s = Settings3964::new(variant));
        p.handle_rx(at(0), &[STX]);
        assert_eq!(out(&mut p, at(1)), [DLE]);
        p.handle_rx(at(3), frame);
        assert_eq!(out(&mut p, at(4)), [DLE]);
        assert_eq!(
            events(&mut p),
            [Event3964::Received {
                data: data.to_vec()
            }]
        );
        assert_eq!(p.take_received().as_deref(), Some(data));
        assert!(p.is_idle());
    }
}

#[test]
fn a_held_acknowledgement_goes_out_only_when_confirmed() {
    // hold_ack: the final DLE (003 6.3.1) waits until the runtime stored the telegram.
    let (_, data, frame) = VECTORS[0];
    let mut p = station(|s| s.hold_ack = true);
    p.handle_rx(at(0), &[STX]);
    assert_eq!(out(&mut p, at(1)), [DLE]);
    p.handle_rx(at(3), frame);
    assert_eq!(out(&mut p, at(4)), [], "no DLE before the confirmation");
    assert!(p.awaiting_confirm());
    assert_eq!(p.poll_timeout(), None);
    assert_eq!(
        events(&mut p),
        [Event3964::Received {
            data: data.to_vec()
        }]
    );
    assert_eq!(p.take_received().as_deref(), Some(data));
    assert!(!p.is_idle());
    p.confirm_received(at(5), Ok(()));
    assert_eq!(out(&mut p, at(6)), [DLE]);
    assert!(p.is_idle());
    // Confirming again does nothing.
    p.confirm_received(at(7), Ok(()));
    assert_eq!(out(&mut p, at(8)), []);
}

#[test]
fn a_refused_confirmation_is_a_nak_and_the_partner_repeats() {
    let (_, data, frame) = VECTORS[0];
    let mut p = station(|s| s.hold_ack = true);
    p.handle_rx(at(0), &[STX]);
    assert_eq!(out(&mut p, at(1)), [DLE]);
    p.handle_rx(at(3), frame);
    assert_eq!(p.take_received().as_deref(), Some(data));
    p.confirm_received(at(5), Err(ids::CPU_TRANSFER_ERROR));
    assert_eq!(out(&mut p, at(6)), [NAK]);
    assert_eq!(
        raised(&events(&mut p)),
        [ids::CPU_TRANSFER_ERROR, ids::RECEIVE_REPETITION]
    );
    // The repetition (6.3.1) is received and, confirmed, acknowledged.
    p.handle_rx(at(20), &[STX]);
    assert_eq!(out(&mut p, at(21)), [DLE]);
    p.handle_rx(at(23), frame);
    assert_eq!(p.take_received().as_deref(), Some(data));
    p.confirm_received(at(25), Ok(()));
    assert_eq!(out(&mut p, at(26)), [DLE]);
    assert!(p.is_idle());
}

#[test]
fn a_station_not_ready_answers_stx_with_nak() {
    // 003 6.3.1 "When the driver is not ready yet at reception of the STX, it sends a NAK";
    // 7.2 08 0Ah.
    let mut p = station(|_| {});
    p.set_receive_ready(false);
    p.handle_rx(at(0), &[STX]);
    assert_eq!(out(&mut p, at(1)), [NAK]);
    assert_eq!(raised(&events(&mut p)), [ids::NO_FREE_RECEIVE_BUFFER]);
    p.set_receive_ready(true);
    p.handle_rx(at(10), &[STX]);
    assert_eq!(out(&mut p, at(11)), [DLE]);
}

#[test]
fn bad_bcc_is_answered_with_nak() {
    // vectors: "receiver rejects a bad BCC: ... 41 42 43 10 03 54 -> 15 (NAK) instead of DLE".
    let mut p = station(|_| {});
    p.handle_rx(at(0), &[STX]);
    assert_eq!(out(&mut p, at(1)), [DLE]);
    p.handle_rx(at(3), &[0x41, 0x42, 0x43, 0x10, 0x03, 0x54]);
    assert_eq!(out(&mut p, at(4)), [NAK]);
    assert_eq!(
        raised(&events(&mut p)),
        [ids::BCC_ERROR, ids::RECEIVE_REPETITION]
    );
    assert_eq!(p.received_len(), 0);
}

#[test]
fn qvz_after_stx_repeats_stx_up_to_the_setup_attempts() {
    // 6.3.1: "When the QVZ expires after an STX, the STX is repeated. This process is repeated 5
    // times after which ... a NAK"; 6.3.3: 6 setup attempts, QVZ 2000 ms.
    let mut a = station(|_| {});
    let id = a.send(at(0), b"X".to_vec()).expect("accepted");
    let mut now = at(0);
    let mut stx = 0;
    loop {
        let sent = out(&mut a, now + ms(1));
        if sent == [NAK] {
            break;
        }
        assert_eq!(sent, [STX]);
        stx += 1;
        let deadline = a.poll_timeout().expect("QVZ runs");
        assert_eq!(deadline, now + ms(1) + ms(2000));
        a.handle_timeout(Instant::from_micros(deadline.as_micros() - 1));
        assert_eq!(a.poll_transmit(), None, "early timeout does nothing");
        now = deadline;
        a.handle_timeout(now);
    }
    assert_eq!(stx, 6);
    let ev = events(&mut a);
    let mut expected = vec![ids::SEND_SETUP_TIMEOUT, ids::SEND_REPETITION];
    expected.extend([ids::SEND_SETUP_TIMEOUT; 5]);
    expected.push(ids::SEND_SETUP_ATTEMPTS_EXHAUSTED);
    assert_eq!(raised(&ev), expected);
    assert_eq!(
        ev.last(),
        Some(&Event3964::SendFailed {
            id,
            event: ids::SEND_SETUP_ATTEMPTS_EXHAUSTED,
            first: ids::SEND_SETUP_TIMEOUT
        })
    );
    assert!(a.is_idle());
}

#[test]
fn nak_after_stx_is_a_failed_setup() {
    let mut a = station(|s| s.setup_attempts = 2);
    let id = a.send(at(0), b"X".to_vec()).expect("accepted");
    assert_eq!(out(&mut a, at(1)), [STX]);
    a.handle_rx(at(2), &[NAK]);
    assert_eq!(out(&mut a, at(3)), [STX]);
    a.handle_rx(at(4), &[0x41]);
    assert_eq!(out(&mut a, at(5)), [NAK]);
    let ev = events(&mut a);
    assert_eq!(
        raised(&ev),
        [
            ids::SEND_SETUP_REJECTED,
            ids::SEND_REPETITION,
            ids::SEND_SETUP_REJECTED,
            ids::SEND_SETUP_ATTEMPTS_EXHAUSTED
        ]
    );
    assert!(ev.contains(&Event3964::SendFailed {
        id,
        event: ids::SEND_SETUP_ATTEMPTS_EXHAUSTED,
        first: ids::SEND_SETUP_REJECTED
    }));
}

#[test]
fn nak_after_the_telegram_repeats_up_to_the_transmission_attempts() {
    // 6.3.1: "when a character other than DLE is received the attempt to establish the connection
    // and the telegram are repeated. This process is also repeated 5 times after which a NAK".
    let mut a = station(|_| {});
    let id = a.send(at(0), b"ABC".to_vec()).expect("accepted");
    let mut now = at(0);
    for _ in 0..6 {
        assert_eq!(out(&mut a, now + ms(1)), [STX]);
        a.handle_rx(now + ms(2), &[DLE]);
        assert_eq!(
            out(&mut a, now + ms(8)),
            [0x41, 0x42, 0x43, 0x10, 0x03, 0x53]
        );
        now += ms(10);
        a.handle_rx(now, &[NAK]);
    }
    assert_eq!(out(&mut a, now + ms(1)), [NAK]);
    let ev = events(&mut a);
    let mut expected = vec![ids::SEND_END_REJECTED, ids::SEND_REPETITION];
    expected.extend([ids::SEND_END_REJECTED; 5]);
    expected.push(ids::SEND_ATTEMPTS_EXHAUSTED);
    assert_eq!(raised(&ev), expected);
    assert_eq!(
        ev.last(),
        Some(&Event3964::SendFailed {
            id,
            event: ids::SEND_ATTEMPTS_EXHAUSTED,
            first: ids::SEND_END_REJECTED
        })
    );
}

#[test]
fn qvz_after_the_telegram_repeats_the_transmission() {
    let mut a = station(|s| s.transmission_attempts = 1);
    let id = a.send(at(0), b"A".to_vec()).expect("accepted");
    assert_eq!(out(&mut a, at(1)), [STX]);
    a.handle_rx(at(2), &[DLE]);
    assert_eq!(out(&mut a, at(5)), encode(b"A", Variant::P3964R));
    assert_eq!(a.poll_timeout(), Some(at(2005)));
    a.handle_timeout(at(2005));
    assert_eq!(out(&mut a, at(2006)), [NAK]);
    let ev = events(&mut a);
    assert_eq!(
        raised(&ev),
        [ids::SEND_END_TIMEOUT, ids::SEND_ATTEMPTS_EXHAUSTED]
    );
    assert!(ev.contains(&Event3964::SendFailed {
        id,
        event: ids::SEND_ATTEMPTS_EXHAUSTED,
        first: ids::SEND_END_TIMEOUT
    }));
}

#[test]
fn characters_during_the_send_abort_the_attempt() {
    // 7.2, 07 04h: "during current send operation, one or more characters were received";
    // 07 06h: "Acknowledgment code (DLE) received to early".
    for (byte, cause) in [
        (0x41, ids::SEND_ABORTED_BY_PARTNER),
        (DLE, ids::SEND_END_REJECTED),
    ] {
        let mut a = station(|_| {});
        a.send(at(0), b"ABCDEF".to_vec()).expect("accepted");
        assert_eq!(out(&mut a, at(1)), [STX]);
        a.handle_rx(at(2), &[DLE]);
        let frame = a.poll_transmit().expect("telegram");
        assert_eq!(frame, encode(b"ABCDEF", Variant::P3964R));
        a.handle_rx(at(3), &[byte]);
        a.handle_tx_done(at(9));
        assert_eq!(out(&mut a, at(10)), [STX], "the attempt is repeated");
        assert_eq!(raised(&events(&mut a)), [cause, ids::SEND_REPETITION]);
    }
}

#[test]
fn zvz_expiry_while_receiving_is_answered_with_nak() {
    // 6.3.1 "Passive operation": "When the ZVZ is exceeded at reception, a NAK is sent"; 7.2
    // 08 06h; 6.3.3: ZVZ 220 ms.
    let mut p = station(|_| {});
    p.handle_rx(at(0), &[STX]);
    assert_eq!(out(&mut p, at(1)), [DLE]);
    assert_eq!(
        p.poll_timeout(),
        Some(at(221)),
        "first character after DLE within ZVZ"
    );
    p.handle_rx(at(100), &[0x41]);
    assert_eq!(p.poll_timeout(), Some(at(320)));
    p.handle_timeout(at(319));
    assert_eq!(p.poll_transmit(), None);
    p.handle_timeout(at(320));
    assert_eq!(out(&mut p, at(321)), [NAK]);
    assert_eq!(
        raised(&events(&mut p)),
        [ids::CHARACTER_DELAY_EXCEEDED, ids::RECEIVE_REPETITION]
    );
    assert_eq!(p.poll_timeout(), None);
}

#[test]
fn passive_rules_in_idle() {
    // 6.3.1: "it receives a character that is not equal to STX it will transmit a NAK. The driver
    // does not respond with an answer to the reception of a NAK."
    let mut p = station(|_| {});
    p.handle_rx(at(0), &[0x41]);
    assert_eq!(out(&mut p, at(1)), [NAK]);
    assert_eq!(raised(&events(&mut p)), [ids::RECEIVE_SETUP_ERROR]);
    p.handle_rx(at(2), &[NAK]);
    assert_eq!(out(&mut p, at(3)), Vec::<u8>::new());
    assert!(events(&mut p).is_empty());
    // 7.2, 08 0Ch: a faulty character in idle is reported at once; a BREAK is no character.
    p.handle_line_error(at(4), LineError::Parity);
    assert_eq!(out(&mut p, at(5)), [NAK]);
    p.handle_line_error(at(6), LineError::Break);
    assert_eq!(out(&mut p, at(7)), Vec::<u8>::new());
    assert_eq!(
        raised(&events(&mut p)),
        [ids::CHARACTER_ERROR, ids::LINE_BREAK]
    );
}

#[test]
fn receive_faults_are_answered_with_nak_at_the_end() {
    let cases: [(&[u8], EventId); 4] = [
        // 08 05h: DLE followed by another code.
        (
            &[0x41, DLE, 0x07, 0x42, DLE, ETX, 0x00],
            ids::RECEIVE_LOGICAL_ERROR,
        ),
        // 08 16h: longer than the 4 bytes configured below.
        (&encode(b"ABCDE", Variant::P3964R), ids::FRAME_TOO_LONG),
        // 08 08h.
        (&[0x41, DLE, ETX, 0x00], ids::BCC_ERROR),
        // A doubled DLE is data, and the BCC covers it twice.
        (&encode(&[DLE, DLE, 1], Variant::P3964R), EventId::new(0, 0)),
    ];
    for (frame, cause) in cases {
        let mut p = station(|s| s.max_len = 4);
        p.handle_rx(at(0), &[STX]);
        assert_eq!(out(&mut p, at(1)), [DLE]);
        let (last, head) = frame.split_last().expect("not empty");
        p.handle_rx(at(2), head);
        assert_eq!(p.poll_transmit(), None, "no answer before the end");
        p.handle_rx(at(3), &[*last]);
        let ev = events(&mut p);
        if cause == EventId::new(0, 0) {
            assert_eq!(out(&mut p, at(4)), [DLE]);
            assert_eq!(
                ev,
                [Event3964::Received {
                    data: vec![DLE, DLE, 1]
                }]
            );
        } else {
            assert_eq!(out(&mut p, at(4)), [NAK]);
            assert_eq!(raised(&ev), [cause, ids::RECEIVE_REPETITION]);
        }
    }
}

#[test]
fn characters_before_our_dle_and_line_errors_spoil_the_reception() {
    // 7.2, 08 02h: "After a STX was received, partner sent more codes without waiting for DLE."
    let mut p = station(|_| {});
    p.handle_rx(at(0), &[STX, 0x41, DLE, ETX, 0x52]);
    assert_eq!(out(&mut p, at(1)), [DLE, NAK]);
    assert_eq!(
        raised(&events(&mut p)),
        [ids::RECEIVE_SETUP_ERROR, ids::RECEIVE_REPETITION]
    );
    // 7.2, 08 0Ch: "If this occurs during ... receive operation, repetitions are initiated."
    p.handle_rx(at(10), &[STX]);
    assert_eq!(out(&mut p, at(11)), [DLE]);
    p.handle_rx(at(12), &[0x41]);
    p.handle_line_error(at(13), LineError::Framing);
    p.handle_rx(at(14), &[DLE, ETX, 0x00]);
    assert_eq!(out(&mut p, at(15)), [NAK]);
    assert_eq!(raised(&events(&mut p)), [ids::CHARACTER_ERROR]);
}

#[test]
fn a_full_receive_buffer_answers_stx_with_nak() {
    let mut p = station(|s| s.receive_buffers = 1);
    p.handle_rx(at(0), &[STX]);
    out(&mut p, at(1));
    p.handle_rx(at(2), &encode(b"A", Variant::P3964R));
    assert_eq!(out(&mut p, at(3)), [DLE]);
    p.handle_rx(at(4), &[STX]);
    assert_eq!(out(&mut p, at(5)), [NAK]);
    assert_eq!(raised(&events(&mut p)), [ids::NO_FREE_RECEIVE_BUFFER]);
    assert_eq!(p.take_received(), Some(b"A".to_vec()));
    p.handle_rx(at(6), &[STX]);
    assert_eq!(out(&mut p, at(7)), [DLE]);
}

#[test]
fn repetitions_beyond_our_attempts_raise_a_mismatch() {
    // 7.2, 08 15h (our reading, see Proc3964): the partner repeats more often than we would.
    let mut p = station(|s| s.transmission_attempts = 2);
    let bad = [0x41, DLE, ETX, 0x00];
    let mut seen = Vec::new();
    for round in 0..4 {
        let t = at(round * 100);
        p.handle_rx(t, &[STX]);
        assert_eq!(out(&mut p, t + ms(1)), [DLE]);
        p.handle_rx(t + ms(2), &bad);
        assert_eq!(out(&mut p, t + ms(3)), [NAK]);
        seen.extend(raised(&events(&mut p)));
    }
    assert_eq!(
        seen,
        [
            ids::BCC_ERROR,
            ids::RECEIVE_REPETITION,
            ids::BCC_ERROR,
            ids::ATTEMPTS_MISMATCH,
            ids::BCC_ERROR,
            ids::BCC_ERROR
        ]
    );
}

#[test]
fn send_refuses_what_cannot_be_sent() {
    let mut a = station(|s| s.send_queue = 2);
    assert_eq!(a.send(at(0), Vec::new()), Err(SendError::Empty));
    assert_eq!(
        a.send(at(0), vec![0; 251]),
        Err(SendError::TooLong { len: 251, max: 250 })
    );
    assert_eq!(
        SendError::TooLong { len: 251, max: 250 }.event(),
        Some(ids::TRANSFER_LENGTH_INVALID)
    );
    for _ in 0..3 {
        a.send(at(0), vec![1]).expect("one in progress, two queued");
    }
    assert_eq!(
        a.send(at(0), vec![1]),
        Err(SendError::QueueFull { capacity: 2 })
    );
    let mut big = station(|s| s.max_len = 1024);
    assert!(big.send(at(0), vec![DLE; 1024]).is_ok());
}

#[test]
fn initialization_conflict_by_hand() {
    // 6.3.1 "Initialization conflict": "the station with the lower priority will transmit the DLE
    // and change to receive mode".
    let mut high = station(|_| {});
    let mut low = station(|s| s.priority = Priority::Low);
    let id_high = high.send(at(0), b"H".to_vec()).expect("accepted");
    let id_low = low.send(at(0), b"L".to_vec()).expect("accepted");
    assert_eq!(out(&mut high, at(1)), [STX]);
    assert_eq!(out(&mut low, at(1)), [STX]);
    high.handle_rx(at(2), &[STX]);
    assert_eq!(
        high.poll_transmit(),
        None,
        "the high-priority side keeps waiting for DLE"
    );
    low.handle_rx(at(2), &[STX]);
    assert_eq!(out(&mut low, at(3)), [DLE]);
    high.handle_rx(at(4), &[DLE]);
    let frame = out(&mut high, at(5));
    low.handle_rx(at(6), &frame);
    assert_eq!(
        out(&mut low, at(7)),
        [DLE, STX],
        "acknowledge, then send its own"
    );
    high.handle_rx(at(8), &[DLE, STX]);
    assert_eq!(out(&mut high, at(9)), [DLE]);
    low.handle_rx(at(10), &[DLE]);
    let frame = out(&mut low, at(11));
    high.handle_rx(at(12), &frame);
    assert_eq!(out(&mut high, at(13)), [DLE]);
    low.handle_rx(at(14), &[DLE]);
    let (eh, el) = (events(&mut high), events(&mut low));
    assert_eq!(
        eh,
        [
            Event3964::Sent { id: id_high },
            Event3964::Received {
                data: b"L".to_vec()
            }
        ]
    );
    assert_eq!(
        el,
        [
            Event3964::Received {
                data: b"H".to_vec()
            },
            Event3964::Sent { id: id_low }
        ]
    );
}

// --- two stations on a simulated line ---

/// One end of the simulated line.
struct End {
    station: Proc3964,
    /// When this end's transmitter is free again.
    free_at: Instant,
    /// Bytes on their way to this end: (arrival, byte).
    inbox: VecDeque<(Instant, u8)>,
    events: Vec<(Instant, Event3964)>,
    /// Bytes written so far, for fault injection by position.
    written: usize,
}

/// Two stations wired back to back; every byte takes one character time (the virtual clock steps
/// to the next arrival or deadline, as quinn-proto's test `Pair` does).
struct Pair {
    now: Instant,
    char_time: Duration,
    a: End,
    b: End,
    /// Applied to every byte a writes (position, byte): `None` drops it.
    fault_a: Box<dyn FnMut(usize, u8) -> Option<u8>>,
}

impl Pair {
    fn new(a: Proc3964, b: Proc3964) -> Self {
        let end = |station| End {
            station,
            free_at: Instant::ZERO,
            inbox: VecDeque::new(),
            events: Vec::new(),
            written: 0,
        };
        // 9600 bit/s, 11 bits a character (8E1): about 1.15 ms.
        Self {
            now: Instant::ZERO,
            char_time: Duration::from_micros(1146),
            a: end(a),
            b: end(b),
            fault_a: Box::new(clean),
        }
    }

    fn flush(
        now: Instant,
        char_time: Duration,
        from: &mut End,
        to: &mut End,
        fault: &mut dyn FnMut(usize, u8) -> Option<u8>,
    ) {
        while let Some(buf) = from.station.poll_transmit() {
            let start = from.free_at.max(now);
            for (i, &byte) in buf.iter().enumerate() {
                let arrival = start + char_time * u32::try_from(i + 1).expect("short buffers");
                if let Some(byte) = fault(from.written, byte) {
                    to.inbox.push_back((arrival, byte));
                }
                from.written += 1;
            }
            from.free_at = start + char_time * u32::try_from(buf.len()).expect("short buffers");
            from.station.handle_tx_done(from.free_at);
        }
        while let Some(event) = from.station.poll_event() {
            if matches!(event, Event3964::Received { .. }) {
                from.station.take_received();
            }
            from.events.push((now, event));
        }
    }

    /// Advances to the next arrival or deadline; false when nothing is left to happen.
    fn step(&mut self) -> bool {
        let (now, ct) = (self.now, self.char_time);
        Self::flush(now, ct, &mut self.a, &mut self.b, &mut self.fault_a);
        Self::flush(now, ct, &mut self.b, &mut self.a, &mut clean);
        let next = [
            self.a.inbox.front().map(|x| x.0),
            self.b.inbox.front().map(|x| x.0),
            self.a.station.poll_timeout(),
            self.b.station.poll_timeout(),
        ]
        .into_iter()
        .flatten()
        .min();
        let Some(next) = next else { return false };
        self.now = self.now.max(next);
        for end in [&mut self.a, &mut self.b] {
            let mut bytes = Vec::new();
            while end.inbox.front().is_some_and(|x| x.0 <= self.now) {
                bytes.extend(end.inbox.pop_front().map(|x| x.1));
            }
            if !bytes.is_empty() {
                end.station.handle_rx(self.now, &bytes);
            }
        }
        for end in [&mut self.a, &mut self.b] {
            if end.station.poll_timeout().is_some_and(|t| t <= self.now) {
                end.station.handle_timeout(self.now);
            }
        }
        true
    }

    /// Runs until nothing is left to happen; a livelock fails the test.
    fn drive(&mut self) {
        for _ in 0..100_000 {
            if !self.step() {
                assert!(self.a.station.is_idle() && self.b.station.is_idle());
                return;
            }
        }
        panic!("no rest after 100000 steps");
    }
}

/// The fault filter that changes nothing.
fn clean(_: usize, byte: u8) -> Option<u8> {
    Some(byte)
}

fn sent_ids(end: &End) -> Vec<u64> {
    end.events
        .iter()
        .filter_map(|(_, e)| match e {
            Event3964::Sent { id } => Some(id.get()),
            _ => None,
        })
        .collect()
}

fn received(end: &End) -> Vec<Vec<u8>> {
    end.events
        .iter()
        .filter_map(|(_, e)| match e {
            Event3964::Received { data } => Some(data.clone()),
            _ => None,
        })
        .collect()
}

fn end_raised(end: &End) -> Vec<EventId> {
    raised(
        &end.events
            .iter()
            .map(|(_, e)| e.clone())
            .collect::<Vec<_>>(),
    )
}

#[test]
fn simultaneous_starts_on_the_line() {
    let mut pair = Pair::new(station(|_| {}), station(|s| s.priority = Priority::Low));
    pair.a
        .station
        .send(at(0), b"from high".to_vec())
        .expect("accepted");
    pair.b
        .station
        .send(at(0), b"from low".to_vec())
        .expect("accepted");
    pair.drive();
    assert_eq!(received(&pair.b), [b"from high".to_vec()]);
    assert_eq!(received(&pair.a), [b"from low".to_vec()]);
    assert_eq!((sent_ids(&pair.a), sent_ids(&pair.b)), (vec![1], vec![1]));
    assert!(end_raised(&pair.a).is_empty() && end_raised(&pair.b).is_empty());
    let first_rx_at_low = pair
        .b
        .events
        .iter()
        .find(|(_, e)| matches!(e, Event3964::Received { .. }))
        .map(|x| x.0);
    let first_rx_at_high = pair
        .a
        .events
        .iter()
        .find(|(_, e)| matches!(e, Event3964::Received { .. }))
        .map(|x| x.0);
    assert!(
        first_rx_at_low < first_rx_at_high,
        "the low-priority side receives first"
    );
}

#[test]
fn a_corrupted_byte_is_repaired_by_repetition() {
    let mut pair = Pair::new(station(|_| {}), station(|_| {}));
    // Byte 0 is STX, 1..=3 "ABC": flip a bit of 'B' once.
    pair.fault_a = Box::new(|pos, byte| Some(if pos == 2 { byte ^ 0x01 } else { byte }));
    let id = pair
        .a
        .station
        .send(at(0), b"ABC".to_vec())
        .expect("accepted");
    pair.drive();
    assert_eq!(received(&pair.b), [b"ABC".to_vec()]);
    assert_eq!(sent_ids(&pair.a), [id.get()]);
    assert_eq!(
        end_raised(&pair.b),
        [ids::BCC_ERROR, ids::RECEIVE_REPETITION]
    );
    assert_eq!(
        end_raised(&pair.a),
        [ids::SEND_END_REJECTED, ids::SEND_REPETITION]
    );
}

#[test]
fn a_line_that_always_corrupts_exhausts_the_transmission_attempts() {
    let mut pair = Pair::new(station(|_| {}), station(|_| {}));
    // Every 'A' arrives as '@': each BCC check fails.
    pair.fault_a = Box::new(|_, byte| Some(if byte == b'A' { b'@' } else { byte }));
    let id = pair.a.station.send(at(0), b"A".to_vec()).expect("accepted");
    pair.drive();
    let mut sender = vec![ids::SEND_END_REJECTED, ids::SEND_REPETITION];
    sender.extend([ids::SEND_END_REJECTED; 5]);
    sender.push(ids::SEND_ATTEMPTS_EXHAUSTED);
    assert_eq!(end_raised(&pair.a), sender);
    let mut receiver = vec![ids::BCC_ERROR, ids::RECEIVE_REPETITION];
    receiver.extend([ids::BCC_ERROR; 5]);
    assert_eq!(
        end_raised(&pair.b),
        receiver,
        "equal attempts on both sides: no 08 15h"
    );
    assert!(pair.a.events.iter().any(|(_, e)| *e
        == Event3964::SendFailed {
            id,
            event: ids::SEND_ATTEMPTS_EXHAUSTED,
            first: ids::SEND_END_REJECTED
        }));
    assert!(received(&pair.b).is_empty());
}

#[test]
fn a_deaf_partner_exhausts_the_setup_attempts_in_the_manuals_time() {
    let mut pair = Pair::new(station(|_| {}), station(|_| {}));
    pair.fault_a = Box::new(|_, _| None);
    let id = pair.a.station.send(at(0), b"A".to_vec()).expect("accepted");
    pair.drive();
    let failed = pair
        .a
        .events
        .iter()
        .find(|(_, e)| matches!(e, Event3964::SendFailed { .. }));
    let (when, event) = failed.expect("gave up");
    assert_eq!(
        *event,
        Event3964::SendFailed {
            id,
            event: ids::SEND_SETUP_ATTEMPTS_EXHAUSTED,
            first: ids::SEND_SETUP_TIMEOUT
        }
    );
    // 6 x (one STX on the wire + QVZ 2000 ms).
    assert_eq!(*when, Instant::ZERO + (pair.char_time + ms(2000)) * 6);
}

/// One thing that can happen to a station.
#[derive(Clone, Debug)]
enum Op {
    Rx(Vec<u8>),
    LineError(LineError),
    Send(Vec<u8>),
    Wait(u16),
}

fn op() -> impl Strategy<Value = Op> {
    let byte = prop_oneof![Just(STX), Just(DLE), Just(ETX), Just(NAK), any::<u8>()];
    prop_oneof![
        4 => prop::collection::vec(byte, 1..12).prop_map(Op::Rx),
        1 => prop_oneof![Just(LineError::Parity), Just(LineError::Break)].prop_map(Op::LineError),
        1 => prop::collection::vec(any::<u8>(), 0..300).prop_map(Op::Send),
        2 => (0u16..3000).prop_map(Op::Wait),
    ]
}

fn payload() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(
        prop_oneof![Just(DLE), Just(ETX), Just(STX), Just(NAK), any::<u8>()],
        1..=250,
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn any_payload_round_trips(data in prop::collection::vec(any::<u8>(), 0..=1024), r in any::<bool>()) {
        let variant = if r { Variant::P3964R } else { Variant::P3964 };
        let frame = encode(&data, variant);
        if r {
            prop_assert_eq!(frame.iter().fold(0, |x, b| x ^ b), 0, "BCC closes the XOR");
        }
        let mut d = Deframer::new(variant, 1024);
        let mut progress = Progress::Incomplete;
        for (i, &b) in frame.iter().enumerate() {
            prop_assert_eq!(progress, Progress::Incomplete, "ended early at {}", i);
            progress = d.push(b);
        }
        prop_assert_eq!(progress, Progress::Complete);
        prop_assert_eq!(d.finish(), Ok(data));
    }

    #[test]
    fn chunking_does_not_change_the_result(data in payload(), cuts in prop::collection::vec(any::<prop::sample::Index>(), 0..8), bad in any::<bool>()) {
        let mut frame = encode(&data, Variant::P3964R);
        if bad {
            if let Some(bcc) = frame.last_mut() { *bcc ^= 0x80; }
        }
        let mut points: Vec<usize> = cuts.iter().map(|c| c.index(frame.len() + 1)).collect();
        points.extend([0, frame.len()]);
        points.sort_unstable();
        let run = |chunks: &[&[u8]]| {
            let mut p = station(|_| {});
            p.handle_rx(at(0), &[STX]);
            let mut wire = out(&mut p, at(1));
            for (i, chunk) in chunks.iter().enumerate() {
                p.handle_rx(at(2 + i as u64), chunk);
                wire.extend(out(&mut p, at(2 + i as u64)));
            }
            (wire, events(&mut p))
        };
        let chunks: Vec<&[u8]> = points.windows(2).filter_map(|w| frame.get(w[0]..w[1])).collect();
        let whole = run(&[&frame]);
        prop_assert_eq!(run(&chunks), whole.clone());
        prop_assert_eq!(whole.0, if bad { vec![DLE, NAK] } else { vec![DLE, DLE] });
    }

    #[test]
    fn any_input_comes_to_rest(ops in prop::collection::vec(op(), 0..40), low in any::<bool>()) {
        let mut p = station(|s| if low { s.priority = Priority::Low });
        let mut now = at(0);
        for op in ops {
            match op {
                Op::Rx(bytes) => p.handle_rx(now, &bytes),
                Op::LineError(e) => p.handle_line_error(now, e),
                Op::Send(data) => { let _ = p.send(now, data); }
                Op::Wait(n) => {
                    now += ms(n.into());
                    if p.poll_timeout().is_some_and(|t| t <= now) { p.handle_timeout(now); }
                }
            }
            out(&mut p, now);
            events(&mut p);
            p.take_received();
        }
        // Silence from now on: every job and reception ends by its own timers.
        for _ in 0..10_000 {
            out(&mut p, now);
            events(&mut p);
            match p.poll_timeout() {
                Some(t) => {
                    prop_assert!(t >= now, "a deadline in the past");
                    now = t;
                    p.handle_timeout(now);
                }
                None => break,
            }
        }
        prop_assert!(p.is_idle());
    }

    #[test]
    fn telegrams_cross_the_line_both_ways(
        from_a in prop::collection::vec((payload(), 0u64..3000), 1..4),
        from_b in prop::collection::vec((payload(), 0u64..3000), 1..4),
        r in any::<bool>(),
    ) {
        let variant = if r { Variant::P3964R } else { Variant::P3964 };
        let mut pair = Pair::new(station(|s| s.variant = variant), station(|s| {
            s.variant = variant;
            s.priority = Priority::Low;
        }));
        // Queue each side's telegrams after gaps of 0, 500, ... ms, so that both sides often
        // start at the same instant.
        let timed = |list: &[(Vec<u8>, u64)], to_b: bool| {
            let mut t = 0;
            list.iter().map(|(d, gap)| { t += gap / 500 * 500; (t, to_b, d.clone()) }).collect::<Vec<_>>()
        };
        let mut plan = timed(&from_a, true);
        plan.extend(timed(&from_b, false));
        plan.sort_by_key(|x| x.0);
        for (t, to_b, data) in plan {
            while pair.now < at(t) && pair.step() {}
            pair.now = pair.now.max(at(t));
            let end = if to_b { &mut pair.a } else { &mut pair.b };
            end.station.send(pair.now, data).expect("queue has room");
        }
        pair.drive();
        let sent_a: Vec<Vec<u8>> = from_a.iter().map(|x| x.0.clone()).collect();
        let sent_b: Vec<Vec<u8>> = from_b.iter().map(|x| x.0.clone()).collect();
        prop_assert_eq!(received(&pair.b), sent_a);
        prop_assert_eq!(received(&pair.a), sent_b);
        prop_assert_eq!(sent_ids(&pair.a).len(), from_a.len());
        prop_assert_eq!(sent_ids(&pair.b).len(), from_b.len());
        prop_assert!(end_raised(&pair.a).is_empty(), "{:?}", end_raised(&pair.a));
        prop_assert!(end_raised(&pair.b).is_empty(), "{:?}", end_raised(&pair.b));
    }
}

#[test]
fn a_line_error_while_sending_starts_a_repetition_and_is_the_first_error() {
    // 7.2 08 0Ch: "If this occurs during send or receive operation, repetitions are initiated";
    // 07 01h: the STATUS of the send names the first error that occurred.
    let mut a = station(|_| {});
    let id = a.send(at(0), b"X".to_vec()).expect("accepted");
    assert_eq!(out(&mut a, at(1)), [STX]);
    // The partner's answer to STX arrives with a parity or framing error (a PARMRK mark).
    a.handle_line_error(at(2), LineError::ParityOrFraming);
    let repeated = out(&mut a, at(3));
    assert_eq!(repeated, [STX], "the connection setup is repeated");
    assert_eq!(
        raised(&events(&mut a)),
        [ids::CHARACTER_ERROR, ids::SEND_REPETITION]
    );
    // The repetition runs into QVZ every time: the job fails with the first error as STATUS.
    let mut now = at(3);
    for _ in 0..32 {
        let Some(deadline) = a.poll_timeout() else {
            break;
        };
        now = now.max(deadline);
        a.handle_timeout(now);
        out(&mut a, now);
    }
    let ev = events(&mut a);
    assert_eq!(
        ev.last(),
        Some(&Event3964::SendFailed {
            id,
            event: ids::SEND_SETUP_ATTEMPTS_EXHAUSTED,
            first: ids::CHARACTER_ERROR
        })
    );
    assert!(a.is_idle());
}
