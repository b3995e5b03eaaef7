//! Tag types and byte orders: encode then decode is the identity for every type and order, and
//! known frames from device manuals are checked byte for byte.

use proptest::prelude::*;
use proto_core::profiles::ksvario::{Address, Format};
use proto_core::profiles::{
    BitUpdate, ByteOrder, CharOrder, DataType, DeviceProfile, EncodeError, Quality, Table, Tag,
    Value,
};

const ORDERS: [ByteOrder; 4] = [
    ByteOrder::Abcd,
    ByteOrder::Cdab,
    ByteOrder::Badc,
    ByteOrder::Dcba,
];

fn generic(tag: Tag) -> (DeviceProfile, Tag) {
    (DeviceProfile::generic("dev", 1, vec![tag.clone()]), tag)
}

/// Encodes `value` to a writable holding tag of `data_type` and decodes the words again.
fn roundtrip(data_type: DataType, value: &Value) -> (Vec<u16>, Value) {
    let (profile, tag) = generic(Tag::holding("t", 0, data_type).writable());
    let words = profile
        .encode_value(&tag, value)
        .unwrap_or_else(|e| panic!("{value:?} on {data_type:?}: {e}"));
    assert_eq!(words.len(), usize::from(data_type.words()));
    let (decoded, quality) = profile.decode(&tag, &words);
    assert_eq!(quality, Quality::Good);
    (words, decoded)
}

fn order() -> impl Strategy<Value = ByteOrder> {
    prop::sample::select(ORDERS.to_vec())
}

proptest! {
    #[test]
    fn u16_and_i16_roundtrip(u in any::<u16>(), i in any::<i16>()) {
        prop_assert_eq!(roundtrip(DataType::U16, &Value::Int(i64::from(u))).1, Value::Int(i64::from(u)));
        prop_assert_eq!(roundtrip(DataType::I16, &Value::Int(i64::from(i))).1, Value::Int(i64::from(i)));
    }

    #[test]
    fn thirty_two_bit_types_roundtrip(o in order(), u in any::<u32>(), i in any::<i32>(), f in any::<f32>()) {
        prop_assert_eq!(roundtrip(DataType::U32(o), &Value::Int(i64::from(u))).1, Value::Int(i64::from(u)));
        prop_assert_eq!(roundtrip(DataType::I32(o), &Value::Int(i64::from(i))).1, Value::Int(i64::from(i)));
        if f.is_finite() {
            // An f32 reads in its own shortest form (0.95, not 0.949999988079071), which writes
            // back to the same register bits.
            let (words, decoded) = roundtrip(DataType::F32(o), &Value::Float(f64::from(f)));
            let shortest: f64 = f.to_string().parse().unwrap();
            prop_assert_eq!(&decoded, &Value::Float(shortest));
            prop_assert_eq!(roundtrip(DataType::F32(o), &decoded).0, words);
        }
    }

    #[test]
    fn sixty_four_bit_types_roundtrip(o in order(), u in any::<u64>(), i in any::<i64>(), f in any::<f64>()) {
        prop_assert_eq!(roundtrip(DataType::U64(o), &Value::UInt(u)).1, Value::UInt(u));
        prop_assert_eq!(roundtrip(DataType::I64(o), &Value::Int(i)).1, Value::Int(i));
        if f.is_finite() {
            prop_assert_eq!(roundtrip(DataType::F64(o), &Value::Float(f)).1, Value::Float(f));
        }
    }

    #[test]
    fn words_roundtrip_through_every_order(o in order(), words in prop::array::uniform4(any::<u16>())) {
        // The layout itself is invertible: bytes -> registers -> bytes.
        let bytes = o.bytes(&words);
        prop_assert_eq!(o.registers(&bytes), words.to_vec());
    }

    #[test]
    fn strings_roundtrip(text in "[ -~]{0,10}", registers in 5u16..8, low in any::<bool>()) {
        let order = if low { CharOrder::LowFirst } else { CharOrder::HighFirst };
        let data_type = DataType::String { registers, order };
        let (words, decoded) = roundtrip(data_type, &Value::Text(text.clone()));
        prop_assert_eq!(words.len(), usize::from(registers));
        // Trailing spaces are trimmed on read, like the NUL padding.
        prop_assert_eq!(decoded, Value::Text(text.trim_end_matches(' ').to_owned()));
    }

    #[test]
    fn scaled_values_with_offset_roundtrip(raw in any::<i16>(), o in order()) {
        // value = raw x 0.5 + 100
        let (profile, tag) = generic(
            Tag::holding("t", 0, DataType::I32(o)).writable().scale(0.5).offset(100.0),
        );
        let value = f64::from(raw) * 0.5 + 100.0;
        let words = profile.encode(&tag, value).unwrap();
        prop_assert_eq!(profile.decode(&tag, &words).0, Value::Float(value));
    }

    #[test]
    fn bit_updates_change_only_their_bit(current in any::<u16>(), bit in 0u8..16, on in any::<bool>()) {
        let (profile, tag) = generic(Tag::holding("b", 7, DataType::Bit(bit)).writable());
        let update = profile.bit_update(&tag, &Value::Bool(on)).unwrap().unwrap();
        let next = update.apply(current);
        let mask = 1u16 << bit;
        prop_assert_eq!(next & !mask, current & !mask);
        prop_assert_eq!(next & mask != 0, on);
        prop_assert_eq!(profile.decode(&tag, &[next]).0, Value::Bool(on));
    }
}

