//! Frames from the seed manuals, one scenario a file under `tests/vectors/`: each is decoded through
//! the framing and the PDU codec, checked against the values the manual names, and re-encoded byte
//! for byte.
//!
//! File format: `#` comment lines (what the frame is and where it comes from), then hex bytes
//! separated by white space.

use proto_core::checksum::{bcc, crc16_modbus};
use proto_core::modbus::pdu::{ExceptionCode, ExceptionResponse, FunctionCode, Request, Response};
use proto_core::modbus::rtu::{self, FrameLen};
use proto_core::modbus::{ascii, FrameError};

macro_rules! vector {
    ($name:literal) => {
        parse_hex($name, include_str!(concat!("vectors/", $name, ".hex")))
    };
}

/// The bytes of a vector file (comments skipped).
fn parse_hex(name: &str, text: &str) -> Vec<u8> {
    text.lines()
        .filter(|line| !line.trim_start().starts_with('#'))
        .flat_map(str::split_whitespace)
        .map(|byte| {
            u8::from_str_radix(byte, 16).unwrap_or_else(|e| panic!("{name}: bad hex {byte:?}: {e}"))
        })
        .collect()
}

/// Checks the CRC the manual printed, then splits the frame.
fn split_rtu(name: &str, frame: &[u8]) -> (u8, Vec<u8>) {
    let (body, crc) = frame.split_at(frame.len() - 2);
    assert_eq!(crc16_modbus(body).to_le_bytes(), crc, "{name}: CRC");
    let decoded = rtu::decode_frame(frame).unwrap_or_else(|e| panic!("{name}: {e}"));
    let mut again = Vec::new();
    rtu::encode_frame(decoded.address, decoded.pdu, &mut again);
    assert_eq!(again, frame, "{name}: RTU re-encoding");
    // The same PDU over ASCII survives the round trip too.
    let mut text = Vec::new();
    ascii::encode_frame(decoded.address, decoded.pdu, &mut text);
    assert_eq!(
        ascii::decode_frame(&text),
        Ok((decoded.address, decoded.pdu.to_vec())),
        "{name}: ASCII"
    );
    (decoded.address, decoded.pdu.to_vec())
}

/// Decodes a request frame as a slave does and re-encodes it.
fn decode_request(name: &str, frame: &[u8], expected_len: FrameLen) -> (u8, Request) {
    assert_eq!(
        rtu::expected_request_len(frame),
        expected_len,
        "{name}: length from the header"
    );
    let (address, pdu) = split_rtu(name, frame);
    let request = Request::decode(&pdu).unwrap_or_else(|e| panic!("{name}: {e}"));
    assert_eq!(request.to_bytes(), pdu, "{name}: PDU re-encoding");
    (address, request)
}

/// Decodes a response frame against its request as a master does and re-encodes it.
fn decode_response(
    name: &str,
    request: &Request,
    frame: &[u8],
    expected_len: FrameLen,
) -> (u8, Result<Response, ExceptionResponse>) {
    assert_eq!(
        rtu::expected_response_len(frame),
        expected_len,
        "{name}: length from the header"
    );
    let (address, pdu) = split_rtu(name, frame);
    let answer = Response::decode_for(request, &pdu).unwrap_or_else(|e| panic!("{name}: {e}"));
    let mut again = Vec::new();
    match &answer {
        Ok(response) => response.encode(&mut again),
        Err(exception) => exception.encode(&mut again),
    }
    assert_eq!(again, pdu, "{name}: PDU re-encoding");
    (address, answer)
}

fn complete(frame: &[u8]) -> FrameLen {
    FrameLen::Complete(frame.len())
}

