use super::*;

#[test]
fn exception_codes_roundtrip() {
    for code in 0..=255u8 {
        assert_eq!(u8::from(ExceptionCode::from(code)), code);
    }
    assert_eq!(
        ExceptionCode::from(0x0B),
        ExceptionCode::GatewayTargetFailedToRespond
    );
    assert_eq!(ExceptionCode::from(0x09), ExceptionCode::Other(0x09));
    assert_eq!(
        ExceptionCode::IllegalDataAddress.to_string(),
        "02h (illegal data address)"
    );
}

#[test]
fn errors_map_to_the_exception_a_server_answers() {
    let cases = [
        (
            PduError::UnsupportedFunction(0x41),
            ExceptionCode::IllegalFunction,
        ),
        (
            PduError::UnsupportedMeiType(0x0D),
            ExceptionCode::IllegalFunction,
        ),
        (
            PduError::QuantityOutOfRange {
                function: 3,
                quantity: 0,
                min: 1,
                max: 125,
            },
            ExceptionCode::IllegalDataValue,
        ),
        (
            PduError::ByteCountMismatch {
                function: 16,
                byte_count: 3,
                expected: 4,
            },
            ExceptionCode::IllegalDataValue,
        ),
        (
            PduError::IllegalValue {
                function: 5,
                field: "value",
                value: 0x1234,
            },
            ExceptionCode::IllegalDataValue,
        ),
        (
            PduError::TooShort {
                function: 3,
                needed: 5,
                have: 3,
            },
            ExceptionCode::IllegalDataValue,
        ),
        (
            PduError::TrailingData {
                function: 3,
                extra: 1,
            },
            ExceptionCode::IllegalDataValue,
        ),
        (PduError::Empty, ExceptionCode::IllegalDataValue),
        (
            PduError::AddressOutOfRange {
                function: 3,
                address: 0xFFFF,
                quantity: 2,
            },
            ExceptionCode::IllegalDataAddress,
        ),
        (
            PduError::FunctionMismatch {
                expected: 3,
                got: 4,
            },
            ExceptionCode::ServerDeviceFailure,
        ),
    ];
    for (error, code) in cases {
        assert_eq!(ExceptionCode::from(&error), code, "{error}");
    }
    let answer = ExceptionResponse::for_error(0x41, &PduError::UnsupportedFunction(0x41));
    let mut out = Vec::new();
    answer.encode(&mut out);
    assert_eq!(out, [0xC1, 0x01]);
    assert_eq!(ExceptionResponse::decode(&out), Ok(answer));
    assert_eq!(
        ExceptionResponse::decode(&[0x03, 0x02]),
        Err(PduError::FunctionMismatch {
            expected: 0x83,
            got: 0x03
        })
    );
}

#[test]
fn function_codes() {
    assert!(FunctionCode::WRITE_MULTIPLE_REGISTERS.is_write());
    assert!(!FunctionCode::READ_HOLDING_REGISTERS.is_write());
    assert_eq!(FunctionCode::READ_HOLDING_REGISTERS.to_exception(), 0x83);
    assert!(FunctionCode(0x83).is_exception());
    assert!(FunctionCode(0x2B).is_supported());
    assert!(!FunctionCode(0x14).is_supported());
    assert_eq!(
        FunctionCode(0x17).to_string(),
        "17h (read/write multiple registers)"
    );
    assert_eq!(FunctionCode(0x64).to_string(), "64h");
    assert!(diag::is_known(0x42) && diag::is_known(0x12) && !diag::is_known(0x03));
}
