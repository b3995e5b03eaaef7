//! Property tests of the codecs: encode -> decode round trips, no panics on arbitrary bytes, the
//! length helpers agree with the encoders, and lying quantities and byte counts give the right
//! errors.

use proptest::collection::vec;
use proptest::prelude::*;
use proto_core::checksum::{crc16_modbus, lrc};
use proto_core::modbus::ascii::{self, AsciiEvent, AsciiFrameAssembler};
use proto_core::modbus::pdu::{
    diag, ExceptionCode, ExceptionResponse, FunctionCode, PduError, Request, Response,
};
use proto_core::modbus::rtu::{self, FrameLen};
use proto_core::modbus::FrameError;

/// An address and a quantity in 1..=max that stay inside the 16-bit address space.
fn range(max: u16) -> impl Strategy<Value = (u16, u16)> {
    (1..=max).prop_flat_map(|quantity| (0..=(u16::MAX - (quantity - 1)), Just(quantity)))
}

fn known_sub_function() -> impl Strategy<Value = u16> {
    prop_oneof![
        Just(0x01u16),
        Just(0x02),
        Just(0x04),
        0x0Au16..=0x12,
        0x40u16..=0x42
    ]
}

/// Every request the server-side decoder accepts (within the specification's limits).
fn request() -> impl Strategy<Value = Request> {
    prop_oneof![
        range(2000).prop_map(|(address, quantity)| Request::ReadCoils { address, quantity }),
        range(2000)
            .prop_map(|(address, quantity)| Request::ReadDiscreteInputs { address, quantity }),
        range(125)
            .prop_map(|(address, quantity)| Request::ReadHoldingRegisters { address, quantity }),
        range(125)
            .prop_map(|(address, quantity)| Request::ReadInputRegisters { address, quantity }),
        (any::<u16>(), any::<bool>())
            .prop_map(|(address, value)| Request::WriteSingleCoil { address, value }),
        (any::<u16>(), any::<u16>())
            .prop_map(|(address, value)| Request::WriteSingleRegister { address, value }),
        Just(Request::ReadExceptionStatus),
        vec(any::<u8>(), 0..=250).prop_map(|data| Request::Diagnostics {
            sub_function: 0,
            data
        }),
        (known_sub_function(), any::<[u8; 2]>()).prop_map(|(sub_function, data)| {
            Request::Diagnostics {
                sub_function,
                data: data.to_vec(),
            }
        }),
        Just(Request::GetCommEventCounter),
        Just(Request::GetCommEventLog),
        range(1968).prop_flat_map(|(address, quantity)| {
            vec(any::<bool>(), usize::from(quantity))
                .prop_map(move |values| Request::WriteMultipleCoils { address, values })
        }),
        range(123).prop_flat_map(|(address, quantity)| {
            vec(any::<u16>(), usize::from(quantity))
                .prop_map(move |values| Request::WriteMultipleRegisters { address, values })
        }),
        Just(Request::ReportServerId),
        (range(125), range(121)).prop_flat_map(
            |((read_address, read_quantity), (write_address, write_quantity))| {
                vec(any::<u16>(), usize::from(write_quantity)).prop_map(move |values| {
                    Request::ReadWriteMultipleRegisters {
                        read_address,
                        read_quantity,
                        write_address,
                        values,
                    }
                })
            }
        ),
        (1u8..=4, any::<u8>()).prop_map(|(read_code, object_id)| {
            Request::ReadDeviceIdentification {
                read_code,
                object_id,
            }
        }),
    ]
}

