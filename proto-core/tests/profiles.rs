//! Device profiles: addressing, limits, decoding of special values, encoding of writes.
//!
//! Facts come from the seed manuals: 001 (KS vario) chapter 4, 002 (Altivar 61/71) "Modbus-Protokoll".

use std::time::Duration;

use proptest::prelude::*;
use proto_core::modbus::pdu::FunctionCode;
use proto_core::profiles::altivar::{self, DriveState};
use proto_core::profiles::ksvario::{self, Address, AddressError, Area, Format};
use proto_core::profiles::{
    ByteOrder, DataType, DeviceProfile, EncodeError, Quality, SpecialValues, Table, Tag, Value,
};

fn f32_words(value: f32) -> [u16; 2] {
    let bits = value.to_bits();
    [(bits >> 16) as u16, bits as u16]
}

// --- KS vario addressing (001 4.1, 4.5) ---

#[test]
fn ksvario_float_address_of_3415_is_9aae() {
    // 001 4.5: "Schreibadresse 2 * 3415 + 8000H" = 9A AE.
    assert_eq!(Address::new(Format::Float, 3415).encode(), Ok(0x9AAE));
    assert_eq!(Address::new(Format::Float, 3416).encode(), Ok(0x9AB0));
    assert_eq!(
        Address::decode(0x9AAE),
        Ok(Address::new(Format::Float, 3415))
    );
}

#[test]
fn ksvario_fix_point_adds_4000h() {
    assert_eq!(Address::new(Format::FixPoint1, 3415).encode(), Ok(0x4D57));
    assert_eq!(
        Address::decode(0x4D57),
        Ok(Address::new(Format::FixPoint1, 3415))
    );
    assert_eq!(
        Address::decode(0x0D57),
        Ok(Address::new(Format::Integer, 3415))
    );
}

#[test]
fn ksvario_mid_float_and_too_large_index_are_errors() {
    assert_eq!(Address::decode(0x9AAF), Err(AddressError::MidFloat(0x9AAF)));
    assert_eq!(
        Address::locate(0x9AAF),
        (Address::new(Format::Float, 3415), true)
    );
    assert_eq!(
        Address::new(Format::Integer, 0x4000).encode(),
        Err(AddressError::IndexTooLarge(0x4000))
    );
}

#[test]
fn ksvario_areas_of_512_words() {
    // 001 4.1 "Modbus-Verzeichnis (Datenformat: Integer)".
    assert_eq!(ksvario::area(0), Area::Device);
    assert_eq!(ksvario::area(511), Area::Device);
    assert_eq!(ksvario::area(512), Area::Visualisation);
    assert_eq!(ksvario::area(1023), Area::Visualisation);
    assert_eq!(ksvario::area(1024), Area::Channel(1));
    assert_eq!(ksvario::area(1536), Area::Channel(2));
    assert_eq!(ksvario::area(15872), Area::Channel(30));
    assert_eq!(ksvario::area(16383), Area::Channel(30));
    // The float directory: 8800 hex is channel 1, FC00 hex channel 30.
    assert_eq!(
        Address::decode(0x8800).map(Address::area),
        Ok(Area::Channel(1))
    );
    assert_eq!(
        Address::decode(0xFC00).map(Address::area),
        Ok(Area::Channel(30))
    );
    assert_eq!(
        Address::decode(0x8400).map(Address::area),
        Ok(Area::Visualisation)
    );
    // 001 4.2.1 / 4.2.2: 0498 hex is ti1 of channel 1, 15990 SetpInterface of channel 30.
    assert_eq!(ksvario::channel_index(1, 152), Some(0x0498));
    assert_eq!(ksvario::channel_index(30, 118), Some(15990));
    assert_eq!(ksvario::channel_index(0, 0), None);
    assert_eq!(ksvario::channel_index(31, 0), None);
    assert_eq!(ksvario::channel_index(1, 512), None);
}

proptest! {
    #[test]
    fn ksvario_addresses_round_trip(index in 0u16..=0x3FFF, format in 0u8..3) {
        let format = [Format::Integer, Format::FixPoint1, Format::Float][usize::from(format)];
        let address = Address::new(format, index);
        let register = address.encode().unwrap();
        prop_assert_eq!(Address::decode(register), Ok(address));
    }

    #[test]
    fn decode_never_panics(words in proptest::collection::vec(any::<u16>(), 0..3)) {
        for profile in [DeviceProfile::altivar71(), DeviceProfile::ksvario()] {
            for tag in &profile.tags {
                let (_, quality) = profile.decode(tag, &words);
                if words.len() < usize::from(tag.words()) {
                    prop_assert_eq!(quality, Quality::CommFailure);
                }
            }
        }
    }
}