#[test]
fn altivar_fc03_read_w3102() {
    let req = vector!("altivar-fc03-w3102-request");
    let (address, request) = decode_request("fc03 request", &req, complete(&req));
    assert_eq!(
        (address, &request),
        (
            2,
            &Request::ReadHoldingRegisters {
                address: 3102,
                quantity: 4
            }
        )
    );
    let resp = vector!("altivar-fc03-w3102-response");
    let (address, answer) = decode_response("fc03 response", &request, &resp, complete(&resp));
    assert_eq!(
        (address, answer),
        (2, Ok(Response::ReadHoldingRegisters(vec![40, 600, 500, 0])))
    );
}

#[test]
fn altivar_fc03_card_servers() {
    let req = vector!("altivar-fc03-controller-inside-mw20-request");
    let (address, request) = decode_request("mw20 request", &req, complete(&req));
    assert_eq!(
        (address, &request),
        (
            54,
            &Request::ReadHoldingRegisters {
                address: 20,
                quantity: 5
            }
        )
    );
    let resp = vector!("altivar-fc03-controller-inside-mw20-response");
    let (_, answer) = decode_response("mw20 response", &request, &resp, complete(&resp));
    assert_eq!(
        answer,
        Ok(Response::ReadHoldingRegisters(vec![
            0x0054, 0x0123, 0x01A3, 0x1AD5, 0x009E
        ]))
    );

    let req = vector!("altivar-fc03-ethernet-ip-request");
    let (address, request) = decode_request("ip request", &req, complete(&req));
    assert_eq!(
        (address, &request),
        (
            104,
            &Request::ReadHoldingRegisters {
                address: 60006,
                quantity: 4
            }
        )
    );
    let resp = vector!("altivar-fc03-ethernet-ip-response");
    let (_, answer) = decode_response("ip response", &request, &resp, complete(&resp));
    assert_eq!(
        answer,
        Ok(Response::ReadHoldingRegisters(vec![139, 160, 69, 241]))
    );
}

#[test]
fn altivar_fc06_write_acc() {
    let req = vector!("altivar-fc06-w9001-acc-request");
    let (address, request) = decode_request("fc06 request", &req, complete(&req));
    assert_eq!(
        (address, &request),
        (
            2,
            &Request::WriteSingleRegister {
                address: 9001,
                value: 13
            }
        )
    );
    let resp = vector!("altivar-fc06-w9001-acc-response");
    assert_eq!(req, resp, "the answer is the echo");
    let (_, answer) = decode_response("fc06 response", &request, &resp, complete(&resp));
    assert_eq!(
        answer,
        Ok(Response::WriteSingleRegister {
            address: 9001,
            value: 13
        })
    );
}

#[test]
fn altivar_fc08_echo() {
    let req = vector!("altivar-fc08-echo-request");
    // Sub-function 00 echoes any data: its length is not in the header.
    let (address, request) = decode_request("fc08 request", &req, FrameLen::Unknown);
    assert_eq!(
        (address, &request),
        (
            4,
            &Request::Diagnostics {
                sub_function: 0,
                data: vec![0x31, 0x32]
            }
        )
    );
    let resp = vector!("altivar-fc08-echo-response");
    let (_, answer) = decode_response("fc08 response", &request, &resp, FrameLen::Unknown);
    assert_eq!(
        answer,
        Ok(Response::Diagnostics {
            sub_function: 0,
            data: vec![0x31, 0x32]
        })
    );
}

#[test]
fn altivar_fc16_write_acc_dec() {
    let req = vector!("altivar-fc16-w9001-request");
    let (address, request) = decode_request("fc16 request", &req, complete(&req));
    assert_eq!(
        (address, &request),
        (
            2,
            &Request::WriteMultipleRegisters {
                address: 9001,
                values: vec![20, 30]
            }
        )
    );
    let resp = vector!("altivar-fc16-w9001-response");
    let (_, answer) = decode_response("fc16 response", &request, &resp, complete(&resp));
    assert_eq!(
        answer,
        Ok(Response::WriteMultipleRegisters {
            address: 9001,
            quantity: 2
        })
    );
}