/// A request of the CP master's sizes and a normal response that fits it.
fn exchange() -> impl Strategy<Value = (Request, Response)> {
    prop_oneof![
        (range(2040), any::<bool>()).prop_flat_map(|((address, quantity), inputs)| {
            vec(any::<bool>(), usize::from(quantity)).prop_map(move |bits| {
                if inputs {
                    (
                        Request::ReadDiscreteInputs { address, quantity },
                        Response::ReadDiscreteInputs(bits),
                    )
                } else {
                    (
                        Request::ReadCoils { address, quantity },
                        Response::ReadCoils(bits),
                    )
                }
            })
        }),
        (range(127), any::<bool>()).prop_flat_map(|((address, quantity), input)| {
            vec(any::<u16>(), usize::from(quantity)).prop_map(move |values| {
                if input {
                    (
                        Request::ReadInputRegisters { address, quantity },
                        Response::ReadInputRegisters(values),
                    )
                } else {
                    (
                        Request::ReadHoldingRegisters { address, quantity },
                        Response::ReadHoldingRegisters(values),
                    )
                }
            })
        }),
        (any::<u16>(), any::<bool>()).prop_map(|(address, value)| {
            (
                Request::WriteSingleCoil { address, value },
                Response::WriteSingleCoil { address, value },
            )
        }),
        (any::<u16>(), any::<u16>()).prop_map(|(address, value)| {
            (
                Request::WriteSingleRegister { address, value },
                Response::WriteSingleRegister { address, value },
            )
        }),
        any::<u8>().prop_map(|status| (
            Request::ReadExceptionStatus,
            Response::ReadExceptionStatus(status)
        )),
        (any::<u16>(), vec(any::<u8>(), 0..=250), any::<[u8; 2]>()).prop_map(
            |(sub_function, data, counter)| {
                let data = if sub_function == 0 {
                    data
                } else {
                    data.into_iter().chain([0, 0]).take(2).collect()
                };
                let answer = if diag::echoes_data(sub_function) {
                    data.clone()
                } else {
                    counter.to_vec()
                };
                (
                    Request::Diagnostics { sub_function, data },
                    Response::Diagnostics {
                        sub_function,
                        data: answer,
                    },
                )
            }
        ),
        (any::<u16>(), any::<u16>()).prop_map(|(status, event_count)| {
            (
                Request::GetCommEventCounter,
                Response::GetCommEventCounter {
                    status,
                    event_count,
                },
            )
        }),
        (
            any::<u16>(),
            any::<u16>(),
            any::<u16>(),
            vec(any::<u8>(), 0..=64)
        )
            .prop_map(|(status, event_count, message_count, events)| {
                (
                    Request::GetCommEventLog,
                    Response::GetCommEventLog {
                        status,
                        event_count,
                        message_count,
                        events,
                    },
                )
            }),
        range(2040).prop_map(|(address, quantity)| {
            let values = vec![true; usize::from(quantity)];
            (
                Request::WriteMultipleCoils { address, values },
                Response::WriteMultipleCoils { address, quantity },
            )
        }),
        range(127).prop_map(|(address, quantity)| {
            let values = vec![0; usize::from(quantity)];
            (
                Request::WriteMultipleRegisters { address, values },
                Response::WriteMultipleRegisters { address, quantity },
            )
        }),
        vec(any::<u8>(), 0..=255)
            .prop_map(|bytes| (Request::ReportServerId, Response::ReportServerId(bytes))),
        range(125).prop_flat_map(|(read_address, read_quantity)| {
            vec(any::<u16>(), usize::from(read_quantity)).prop_map(move |values| {
                let request = Request::ReadWriteMultipleRegisters {
                    read_address,
                    read_quantity,
                    write_address: 0,
                    values: vec![1],
                };
                (request, Response::ReadWriteMultipleRegisters(values))
            })
        }),
        (
            1u8..=4,
            any::<u8>(),
            any::<bool>(),
            any::<u8>(),
            vec((any::<u8>(), vec(any::<u8>(), 0..=20)), 0..=10)
        )
            .prop_map(
                |(read_code, conformity_level, more_follows, next_object_id, objects)| {
                    (
                        Request::ReadDeviceIdentification {
                            read_code,
                            object_id: 0,
                        },
                        Response::ReadDeviceIdentification {
                            read_code,
                            conformity_level,
                            more_follows,
                            next_object_id,
                            objects,
                        },
                    )
                }
            ),
    ]
}

