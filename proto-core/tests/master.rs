//! The Modbus master engine on a simulated clock: every timing rule is checked by feeding instants,
//! never by sleeping. A small slave built from proto-core's own codec answers where a real answer
//! is needed.
//!
//! Modules: `support` (the simulated line and the test slave), `submit` (the job checks), `ascii`
//! (the ASCII master), `attempts` (per-request attempts); the RTU master is tested here.

#[path = "master/ascii.rs"]
mod ascii;
#[path = "master/attempts.rs"]
mod attempts;
#[path = "master/submit.rs"]
mod submit;
#[path = "master/support.rs"]
mod support;

use core::time::Duration;

use proptest::prelude::*;
use proto_core::event::{ids, EventId};
use proto_core::modbus::master::{LineError, MasterEvent, OperatingMode, Outcome, SubmitError};
use proto_core::modbus::pdu::{ExceptionCode, Request, Response};
use proto_core::time::Instant;

use self::support::*;

// --- RTU transactions ---

#[test]
fn altivar_read_through_the_test_slave() {
    let mut line = Line::new(rtu_config());
    let mut slave = TestSlave::altivar();
    let id = line.submit(2, atv_read());
    let request = line.transmit();
    assert_eq!(request, ATV_READ_REQUEST);
    let answer = slave.answer_rtu(&request).expect("the slave answers");
    assert_eq!(
        answer, ATV_READ_RESPONSE,
        "the test slave reproduces the manual's answer"
    );
    line.advance(Duration::from_millis(3));
    line.rx(&answer);
    let last_byte = line.now;
    // 003 6.4.3: the frame ends by 3.5 character times of silence, not by its announced length.
    assert!(line.events.is_empty(), "complete before the silence");
    line.fire();
    assert_eq!(line.now, last_byte + timing().t35);
    assert_eq!(
        line.events,
        [MasterEvent::Completed {
            id,
            slave: 2,
            request: atv_read(),
            outcome: Outcome::Response(Response::ReadHoldingRegisters(vec![40, 600, 500, 0])),
        }]
    );
    // The silence that ended the reply is also the gap before the next request.
    assert!(line.master.is_idle());
}

#[test]
fn altivar_write_echo_and_exception() {
    let mut line = Line::new(rtu_config());
    let mut slave = TestSlave::altivar();
    line.submit(
        2,
        Request::WriteSingleRegister {
            address: 9001,
            value: 13,
        },
    );
    let request = line.transmit();
    assert_eq!(request, ATV_WRITE_ACC);
    line.rx(&slave.answer_rtu(&request).expect("echo"));
    line.settle();
    line.submit(
        4,
        Request::WriteMultipleRegisters {
            address: 3201,
            values: vec![1],
        },
    );
    assert_eq!(line.transmit(), ATV_WRITE_ETA_REQUEST);
    line.rx(&ATV_WRITE_ETA_EXCEPTION);
    line.fire();
    assert_eq!(line.raised(), [ids::MODBUS_EXCEPTION_DEVICE_FAILURE]);
    assert_eq!(
        line.outcomes(),
        [
            Outcome::Response(Response::WriteSingleRegister {
                address: 9001,
                value: 13
            }),
            Outcome::Exception(ExceptionCode::ServerDeviceFailure)
        ]
    );
}

#[test]
fn no_reply_raises_0830_exactly_at_the_reply_monitoring_time() {
    let mut line = Line::new(rtu_config());
    line.submit(2, atv_read());
    line.transmit();
    let tx_done = line.now;
    let deadline = tx_done + Duration::from_millis(2000);
    assert_eq!(line.master.poll_timeout(), Some(deadline));
    line.master
        .handle_timeout(Instant::from_micros(deadline.as_micros() - 1));
    line.drain();
    assert!(
        line.events.is_empty(),
        "nothing before the reply monitoring time: {:?}",
        line.events
    );
    line.fire();
    assert_eq!(line.now, deadline);
    assert_eq!(line.raised(), [ids::MODBUS_NO_REPLY]);
    assert_eq!(line.outcomes(), [Outcome::Failed(ids::MODBUS_NO_REPLY)]);
}