// --- limits and functions ---

#[test]
fn altivar_limits_and_functions() {
    // 002 "Modbus-Funktionen": FC03 63 words, FC16 61, FC23 20 / 20.
    let profile = DeviceProfile::altivar71();
    assert_eq!(profile.name, "altivar71");
    assert_eq!(profile.default_address, 2);
    assert_eq!(profile.limits.read_registers, 63);
    assert_eq!(profile.limits.write_registers, 61);
    let rw = profile.limits.read_write.expect("FC23");
    assert_eq!((rw.read, rw.write), (20, 20));
    assert_eq!(profile.limits.max_read(Table::HoldingRegisters), 63);
    for code in [0x03, 0x06, 0x08, 0x10, 0x17, 0x2B] {
        assert!(profile.supports(FunctionCode(code)), "{code:#04x}");
    }
    for code in [0x01, 0x02, 0x04, 0x05, 0x0F] {
        assert!(!profile.supports(FunctionCode(code)), "{code:#04x}");
    }
}

#[test]
fn ksvario_limits_from_the_250_byte_buffer() {
    let profile = DeviceProfile::ksvario();
    assert_eq!(profile.default_address, 17);
    assert_eq!(profile.limits.max_adu_len, 250);
    // A full FC16 request must fit the 250-byte buffer: 9 bytes of frame + 2 per register.
    let max_write = usize::from(profile.limits.write_registers);
    assert!(9 + 2 * max_write <= 250 && 9 + 2 * (max_write + 1) > 250);
    // 001 3.1: "maximal 120 Integer- bzw. 60 Realdaten".
    assert_eq!(profile.limits.read_registers, 120);
    assert_eq!(profile.limits.write_registers, 120);
    assert!(profile.limits.read_write.is_none());
    for code in [0x03, 0x04, 0x06, 0x08, 0x10] {
        assert!(profile.supports(FunctionCode(code)));
    }
    assert!(!profile.supports(FunctionCode(0x17)));
    assert_eq!(ksvario::diag::ALL.len(), 16);
    assert!(ksvario::diag::is_counter(0x42) && !ksvario::diag::is_counter(0x0A));
}

#[test]
fn altivar_keep_alive_refreshes_cmd_inside_the_10_s_timeout() {
    let profile = DeviceProfile::altivar71();
    let keep_alive = profile.keep_alive.clone().expect("keep-alive");
    assert_eq!(keep_alive.tag, "CMD");
    assert_eq!(keep_alive.timeout, Duration::from_secs(10));
    assert!(keep_alive.period < keep_alive.timeout);
    assert!(profile
        .tag("CMD")
        .is_some_and(|t| t.writable && t.address == 8501));
    assert!(DeviceProfile::ksvario().keep_alive.is_none());
}

// --- Altivar tags and decoding ---

#[test]
fn altivar_tags_have_the_manual_addresses() {
    let profile = DeviceProfile::altivar71();
    let expect = [
        ("ETA", 3201),
        ("RFRD", 8604),
        ("LCR", 3204),
        ("OTR", 3205),
        ("ULN", 3207),
        ("THD", 3209),
        ("THR", 9630),
        ("LFT", 7121),
        ("CMD", 8501),
        ("LFRD", 8602),
        ("ACC", 9001),
        ("DEC", 9002),
        ("SFr", 3102),
        ("tFr", 3103),
        ("HSP", 3104),
        ("LSP", 3105),
        ("CHCF", 8401),
        ("COP", 8402),
        ("M1CT", 6011),
        ("M1EC", 6010),
        ("NMA1", 12701),
        ("NCA8", 12728),
        ("NM1", 12741),
        ("NM8", 0x31CC),
        ("NC1", 0x31D9),
        ("NC8", 0x31E0),
    ];
    for (name, address) in expect {
        let tag = profile.tag(name).unwrap_or_else(|| panic!("tag {name}"));
        assert_eq!(tag.address, address, "{name}");
    }
    assert!(!profile.tag("ETA").unwrap().writable);
    assert!(!profile.tag("RFRD").unwrap().writable);
    assert!(profile.tag("LFRD").unwrap().writable);
    assert_eq!(altivar::NMA_DEFAULT[..2], [3201, 8604]);
    assert_eq!(altivar::NCA_DEFAULT[..2], [8501, 8602]);
}