fn exception_code() -> impl Strategy<Value = ExceptionCode> {
    any::<u8>().prop_map(ExceptionCode::from)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn request_roundtrip(request in request(), address in any::<u8>()) {
        let pdu = request.to_bytes();
        prop_assert_eq!(Request::decode(&pdu), Ok(request.clone()));
        // Through RTU framing, with the length known from the header unless FC 08/00.
        let mut frame = Vec::new();
        rtu::encode_frame(address, &pdu, &mut frame);
        let decoded = rtu::decode_frame(&frame).unwrap();
        prop_assert_eq!((decoded.address, decoded.pdu), (address, &pdu[..]));
        let echo = matches!(&request, Request::Diagnostics { sub_function: 0, .. });
        let expected = if echo { FrameLen::Unknown } else { FrameLen::Complete(frame.len()) };
        prop_assert_eq!(rtu::expected_request_len(&frame), expected);
        if !echo {
            for cut in 0..frame.len() {
                let len = rtu::expected_request_len(&frame[..cut]);
                prop_assert!(matches!(len, FrameLen::NeedMore(n) if n > cut && n <= frame.len()), "{cut}: {len:?}");
            }
        }
        // Through ASCII framing.
        let mut text = Vec::new();
        ascii::encode_frame(address, &pdu, &mut text);
        prop_assert_eq!(ascii::decode_frame(&text), Ok((address, pdu)));
    }

    #[test]
    fn response_roundtrip((request, response) in exchange(), address in any::<u8>()) {
        let pdu = response.to_bytes();
        prop_assert_eq!(Response::decode_for(&request, &pdu), Ok(Ok(response.clone())));
        let mut frame = Vec::new();
        rtu::encode_frame(address, &pdu, &mut frame);
        let len = rtu::expected_response_len(&frame);
        if matches!(request, Request::Diagnostics { sub_function: 0, .. }) {
            prop_assert_eq!(len, FrameLen::Unknown);
        } else {
            prop_assert_eq!(len, FrameLen::Complete(frame.len()));
            for cut in 0..frame.len() {
                let len = rtu::expected_response_len(&frame[..cut]);
                prop_assert!(matches!(len, FrameLen::NeedMore(n) if n > cut && n <= frame.len()), "{cut}: {len:?}");
            }
        }
        prop_assert!(frame.len() <= rtu::MAX_FRAME_LEN);
        prop_assert_eq!(rtu::decode_frame(&frame).map(|f| f.pdu.to_vec()), Ok(pdu));
    }

    #[test]
    fn exception_roundtrip(request in request(), code in exception_code(), address in any::<u8>()) {
        let exception = ExceptionResponse::new(request.function(), code);
        let mut pdu = Vec::new();
        exception.encode(&mut pdu);
        prop_assert_eq!(Response::decode_for(&request, &pdu), Ok(Err(exception)));
        prop_assert_eq!(ExceptionResponse::decode(&pdu), Ok(exception));
        let mut frame = Vec::new();
        rtu::encode_frame(address, &pdu, &mut frame);
        let altivar_form = request.function() == FunctionCode::ENCAPSULATED_INTERFACE && u8::from(code) == 0x0E;
        if !altivar_form {
            prop_assert_eq!(rtu::expected_response_len(&frame), FrameLen::Complete(5));
        }
    }

    #[test]
    fn request_decode_never_panics(bytes in vec(any::<u8>(), 0..300)) {
        if let Err(error) = Request::decode(&bytes) {
            // Every refusal maps to 01, 02 or 03.
            let code = u8::from(ExceptionCode::from(&error));
            prop_assert!((1..=3).contains(&code), "{error}");
        }
    }

    #[test]
    fn request_decode_with_a_known_function_never_panics(function in prop_oneof![1u8..=8, Just(0x0B), Just(0x0C), 0x0Fu8..=0x11, Just(0x17), Just(0x2B)], rest in vec(any::<u8>(), 0..40)) {
        let pdu: Vec<u8> = core::iter::once(function).chain(rest).collect();
        if let Ok(request) = Request::decode(&pdu) {
            // Whatever decodes re-encodes to the same bytes.
            prop_assert_eq!(request.to_bytes(), pdu);
        }
    }

    #[test]
    fn response_decode_never_panics(request in request(), bytes in vec(any::<u8>(), 0..300)) {
        let _ = Response::decode_for(&request, &bytes);
        // With the right function code in front, the decoder gets past the first check.
        let pdu: Vec<u8> = core::iter::once(request.function().0).chain(bytes).collect();
        if let Ok(Ok(response)) = Response::decode_for(&request, &pdu) {
            prop_assert_eq!(response.function(), request.function());
        }
    }

    #[test]
    fn framing_never_panics(bytes in vec(any::<u8>(), 0..600)) {
        let _ = rtu::decode_frame(&bytes);
        let _ = ascii::decode_frame(&bytes);
        for len in [rtu::expected_request_len(&bytes), rtu::expected_response_len(&bytes)] {
            match len {
                FrameLen::NeedMore(n) => prop_assert!(n > bytes.len()),
                FrameLen::Complete(n) => prop_assert!(n <= bytes.len() && n >= 4),
                FrameLen::Unknown => {}
            }
        }
        let mut framed = vec![ascii::COLON];
        framed.extend(&bytes);
        framed.extend([ascii::CR, ascii::LF]);
        let _ = ascii::decode_frame(&framed);
    }

    #[test]
    fn ascii_decode_of_hex_text_never_panics(text in "[0-9A-Fa-f:xG]{0,600}") {
        let frame = format!(":{text}\r\n");
        if let Ok((address, pdu)) = ascii::decode_frame(frame.as_bytes()) {
            let body: Vec<u8> = core::iter::once(address).chain(pdu).collect();
            prop_assert_eq!(frame.len(), 1 + 2 * (body.len() + 1) + 2);
            let lrc_text = frame.get(frame.len() - 4..frame.len() - 2).unwrap_or_default();
            prop_assert_eq!(u8::from_str_radix(lrc_text, 16).ok(), Some(lrc(&body)));
        }
    }

    #[test]
    fn every_single_bit_error_breaks_the_crc(pdu in vec(any::<u8>(), 1..250), address in any::<u8>(), bit in any::<prop::sample::Index>()) {
        let mut frame = Vec::new();
        rtu::encode_frame(address, &pdu, &mut frame);
        let bit = bit.index(frame.len() * 8);
        if let Some(byte) = frame.get_mut(bit / 8) {
            *byte ^= 1 << (bit % 8);
        }
        let (body, _) = frame.split_at(frame.len() - 2);
        let result = rtu::decode_frame(&frame);
        prop_assert!(matches!(result, Err(FrameError::BadCrc { expected, .. }) if expected == crc16_modbus(body)), "{result:?}");
    }

    #[test]
    fn ascii_assembler_is_chunking_invariant(stream in vec(prop_oneof![Just(b':'), Just(b'\r'), Just(b'\n'), any::<u8>()], 0..700), cuts in vec(any::<prop::sample::Index>(), 0..8)) {
        let mut whole = AsciiFrameAssembler::new();
        let mut expected = Vec::new();
        whole.feed(&stream, &mut expected);

        let mut points: Vec<usize> = cuts.iter().map(|i| i.index(stream.len() + 1)).collect();
        points.sort_unstable();
        let mut chunked = AsciiFrameAssembler::new();
        let mut events = Vec::new();
        let mut start = 0;
        for point in points.into_iter().chain([stream.len()]) {
            chunked.feed(&stream[start..point], &mut events);
            start = point;
        }
        prop_assert_eq!(&events, &expected);
        prop_assert_eq!(chunked.discarded(), whole.discarded());
        // Every byte is in a frame, still pending, or counted as discarded.
        let framed: usize = events.iter().map(|e| if let AsciiEvent::Frame(f) = e { f.len() } else { 0 }).sum();
        prop_assert_eq!(framed as u64 + chunked.pending() as u64 + chunked.discarded(), stream.len() as u64);
        for event in &events {
            if let AsciiEvent::Frame(frame) = event {
                prop_assert!(frame.len() <= ascii::MAX_FRAME_CHARS);
                prop_assert_eq!(frame.first(), Some(&ascii::COLON));
                prop_assert_eq!(frame.last(), Some(&ascii::LF));
            }
        }
    }

    #[test]
    fn fc03_quantity_outside_1_to_125_is_refused(address in any::<u16>(), quantity in prop_oneof![Just(0u16), 126u16..]) {
        let pdu = Request::ReadHoldingRegisters { address, quantity }.to_bytes();
        prop_assert_eq!(
            Request::decode(&pdu),
            Err(PduError::QuantityOutOfRange { function: 3, quantity, min: 1, max: 125 })
        );
    }

    #[test]
    fn fc15_quantity_lies_are_refused(quantity in 1969u16.., byte_count in any::<u8>(), data in vec(any::<u8>(), 0..300)) {
        let mut pdu = vec![0x0F, 0x00, 0x00];
        pdu.extend(quantity.to_be_bytes());
        pdu.push(byte_count);
        pdu.extend(data);
        prop_assert_eq!(
            Request::decode(&pdu),
            Err(PduError::QuantityOutOfRange { function: 0x0F, quantity, min: 1, max: 1968 })
        );
    }

    #[test]
    fn fc16_byte_count_lies_are_refused(quantity in 1u16..=123, byte_count in any::<u8>(), data in vec(any::<u8>(), 0..300)) {
        prop_assume!(usize::from(byte_count) != 2 * usize::from(quantity));
        let mut pdu = vec![0x10, 0x00, 0x00];
        pdu.extend(quantity.to_be_bytes());
        pdu.push(byte_count);
        pdu.extend(data);
        let error = Request::decode(&pdu).unwrap_err();
        prop_assert_eq!(&error, &PduError::ByteCountMismatch { function: 0x10, byte_count, expected: 2 * usize::from(quantity) });
        prop_assert_eq!(ExceptionCode::from(&error), ExceptionCode::IllegalDataValue);
    }

    #[test]
    fn short_register_answers_name_the_cp_event(quantity in 1u16..=127, shortfall in 1usize..=254) {
        // A byte count below 2 x quantity is 0E 54h, above it 0E 55h.
        let request = Request::ReadHoldingRegisters { address: 0, quantity };
        let needed = 2 * usize::from(quantity);
        let byte_count = needed.saturating_sub(shortfall);
        let mut pdu = vec![0x03, u8::try_from(byte_count).unwrap()];
        pdu.extend(vec![0; byte_count]);
        let result = Response::decode_for(&request, &pdu);
        prop_assert!(matches!(result, Err(PduError::ByteCountTooSmall { .. })), "{result:?}");
        let byte_count = (needed + shortfall).min(255);
        if byte_count > needed {
            let mut pdu = vec![0x03, u8::try_from(byte_count).unwrap()];
            pdu.extend(vec![0; byte_count]);
            let result = Response::decode_for(&request, &pdu);
            prop_assert!(matches!(result, Err(PduError::ByteCountMismatch { .. })), "{result:?}");
        }
    }
}