#[test]
fn altivar_fc43_device_identification() {
    let req = vector!("altivar-fc43-device-id-request");
    let (address, request) = decode_request("fc43 request", &req, complete(&req));
    assert_eq!(
        (address, &request),
        (
            2,
            &Request::ReadDeviceIdentification {
                read_code: 1,
                object_id: 0
            }
        )
    );
    let resp = vector!("altivar-fc43-device-id-response");
    assert_eq!(resp.len(), 55);
    let (_, answer) = decode_response("fc43 response", &request, &resp, complete(&resp));
    let expected = Response::ReadDeviceIdentification {
        read_code: 1,
        conformity_level: 2,
        more_follows: false,
        next_object_id: 0,
        objects: vec![
            (0x00, b"Telemecanique".to_vec()),
            (0x01, b"ATV71HU15M3".to_vec()),
            (0x02, b"0201".to_vec()),
            (0x06, b"MACHINE 4".to_vec()),
        ],
    };
    assert_eq!(answer, Ok(expected));
    // Cut anywhere, the header walk asks for more instead of guessing.
    for cut in 0..resp.len() {
        assert!(
            matches!(rtu::expected_response_len(&resp[..cut]), FrameLen::NeedMore(n) if n > cut && n <= resp.len())
        );
    }
}

#[test]
fn altivar_fc23_communication_scanner() {
    let req = vector!("altivar-fc23-scanner-request");
    let (address, request) = decode_request("fc23 request", &req, complete(&req));
    let expected = Request::ReadWriteMultipleRegisters {
        read_address: 0x31C5,
        read_quantity: 8,
        write_address: 0x31D9,
        values: vec![0x000F, 0x1388, 0x1F40, 0x01F4, 0x04B0, 0x0258],
    };
    assert_eq!((address, &request), (20, &expected));
    let resp = vector!("altivar-fc23-scanner-response");
    let (_, answer) = decode_response("fc23 response", &request, &resp, complete(&resp));
    assert_eq!(
        answer,
        Ok(Response::ReadWriteMultipleRegisters(vec![
            7, 5000, 100, 69, 240, 101, 50, 0
        ]))
    );
}

#[test]
fn altivar_exceptions_and_missing_words() {
    let req = vector!("altivar-fc16-eta-read-only-request");
    let (address, request) = decode_request("eta request", &req, complete(&req));
    assert_eq!(
        (address, &request),
        (
            4,
            &Request::WriteMultipleRegisters {
                address: 3201,
                values: vec![1]
            }
        )
    );
    let resp = vector!("altivar-fc16-eta-read-only-exception");
    let (_, answer) = decode_response("eta exception", &request, &resp, complete(&resp));
    let exception = ExceptionResponse {
        function: FunctionCode::WRITE_MULTIPLE_REGISTERS,
        code: ExceptionCode::ServerDeviceFailure,
    };
    assert_eq!(answer, Err(exception));

    let req = vector!("altivar-fc03-w8400-request");
    let (address, request) = decode_request("w8400 request", &req, complete(&req));
    assert_eq!(
        (address, &request),
        (
            12,
            &Request::ReadHoldingRegisters {
                address: 8400,
                quantity: 3
            }
        )
    );
    let resp = vector!("altivar-fc03-w8400-missing-response");
    let (_, answer) = decode_response("w8400 missing", &request, &resp, complete(&resp));
    assert_eq!(
        answer,
        Ok(Response::ReadHoldingRegisters(vec![0x8000, 3, 2]))
    );
    let resp = vector!("altivar-fc03-w8400-protected-response");
    let (_, answer) = decode_response("w8400 protected", &request, &resp, complete(&resp));
    assert_eq!(
        answer,
        Ok(Response::ReadHoldingRegisters(vec![0x8000, 0x8000, 2]))
    );
    let resp = vector!("altivar-fc03-w8400-all-missing-exception");
    let (_, answer) = decode_response("w8400 all missing", &request, &resp, complete(&resp));
    let exception = ExceptionResponse {
        function: FunctionCode::READ_HOLDING_REGISTERS,
        code: ExceptionCode::IllegalDataAddress,
    };
    assert_eq!(answer, Err(exception));
}

