use super::*;
use crate::modbus::rtu::{encode_frame, expected_request_len};

/// 9600 Bd, 11 bits: t1.5 = 1718 µs, t3.5 = 4010 µs (003 6.4.3: 9600 -> 4 ms).
fn timing() -> CharTiming {
    CharTiming::exact(9600, 11)
}

fn at(micros: u64) -> Instant {
    Instant::from_micros(micros)
}

/// FC 03 request to slave 2: read 4 registers from 0C1Eh, with its CRC.
fn request() -> Vec<u8> {
    let mut frame = Vec::new();
    encode_frame(0x02, &[0x03, 0x0C, 0x1E, 0x00, 0x04], &mut frame);
    frame
}

#[test]
fn a_frame_ends_after_t35_of_silence_and_not_before() {
    let mut f = SilenceFramer::new(timing());
    assert_eq!(f.deadline(), None);
    assert_eq!(f.push(at(1000), &request()), None);
    let end = at(1000) + timing().t3_5();
    assert_eq!(f.deadline(), Some(end));
    assert_eq!(f.poll(at(1000 + 4009)), None);
    assert!(f.is_open());
    assert_eq!(
        f.poll(at(1000 + 4010)),
        Some(Cut {
            end,
            outcome: Outcome::Frame(request())
        })
    );
    assert!(!f.is_open());
    assert_eq!(f.deadline(), None);
    assert_eq!(f.poll(at(1_000_000)), None);
}

#[test]
fn the_deadline_follows_the_last_byte_and_the_multiplier() {
    let t = timing().with_multiplier(3);
    let mut f = SilenceFramer::new(t);
    let frame = request();
    f.push(at(0), &frame[..3]);
    assert_eq!(f.deadline(), Some(at(0) + t.t3_5()));
    // 10 ms later: beyond t3.5 of the plain timing, within 3 x t3.5, so the frame goes on.
    assert_eq!(f.poll(at(10_000)), None);
    f.push(at(10_000), &frame[3..]);
    assert_eq!(t.t3_5(), timing().t3_5() * 3);
    assert_eq!(f.deadline(), Some(at(10_000 + 12_031)));
    assert_eq!(f.poll(at(10_000 + 12_030)), None);
    let cut = f.poll(at(10_000 + 12_031)).unwrap();
    assert_eq!(cut.outcome, Outcome::Frame(frame));
}

#[test]
fn a_byte_after_the_silence_begins_a_new_frame() {
    let mut f = SilenceFramer::new(timing());
    f.push(at(0), &[0x02, 0x03]);
    let cut = f.poll(at(5000)).unwrap();
    assert_eq!(
        cut.outcome,
        Outcome::Discard {
            fault: Fault::TooShort,
            received: 2,
            kept: 2
        }
    );
    f.push(at(5000), &request());
    assert_eq!(f.deadline(), Some(at(5000 + 4010)));
    assert_eq!(
        f.poll(at(9010)).map(|c| c.outcome),
        Some(Outcome::Frame(request()))
    );
}

#[test]
fn a_gap_between_t15_and_t35_voids_the_frame_only_when_checked() {
    let frame = request();
    // One character takes 1146 µs. The fourth byte arrives 3646 µs after the third: a silence of
    // 2.5 ms before it, above t1.5 (1718 µs), below t3.5 (4010 µs); the last four follow
    // without a gap, two at a time.
    let feed = |f: &mut SilenceFramer| {
        f.push(at(0), &frame[..3]);
        assert_eq!(f.poll(at(3646)), None);
        let raised = f.push(at(3646), &frame[3..4]);
        assert_eq!(f.poll(at(5938)), None);
        f.push(at(5938), &frame[4..6]);
        assert_eq!(f.poll(at(8230)), None);
        f.push(at(8230), &frame[6..]);
        (raised, f.poll(at(8230 + 4010)).map(|c| c.outcome))
    };
    let mut checked = SilenceFramer::new(timing()).check_t15(true);
    assert_eq!(
        feed(&mut checked),
        (
            Some(Fault::GapInsideFrame),
            Some(Outcome::Discard {
                fault: Fault::GapInsideFrame,
                received: 8,
                kept: 8
            })
        )
    );
    let mut unchecked = SilenceFramer::new(timing());
    assert_eq!(
        feed(&mut unchecked),
        (None, Some(Outcome::Frame(frame.clone())))
    );
    // A silence within t1.5 (1 ms) leaves the frame good even when checked.
    let mut f = SilenceFramer::new(timing()).check_t15(true);
    f.push(at(0), &frame[..3]);
    assert_eq!(f.push(at(2146), &frame[3..]), None);
    assert_eq!(
        f.poll(at(2146 + 4010)).map(|c| c.outcome),
        Some(Outcome::Frame(frame))
    );
}