#[test]
fn retries_repeat_the_same_frame_and_raise_each_failure() {
    let mut config = rtu_config();
    config.retries = 2;
    config.reply_timeout = Duration::from_millis(100);
    let mut line = Line::new(config);
    let mut slave = TestSlave::altivar();
    line.submit(2, atv_read());
    for _ in 0..2 {
        assert_eq!(line.transmit(), ATV_READ_REQUEST);
        line.fire();
        assert!(
            line.outcomes().is_empty(),
            "a repeated attempt does not complete the transaction"
        );
    }
    // Third attempt: the slave answers.
    let request = line.transmit();
    line.rx(&slave.answer_rtu(&request).expect("answer"));
    line.fire();
    assert_eq!(line.raised(), [ids::MODBUS_NO_REPLY, ids::MODBUS_NO_REPLY]);
    assert_eq!(
        line.outcomes(),
        [Outcome::Response(Response::ReadHoldingRegisters(vec![
            40, 600, 500, 0
        ]))]
    );

    // All attempts fail: three events, one completion.
    let mut line = Line::new(config);
    line.submit(2, atv_read());
    for _ in 0..3 {
        line.transmit();
        line.fire();
    }
    assert_eq!(line.raised(), [ids::MODBUS_NO_REPLY; 3]);
    assert_eq!(line.outcomes(), [Outcome::Failed(ids::MODBUS_NO_REPLY)]);
    assert!(line.master.poll_transmit().is_none());
}

#[test]
fn wrong_slave_raises_0831_at_the_first_character_and_fails_after_the_frame() {
    let mut line = Line::new(rtu_config());
    line.submit(2, atv_read());
    line.transmit();
    let foreign = rtu_frame(3, &[0x03, 0x02, 0x00, 0x01]);
    line.rx(&foreign[..1]);
    assert_eq!(line.raised(), [ids::MODBUS_WRONG_SLAVE_CHAR]);
    assert!(
        line.outcomes().is_empty(),
        "the rest of the foreign frame is waited for"
    );
    line.advance(Duration::from_millis(1));
    line.rx(&foreign[1..]);
    let last = line.now;
    line.fire();
    assert_eq!(line.now, last + timing().t35);
    assert_eq!(
        line.outcomes(),
        [Outcome::Failed(ids::MODBUS_WRONG_SLAVE_CHAR)]
    );
}

#[test]
fn wrong_slave_with_interference_suppression_is_0e50() {
    let mut config = rtu_config();
    config.mode = OperatingMode::InterferenceSuppression;
    let mut line = Line::new(config);
    line.submit(2, atv_read());
    line.transmit();
    let mut foreign = ATV_READ_RESPONSE.to_vec();
    foreign[0] = 3;
    let foreign = rtu_frame(3, &foreign[1..foreign.len() - 2]);
    line.rx(&foreign);
    line.fire();
    assert_eq!(line.raised(), [ids::MODBUS_WRONG_SLAVE]);
    assert_eq!(line.outcomes(), [Outcome::Failed(ids::MODBUS_WRONG_SLAVE)]);
}

#[test]
fn bad_crc_is_0e57_after_the_silence() {
    let mut line = Line::new(rtu_config());
    line.submit(2, atv_read());
    line.transmit();
    let mut bad = ATV_READ_RESPONSE;
    bad[12] ^= 0x01;
    line.rx(&bad);
    assert!(
        line.events.is_empty(),
        "a wrong CRC at the announced length waits for the silence"
    );
    line.fire();
    assert_eq!(line.raised(), [ids::MODBUS_CHECKSUM_ERROR]);
    assert_eq!(
        line.outcomes(),
        [Outcome::Failed(ids::MODBUS_CHECKSUM_ERROR)]
    );
}

