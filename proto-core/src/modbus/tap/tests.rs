//! The tap against frames of the demo's drives (002: Altivar W3102..W3105 = 40 600 500 0) and
//! the timing of 003 6.4.3, on a clock the tests step.

use super::*;
use crate::modbus::rtu::encode_frame;

/// 9600 Bd, 8E1: 11 bits a character, t1.5 = 1.72 ms, t3.5 = 4.01 ms (003 6.4.3: "9600 -> 4 ms").
fn tap() -> Tap {
    Tap::new(TapConfig::new(9600, 11))
}

fn at(ms: u64) -> Instant {
    Instant::from_millis(ms)
}

fn frame(address: u8, pdu: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    encode_frame(address, pdu, &mut out);
    out
}

/// Every event up to `now` (the tap's deadlines handled as the runtime would).
fn events_until(tap: &mut Tap, now: Instant) -> Vec<TapEvent> {
    while let Some(t) = tap.poll_timeout().filter(|&t| t <= now) {
        tap.handle_timeout(t);
    }
    tap.handle_timeout(now);
    std::iter::from_fn(|| tap.poll_event()).collect()
}

fn exchanges(events: &[TapEvent]) -> Vec<Exchange> {
    events
        .iter()
        .filter_map(|e| match e {
            TapEvent::Exchange(x) => Some(x.clone()),
            _ => None,
        })
        .collect()
}

/// FC 03 request of the Altivar at address 2: W3102, 4 registers.
fn read_atv() -> Vec<u8> {
    frame(2, &[0x03, 0x0C, 0x1E, 0x00, 0x04])
}

/// Its answer: SFr 40, tFr 600, HSP 500, LSP 0.
fn atv_answer() -> Vec<u8> {
    frame(
        2,
        &[0x03, 0x08, 0x00, 0x28, 0x02, 0x58, 0x01, 0xF4, 0x00, 0x00],
    )
}

#[test]
fn a_read_answer_yields_the_values_at_the_requests_start() {
    let mut tap = tap();
    tap.handle_rx(at(0), &read_atv());
    // The request ends by silence, t3.5 after its last byte: then it waits for its answer.
    assert_eq!(tap.poll_timeout(), Some(at(0) + tap.config.timing.t3_5()));
    tap.handle_rx(at(20), &atv_answer());
    let events = events_until(&mut tap, at(40));
    assert_eq!(
        exchanges(&events),
        vec![Exchange {
            address: 2,
            request: Request::ReadHoldingRegisters {
                address: 3102,
                quantity: 4
            },
            outcome: Outcome::Answered(vec![Block {
                table: Table::HoldingRegisters,
                start: 3102,
                values: Values::Words(vec![40, 600, 500, 0]),
            }]),
        }]
    );
    assert_eq!(
        events
            .iter()
            .filter(|e| matches!(e, TapEvent::Frame { .. }))
            .count(),
        2
    );
    let c = tap.counters();
    assert_eq!(
        (c.frames, c.pairs, c.missing_answers, c.bad_crc),
        (2, 1, 0, 0)
    );
    assert_eq!(tap.poll_timeout(), None, "nothing waits");
}

#[test]
fn coil_and_input_reads_keep_as_many_bits_as_the_request_asked_for() {
    let mut tap = tap();
    // FC 01 of 10 coils from 5: two data bytes, the last 6 bits padding.
    tap.handle_rx(at(0), &frame(9, &[0x01, 0x00, 0x05, 0x00, 0x0A]));
    tap.handle_rx(at(20), &frame(9, &[0x01, 0x02, 0b1000_0001, 0b11]));
    // FC 04 of input registers 1004..1006 of the KS vario at 17: 1066 140 4158.
    tap.handle_rx(at(40), &frame(17, &[0x04, 0x03, 0xEC, 0x00, 0x03]));
    tap.handle_rx(
        at(60),
        &frame(17, &[0x04, 0x06, 0x04, 0x2A, 0x00, 0x8C, 0x10, 0x3E]),
    );
    let got = exchanges(&events_until(&mut tap, at(100)));
    let mut bits = vec![false; 10];
    bits[0] = true;
    bits[7] = true;
    bits[8] = true;
    bits[9] = true;
    assert_eq!(
        got.iter().map(|x| x.outcome.clone()).collect::<Vec<_>>(),
        vec![
            Outcome::Answered(vec![Block {
                table: Table::Coils,
                start: 5,
                values: Values::Bits(bits),
            }]),
            Outcome::Answered(vec![Block {
                table: Table::InputRegisters,
                start: 1004,
                values: Values::Words(vec![1066, 140, 4158]),
            }]),
        ]
    );
}