#[test]
fn altivar_8000h_is_not_available() {
    let profile = DeviceProfile::altivar71();
    let chcf = profile.tag("CHCF").unwrap();
    assert_eq!(
        profile.decode(chcf, &[0x8000]),
        (Value::Int(0x8000), Quality::NotDefined)
    );
    assert_eq!(profile.decode(chcf, &[3]), (Value::Int(3), Quality::Good));
    // A signed tag reports the raw number too.
    let otr = profile.tag("OTR").unwrap();
    assert_eq!(
        profile.decode(otr, &[0x8000]),
        (Value::Int(-32768), Quality::NotDefined)
    );
    assert_eq!(
        profile.decode(otr, &[0xFFF6]),
        (Value::Int(-10), Quality::Good)
    );
}

#[test]
fn altivar_scaling() {
    let profile = DeviceProfile::altivar71();
    let decode = |name: &str, raw: u16| profile.decode(profile.tag(name).unwrap(), &[raw]);
    // 002 "Beispiel 1": SFr 16#0028 = 4 kHz, tFr 16#0258 = 60 Hz, HSP 16#01F4 = 50 Hz.
    assert_eq!(decode("SFr", 0x0028), (Value::Float(4.0), Quality::Good));
    assert_eq!(decode("tFr", 0x0258), (Value::Float(60.0), Quality::Good));
    assert_eq!(decode("HSP", 0x01F4), (Value::Float(50.0), Quality::Good));
    assert_eq!(decode("ACC", 13), (Value::Float(1.3), Quality::Good));
    assert_eq!(decode("RFRD", 600), (Value::Int(600), Quality::Good));
    assert_eq!(
        decode("LFRD", (-598i16) as u16),
        (Value::Int(-598), Quality::Good)
    );
}

#[test]
fn altivar_status_word_bits_and_state() {
    // 002: ETA 16#8637 = operation enabled, reverse, speed reached.
    let profile = DeviceProfile::altivar71();
    let eta = profile.tag("ETA").unwrap();
    let field = |name: &str| eta.bit_field(name).unwrap().extract(0x8637);
    assert_eq!(field("operation_enabled"), 1);
    assert_eq!(field("reverse"), 1);
    assert_eq!(field("target_reached"), 1);
    assert_eq!(field("fault"), 0);
    assert_eq!(DriveState::from_eta(0x8637), DriveState::OperationEnabled);
    assert_eq!(DriveState::from_eta(0x0250), DriveState::SwitchOnDisabled);
    assert_eq!(DriveState::from_eta(0x0231), DriveState::ReadyToSwitchOn);
    assert_eq!(DriveState::from_eta(0x0233), DriveState::SwitchedOn);
    assert_eq!(DriveState::from_eta(0x0218), DriveState::Fault);
    for state in [
        DriveState::SwitchOnDisabled,
        DriveState::ReadyToSwitchOn,
        DriveState::SwitchedOn,
        DriveState::OperationEnabled,
        DriveState::QuickStopActive,
        DriveState::FaultReactionActive,
        DriveState::Fault,
    ] {
        assert_eq!(DriveState::from_eta(state.eta_bits()), state);
    }
}

#[test]
fn altivar_writes_are_checked() {
    let profile = DeviceProfile::altivar71();
    let acc = profile.tag("ACC").unwrap();
    assert_eq!(profile.encode(acc, 1.3), Ok(vec![13]));
    assert_eq!(profile.encode(acc, 2.0), Ok(vec![20]));
    assert!(matches!(
        profile.encode(acc, 1000.0),
        Err(EncodeError::OutOfRange { .. })
    ));
    assert!(matches!(
        profile.encode(acc, f64::NAN),
        Err(EncodeError::NotFinite(_))
    ));
    let eta = profile.tag("ETA").unwrap();
    assert_eq!(
        profile.encode(eta, 1.0),
        Err(EncodeError::ReadOnly("ETA".to_owned()))
    );
    let lfrd = profile.tag("LFRD").unwrap();
    assert_eq!(profile.encode(lfrd, -1500.0), Ok(vec![(-1500i16) as u16]));
    assert!(profile.encode(lfrd, 40000.0).is_err());
}

// --- KS vario decoding ---

