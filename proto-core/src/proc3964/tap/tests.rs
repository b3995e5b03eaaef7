//! The tap against the manual's 3964R frames (003 6.3.1; the same vectors as `frame::tests`), on a
//! clock the tests step.

use super::*;
use crate::proc3964::frame::encode;
use crate::proc3964::{ETX, NAK};

fn tap() -> Tap3964 {
    Tap3964::new(TapConfig3964::new(Variant::P3964R))
}

fn at(ms: u64) -> Instant {
    Instant::from_millis(ms)
}

fn events(tap: &mut Tap3964) -> Vec<TapEvent3964> {
    std::iter::from_fn(|| tap.poll_event()).collect()
}

/// One complete exchange started by `sender` at `t`: STX, DLE, the telegram, then `ack`.
fn exchange(tap: &mut Tap3964, sender: Side, t: u64, data: &[u8], ack: u8) {
    tap.handle_rx(sender, at(t), &[STX]);
    tap.handle_rx(sender.other(), at(t + 2), &[DLE]);
    tap.handle_rx(sender, at(t + 10), &encode(data, Variant::P3964R));
    tap.handle_rx(sender.other(), at(t + 12), &[ack]);
}

#[test]
fn an_acknowledged_telegram_is_delivered_with_dle_doubling_undone() {
    let mut tap = tap();
    // 10 20 on the wire: 10 10 20 10 03 33.
    exchange(&mut tap, Side::A, 0, &[0x10, 0x20], DLE);
    assert_eq!(
        events(&mut tap),
        [TapEvent3964::Telegram {
            side: Side::A,
            data: vec![0x10, 0x20],
            at: at(12),
        }]
    );
    exchange(&mut tap, Side::B, 100, b"ABC", DLE);
    assert_eq!(
        events(&mut tap),
        [TapEvent3964::Telegram {
            side: Side::B,
            data: b"ABC".to_vec(),
            at: at(112),
        }]
    );
    assert_eq!(tap.counters().telegrams, [1, 1]);
    assert_eq!(tap.poll_timeout(), None, "idle after the acknowledgement");
}

#[test]
fn bytes_split_in_chunks_give_the_same_telegram() {
    let mut tap = tap();
    tap.handle_rx(Side::A, at(0), &[STX]);
    tap.handle_rx(Side::B, at(1), &[DLE]);
    for (i, &b) in [0x41, 0x42, 0x43, 0x10, 0x03, 0x53].iter().enumerate() {
        tap.handle_rx(Side::A, at(2 + i as u64), &[b]);
    }
    tap.handle_rx(Side::B, at(20), &[DLE]);
    assert!(matches!(
        events(&mut tap).as_slice(),
        [TapEvent3964::Telegram { side: Side::A, data, .. }] if data == b"ABC"
    ));
}

#[test]
fn a_bad_bcc_answered_with_nak_and_the_repetition_are_reported() {
    let mut tap = tap();
    tap.handle_rx(Side::A, at(0), &[STX]);
    tap.handle_rx(Side::B, at(2), &[DLE]);
    tap.handle_rx(Side::A, at(10), &[0x41, 0x42, 0x43, DLE, ETX, 0x54]);
    tap.handle_rx(Side::B, at(12), &[NAK]);
    assert_eq!(
        events(&mut tap),
        [
            TapEvent3964::Fault {
                side: Side::A,
                fault: Fault::Frame(FrameError::BadBcc {
                    expected: 0x53,
                    actual: 0x54
                }),
            },
            TapEvent3964::Fault {
                side: Side::A,
                fault: Fault::Nak {
                    after_telegram: true
                },
            },
        ]
    );
    // 6.3.1: after NAK the sender repeats the telegram, from the STX on.
    exchange(&mut tap, Side::A, 50, b"ABC", DLE);
    let seen = events(&mut tap);
    assert_eq!(seen[0], TapEvent3964::Repetition { side: Side::A });
    assert!(matches!(&seen[1], TapEvent3964::Telegram { data, .. } if data == b"ABC"));
    let c = tap.counters();
    assert_eq!(
        (c.bad_bcc, c.naks, c.repetitions, c.telegrams),
        (1, 1, 1, [1, 0])
    );
}