#[test]
fn confirmed_writes_yield_what_the_device_now_holds() {
    let mut tap = tap();
    let mut t = 0;
    let mut pair = |tap: &mut Tap, address: u8, request: &[u8], answer: &[u8]| {
        tap.handle_rx(at(t), &frame(address, request));
        tap.handle_rx(at(t + 20), &frame(address, answer));
        t += 40;
    };
    // FC 06: ACC (W9001) = 13, the answer is the echo (the same bytes as the request).
    pair(
        &mut tap,
        2,
        &[0x06, 0x23, 0x29, 0x00, 0x0D],
        &[0x06, 0x23, 0x29, 0x00, 0x0D],
    );
    // FC 16: W10..W11 = 1, 2.
    pair(
        &mut tap,
        2,
        &[0x10, 0x00, 0x0A, 0x00, 0x02, 0x04, 0x00, 0x01, 0x00, 0x02],
        &[0x10, 0x00, 0x0A, 0x00, 0x02],
    );
    // FC 05: coil 3 on; FC 15: coils 0..2 = 1 0 1.
    pair(
        &mut tap,
        2,
        &[0x05, 0x00, 0x03, 0xFF, 0x00],
        &[0x05, 0x00, 0x03, 0xFF, 0x00],
    );
    pair(
        &mut tap,
        2,
        &[0x0F, 0x00, 0x00, 0x00, 0x03, 0x01, 0b101],
        &[0x0F, 0x00, 0x00, 0x00, 0x03],
    );
    let got: Vec<Outcome> = exchanges(&events_until(&mut tap, at(1000)))
        .into_iter()
        .map(|x| x.outcome)
        .collect();
    let words = |start, v: Vec<u16>| {
        Outcome::Answered(vec![Block {
            table: Table::HoldingRegisters,
            start,
            values: Values::Words(v),
        }])
    };
    let bits = |start, v: Vec<bool>| {
        Outcome::Answered(vec![Block {
            table: Table::Coils,
            start,
            values: Values::Bits(v),
        }])
    };
    assert_eq!(
        got,
        vec![
            words(9001, vec![13]),
            words(10, vec![1, 2]),
            bits(3, vec![true]),
            bits(0, vec![true, false, true]),
        ]
    );
    assert_eq!(tap.counters().pairs, 4);
}

#[test]
fn an_exception_is_paired_and_carries_no_values() {
    let mut tap = tap();
    tap.handle_rx(at(0), &read_atv());
    tap.handle_rx(at(20), &frame(2, &[0x83, 0x02]));
    let got = exchanges(&events_until(&mut tap, at(40)));
    assert_eq!(
        got.first().map(|x| &x.outcome),
        Some(&Outcome::Exception(ExceptionCode::IllegalDataAddress))
    );
    assert_eq!(tap.counters().pairs, 1);
}

#[test]
fn a_bad_crc_is_counted_and_its_request_reported_missing() {
    let mut tap = tap();
    tap.handle_rx(at(0), &read_atv());
    let mut broken = atv_answer();
    if let Some(b) = broken.get_mut(4) {
        *b ^= 0x01;
    }
    tap.handle_rx(at(20), &broken);
    let events = events_until(&mut tap, at(40));
    assert!(events.contains(&TapEvent::Discarded {
        reason: DiscardReason::BadCrc,
        len: 13
    }));
    assert!(exchanges(&events).is_empty(), "nothing yet");
    // The answer timeout after the request's end: missing, no values.
    let end = at(0) + tap.config.timing.t3_5();
    assert_eq!(tap.poll_timeout(), Some(end + DEFAULT_ANSWER_TIMEOUT));
    let got = exchanges(&events_until(&mut tap, end + DEFAULT_ANSWER_TIMEOUT));
    assert_eq!(got.len(), 1);
    assert_eq!(got.first().map(|x| &x.outcome), Some(&Outcome::Missing));
    let c = tap.counters();
    assert_eq!((c.bad_crc, c.missing_answers, c.pairs), (1, 1, 0));
}

#[test]
fn a_request_followed_by_another_request_missed_its_answer() {
    let mut tap = tap();
    tap.handle_rx(at(0), &read_atv());
    // The master goes on to slave 3 (the same read), slave 3 answers.
    tap.handle_rx(at(20), &frame(3, &[0x03, 0x0C, 0x1E, 0x00, 0x04]));
    tap.handle_rx(
        at(40),
        &frame(
            3,
            &[0x03, 0x08, 0x00, 0x28, 0x02, 0x58, 0x01, 0xF4, 0x00, 0x00],
        ),
    );
    let got = exchanges(&events_until(&mut tap, at(60)));
    assert_eq!(
        got.iter()
            .map(|x| (x.address, matches!(x.outcome, Outcome::Missing)))
            .collect::<Vec<_>>(),
        vec![(2, true), (3, false)]
    );
}

#[test]
fn an_answer_of_another_address_is_not_taken_for_the_awaited_one() {
    let mut tap = tap();
    tap.handle_rx(at(0), &read_atv());
    // Slave 3 answers a request the tap never saw: neither the answer awaited nor a request.
    tap.handle_rx(
        at(20),
        &frame(
            3,
            &[0x03, 0x08, 0x00, 0x28, 0x02, 0x58, 0x01, 0xF4, 0x00, 0x00],
        ),
    );
    let events = events_until(&mut tap, at(40));
    assert!(events.contains(&TapEvent::Discarded {
        reason: DiscardReason::Unpaired,
        len: 13
    }));
    // The request to 2 still waits: its own answer is taken.
    tap.handle_rx(at(60), &atv_answer());
    let got = exchanges(&events_until(&mut tap, at(80)));
    assert!(matches!(
        got.first().map(|x| &x.outcome),
        Some(Outcome::Answered(_))
    ));
}