#[test]
fn reply_checks_raise_the_cps_events() {
    let cases: [(&[u8], EventId); 5] = [
        (
            &[0x04, 0x08, 0, 1, 0, 2, 0, 3, 0, 4],
            ids::MODBUS_WRONG_FUNCTION,
        ),
        (
            &[0x03, 0x06, 0, 1, 0, 2, 0, 3],
            ids::MODBUS_BYTE_COUNT_TOO_SMALL,
        ),
        (
            &[0x03, 0x0A, 0, 1, 0, 2, 0, 3, 0, 4, 0, 5],
            ids::MODBUS_BYTE_COUNT_WRONG,
        ),
        (&[0x03, 0x08, 0, 1, 0, 2, 0, 3], ids::MODBUS_BYTE_UNDERFLOW),
        (&[0x03], ids::MODBUS_BYTE_UNDERFLOW),
    ];
    for (pdu, event) in cases {
        let mut line = Line::new(rtu_config());
        line.submit(2, atv_read());
        line.transmit();
        line.rx(&rtu_frame(2, pdu));
        line.settle();
        assert_eq!(line.raised(), [event], "reply {pdu:02X?}");
        assert_eq!(line.outcomes(), [Outcome::Failed(event)]);
    }
    // A wrong echo of FC 06.
    let mut line = Line::new(rtu_config());
    line.submit(
        2,
        Request::WriteSingleRegister {
            address: 9001,
            value: 13,
        },
    );
    line.transmit();
    line.rx(&rtu_frame(2, &[0x06, 0x23, 0x29, 0x00, 0x0E]));
    line.fire();
    assert_eq!(line.raised(), [ids::MODBUS_ECHO_WRONG]);
}

#[test]
fn exception_codes_1_to_7_raise_0e61_to_0e67() {
    for code in 1u8..=7 {
        let mut line = Line::new(rtu_config());
        line.submit(2, atv_read());
        line.transmit();
        line.rx(&rtu_frame(2, &[0x83, code]));
        line.fire();
        assert_eq!(line.raised(), [EventId::new(0x0E, 0x60 + code)]);
        assert_eq!(
            line.outcomes(),
            [Outcome::Exception(ExceptionCode::from(code))]
        );
    }
    // 0B (gateway target failed to respond) has no event in 7.2: only the outcome reports it.
    let mut line = Line::new(rtu_config());
    line.submit(2, atv_read());
    line.transmit();
    line.rx(&rtu_frame(2, &[0x83, 0x0B]));
    line.fire();
    assert!(line.raised().is_empty());
    assert_eq!(
        line.outcomes(),
        [Outcome::Exception(
            ExceptionCode::GatewayTargetFailedToRespond
        )]
    );
}

#[test]
fn broadcast_is_not_awaited_and_the_turnaround_delay_holds_the_next_request() {
    let mut config = rtu_config();
    config.turnaround_delay = Duration::from_millis(100);
    let mut line = Line::new(config);
    let id = line.submit(
        0,
        Request::WriteSingleRegister {
            address: 9001,
            value: 13,
        },
    );
    line.transmit();
    let tx_done = line.now;
    assert_eq!(
        line.events,
        [MasterEvent::Completed {
            id,
            slave: 0,
            request: Request::WriteSingleRegister {
                address: 9001,
                value: 13
            },
            outcome: Outcome::Broadcast
        }]
    );
    // The next request is queued, but not sent before the turnaround delay.
    line.submit(2, atv_read());
    assert!(line.master.poll_transmit().is_none());
    assert_eq!(
        line.master.poll_timeout(),
        Some(tx_done + Duration::from_millis(100))
    );
    line.master
        .handle_timeout(tx_done + Duration::from_micros(99_999));
    assert!(line.master.poll_transmit().is_none());
    line.fire();
    assert_eq!(line.transmit(), ATV_READ_REQUEST);
    // No 08 30h was raised for the broadcast.
    assert!(line.raised().is_empty());
}

