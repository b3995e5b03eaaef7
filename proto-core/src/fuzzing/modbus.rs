//! The Modbus framing and PDU entry points.

use crate::modbus::ascii::{self, AsciiEvent, AsciiFrameAssembler};
use crate::modbus::pdu::{ExceptionResponse, Limits, Request, Response};
use crate::modbus::rtu::{self, FrameLen};
use crate::modbus::slave::CP_SLAVE_LIMITS;

use super::as_u64;

/// The longest prefix whose lengths [`fuzz_rtu`] follows byte by byte (beyond any frame).
const LEN_CHECK_BYTES: usize = rtu::MAX_FRAME_LEN + 8;

/// The RTU frame decoder and the length rules of the request and response headers.
///
/// - a frame that decodes re-encodes to the same bytes, and its PDU is checked as in
///   [`fuzz_pdu`];
/// - [`rtu::expected_request_len`] and [`rtu::expected_response_len`], asked after every byte of
///   a growing buffer, answer consistently: `NeedMore(n)` asks for more than is there and is kept
///   until `n` bytes are there, `Complete(n)` comes exactly when the n-th byte arrives and stays,
///   `Unknown` stays.
pub fn fuzz_rtu(data: &[u8]) {
    if let Ok(frame) = rtu::decode_frame(data) {
        let mut again = Vec::new();
        rtu::encode_frame(frame.address, frame.pdu, &mut again);
        assert_eq!(again, data, "RTU re-encoding");
        check_request_pdu(frame.pdu);
    }
    let head = data.get(..LEN_CHECK_BYTES).unwrap_or(data);
    check_frame_len(head, rtu::expected_request_len);
    check_frame_len(head, rtu::expected_response_len);
}

/// Asks `len_of` after every byte of `buf` and checks that the answers agree with each other.
fn check_frame_len(buf: &[u8], len_of: fn(&[u8]) -> FrameLen) {
    let mut previous: Option<FrameLen> = None;
    for m in 0..=buf.len() {
        let prefix = buf.get(..m).unwrap_or(buf);
        let now = len_of(prefix);
        match now {
            FrameLen::NeedMore(n) => assert!(n > m, "NeedMore({n}) with {m} bytes"),
            FrameLen::Complete(n) => {
                assert!(n <= m, "Complete({n}) with {m} bytes");
                assert!(n >= rtu::MIN_FRAME_LEN, "Complete({n}) below the minimum");
            }
            FrameLen::Unknown => {}
        }
        match (previous, now) {
            (None, _) => {}
            // Still waiting for the bytes asked for.
            (Some(FrameLen::NeedMore(_)), FrameLen::NeedMore(_)) => {}
            (Some(FrameLen::NeedMore(n)), later) => {
                assert!(m >= n, "NeedMore({n}) answered {later:?} at {m} bytes");
                if let FrameLen::Complete(k) = later {
                    assert_eq!(k, m, "the length became known after the frame ended");
                }
            }
            (Some(before), later) => {
                assert_eq!(before, later, "a known length changed at {m} bytes");
            }
        }
        previous = Some(now);
    }
}

/// The ASCII frame decoder and [`AsciiFrameAssembler`].
///
/// - a frame that decodes re-encodes to the same characters (apart from the case of the hex
///   digits), and its PDU is checked as in [`fuzz_pdu`];
/// - the assembler gives the same events whether fed byte by byte or in chunks;
/// - every frame it hands out starts with ':', ends with LF and is at most
///   [`ascii::MAX_FRAME_CHARS`] long; a partial frame never reaches that length;
/// - nothing is lost silently: bytes fed = bytes in frames + bytes counted as discarded + bytes
///   of the partial frame, also after a reset.
pub fn fuzz_ascii(data: &[u8]) {
    if let Ok((address, pdu)) = ascii::decode_frame(data) {
        let mut again = Vec::new();
        ascii::encode_frame(address, &pdu, &mut again);
        assert!(again.eq_ignore_ascii_case(data), "ASCII re-encoding");
        check_request_pdu(&pdu);
    }

    let mut single = AsciiFrameAssembler::new();
    let by_byte: Vec<AsciiEvent> = data.iter().filter_map(|&b| single.push(b)).collect();
    let chunk = data.first().map_or(1, |&b| usize::from(b % 17) + 1);
    let mut chunked = AsciiFrameAssembler::new();
    let mut by_chunk = Vec::new();
    for part in data.chunks(chunk) {
        chunked.feed(part, &mut by_chunk);
    }
    assert_eq!(by_byte, by_chunk, "chunking changed the events");
    assert_eq!(single.pending(), chunked.pending());

    let mut in_frames = 0usize;
    for event in &by_byte {
        if let AsciiEvent::Frame(frame) = event {
            assert_eq!(frame.first(), Some(&ascii::COLON), "frame start");
            assert_eq!(frame.last(), Some(&ascii::LF), "frame end");
            assert!(frame.len() <= ascii::MAX_FRAME_CHARS, "frame length");
            in_frames += frame.len();
            if let Ok((_, pdu)) = ascii::decode_frame(frame) {
                check_request_pdu(&pdu);
            }
        }
    }
    assert!(single.pending() < ascii::MAX_FRAME_CHARS, "partial frame");
    assert_eq!(single.in_frame(), single.pending() > 0);
    let fed = as_u64(data.len());
    assert_eq!(
        as_u64(in_frames) + single.discarded() + as_u64(single.pending()),
        fed,
        "bytes lost without being counted"
    );
    let pending = single.pending();
    assert_eq!(single.reset(), pending);
    assert_eq!(as_u64(in_frames) + single.discarded(), fed, "after reset");
}