/// The KS vario manual prints address and PDU without CRC: they are framed here.
fn framed(address_and_pdu: &[u8]) -> Vec<u8> {
    let (&address, pdu) = address_and_pdu.split_first().expect("vector not empty");
    let mut frame = Vec::new();
    rtu::encode_frame(address, pdu, &mut frame);
    frame
}

#[test]
fn ksvario_fc16_float_write() {
    let req = framed(&vector!("ksvario-fc16-float-3415-pdu-request"));
    let (address, request) = decode_request("ks fc16 request", &req, complete(&req));
    // 222.0 = 43 5E 00 00, 333.0 = 43 A6 80 00, high word first.
    let expected = Request::WriteMultipleRegisters {
        address: 0x9AAE,
        values: vec![0x435E, 0x0000, 0x43A6, 0x8000],
    };
    assert_eq!((address, &request), (17, &expected));
    assert_eq!(f32::from_bits(0x435E_0000), 222.0);
    assert_eq!(f32::from_bits(0x43A6_8000), 333.0);
    // 001: float address = 2 x integer address + 0x8000.
    assert_eq!(0x9AAE, 2 * 3415 + 0x8000);
    let resp = framed(&vector!("ksvario-fc16-float-3415-pdu-response"));
    let (_, answer) = decode_response("ks fc16 response", &request, &resp, complete(&resp));
    assert_eq!(
        answer,
        Ok(Response::WriteMultipleRegisters {
            address: 0x9AAE,
            quantity: 4
        })
    );
}

#[test]
fn ksvario_fc04_read() {
    let req = framed(&vector!("ksvario-fc04-1004-pdu-request"));
    let (address, request) = decode_request("ks fc04 request", &req, complete(&req));
    assert_eq!(
        (address, &request),
        (
            17,
            &Request::ReadInputRegisters {
                address: 1004,
                quantity: 3
            }
        )
    );
    let resp = framed(&vector!("ksvario-fc04-1004-pdu-response"));
    let (_, answer) = decode_response("ks fc04 response", &request, &resp, complete(&resp));
    assert_eq!(
        answer,
        Ok(Response::ReadInputRegisters(vec![1066, 140, 4158]))
    );
}

#[test]
fn corrupted_manual_frames_are_rejected() {
    let mut frame = vector!("altivar-fc03-w3102-response");
    if let Some(byte) = frame.get_mut(4) {
        *byte ^= 0x01;
    }
    assert!(matches!(
        rtu::decode_frame(&frame),
        Err(FrameError::BadCrc { actual: 0xB052, .. })
    ));
    let frame = vector!("altivar-fc03-w3102-response");
    assert_eq!(
        rtu::decode_frame(&frame[..frame.len() - 1])
            .map(|f| f.address)
            .ok(),
        None
    );
}

#[test]
fn bcc_of_3964_telegrams() {
    for (name, telegram) in [
        ("3964r-abc", vector!("3964r-abc-telegram")),
        ("3964r-dle-doubled", vector!("3964r-dle-doubled-telegram")),
    ] {
        let (check, covered) = telegram.split_last().expect("not empty");
        assert_eq!(bcc(covered), *check, "{name}");
    }
    // 3964 without BCC: the same bytes as 3964R up to DLE ETX.
    let plain = vector!("3964-abc-telegram");
    let with_bcc = vector!("3964r-abc-telegram");
    assert_eq!(with_bcc.get(..plain.len()), Some(&plain[..]));
    let bad = vector!("3964r-abc-bad-bcc-telegram");
    let (check, covered) = bad.split_last().expect("not empty");
    assert_ne!(bcc(covered), *check);
}