#[test]
fn a_request_waits_for_t35_of_silence() {
    let mut line = Line::new(rtu_config());
    let mut slave = TestSlave::altivar();
    line.submit(2, atv_read());
    let request = line.transmit();
    line.rx(&slave.answer_rtu(&request).expect("answer"));
    let last_byte = line.now;
    // The reply ends, and the gap after it runs out, t3.5 after its last byte.
    assert_eq!(line.master.poll_timeout(), Some(last_byte + timing().t35));
    line.fire();
    assert_eq!(line.outcomes().len(), 1);
    assert!(line.master.is_idle());
    // Noise on the line starts a new gap (and is reported once in normal operation); a request
    // submitted in it is queued until t3.5 after the noise.
    line.advance(Duration::from_millis(1));
    line.rx(&[0x00]);
    let noise = line.now;
    assert_eq!(line.raised(), [ids::MODBUS_BYTE_OVERFLOW]);
    line.submit(2, atv_read());
    assert!(line.master.poll_transmit().is_none());
    line.master
        .handle_timeout(Instant::from_micros((noise + timing().t35).as_micros() - 1));
    assert!(line.master.poll_transmit().is_none());
    line.fire();
    assert_eq!(line.now, noise + timing().t35);
    assert_eq!(
        line.master.poll_transmit().as_deref(),
        Some(&ATV_READ_REQUEST[..])
    );
}

#[test]
fn second_submit_while_busy_is_refused() {
    let mut line = Line::new(rtu_config());
    line.submit(2, atv_read());
    assert_eq!(
        line.master.submit(line.now, 2, atv_read()),
        Err(SubmitError::Busy)
    );
    line.transmit();
    assert_eq!(
        line.master.submit(line.now, 2, atv_read()),
        Err(SubmitError::Busy)
    );
    assert!(!line.master.is_idle());
}

#[test]
fn idle_bytes_and_line_errors_depend_on_the_operating_mode() {
    let mut line = Line::new(rtu_config());
    line.rx(&[0x12, 0x34]);
    line.advance(Duration::from_micros(500));
    line.rx(&[0x56]);
    line.master.handle_line_error(line.now, LineError::Parity);
    line.master.handle_line_error(line.now, LineError::Break);
    line.drain();
    assert_eq!(
        line.raised(),
        [
            ids::MODBUS_BYTE_OVERFLOW,
            ids::CHARACTER_ERROR,
            ids::LINE_BREAK
        ]
    );
    line.settle();
    line.rx(&[0x12]);
    assert_eq!(
        line.raised().len(),
        4,
        "a new burst after the silence is reported again"
    );

    let mut config = rtu_config();
    config.mode = OperatingMode::InterferenceSuppression;
    let mut line = Line::new(config);
    line.rx(&[0x12, 0x34]);
    line.master.handle_line_error(line.now, LineError::Framing);
    line.drain();
    assert!(
        line.events.is_empty(),
        "ignored while idle: {:?}",
        line.events
    );
    line.settle();
    // Outside idle, a line error is handled: the attempt fails when the line falls silent.
    line.submit(2, atv_read());
    line.transmit();
    line.master.handle_line_error(line.now, LineError::Overrun);
    line.drain();
    line.settle();
    assert_eq!(line.raised(), [ids::CHARACTER_ERROR]);
    assert_eq!(line.outcomes(), [Outcome::Failed(ids::CHARACTER_ERROR)]);
}

#[test]
fn an_endless_reply_overflows_with_0832_and_is_given_up_after_the_reply_monitoring_time() {
    let mut config = rtu_config();
    config.reply_timeout = Duration::from_millis(50);
    let mut line = Line::new(config);
    line.submit(2, atv_read());
    line.transmit();
    // Slave 2 claims 255 data bytes, then keeps talking, one byte a millisecond (below t3.5).
    line.rx(&[0x02, 0x03, 0xFF]);
    let mut overflow_at = None;
    for _ in 0..400 {
        line.advance(Duration::from_millis(1));
        line.rx(&[0x55]);
        if overflow_at.is_none() && !line.raised().is_empty() {
            overflow_at = Some(line.now);
        }
        if !line.outcomes().is_empty() {
            break;
        }
    }
    // The byte after the transaction gave up is an unexpected one (0E 53h).
    assert_eq!(
        line.raised(),
        [ids::MODBUS_RECEIVE_OVERFLOW, ids::MODBUS_BYTE_OVERFLOW]
    );
    assert_eq!(
        line.outcomes(),
        [Outcome::Failed(ids::MODBUS_RECEIVE_OVERFLOW)]
    );
    let overflow_at = overflow_at.expect("overflow raised");
    // Given up one reply monitoring time after the overflow, although the line never fell silent.
    assert!(
        line.now <= overflow_at + Duration::from_millis(51),
        "{:?} vs {overflow_at:?}",
        line.now
    );
}