/// Known frames, byte for byte: the registers as they appear in the PDU, high byte first.
fn pdu_bytes(words: &[u16]) -> Vec<u8> {
    words.iter().flat_map(|w| w.to_be_bytes()).collect()
}

#[test]
fn ksvario_float_at_twice_the_address_plus_8000h_is_big_endian() {
    // 001 4.5: the float of integer address 3415 is at 2 x 3415 + 8000h = 9AAEh, in the
    // "Motorola format": 222.0 = 435E0000h, high word first.
    assert_eq!(Address::new(Format::Float, 3415).encode(), Ok(0x9AAE));
    let (profile, tag) =
        generic(Tag::holding("sp", 0x9AAE, DataType::F32(ByteOrder::Abcd)).writable());
    let words = profile.encode_value(&tag, &Value::Float(222.0)).unwrap();
    assert_eq!(pdu_bytes(&words), [0x43, 0x5E, 0x00, 0x00]);
    assert_eq!(
        profile.decode(&tag, &[0x435E, 0x0000]).0,
        Value::Float(222.0)
    );
}

#[test]
fn cdab_float_puts_the_low_word_first() {
    // 123.456f32 = 42F6E979h; CDAB (word swapped) sends E9 79 42 F6.
    let (profile, tag) = generic(Tag::holding("f", 0, DataType::F32(ByteOrder::Cdab)).writable());
    let words = profile
        .encode_value(&tag, &Value::Float(f64::from(123.456f32)))
        .unwrap();
    assert_eq!(pdu_bytes(&words), [0xE9, 0x79, 0x42, 0xF6]);
    // BADC swaps the bytes inside each register: F6 42 79 E9; DCBA is little endian.
    let (p2, t2) = generic(Tag::holding("f", 0, DataType::F32(ByteOrder::Badc)).writable());
    assert_eq!(
        pdu_bytes(
            &p2.encode_value(&t2, &Value::Float(f64::from(123.456f32)))
                .unwrap()
        ),
        [0xF6, 0x42, 0x79, 0xE9]
    );
    let (p3, t3) = generic(Tag::holding("f", 0, DataType::F32(ByteOrder::Dcba)).writable());
    assert_eq!(
        pdu_bytes(
            &p3.encode_value(&t3, &Value::Float(f64::from(123.456f32)))
                .unwrap()
        ),
        [0x79, 0xE9, 0xF6, 0x42]
    );
}

#[test]
fn dcba_u64_is_little_endian_and_exact_above_i64_max() {
    let value = 0x0123_4567_89AB_CDEFu64;
    let (profile, tag) = generic(Tag::holding("n", 0, DataType::U64(ByteOrder::Dcba)).writable());
    let words = profile.encode_value(&tag, &Value::UInt(value)).unwrap();
    assert_eq!(
        pdu_bytes(&words),
        [0xEF, 0xCD, 0xAB, 0x89, 0x67, 0x45, 0x23, 0x01]
    );
    assert_eq!(profile.decode(&tag, &words).0, Value::UInt(value));
    // GHEFCDAB (`Cdab` for 64 bits): the registers reversed, each big endian.
    let (p2, t2) = generic(Tag::holding("n", 0, DataType::U64(ByteOrder::Cdab)).writable());
    assert_eq!(
        pdu_bytes(&p2.encode_value(&t2, &Value::UInt(value)).unwrap()),
        [0xCD, 0xEF, 0x89, 0xAB, 0x45, 0x67, 0x01, 0x23]
    );
    // u64::MAX is written and read exactly (no detour through f64).
    let words = profile.encode_value(&tag, &Value::UInt(u64::MAX)).unwrap();
    assert_eq!(words, [0xFFFF; 4]);
    assert_eq!(profile.decode(&tag, &words).0, Value::UInt(u64::MAX));
    // A negative number does not fit.
    assert!(matches!(
        profile.encode_value(&tag, &Value::Int(-1)),
        Err(EncodeError::OutOfRange { .. })
    ));
}