#[test]
fn an_overlong_frame_is_kept_up_to_the_largest_and_counted_in_full() {
    let mut f = SilenceFramer::new(timing());
    assert_eq!(f.push(at(0), &[0x11; 200]), None);
    assert_eq!(f.push(at(100), &[0x11; 100]), Some(Fault::TooLong));
    // Reported once: the frame already has its fault.
    assert_eq!(f.push(at(200), &[0x11; 10]), None);
    assert_eq!(
        f.poll(at(200 + 4010)).map(|c| c.outcome),
        Some(Outcome::Discard {
            fault: Fault::TooLong,
            received: 310,
            kept: MAX_FRAME_LEN
        })
    );
}

#[test]
fn a_line_error_voids_the_frame_or_begins_an_empty_one() {
    let mut f = SilenceFramer::new(timing());
    f.fail(at(50), Fault::LineError);
    assert_eq!(f.deadline(), Some(at(50 + 4010)));
    assert_eq!(
        f.poll(at(50 + 4010)).map(|c| c.outcome),
        Some(Outcome::Discard {
            fault: Fault::LineError,
            received: 0,
            kept: 0
        })
    );
    // Inside a frame: the bytes before and after it go with it, a later fault replaces an
    // earlier one.
    f.push(at(10_000), &[0x11; 300]);
    f.fail(at(10_100), Fault::LineError);
    f.push(at(10_200), &request());
    let cut = f.poll(at(10_200 + 4010)).unwrap();
    assert_eq!(
        cut.outcome,
        Outcome::Discard {
            fault: Fault::LineError,
            received: 308,
            kept: MAX_FRAME_LEN
        }
    );
}

#[test]
fn take_fault_hands_over_the_bytes_so_far_and_the_frame_goes_on() {
    let mut f = SilenceFramer::new(timing());
    assert_eq!(f.take_fault(), None);
    f.push(at(0), &[0x11; 265]);
    assert_eq!(f.take_fault(), Some((Fault::TooLong, 265)));
    assert_eq!(f.take_fault(), None);
    f.fail(at(10), Fault::LineError);
    f.push(at(20), &[1, 2]);
    assert_eq!(
        f.poll(at(20 + 4010)).map(|c| c.outcome),
        Some(Outcome::Discard {
            fault: Fault::LineError,
            received: 2,
            kept: 2
        })
    );
}

#[test]
fn the_length_check_finds_trailing_bytes_before_the_crc() {
    let mut frame = request();
    frame.push(0xFF);
    let mut f = SilenceFramer::new(timing()).check_length(expected_request_len);
    f.push(at(0), &frame);
    assert_eq!(
        f.poll(at(4010)).map(|c| c.outcome),
        Some(Outcome::Discard {
            fault: Fault::TrailingData,
            received: 9,
            kept: 9
        })
    );
    // Without the check the same bytes fail their CRC.
    let mut f = SilenceFramer::new(timing());
    f.push(at(0), &frame);
    assert_eq!(
        f.poll(at(4010)).map(|c| c.outcome),
        Some(Outcome::Discard {
            fault: Fault::BadCrc,
            received: 9,
            kept: 9
        })
    );
}

#[test]
fn frame_errors_map_to_one_fault_each() {
    let bad_crc = FrameError::BadCrc {
        expected: 1,
        actual: 2,
    };
    assert_eq!(Fault::from(&bad_crc), Fault::BadCrc);
    let too_long = FrameError::TooLong { len: 265, max: 264 };
    assert_eq!(Fault::from(&too_long), Fault::TooLong);
    let too_short = FrameError::TooShort { len: 3, min: 4 };
    assert_eq!(Fault::from(&too_short), Fault::TooShort);
}