#[test]
fn a_reply_before_the_estimated_end_of_transmission_is_taken() {
    // A pty delivers the answer before the runtime's estimate of the last byte's departure.
    let mut line = Line::new(rtu_config());
    let mut slave = TestSlave::altivar();
    line.submit(2, atv_read());
    let request = line.master.poll_transmit().expect("ADU");
    let answer = slave.answer_rtu(&request).expect("answer");
    line.master
        .handle_tx_done(line.now + Duration::from_millis(5));
    line.rx(&answer);
    line.fire();
    assert_eq!(
        line.outcomes(),
        [Outcome::Response(Response::ReadHoldingRegisters(vec![
            40, 600, 500, 0
        ]))]
    );
    // Even before handle_tx_done: the reply is the reply.
    let mut line = Line::new(rtu_config());
    line.submit(2, atv_read());
    line.master.poll_transmit().expect("ADU");
    line.rx(&answer);
    line.master.handle_tx_done(line.now);
    line.drain();
    line.fire();
    assert_eq!(line.outcomes().len(), 1);
}

#[test]
fn a_reply_of_the_cps_largest_size_is_received() {
    // FC 03 with 127 registers: 259 bytes, more than the specification's 256 (003 6.4.4.3).
    let mut line = Line::new(rtu_config());
    line.submit(
        2,
        Request::ReadHoldingRegisters {
            address: 0,
            quantity: 127,
        },
    );
    line.transmit();
    let values: Vec<u16> = (0..127).collect();
    let mut pdu = Vec::new();
    Response::ReadHoldingRegisters(values.clone()).encode(&mut pdu);
    line.rx(&rtu_frame(2, &pdu));
    line.fire();
    assert_eq!(
        line.outcomes(),
        [Outcome::Response(Response::ReadHoldingRegisters(values))]
    );
}

// --- Chunking ---

proptest! {
    /// However the reply is cut into chunks and however the chunks are spaced (below t3.5), the
    /// master reports the same events.
    #[test]
    fn chunking_does_not_change_the_outcome(
        cuts in proptest::collection::vec(0usize..=ATV_READ_RESPONSE.len(), 0..8),
        gaps in proptest::collection::vec(0u64..1900, 8),
        corrupt in proptest::option::of(0usize..ATV_READ_RESPONSE.len()),
    ) {
        let mut reply = ATV_READ_RESPONSE.to_vec();
        if let Some(i) = corrupt {
            reply[i] ^= 0x40;
        }
        let run = |chunks: &[&[u8]], gaps: &[u64]| {
            let mut line = Line::new(rtu_config());
            line.submit(2, atv_read());
            line.transmit();
            for (chunk, gap) in chunks.iter().zip(gaps.iter().chain(core::iter::repeat(&0))) {
                line.advance(Duration::from_micros(*gap));
                line.rx(chunk);
            }
            line.settle();
            line.events
        };
        let whole = run(&[&reply], &[]);
        let mut cuts = cuts;
        cuts.sort_unstable();
        let mut chunks = Vec::new();
        let mut from = 0;
        for cut in cuts.into_iter().chain([reply.len()]) {
            if cut > from {
                chunks.push(&reply[from..cut]);
                from = cut;
            }
        }
        prop_assert_eq!(run(&chunks, &gaps), whole);
    }
}

