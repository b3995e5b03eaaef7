//! The ASCII master (003 6.4.2.2): framing, character delay time, 32-bit registers.

use core::time::Duration;

use proto_core::event::{ids, EventId};
use proto_core::modbus::ascii;
use proto_core::modbus::master::{
    Framing, JobError, Master, MasterConfig, MasterEvent, Outcome, Request32, Response32,
    SubmitError,
};
use proto_core::modbus::pdu::{FunctionCode, Response};

use super::support::*;

fn ascii_config(registers32: bool) -> MasterConfig {
    let mut config = MasterConfig::ascii();
    config.framing = Framing::Ascii {
        char_delay: Duration::from_millis(50),
        registers32,
    };
    config
}

#[test]
fn ascii_round_trip_with_the_test_slave() {
    let mut line = Line::new(ascii_config(false));
    let mut slave = TestSlave::altivar();
    let id = line.submit(2, atv_read());
    let request = line.transmit();
    assert_eq!(request, b":02030C1E0004CD\r\n");
    let answer = slave.answer_ascii(&request).expect("answer");
    for byte in &answer {
        line.advance(Duration::from_millis(1));
        line.rx(&[*byte]);
    }
    assert_eq!(
        line.events,
        [MasterEvent::Completed {
            id,
            slave: 2,
            request: atv_read(),
            outcome: Outcome::Response(Response::ReadHoldingRegisters(vec![40, 600, 500, 0]))
        }]
    );
    assert!(line.master.is_idle(), "ASCII frames need no silent gap");
}

fn ascii_reply_events(reply: &[u8]) -> (Vec<EventId>, Vec<Outcome>) {
    let mut line = Line::new(ascii_config(false));
    line.submit(2, atv_read());
    line.transmit();
    line.rx(reply);
    line.settle();
    (line.raised(), line.outcomes())
}

#[test]
fn ascii_reply_errors() {
    let mut good = Vec::new();
    ascii::encode_frame(2, &ATV_READ_RESPONSE[1..11], &mut good);
    let values = Outcome::Response(Response::ReadHoldingRegisters(vec![40, 600, 500, 0]));
    // 08 34h: a ':' inside the message restarts it without failing the job.
    let restarted = [&b":0203"[..], &good].concat();
    assert_eq!(
        ascii_reply_events(&restarted),
        (vec![ids::MODBUS_ASCII_START_IN_FRAME], vec![values])
    );
    // 08 33h: a wrong start character.
    let wrong_start = [&b"X"[..], &good].concat();
    let failed = |e| (vec![e], vec![Outcome::Failed(e)]);
    assert_eq!(
        ascii_reply_events(&wrong_start),
        failed(ids::MODBUS_ASCII_WRONG_START)
    );
    // 0E 58h: a character that is not a hex digit.
    let mut bad_char = good.clone();
    bad_char[5] = b'G';
    assert_eq!(
        ascii_reply_events(&bad_char),
        failed(ids::MODBUS_ASCII_INVALID_CHARACTER)
    );
    // 0E 58h: lower-case hex is not one of the characters 0...9, A...F (003 7.2).
    let lower = good.to_ascii_lowercase();
    assert_ne!(lower, good, "the reply has hex letters");
    assert_eq!(
        ascii_reply_events(&lower),
        failed(ids::MODBUS_ASCII_INVALID_CHARACTER)
    );
    // 0E 57h: the LRC does not match.
    let mut bad_lrc = good.clone();
    let lrc_at = bad_lrc.len() - 3;
    bad_lrc[lrc_at] = if bad_lrc[lrc_at] == b'0' { b'1' } else { b'0' };
    assert_eq!(
        ascii_reply_events(&bad_lrc),
        failed(ids::MODBUS_CHECKSUM_ERROR)
    );
    // 08 06h: the character delay time runs out inside the frame.
    assert_eq!(
        ascii_reply_events(&good[..10]),
        failed(ids::CHARACTER_DELAY_EXCEEDED)
    );
    // 0E 50h: the wrong slave answered.
    let mut other = Vec::new();
    ascii::encode_frame(3, &ATV_READ_RESPONSE[1..11], &mut other);
    assert_eq!(ascii_reply_events(&other), failed(ids::MODBUS_WRONG_SLAVE));
}

#[test]
fn ascii_character_delay_is_measured_between_characters() {
    let mut line = Line::new(ascii_config(false));
    line.submit(2, atv_read());
    line.transmit();
    line.rx(b":02");
    let last = line.now;
    assert_eq!(
        line.master.poll_timeout(),
        Some(last + Duration::from_millis(50))
    );
    line.master
        .handle_timeout(last + Duration::from_micros(49_999));
    line.drain();
    assert!(line.events.is_empty());
    line.fire();
    assert_eq!(line.raised(), [ids::CHARACTER_DELAY_EXCEEDED]);
}

#[test]
fn ascii_32_bit_registers() {
    let mut line = Line::new(ascii_config(true));
    let request = Request32::ReadHoldingRegisters {
        address: 0x10,
        quantity: 2,
    };
    let id = line
        .master
        .submit_registers32(line.now, 5, request.clone())
        .expect("accepted");
    let adu = line.transmit();
    // The function code on the wire is 03h (003 6.4.4: bit 6 is master information only).
    assert_eq!(
        ascii::decode_frame(&adu),
        Ok((5, vec![0x03, 0x00, 0x10, 0x00, 0x02]))
    );
    let mut reply = Vec::new();
    ascii::encode_frame(
        5,
        &[0x03, 0x08, 0x12, 0x34, 0x56, 0x78, 0x00, 0x00, 0x00, 0x01],
        &mut reply,
    );
    line.rx(&reply);
    assert_eq!(
        line.events,
        [MasterEvent::Completed32 {
            id,
            slave: 5,
            request,
            outcome: Outcome::Response(Response32::ReadHoldingRegisters(vec![0x1234_5678, 1]))
        }]
    );
    // Limits 1..62 / 1..61, and refused without the parameter.
    let mut master = Master::new(ascii_config(true));
    let too_many = Request32::ReadHoldingRegisters {
        address: 0,
        quantity: 63,
    };
    assert_eq!(
        master.submit_registers32(START, 1, too_many.clone()),
        Err(SubmitError::Invalid(JobError::RegisterCount {
            quantity: 63,
            max: 62
        }))
    );
    let writes = Request32::WriteMultipleRegisters {
        address: 0,
        values: vec![0; 62],
    };
    assert_eq!(
        master.submit_registers32(START, 1, writes),
        Err(SubmitError::Invalid(JobError::WriteCount {
            quantity: 62,
            max: 61
        }))
    );
    let mut plain = Master::new(ascii_config(false));
    assert_eq!(
        plain.submit_registers32(
            START,
            1,
            Request32::WriteSingleRegister {
                address: 0,
                value: 1
            }
        ),
        Err(SubmitError::Invalid(JobError::IllegalFunction {
            function: 0x46
        }))
    );
    assert_eq!(FunctionCode::READ_HOLDING_REGISTERS.0 | 0x40, 0x43);
}