#[test]
fn a_nak_to_the_connection_request_is_a_failed_setup() {
    let mut tap = tap();
    tap.handle_rx(Side::B, at(0), &[STX]);
    tap.handle_rx(Side::A, at(1), &[NAK]);
    assert_eq!(
        events(&mut tap),
        [TapEvent3964::Fault {
            side: Side::B,
            fault: Fault::Nak {
                after_telegram: false
            },
        }]
    );
    assert_eq!(tap.poll_timeout(), None);
}

#[test]
fn a_missing_dle_is_reported_when_the_acknowledgement_delay_time_runs_out() {
    let mut tap = tap();
    let qvz = tap.config().qvz;
    tap.handle_rx(Side::A, at(0), &[STX]);
    assert_eq!(tap.poll_timeout(), Some(at(0) + qvz));
    tap.handle_timeout(at(1999));
    assert!(events(&mut tap).is_empty(), "QVZ has not run out yet");
    tap.handle_timeout(at(2000));
    assert_eq!(
        events(&mut tap),
        [TapEvent3964::Fault {
            side: Side::A,
            fault: Fault::MissingDle {
                after_telegram: false
            },
        }]
    );
    // After the telegram: no DLE, then the sender starts over.
    tap.handle_rx(Side::A, at(3000), &[STX]);
    tap.handle_rx(Side::B, at(3001), &[DLE]);
    tap.handle_rx(Side::A, at(3002), &encode(b"ABC", Variant::P3964R));
    tap.handle_rx(Side::A, at(6000), &[STX]);
    assert_eq!(
        events(&mut tap),
        [
            TapEvent3964::Repetition { side: Side::A },
            TapEvent3964::Fault {
                side: Side::A,
                fault: Fault::MissingDle {
                    after_telegram: true
                },
            },
            TapEvent3964::Repetition { side: Side::A },
        ]
    );
    assert_eq!(tap.counters().missing_dle, 2);
}

#[test]
fn a_telegram_cut_off_by_the_character_delay_time_is_not_delivered() {
    let mut tap = tap();
    let zvz = tap.config().zvz;
    tap.handle_rx(Side::A, at(0), &[STX]);
    tap.handle_rx(Side::B, at(1), &[DLE]);
    tap.handle_rx(Side::A, at(2), &[0x41, 0x42]);
    assert_eq!(tap.poll_timeout(), Some(at(2) + zvz));
    tap.handle_timeout(at(2) + zvz);
    // The receiver answers NAK after its ZVZ.
    tap.handle_rx(Side::B, at(230), &[NAK]);
    assert_eq!(
        events(&mut tap),
        [
            TapEvent3964::Fault {
                side: Side::A,
                fault: Fault::Frame(FrameError::Incomplete),
            },
            TapEvent3964::Fault {
                side: Side::A,
                fault: Fault::Nak {
                    after_telegram: true
                },
            },
        ]
    );
    assert_eq!(tap.counters().bad_telegrams, 1);
}

#[test]
fn an_initialization_conflict_is_resolved_by_the_partner_that_answers_dle() {
    let mut tap = tap();
    // 6.3.3 "Priority": both send STX; B has the lower priority and answers A's STX with DLE.
    tap.handle_rx(Side::A, at(0), &[STX]);
    tap.handle_rx(Side::B, at(1), &[STX]);
    tap.handle_rx(Side::B, at(3), &[DLE]);
    tap.handle_rx(Side::A, at(5), &encode(b"ABC", Variant::P3964R));
    tap.handle_rx(Side::B, at(7), &[DLE]);
    assert_eq!(
        events(&mut tap),
        [
            TapEvent3964::Fault {
                side: Side::B,
                fault: Fault::Conflict,
            },
            TapEvent3964::Telegram {
                side: Side::A,
                data: b"ABC".to_vec(),
                at: at(7),
            },
        ]
    );
    assert_eq!(tap.counters().conflicts, 1);
}

#[test]
fn stray_bytes_are_counted_before_the_next_request() {
    let mut tap = tap();
    tap.handle_rx(Side::B, at(0), &[0xFF, 0x00, STX]);
    assert_eq!(
        events(&mut tap),
        [TapEvent3964::Fault {
            side: Side::B,
            fault: Fault::Stray { len: 2 },
        }]
    );
    assert_eq!(tap.counters().stray_bytes, 2);
    assert!(tap.poll_timeout().is_some(), "the STX opened a setup");
}