#[test]
fn a_reply_longer_than_announced_is_0e53_and_its_values_are_not_taken() {
    // 003 6.4.3: the reply is what arrived before 3.5 character times of silence; 7.2 0E 53h:
    // "more characters than should have resulted according to byte counter or function code".
    let mut line = Line::new(rtu_config());
    let mut slave = TestSlave::altivar();
    line.submit(2, atv_read());
    let request = line.transmit();
    let answer = slave.answer_rtu(&request).expect("answer");
    line.rx(&answer);
    // Trailing bytes 1 ms later, inside t3.5 (2 ms at 19200 Bd): part of the same frame.
    line.advance(Duration::from_millis(1));
    line.rx(&[0x00, 0x00]);
    let last_byte = line.now;
    assert!(line.events.is_empty());
    line.fire();
    assert_eq!(line.now, last_byte + timing().t35);
    assert_eq!(line.raised(), [ids::MODBUS_BYTE_OVERFLOW]);
    assert_eq!(
        line.outcomes(),
        [Outcome::Failed(ids::MODBUS_BYTE_OVERFLOW)]
    );

    // The same with the trailing bytes in the same read, and with a good CRC over everything.
    let mut line = Line::new(rtu_config());
    line.submit(2, atv_read());
    line.transmit();
    let mut pdu = ATV_READ_RESPONSE[1..ATV_READ_RESPONSE.len() - 2].to_vec();
    pdu.extend_from_slice(&[0x12, 0x34]);
    line.rx(&rtu_frame(2, &pdu));
    line.settle();
    assert_eq!(
        line.outcomes(),
        [Outcome::Failed(ids::MODBUS_BYTE_OVERFLOW)]
    );
}

#[test]
fn a_reply_in_pieces_completes_exactly_when_the_silence_has_passed() {
    let mut line = Line::new(rtu_config());
    let mut slave = TestSlave::altivar();
    line.submit(2, atv_read());
    let request = line.transmit();
    let answer = slave.answer_rtu(&request).expect("answer");
    let t35 = timing().t35;
    let step = Duration::from_micros(1500);
    assert!(step < t35);
    for (i, piece) in answer.chunks(4).enumerate() {
        if i > 0 {
            line.advance(step);
        }
        line.rx(piece);
        assert!(line.outcomes().is_empty());
        assert_eq!(line.master.poll_timeout(), Some(line.now + t35));
    }
    let last_piece = line.now;
    line.fire();
    assert_eq!(line.now, last_piece + t35);
    assert_eq!(line.outcomes().len(), 1);
    assert!(line.master.is_idle());
    // One microsecond before the silence has passed, nothing: run the same line again.
    let mut line = Line::new(rtu_config());
    line.submit(2, atv_read());
    line.transmit();
    line.rx(&answer);
    let early = Instant::from_micros((line.now + t35).as_micros() - 1);
    line.master.handle_timeout(early);
    line.drain();
    assert!(line.outcomes().is_empty());
    line.master.handle_timeout(line.now + t35);
    line.drain();
    assert_eq!(line.outcomes().len(), 1);
}

#[test]
fn a_pause_longer_than_t35_cuts_the_reply() {
    let mut line = Line::new(rtu_config());
    let mut slave = TestSlave::altivar();
    line.submit(2, atv_read());
    let request = line.transmit();
    let answer = slave.answer_rtu(&request).expect("answer");
    line.rx(&answer[..6]);
    line.advance(timing().t35 + Duration::from_micros(100));
    // The first part ended by silence; its last two bytes are not its CRC (0E 57h).
    assert_eq!(line.raised(), [ids::MODBUS_CHECKSUM_ERROR]);
    assert_eq!(
        line.outcomes(),
        [Outcome::Failed(ids::MODBUS_CHECKSUM_ERROR)]
    );
    // The rest is bytes nobody asked for.
    line.rx(&answer[6..]);
    assert_eq!(
        line.raised(),
        [ids::MODBUS_CHECKSUM_ERROR, ids::MODBUS_BYTE_OVERFLOW]
    );
}
