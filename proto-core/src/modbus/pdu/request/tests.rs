use super::*;
use crate::modbus::pdu::ExceptionCode;

fn decode_hex(hex: &str) -> Result<Request, PduError> {
    let bytes: Vec<u8> = hex
        .split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect();
    Request::decode(&bytes)
}

#[test]
fn decodes_and_reencodes_every_function() {
    let cases = [
        (
            "01 00 13 00 13",
            Request::ReadCoils {
                address: 0x13,
                quantity: 0x13,
            },
        ),
        (
            "02 00 C4 00 16",
            Request::ReadDiscreteInputs {
                address: 0xC4,
                quantity: 0x16,
            },
        ),
        (
            "03 0C 1E 00 04",
            Request::ReadHoldingRegisters {
                address: 0x0C1E,
                quantity: 4,
            },
        ),
        (
            "04 03 EC 00 03",
            Request::ReadInputRegisters {
                address: 1004,
                quantity: 3,
            },
        ),
        (
            "05 00 AC FF 00",
            Request::WriteSingleCoil {
                address: 0xAC,
                value: true,
            },
        ),
        (
            "05 00 AC 00 00",
            Request::WriteSingleCoil {
                address: 0xAC,
                value: false,
            },
        ),
        (
            "06 23 29 00 0D",
            Request::WriteSingleRegister {
                address: 0x2329,
                value: 13,
            },
        ),
        ("07", Request::ReadExceptionStatus),
        (
            "08 00 00 31 32",
            Request::Diagnostics {
                sub_function: 0,
                data: vec![0x31, 0x32],
            },
        ),
        (
            "08 00 00",
            Request::Diagnostics {
                sub_function: 0,
                data: vec![],
            },
        ),
        (
            "08 00 0B 00 00",
            Request::Diagnostics {
                sub_function: 0x0B,
                data: vec![0, 0],
            },
        ),
        ("0B", Request::GetCommEventCounter),
        ("0C", Request::GetCommEventLog),
        (
            "0F 00 13 00 0A 02 CD 01",
            Request::WriteMultipleCoils {
                address: 0x13,
                values: vec![
                    true, false, true, true, false, false, true, true, true, false,
                ],
            },
        ),
        (
            "10 23 29 00 02 04 00 14 00 1E",
            Request::WriteMultipleRegisters {
                address: 0x2329,
                values: vec![20, 30],
            },
        ),
        ("11", Request::ReportServerId),
        (
            "17 31 C5 00 08 31 D9 00 06 0C 00 0F 13 88 1F 40 01 F4 04 B0 02 58",
            Request::ReadWriteMultipleRegisters {
                read_address: 0x31C5,
                read_quantity: 8,
                write_address: 0x31D9,
                values: vec![15, 5000, 8000, 500, 1200, 600],
            },
        ),
        (
            "2B 0E 01 00",
            Request::ReadDeviceIdentification {
                read_code: 1,
                object_id: 0,
            },
        ),
    ];
    for (hex, request) in cases {
        assert_eq!(decode_hex(hex).as_ref(), Ok(&request), "{hex}");
        let encoded: Vec<String> = request
            .to_bytes()
            .iter()
            .map(|b| format!("{b:02X}"))
            .collect();
        assert_eq!(encoded.join(" "), hex);
        assert_eq!(request.validate(&Limits::SPEC), Ok(()), "{hex}");
    }
}

#[test]
fn quantity_limits_of_the_spec() {
    let q = |f, quantity, max| {
        Err(PduError::QuantityOutOfRange {
            function: f,
            quantity,
            min: 1,
            max,
        })
    };
    assert_eq!(decode_hex("03 00 00 00 00"), q(3, 0, 125));
    assert_eq!(decode_hex("03 00 00 00 7E"), q(3, 126, 125));
    assert!(decode_hex("03 00 00 00 7D").is_ok());
    assert_eq!(decode_hex("04 00 00 00 7E"), q(4, 126, 125));
    assert_eq!(decode_hex("01 00 00 07 D1"), q(1, 2001, 2000));
    assert!(decode_hex("02 00 00 07 D0").is_ok());
    // FC15 claiming 1969 coils in 6 bytes: the quantity is reported, not the byte count.
    assert_eq!(
        decode_hex("0F 00 00 07 B1 06 00 00 00 00 00 00"),
        q(15, 1969, 1968)
    );
    assert_eq!(decode_hex("10 00 00 00 7C F8"), q(16, 124, 123));
    assert_eq!(
        decode_hex("17 00 00 00 7E 00 00 00 01 02 00 00"),
        q(0x17, 126, 125)
    );
    assert_eq!(
        decode_hex("17 00 00 00 01 00 00 00 7A F4"),
        q(0x17, 122, 121)
    );
}