#[test]
fn a_string_is_two_characters_a_register_padded_with_nul() {
    let data_type = DataType::String {
        registers: 4,
        order: CharOrder::HighFirst,
    };
    let (profile, tag) = generic(Tag::holding("sn", 0, data_type).writable());
    let words = profile
        .encode_value(&tag, &Value::Text("SN-42".into()))
        .unwrap();
    assert_eq!(pdu_bytes(&words), *b"SN-42\0\0\0");
    // Trailing NUL and space are trimmed, inner spaces kept.
    assert_eq!(
        profile.decode(&tag, &[0x4120, 0x4220, 0x2020, 0x0000]).0,
        Value::Text("A B".into())
    );
    // Low byte first: "AB" is 4241h.
    let (p2, t2) = generic(
        Tag::holding(
            "sn",
            0,
            DataType::String {
                registers: 1,
                order: CharOrder::LowFirst,
            },
        )
        .writable(),
    );
    assert_eq!(
        p2.encode_value(&t2, &Value::Text("AB".into())),
        Ok(vec![0x4241])
    );
    assert_eq!(p2.decode(&t2, &[0x4241]).0, Value::Text("AB".into()));
    // Too long, not ASCII, or a number: refused.
    assert!(matches!(
        profile.encode_value(&tag, &Value::Text("123456789".into())),
        Err(EncodeError::TextTooLong { len: 9, max: 8, .. })
    ));
    assert!(matches!(
        profile.encode_value(&tag, &Value::Text("é".into())),
        Err(EncodeError::TextTooLong { .. })
    ));
    assert!(matches!(
        profile.encode_value(&tag, &Value::Int(5)),
        Err(EncodeError::WrongKind { .. })
    ));
}

#[test]
fn a_bit_of_a_register_reads_as_a_bool_and_writes_as_a_mask() {
    let (profile, tag) =
        generic(Tag::new("run", Table::HoldingRegisters, 3, DataType::Bit(5)).writable());
    assert_eq!(profile.decode(&tag, &[0x0020]).0, Value::Bool(true));
    assert_eq!(profile.decode(&tag, &[0xFFDF]).0, Value::Bool(false));
    assert_eq!(
        profile.bit_update(&tag, &Value::Bool(true)),
        Some(Ok(BitUpdate {
            address: 3,
            and: 0xFFDF,
            or: 0x0020
        }))
    );
    assert_eq!(
        profile
            .bit_update(&tag, &Value::Int(0))
            .unwrap()
            .unwrap()
            .apply(0xFFFF),
        0xFFDF
    );
    assert!(matches!(
        profile.bit_update(&tag, &Value::Int(2)),
        Some(Err(EncodeError::OutOfRange { .. }))
    ));
    // A bit tag is not written as a whole register.
    assert!(profile.encode_value(&tag, &Value::Bool(true)).is_err());
}

#[test]
fn scale_and_offset_are_reversed_on_write_and_range_checked() {
    // A temperature in 0.1 K steps from -273.15 degC: value = raw x 0.1 - 273.15.
    let (profile, tag) = generic(
        Tag::holding("t", 0, DataType::U16)
            .writable()
            .scale(0.1)
            .offset(-273.15),
    );
    let (value, _) = profile.decode(&tag, &[2931]);
    assert!((value.as_f64() - 19.95).abs() < 1e-9, "{value:?}");
    assert_eq!(profile.encode(&tag, 19.95), Ok(vec![2931]));
    // Below raw 0 is out of range, with the range in engineering units.
    match profile.encode(&tag, -300.0) {
        Err(EncodeError::OutOfRange { min, max, .. }) => {
            assert!(
                (min + 273.15).abs() < 1e-9 && (max - 6280.35).abs() < 1e-6,
                "{min} {max}"
            );
        }
        other => panic!("{other:?}"),
    }
}