#[test]
fn a_gap_above_t15_inside_a_frame_makes_it_bad_and_t35_ends_it() {
    let mut tap = tap();
    let answer = atv_answer();
    let (head, tail) = answer.split_at(12);
    tap.handle_rx(at(0), &read_atv());
    // 003 6.4.3: t1.5 = 1.72 ms, t3.5 = 4.01 ms at 9600 Bd 8E1. A gap of 2.5 ms before the last
    // byte (1.15 ms on the wire, so it arrives 3.65 ms after the others) voids the answer.
    let char_time = tap.config.timing.char_time;
    let tail_at = at(20) + Duration::from_micros(2500) + char_time;
    tap.handle_rx(at(20), head);
    tap.handle_rx(tail_at, tail);
    let events = events_until(&mut tap, tail_at + Duration::from_millis(5));
    assert!(events.contains(&TapEvent::Discarded {
        reason: DiscardReason::GapInsideFrame,
        len: 13
    }));
    assert_eq!(tap.counters().frames, 2, "one frame, not two");

    // The same bytes with the gap under t1.5 make one good answer (to a fresh request).
    let mut tap2 = self::tap();
    tap2.handle_rx(at(0), &read_atv());
    tap2.handle_rx(at(20), head);
    tap2.handle_rx(at(20) + Duration::from_millis(1) + char_time, tail);
    let got = exchanges(&events_until(&mut tap2, at(60)));
    assert!(matches!(
        got.first().map(|x| &x.outcome),
        Some(Outcome::Answered(_))
    ));

    // Without the check (a USB adapter's bursts) the gap is accepted.
    let mut lax = Tap::new(TapConfig {
        check_inter_character: false,
        ..TapConfig::new(9600, 11)
    });
    lax.handle_rx(at(0), &read_atv());
    lax.handle_rx(at(20), head);
    lax.handle_rx(tail_at, tail);
    assert_eq!(lax.counters().discarded, 0);
    assert_eq!(
        exchanges(&events_until(&mut lax, at(60))).len(),
        1,
        "paired"
    );
}

#[test]
fn a_silence_of_t35_splits_frames() {
    let mut tap = tap();
    let request = read_atv();
    let (head, tail) = request.split_at(3);
    tap.handle_rx(at(0), head);
    // 5 ms > t3.5 (4.01 ms): the head is a frame of its own (too short), the tail another.
    tap.handle_rx(at(5), tail);
    let events = events_until(&mut tap, at(20));
    assert_eq!(tap.counters().frames, 2);
    assert!(events.contains(&TapEvent::Discarded {
        reason: DiscardReason::TooShort,
        len: 3
    }));
}

#[test]
fn a_line_error_inside_a_frame_voids_it() {
    let mut tap = tap();
    tap.handle_rx(at(0), &read_atv());
    let answer = atv_answer();
    tap.handle_rx(at(20), answer.get(..4).unwrap_or_default());
    tap.handle_line_error(at(20), LineError::ParityOrFraming);
    tap.handle_rx(at(21), answer.get(4..).unwrap_or_default());
    let events = events_until(&mut tap, at(40));
    assert!(events.contains(&TapEvent::Discarded {
        reason: DiscardReason::LineError,
        len: 13
    }));
    assert!(exchanges(&events).is_empty());
}

#[test]
fn a_broadcast_expects_no_answer() {
    let mut tap = tap();
    tap.handle_rx(at(0), &frame(0, &[0x06, 0x00, 0x01, 0x00, 0x07]));
    let got = exchanges(&events_until(&mut tap, at(10)));
    assert_eq!(got.first().map(|x| &x.outcome), Some(&Outcome::Broadcast));
    assert_eq!(tap.poll_timeout(), None);
    assert_eq!(tap.counters().missing_answers, 0);
}

#[test]
fn an_answer_that_does_not_fit_its_request_is_invalid() {
    let mut tap = tap();
    tap.handle_rx(at(0), &read_atv());
    // Two registers where four were asked for (003 7.2 0E 55h).
    tap.handle_rx(at(20), &frame(2, &[0x03, 0x04, 0x00, 0x28, 0x02, 0x58]));
    let got = exchanges(&events_until(&mut tap, at(40)));
    assert!(matches!(
        got.first().map(|x| &x.outcome),
        Some(Outcome::Invalid(_))
    ));
    assert_eq!(tap.counters().pairs, 0);
}

#[test]
fn an_overlong_stream_is_one_discarded_frame() {
    let mut tap = tap();
    tap.handle_rx(at(0), &[0x55; 300]);
    let events = events_until(&mut tap, at(10));
    assert!(events.contains(&TapEvent::Discarded {
        reason: DiscardReason::TooLong,
        len: rtu::MAX_FRAME_LEN
    }));
}