#[test]
fn byte_counts_values_and_lengths() {
    assert_eq!(
        decode_hex("10 00 00 00 02 03 00 01 00"),
        Err(PduError::ByteCountMismatch {
            function: 16,
            byte_count: 3,
            expected: 4
        })
    );
    assert_eq!(
        decode_hex("0F 00 00 00 0A 01 FF"),
        Err(PduError::ByteCountMismatch {
            function: 15,
            byte_count: 1,
            expected: 2
        })
    );
    assert_eq!(
        decode_hex("10 00 00 00 02 04 00 01 00"),
        Err(PduError::TooShort {
            function: 16,
            needed: 10,
            have: 9
        })
    );
    assert_eq!(
        decode_hex("03 00 00 00 01 00"),
        Err(PduError::TrailingData {
            function: 3,
            extra: 1
        })
    );
    assert_eq!(
        decode_hex("03 00 00"),
        Err(PduError::TooShort {
            function: 3,
            needed: 5,
            have: 3
        })
    );
    assert_eq!(decode_hex(""), Err(PduError::Empty));
    assert_eq!(
        decode_hex("05 00 00 12 34"),
        Err(PduError::IllegalValue {
            function: 5,
            field: "value",
            value: 0x1234
        })
    );
    assert_eq!(
        decode_hex("08 00 0B 00"),
        Err(PduError::TooShort {
            function: 8,
            needed: 5,
            have: 4
        })
    );
    assert_eq!(
        decode_hex("08 00 0B 00 00 00"),
        Err(PduError::TrailingData {
            function: 8,
            extra: 1
        })
    );
    assert_eq!(
        decode_hex("2B 0D 01 00"),
        Err(PduError::UnsupportedMeiType(0x0D))
    );
    assert_eq!(
        decode_hex("2B 0E 05 00"),
        Err(PduError::IllegalValue {
            function: 0x2B,
            field: "read_device_id_code",
            value: 5
        })
    );
    assert_eq!(
        decode_hex("41 00"),
        Err(PduError::UnsupportedFunction(0x41))
    );
    assert_eq!(
        decode_hex("83 00"),
        Err(PduError::UnsupportedFunction(0x83))
    );
}

#[test]
fn address_checked_after_quantity() {
    assert_eq!(
        decode_hex("03 FF FF 00 02"),
        Err(PduError::AddressOutOfRange {
            function: 3,
            address: 0xFFFF,
            quantity: 2
        })
    );
    assert!(decode_hex("03 FF FF 00 01").is_ok());
    // Quantity 0 at the top of the address space: the quantity wins (libmodbus order).
    assert!(matches!(
        decode_hex("03 FF FF 00 00"),
        Err(PduError::QuantityOutOfRange { .. })
    ));
    let e = decode_hex("10 FF FF 00 02 04 00 01 00 02").unwrap_err();
    assert_eq!(ExceptionCode::from(&e), ExceptionCode::IllegalDataAddress);
}

#[test]
fn cp_limits() {
    let read = Request::ReadHoldingRegisters {
        address: 0,
        quantity: 127,
    };
    assert_eq!(read.validate(&Limits::CP_MASTER_RTU), Ok(()));
    assert!(read.validate(&Limits::CP_MASTER_ASCII).is_err());
    assert!(read.validate(&Limits::SPEC).is_err());
    let coils = Request::WriteMultipleCoils {
        address: 0,
        values: vec![true; 2040],
    };
    assert_eq!(coils.validate(&Limits::CP_MASTER_RTU), Ok(()));
    assert!(coils.validate(&Limits::CP_MASTER_ASCII).is_err());
    let pdu = coils.to_bytes();
    assert_eq!(pdu.len(), 6 + 255);
    assert_eq!(
        Request::decode_with(&pdu, &Limits::CP_MASTER_RTU),
        Ok(coils)
    );
    assert!(Request::WriteMultipleRegisters {
        address: 0,
        values: vec![]
    }
    .validate(&Limits::SPEC)
    .is_err());
    assert!(Request::ReadCoils {
        address: 0,
        quantity: 2041
    }
    .validate(&Limits::CP_MASTER_RTU)
    .is_err());
    assert!(Request::Diagnostics {
        sub_function: 1,
        data: vec![0]
    }
    .validate(&Limits::SPEC)
    .is_err());
    assert!(Request::ReadDeviceIdentification {
        read_code: 0,
        object_id: 0
    }
    .validate(&Limits::SPEC)
    .is_err());
}

#[test]
fn encode_cuts_what_a_byte_count_cannot_describe() {
    let too_many = Request::WriteMultipleRegisters {
        address: 0,
        values: vec![7; 200],
    };
    let pdu = too_many.to_bytes();
    assert_eq!(pdu.get(..6), Some(&[0x10, 0, 0, 0, 127, 254][..]));
    assert_eq!(pdu.len(), 6 + 254);
    assert!(too_many.validate(&Limits::CP_MASTER_RTU).is_err());
    assert!(Request::WriteSingleCoil {
        address: 0,
        value: true
    }
    .is_broadcastable());
    assert!(!Request::ReadExceptionStatus.is_broadcastable());
}

#[test]
fn read_range_of_the_four_reads_only() {
    let read = |fc: u8| decode_hex(&format!("{fc:02X} 00 0A 00 03")).unwrap();
    assert_eq!(read(1).read_range(), Some((Table::Coils, 10, 3)));
    assert_eq!(read(2).read_range(), Some((Table::DiscreteInputs, 10, 3)));
    assert_eq!(read(3).read_range(), Some((Table::HoldingRegisters, 10, 3)));
    assert_eq!(read(4).read_range(), Some((Table::InputRegisters, 10, 3)));
    let write = Request::WriteSingleRegister {
        address: 10,
        value: 3,
    };
    assert_eq!(write.read_range(), None);
    assert_eq!(Request::ReadExceptionStatus.read_range(), None);
}