/// The PDU codec: the whole input as a request PDU, and the rest of the input after a first byte
/// `n` as a response to a request (the next `n` bytes decoded as a request, or one of a fixed set
/// of requests when they do not decode).
///
/// - a request that decodes encodes to bytes that decode to the same request, and the error of
///   one that does not maps to an exception response;
/// - a response that decodes against its request encodes to bytes that decode to the same
///   response; the same for exception responses.
pub fn fuzz_pdu(data: &[u8]) {
    check_request_pdu(data);
    let _ = ExceptionResponse::decode(data);

    let Some((&n, rest)) = data.split_first() else {
        return;
    };
    let (request_bytes, response) = rest.split_at(usize::from(n).min(rest.len()));
    let request = Request::decode_with(request_bytes, &Limits::CP_MASTER_RTU)
        .unwrap_or_else(|_| fallback_request(n));
    check_response(&request, response);
}

/// Requests of every function code the codec knows, for responses whose request did not decode.
fn fallback_request(n: u8) -> Request {
    let requests = [
        Request::ReadCoils {
            address: 0,
            quantity: 10,
        },
        Request::ReadDiscreteInputs {
            address: 100,
            quantity: 2040,
        },
        Request::ReadHoldingRegisters {
            address: 3102,
            quantity: 4,
        },
        Request::ReadInputRegisters {
            address: 1004,
            quantity: 127,
        },
        Request::WriteSingleCoil {
            address: 7,
            value: true,
        },
        Request::WriteSingleRegister {
            address: 9001,
            value: 3,
        },
        Request::ReadExceptionStatus,
        Request::Diagnostics {
            sub_function: 0,
            data: vec![0x12, 0x34],
        },
        Request::Diagnostics {
            sub_function: 0x0B,
            data: vec![0, 0],
        },
        Request::GetCommEventCounter,
        Request::GetCommEventLog,
        Request::WriteMultipleCoils {
            address: 0,
            values: vec![true, false, true, true, false, false, true, false, true],
        },
        Request::WriteMultipleRegisters {
            address: 3415,
            values: vec![0x4148, 0x0000],
        },
        Request::ReportServerId,
        Request::ReadWriteMultipleRegisters {
            read_address: 0,
            read_quantity: 6,
            write_address: 10,
            values: vec![1, 2, 3],
        },
        Request::ReadDeviceIdentification {
            read_code: 1,
            object_id: 0,
        },
    ];
    let index = usize::from(n) % requests.len();
    requests
        .get(index)
        .cloned()
        .unwrap_or(Request::ReadExceptionStatus)
}

/// Decodes `pdu` as a request under every set of limits and checks the round trip.
fn check_request_pdu(pdu: &[u8]) {
    let limits = [
        Limits::SPEC,
        Limits::CP_MASTER_RTU,
        Limits::CP_MASTER_ASCII,
        CP_SLAVE_LIMITS,
    ];
    for limits in &limits {
        match Request::decode_with(pdu, limits) {
            Ok(request) => {
                let bytes = request.to_bytes();
                assert_eq!(
                    Request::decode_with(&bytes, limits),
                    Ok(request.clone()),
                    "request round trip"
                );
                assert_eq!(request.function().0, bytes.first().copied().unwrap_or(0));
            }
            Err(error) => {
                let function = pdu.first().copied().unwrap_or(0);
                let mut out = Vec::new();
                ExceptionResponse::for_error(function, &error).encode(&mut out);
                assert_eq!(out.len(), 2, "an exception response is two bytes");
            }
        }
    }
}

/// Decodes `pdu` as the answer to `request` and checks the round trip.
fn check_response(request: &Request, pdu: &[u8]) {
    match Response::decode_for(request, pdu) {
        Ok(Ok(response)) => {
            assert_eq!(response.function(), request.function());
            let bytes = response.to_bytes();
            assert_eq!(
                Response::decode_for(request, &bytes),
                Ok(Ok(response)),
                "response round trip"
            );
        }
        Ok(Err(exception)) => {
            assert_eq!(exception.function, request.function());
            let mut bytes = Vec::new();
            exception.encode(&mut bytes);
            assert_eq!(
                Response::decode_for(request, &bytes),
                Ok(Err(exception)),
                "exception round trip"
            );
        }
        Err(_) => {}
    }
}
