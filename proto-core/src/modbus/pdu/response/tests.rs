use super::*;

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

#[test]
fn decodes_against_the_request_and_reencodes() {
    let coils = vec![
        true, false, true, true, false, false, true, true, true, false,
    ];
    let cases = [
        (
            Request::ReadCoils {
                address: 0x13,
                quantity: 10,
            },
            "01 02 CD 01",
            Response::ReadCoils(coils.clone()),
        ),
        (
            Request::ReadDiscreteInputs {
                address: 0,
                quantity: 10,
            },
            "02 02 CD 01",
            Response::ReadDiscreteInputs(coils),
        ),
        (
            Request::ReadHoldingRegisters {
                address: 0x0C1E,
                quantity: 4,
            },
            "03 08 00 28 02 58 01 F4 00 00",
            Response::ReadHoldingRegisters(vec![40, 600, 500, 0]),
        ),
        (
            Request::ReadInputRegisters {
                address: 1004,
                quantity: 3,
            },
            "04 06 04 2A 00 8C 10 3E",
            Response::ReadInputRegisters(vec![1066, 140, 4158]),
        ),
        (
            Request::WriteSingleCoil {
                address: 0xAC,
                value: true,
            },
            "05 00 AC FF 00",
            Response::WriteSingleCoil {
                address: 0xAC,
                value: true,
            },
        ),
        (
            Request::WriteSingleRegister {
                address: 0x2329,
                value: 13,
            },
            "06 23 29 00 0D",
            Response::WriteSingleRegister {
                address: 0x2329,
                value: 13,
            },
        ),
        (
            Request::ReadExceptionStatus,
            "07 6D",
            Response::ReadExceptionStatus(0x6D),
        ),
        (
            Request::Diagnostics {
                sub_function: 0,
                data: vec![0x31, 0x32],
            },
            "08 00 00 31 32",
            Response::Diagnostics {
                sub_function: 0,
                data: vec![0x31, 0x32],
            },
        ),
        (
            Request::Diagnostics {
                sub_function: 0x0E,
                data: vec![0, 0],
            },
            "08 00 0E 01 2C",
            Response::Diagnostics {
                sub_function: 0x0E,
                data: vec![0x01, 0x2C],
            },
        ),
        (
            Request::GetCommEventCounter,
            "0B FF FF 01 08",
            Response::GetCommEventCounter {
                status: 0xFFFF,
                event_count: 0x108,
            },
        ),
        (
            Request::GetCommEventLog,
            "0C 08 00 00 01 08 01 21 20 00",
            Response::GetCommEventLog {
                status: 0,
                event_count: 0x108,
                message_count: 0x121,
                events: vec![0x20, 0x00],
            },
        ),
        (
            Request::WriteMultipleCoils {
                address: 0x13,
                values: vec![true; 10],
            },
            "0F 00 13 00 0A",
            Response::WriteMultipleCoils {
                address: 0x13,
                quantity: 10,
            },
        ),
        (
            Request::WriteMultipleRegisters {
                address: 0x2329,
                values: vec![20, 30],
            },
            "10 23 29 00 02",
            Response::WriteMultipleRegisters {
                address: 0x2329,
                quantity: 2,
            },
        ),
        (
            Request::ReportServerId,
            "11 03 2A FF 01",
            Response::ReportServerId(vec![0x2A, 0xFF, 0x01]),
        ),
        (
            Request::ReadWriteMultipleRegisters {
                read_address: 0,
                read_quantity: 2,
                write_address: 0,
                values: vec![1],
            },
            "17 04 00 07 13 88",
            Response::ReadWriteMultipleRegisters(vec![7, 5000]),
        ),
        (
            Request::ReadDeviceIdentification {
                read_code: 1,
                object_id: 0,
            },
            "2B 0E 01 02 00 00 02 00 02 41 42 01 00",
            Response::ReadDeviceIdentification {
                read_code: 1,
                conformity_level: 2,
                more_follows: false,
                next_object_id: 0,
                objects: vec![(0, b"AB".to_vec()), (1, vec![])],
            },
        ),
    ];
    for (request, bytes, response) in cases {
        assert_eq!(
            Response::decode_for(&request, &hex(bytes)),
            Ok(Ok(response.clone())),
            "{bytes}"
        );
        assert_eq!(response.to_bytes(), hex(bytes), "{bytes}");
        assert_eq!(response.function(), request.function());
    }
}

#[test]
fn coils_are_cut_to_the_requested_quantity() {
    let request = Request::ReadCoils {
        address: 0,
        quantity: 3,
    };
    assert_eq!(
        Response::decode_for(&request, &[0x01, 0x01, 0xFF]),
        Ok(Ok(Response::ReadCoils(vec![true; 3])))
    );
}

#[test]
fn cp_master_sizes_are_accepted() {
    let request = Request::ReadHoldingRegisters {
        address: 0,
        quantity: 127,
    };
    let response = Response::ReadHoldingRegisters((0..127).collect());
    let pdu = response.to_bytes();
    assert_eq!(pdu.get(1), Some(&254));
    assert_eq!(Response::decode_for(&request, &pdu), Ok(Ok(response)));
    let request = Request::ReadCoils {
        address: 0,
        quantity: 2040,
    };
    let response = Response::ReadCoils(vec![true; 2040]);
    let pdu = response.to_bytes();
    assert_eq!(pdu.get(1), Some(&255));
    assert_eq!(Response::decode_for(&request, &pdu), Ok(Ok(response)));
}