#[test]
fn quantity_lies_give_the_right_errors() {
    // FC15 claiming 1969 coils in 6 bytes.
    let pdu = [0x0F, 0x00, 0x00, 0x07, 0xB1, 0x06, 0, 0, 0, 0, 0, 0];
    assert_eq!(
        Request::decode(&pdu),
        Err(PduError::QuantityOutOfRange {
            function: 0x0F,
            quantity: 1969,
            min: 1,
            max: 1968
        })
    );
    // FC16 with 2 registers and a byte count of 5.
    let pdu = [0x10, 0x00, 0x00, 0x00, 0x02, 0x05, 0, 1, 0, 2, 0];
    assert_eq!(
        Request::decode(&pdu),
        Err(PduError::ByteCountMismatch {
            function: 0x10,
            byte_count: 5,
            expected: 4
        })
    );
    // FC03 quantity 0 and 126.
    for quantity in [0u16, 126] {
        let pdu = Request::ReadHoldingRegisters {
            address: 0,
            quantity,
        }
        .to_bytes();
        let error = Request::decode(&pdu).unwrap_err();
        assert_eq!(
            error,
            PduError::QuantityOutOfRange {
                function: 3,
                quantity,
                min: 1,
                max: 125
            }
        );
        assert_eq!(
            ExceptionResponse::for_error(3, &error).code,
            ExceptionCode::IllegalDataValue
        );
    }
}