#[test]
fn without_block_check_the_telegram_ends_at_dle_etx() {
    let mut tap = Tap3964::new(TapConfig3964::new(Variant::P3964));
    tap.handle_rx(Side::A, at(0), &[STX]);
    tap.handle_rx(Side::B, at(1), &[DLE]);
    tap.handle_rx(Side::A, at(2), &encode(b"ABC", Variant::P3964));
    tap.handle_rx(Side::B, at(3), &[DLE]);
    assert!(matches!(
        events(&mut tap).as_slice(),
        [TapEvent3964::Telegram { data, .. }] if data == b"ABC"
    ));
}

/// 7.2 08 0Ch: a character with a parity error inside a telegram damages the tap's copy. The
/// receiver may still acknowledge its own (its UART saw no error): the tap reports the line error
/// (and the BCC the missing character breaks) and delivers nothing. Outside a telegram the error is reported at once; the next exchange is
/// delivered as usual.
#[test]
fn a_line_error_inside_a_telegram_is_reported_and_the_telegram_not_delivered() {
    let mut tap = tap();
    tap.handle_rx(Side::A, at(0), &[STX]);
    tap.handle_rx(Side::B, at(2), &[DLE]);
    tap.handle_rx(Side::A, at(10), &[0x41]);
    tap.handle_line_error(Side::A, at(11), LineError::ParityOrFraming);
    tap.handle_rx(Side::A, at(12), &[0x43, DLE, ETX, 0x53]);
    tap.handle_rx(Side::B, at(14), &[DLE]);
    // The faulty 'B' is not in the data, so the BCC does not match either.
    assert_eq!(
        events(&mut tap),
        [
            TapEvent3964::Fault {
                side: Side::A,
                fault: Fault::LineError {
                    error: LineError::ParityOrFraming
                },
            },
            TapEvent3964::Fault {
                side: Side::A,
                fault: Fault::Frame(FrameError::BadBcc {
                    expected: 0x41 ^ 0x43 ^ DLE ^ ETX,
                    actual: 0x53
                }),
            },
        ]
    );
    assert_eq!(tap.counters().telegrams, [0, 0]);

    // A BREAK on B's port while idle: reported for B at once.
    tap.handle_line_error(Side::B, at(20), LineError::Break);
    assert_eq!(
        events(&mut tap),
        [TapEvent3964::Fault {
            side: Side::B,
            fault: Fault::LineError {
                error: LineError::Break
            },
        }]
    );

    // A damaged telegram the receiver refuses: the line error and the NAK, then A repeats.
    tap.handle_rx(Side::A, at(30), &[STX]);
    tap.handle_rx(Side::B, at(32), &[DLE]);
    tap.handle_line_error(Side::A, at(33), LineError::Overrun);
    tap.handle_rx(Side::A, at(34), &encode(b"AB", Variant::P3964R));
    tap.handle_rx(Side::B, at(36), &[NAK]);
    exchange(&mut tap, Side::A, 40, b"ABC", DLE);
    assert_eq!(
        events(&mut tap),
        [
            TapEvent3964::Fault {
                side: Side::A,
                fault: Fault::LineError {
                    error: LineError::Overrun
                },
            },
            TapEvent3964::Fault {
                side: Side::A,
                fault: Fault::Nak {
                    after_telegram: true
                },
            },
            TapEvent3964::Repetition { side: Side::A },
            TapEvent3964::Telegram {
                side: Side::A,
                data: b"ABC".to_vec(),
                at: at(52),
            },
        ]
    );
    let counters = tap.counters();
    assert_eq!(
        (counters.line_errors, counters.naks, counters.telegrams),
        (3, 1, [1, 0])
    );
    assert_eq!(
        Fault::LineError {
            error: LineError::Break
        }
        .as_str(),
        "line_error"
    );
}

/// Every fault's name is one of the names the line creates its counters under, and every such
/// name belongs to a fault.
#[test]
fn the_fault_names_are_the_listed_reasons() {
    let faults = [
        Fault::Nak {
            after_telegram: false,
        },
        Fault::MissingDle {
            after_telegram: true,
        },
        Fault::Frame(FrameError::BadBcc {
            expected: 0,
            actual: 1,
        }),
        Fault::Frame(FrameError::Incomplete),
        Fault::Conflict,
        Fault::Stray { len: 1 },
        Fault::LineError {
            error: LineError::Break,
        },
    ];
    let names: Vec<&str> = faults.iter().map(|f| f.as_str()).collect();
    assert_eq!(names, Fault::REASONS);
}