#[test]
fn ksvario_integer_special_values() {
    // 001 4.1: 31000 not defined, 32000 switched off, 32768 (8000 hex) out of the integer range.
    let profile = DeviceProfile::ksvario();
    let tag = profile.tag("ti1_c1").unwrap();
    assert_eq!(
        profile.decode(tag, &[31000]),
        (Value::Int(31000), Quality::NotDefined)
    );
    assert_eq!(
        profile.decode(tag, &[32000]),
        (Value::Int(32000), Quality::Off)
    );
    assert_eq!(
        profile.decode(tag, &[0x8000]),
        (Value::Int(-32768), Quality::OutOfRange)
    );
    assert_eq!(
        profile.decode(tag, &[180]),
        (Value::Int(180), Quality::Good)
    );
    assert_eq!(
        profile.decode(tag, &[(-30000i16) as u16]),
        (Value::Int(-30000), Quality::Good)
    );
}

#[test]
fn ksvario_fix_point_and_float() {
    let profile = DeviceProfile::ksvario();
    let fix = ksvario::tag("x", Table::HoldingRegisters, 3415, Format::FixPoint1).unwrap();
    assert_eq!(fix.address, 0x4D57);
    assert_eq!(
        profile.decode(&fix, &[2220]),
        (Value::Float(222.0), Quality::Good)
    );
    assert_eq!(profile.decode(&fix, &[31000]).1, Quality::NotDefined);
    // 001 4.5: 222.0 = 43 5E 00 00, 333.0 = 43 A6 80 00.
    let float = profile.tag("data_3415").unwrap();
    assert_eq!(float.address, 0x9AAE);
    assert_eq!(
        profile.decode(float, &[0x435E, 0x0000]),
        (Value::Float(222.0), Quality::Good)
    );
    assert_eq!(
        profile.decode(float, &f32_words(1.5e37)).1,
        Quality::NotDefined
    );
    assert_eq!(
        profile.encode(profile.tag("data_3416").unwrap(), 333.0),
        Ok(vec![0x43A6, 0x8000])
    );
    assert_eq!(profile.decode(float, &[0x435E]).1, Quality::CommFailure);
}

#[test]
fn ksvario_writes_stay_in_the_transfer_range() {
    let profile = DeviceProfile::ksvario();
    let tag = profile.tag("setp_interface_c30").unwrap();
    assert_eq!(profile.encode(tag, 123.0), Ok(vec![123]));
    assert!(profile.encode(tag, 32000.0).is_ok());
    assert!(matches!(
        profile.encode(tag, 32001.0),
        Err(EncodeError::OutOfRange { .. })
    ));
    assert!(matches!(
        profile.encode(tag, -30001.0),
        Err(EncodeError::OutOfRange { .. })
    ));
    let float = profile.tag("data_3415").unwrap();
    assert!(profile.encode(float, 2.0e37).is_err());
    let vis = profile.tag("vis_1004").unwrap();
    assert_eq!(vis.table, Table::InputRegisters);
    assert!(profile.encode(vis, 1.0).is_err());
}

// --- generic devices and 32-bit types ---

#[test]
fn generic_profile_word_orders() {
    let tags = vec![
        Tag::holding("u32_hf", 0, DataType::U32(ByteOrder::Abcd)),
        Tag::holding("i32_lf", 2, DataType::I32(ByteOrder::Cdab)).writable(),
        Tag::holding("f32_lf", 4, DataType::F32(ByteOrder::Cdab)),
        Tag::new("coil", Table::Coils, 0, DataType::Bool),
    ];
    let profile = DeviceProfile::generic("meter", 5, tags);
    assert_eq!(profile.special_values, SpecialValues::NONE);
    let tag = |name: &str| profile.tag(name).unwrap();
    assert_eq!(
        profile.decode(tag("u32_hf"), &[0x0001, 0x0002]),
        (Value::Int(0x0001_0002), Quality::Good)
    );
    assert_eq!(
        profile.decode(tag("i32_lf"), &[0xFFFE, 0xFFFF]),
        (Value::Int(-2), Quality::Good)
    );
    let [high, low] = f32_words(-2.5);
    assert_eq!(
        profile.decode(tag("f32_lf"), &[low, high]),
        (Value::Float(-2.5), Quality::Good)
    );
    assert_eq!(
        profile.decode(tag("coil"), &[1]),
        (Value::Bool(true), Quality::Good)
    );
    assert_eq!(
        profile.encode(tag("i32_lf"), -2.0),
        Ok(vec![0xFFFE, 0xFFFF])
    );
    // No special values: 0x8000 is a number.
    assert_eq!(profile.decode(tag("u32_hf"), &[0x8000, 0]).1, Quality::Good);
    assert_eq!(Quality::OutOfRange.as_str(), "out_of_range");
}