#[test]
fn mismatches_have_their_own_errors() {
    let read = Request::ReadHoldingRegisters {
        address: 0,
        quantity: 2,
    };
    // 0E 51h
    assert_eq!(
        Response::decode_for(&read, &hex("04 04 00 01 00 02")),
        Err(PduError::FunctionMismatch {
            expected: 3,
            got: 4
        })
    );
    assert_eq!(
        Response::decode_for(&read, &hex("84 02")),
        Err(PduError::FunctionMismatch {
            expected: 3,
            got: 0x84
        })
    );
    // 0E 52h
    assert_eq!(
        Response::decode_for(&read, &hex("03 04 00 01 00")),
        Err(PduError::TooShort {
            function: 3,
            needed: 6,
            have: 5
        })
    );
    assert_eq!(
        Response::decode_for(&read, &hex("03")),
        Err(PduError::TooShort {
            function: 3,
            needed: 2,
            have: 1
        })
    );
    // 0E 53h
    assert_eq!(
        Response::decode_for(&read, &hex("03 04 00 01 00 02 00")),
        Err(PduError::TrailingData {
            function: 3,
            extra: 1
        })
    );
    // 0E 54h
    assert_eq!(
        Response::decode_for(&read, &hex("03 02 00 01")),
        Err(PduError::ByteCountTooSmall {
            function: 3,
            byte_count: 2,
            expected: 4
        })
    );
    // 0E 55h
    assert_eq!(
        Response::decode_for(&read, &hex("03 06 00 01 00 02 00 03")),
        Err(PduError::ByteCountMismatch {
            function: 3,
            byte_count: 6,
            expected: 4
        })
    );
    // 0E 56h
    let write = Request::WriteMultipleRegisters {
        address: 0x2329,
        values: vec![20, 30],
    };
    assert_eq!(
        Response::decode_for(&write, &hex("10 23 29 00 03")),
        Err(PduError::EchoMismatch {
            function: 16,
            field: "quantity",
            expected: 2,
            got: 3
        })
    );
    assert_eq!(
        Response::decode_for(&write, &hex("10 23 2A 00 02")),
        Err(PduError::EchoMismatch {
            function: 16,
            field: "address",
            expected: 0x2329,
            got: 0x232A
        })
    );
    let coil = Request::WriteSingleCoil {
        address: 1,
        value: false,
    };
    assert_eq!(
        Response::decode_for(&coil, &hex("05 00 01 FF 00")),
        Err(PduError::EchoMismatch {
            function: 5,
            field: "value",
            expected: 0,
            got: 0xFF00
        })
    );
    let echo = Request::Diagnostics {
        sub_function: 0,
        data: vec![0x31, 0x32],
    };
    assert_eq!(
        Response::decode_for(&echo, &hex("08 00 00 31 33")),
        Err(PduError::EchoMismatch {
            function: 8,
            field: "data",
            expected: 0x32,
            got: 0x33
        })
    );
    assert_eq!(
        Response::decode_for(&echo, &hex("08 00 01 31 32")),
        Err(PduError::EchoMismatch {
            function: 8,
            field: "sub_function",
            expected: 0,
            got: 1
        })
    );
    assert_eq!(
        Response::decode_for(&echo, &hex("08 00 00 31")),
        Err(PduError::TooShort {
            function: 8,
            needed: 5,
            have: 4
        })
    );
    assert_eq!(Response::decode_for(&read, &[]), Err(PduError::Empty));
    assert_eq!(
        Response::decode_for(&Request::GetCommEventLog, &hex("0C 05 00 00 00 00 00")),
        Err(PduError::ByteCountTooSmall {
            function: 12,
            byte_count: 5,
            expected: 6
        })
    );
    let id = Request::ReadDeviceIdentification {
        read_code: 1,
        object_id: 0,
    };
    assert_eq!(
        Response::decode_for(&id, &hex("2B 0E 01 02 12 00 00")),
        Err(PduError::IllegalValue {
            function: 0x2B,
            field: "more_follows",
            value: 0x12
        })
    );
    assert_eq!(
        Response::decode_for(&id, &hex("2B 0E 02 02 00 00 00")),
        Err(PduError::EchoMismatch {
            function: 0x2B,
            field: "read_device_id_code",
            expected: 1,
            got: 2
        })
    );
    assert_eq!(
        Response::decode_for(&id, &hex("2B 0E 01 02 00 00 01 00 05 41")),
        Err(PduError::TooShort {
            function: 0x2B,
            needed: 14,
            have: 10
        })
    );
}

#[test]
fn exception_responses() {
    let read = Request::ReadHoldingRegisters {
        address: 0x20D0,
        quantity: 3,
    };
    let exception = ExceptionResponse {
        function: FunctionCode(3),
        code: ExceptionCode::IllegalDataAddress,
    };
    assert_eq!(
        Response::decode_for(&read, &hex("83 02")),
        Ok(Err(exception))
    );
    assert_eq!(
        Response::decode_for(&read, &hex("83")),
        Err(PduError::TooShort {
            function: 0x83,
            needed: 2,
            have: 1
        })
    );
    assert_eq!(
        Response::decode_for(&read, &hex("83 02 00")),
        Err(PduError::TrailingData {
            function: 0x83,
            extra: 1
        })
    );
    let id = Request::ReadDeviceIdentification {
        read_code: 1,
        object_id: 0,
    };
    let id_exception = ExceptionResponse {
        function: FunctionCode(0x2B),
        code: ExceptionCode::IllegalFunction,
    };
    assert_eq!(
        Response::decode_for(&id, &hex("AB 01")),
        Ok(Err(id_exception))
    );
    // The Altivar's form with the MEI type (002).
    assert_eq!(
        Response::decode_for(&id, &hex("AB 0E 01")),
        Ok(Err(id_exception))
    );
}
