//! Values as written: value = raw x scale + offset, computed on the decimals the numbers are
//! written with; `decimals` only rounds what is presented. The presented number is the `f64`
//! nearest the exact decimal, so its shortest form (what JSON writes, what Rust prints) is that
//! decimal: raw 2931 x 0.1 - 273.15 reads 19.95, never 19.950000000000045, and an `f32` 0.95
//! reads 0.95, never 0.949999988079071.

use proptest::prelude::*;
use proto_core::profiles::ksvario::{self, Format};
use proto_core::profiles::{ByteOrder, DataType, DeviceProfile, Quality, Table, Tag, Value};

fn generic(tag: Tag) -> (DeviceProfile, Tag) {
    (DeviceProfile::generic("dev", 1, vec![tag.clone()]), tag)
}

/// Places after the point of the shortest decimal Rust prints for `x` (no exponent form).
fn places(x: f64) -> usize {
    let text = x.to_string();
    text.split_once('.').map_or(0, |(_, f)| f.len())
}

/// The exact decimal `raw x k / 10^a + m / 10^b` as text, by integer arithmetic.
fn exact(raw: i128, k: i128, a: u32, m: i128, b: u32) -> String {
    let p = a.max(b);
    let n = raw * k * 10i128.pow(p - a) + m * 10i128.pow(p - b);
    let sign = if n < 0 { "-" } else { "" };
    let n = n.unsigned_abs();
    let unit = 10u128.pow(p);
    format!(
        "{sign}{}.{:0width$}",
        n / unit,
        n % unit,
        width = p as usize
    )
}

/// A decimal `k / 10^a` as the float a config file gives (TOML reads "0.1" as the nearest f64).
fn dec(k: i128, a: u32) -> f64 {
    format!("{k}e-{a}").parse().unwrap()
}

#[test]
fn the_issues_examples_read_as_written() {
    // i16, scale 0.1, offset -273.15: raw 2931 is 19.95 with or without decimals = 2 (before,
    // decimals divided: -270.219; without them 19.950000000000045).
    let t = Tag::holding("t", 0, DataType::I16)
        .scale(0.1)
        .offset(-273.15);
    let (profile, _) = generic(t.clone());
    assert_eq!(profile.decode(&t, &[2931]).0, Value::Float(19.95));
    assert_eq!(profile.decode(&t, &[2931]).0.to_string(), "19.95");
    assert_eq!(t.implied_places(), 2);
    let t2 = t.clone().decimals(2);
    assert_eq!(profile.decode(&t2, &[2931]).0, Value::Float(19.95));
    // decimals = 1 rounds what is shown (half away from zero): 20.0.
    let t1 = t.clone().decimals(1);
    assert_eq!(profile.decode(&t1, &[2931]).0, Value::Float(20.0));
    // u64, scale 0.01, decimals 2 (the example config's energy): 12345 is 123.45, not 1.2345.
    let e = Tag::holding("e", 0, DataType::U64(ByteOrder::Abcd))
        .scale(0.01)
        .decimals(2);
    assert_eq!(
        generic(e.clone()).0.decode(&e, &[0, 0, 0, 12345]).0,
        Value::Float(123.45)
    );
    // f32 0.95 with neither scale nor offset: 0.95.
    let pf = Tag::holding("pf", 0, DataType::F32(ByteOrder::Cdab)).writable();
    let (profile, _) = generic(pf.clone());
    let bits = 0.95f32.to_bits();
    let words = [(bits & 0xFFFF) as u16, (bits >> 16) as u16];
    assert_eq!(profile.decode(&pf, &words).0.to_string(), "0.95");
    // A write of 4.6 to a 0.1-step tag is raw 46 and reads back 4.6.
    let acc = Tag::holding("acc", 0, DataType::U16)
        .fix_point(1)
        .writable();
    let (profile, _) = generic(acc.clone());
    let words = profile.encode(&acc, 4.6).unwrap();
    assert_eq!(words, [46]);
    assert_eq!(profile.decode(&acc, &words).0.to_string(), "4.6");
    assert_eq!(profile.encode(&acc, 0.7).unwrap(), [7]);
}

#[test]
fn every_type_with_scale_offset_and_decimals() {
    let with = |data_type| {
        Tag::holding("v", 0, data_type)
            .scale(0.5)
            .offset(-20.0)
            .decimals(1)
            .writable()
    };
    let abcd = ByteOrder::Abcd;
    let cases: Vec<(DataType, Vec<u16>, f64)> = vec![
        (DataType::U16, vec![100], 30.0),
        (DataType::I16, vec![(-3i16) as u16], -21.5),
        (DataType::U32(abcd), vec![1, 0], 32748.0),
        (DataType::I32(abcd), vec![0xFFFF, 0xFFFF], -20.5),
        (DataType::U64(abcd), vec![0, 0, 0, 81], 20.5),
        (
            DataType::I64(abcd),
            vec![0xFFFF, 0xFFFF, 0xFFFF, 0xFFFF],
            -20.5,
        ),
        (
            DataType::F32(abcd),
            {
                let b = 79.9f32.to_bits();
                vec![(b >> 16) as u16, (b & 0xFFFF) as u16]
            },
            20.0, // 79.9 x 0.5 - 20 = 19.95, one place: 20.0
        ),
        (
            DataType::F64(abcd),
            ByteOrder::Abcd.registers(&79.8f64.to_bits().to_be_bytes()),
            19.9,
        ),
    ];
    for (data_type, words, expected) in cases {
        let tag = with(data_type);
        let (profile, _) = generic(tag.clone());
        let (value, quality) = profile.decode(&tag, &words);
        assert_eq!(quality, Quality::Good);
        assert_eq!(value, Value::Float(expected), "{data_type:?}");
        // And back: the presented value writes the same raw number (floats: the same value).
        let again = profile.encode(&tag, expected).unwrap();
        assert_eq!(
            profile.decode(&tag, &again).0,
            Value::Float(expected),
            "{data_type:?}"
        );
    }
    // A bit and a bool are not numbers: scale, offset and decimals do not apply.
    let bit = Tag::holding("b", 0, DataType::Bit(3))
        .scale(0.5)
        .decimals(1);
    assert_eq!(
        generic(bit.clone()).0.decode(&bit, &[8]).0,
        Value::Bool(true)
    );
    let coil = Tag::new("c", Table::Coils, 0, DataType::Bool).decimals(2);
    assert_eq!(
        generic(coil.clone()).0.decode(&coil, &[1]).0,
        Value::Bool(true)
    );
    // An integer without scale and offset stays a whole number whatever its decimals.
    let n = Tag::holding("n", 0, DataType::U16).decimals(2);
    assert_eq!(generic(n.clone()).0.decode(&n, &[7]).0, Value::Int(7));
}

#[test]
fn the_ks_vario_fix_point_reads_as_the_manual_shows_it() {
    // 001 4.1: "Fix Point 1: -3000.0 ...+3200.0 (Auflösung: +/- 0,1)"; the profile's fix point
    // tag is scale 0.1, decimals 1.
    let tag = ksvario::tag("x", Table::HoldingRegisters, 3415, Format::FixPoint1)
        .unwrap()
        .writable();
    assert_eq!((tag.scale, tag.decimals), (0.1, Some(1)));
    let profile = DeviceProfile::ksvario();
    for (raw, shown) in [
        (-30000i16, "-3000"),
        (32000, "3200"),
        (1234, "123.4"),
        (-1, "-0.1"),
        (7, "0.7"),
    ] {
        let (value, quality) = profile.decode(&tag, &[raw as u16]);
        if raw == 32000 {
            // 32000 is the KS vario's "switched off" (001 4.1), shown as the raw number.
            assert_eq!((value, quality), (Value::Int(32000), Quality::Off));
            continue;
        }
        assert_eq!(quality, Quality::Good);
        assert_eq!(value.to_string(), shown, "raw {raw}");
        let words = profile.encode(&tag, value.as_f64()).unwrap();
        assert_eq!(words, [raw as u16], "{shown} writes raw {raw}");
    }
    assert_eq!(
        profile.decode(&tag, &[32001u16]).0.to_string(),
        "3200.1",
        "a plain value next to a special one"
    );
}

#[test]
fn the_altivar_fix_point_tags_are_scale_and_decimals() {
    // 002 "Beispiel 1": SFr 16#0028 = 4 kHz (the switching frequency, 0.1 kHz steps).
    let profile = DeviceProfile::altivar71();
    let sfr = profile.tag("SFr").unwrap();
    assert_eq!(
        (sfr.scale, sfr.decimals, sfr.unit.as_str()),
        (0.1, Some(1), "kHz")
    );
    assert_eq!(profile.decode(sfr, &[0x0028]).0.to_string(), "4");
    let acc = profile.tag("ACC").unwrap();
    assert_eq!(profile.encode(acc, 4.6).unwrap(), [46]);
    assert_eq!(profile.decode(acc, &[46]).0.to_string(), "4.6");
}

proptest! {
    /// Any raw whole number with a scale and an offset of at most 6 places: the presented value
    /// is the exact decimal (for raw numbers an f64 holds), and its shortest form has at most
    /// the places scale and offset imply.
    #[test]
    fn presented_values_have_the_implied_places(
        raw in any::<i32>(),
        k in -100_000i128..=100_000,
        a in 0u32..=6,
        m in -10_000_000i128..=10_000_000,
        b in 0u32..=6,
    ) {
        prop_assume!(k != 0);
        let tag = Tag::holding("t", 0, DataType::I32(ByteOrder::Abcd)).scale(dec(k, a)).offset(dec(m, b));
        let value = tag.present_int(i128::from(raw));
        let implied = tag.implied_places() as usize;
        prop_assert!(implied <= a.max(b) as usize);
        prop_assert!(places(value) <= implied, "{value} has more than {implied} places");
        let exact: f64 = exact(i128::from(raw), k, a, m, b).parse().unwrap();
        prop_assert_eq!(value, exact);
    }

    /// The same over the whole 64-bit range: never more places than implied.
    #[test]
    fn sixty_four_bit_raw_numbers_have_the_implied_places(
        raw in any::<i64>(),
        u in any::<u64>(),
        k in 1i128..=10_000,
        a in 0u32..=9,
        m in -10_000i128..=10_000,
        b in 0u32..=9,
    ) {
        let tag = Tag::holding("t", 0, DataType::I64(ByteOrder::Abcd)).scale(dec(k, a)).offset(dec(m, b));
        let implied = tag.implied_places() as usize;
        for raw in [i128::from(raw), i128::from(u)] {
            let value = tag.present_int(raw);
            prop_assert!(places(value) <= implied, "{value} has more than {implied} places");
        }
    }

    /// `decimals` rounds: at most that many places, and within half a unit of the exact value.
    #[test]
    fn decimals_round_to_their_places(
        raw in any::<i32>(),
        k in 1i128..=100_000,
        a in 0u32..=6,
        m in -10_000_000i128..=10_000_000,
        b in 0u32..=6,
        d in 0u8..=9,
    ) {
        let tag = Tag::holding("t", 0, DataType::I32(ByteOrder::Abcd)).scale(dec(k, a)).offset(dec(m, b)).decimals(d);
        let value = tag.present_int(i128::from(raw));
        prop_assert!(places(value) <= usize::from(d), "{value} has more than {d} places");
        let exact: f64 = exact(i128::from(raw), k, a, m, b).parse().unwrap();
        let half = 0.5 * 10f64.powi(-i32::from(d));
        prop_assert!((value - exact).abs() <= half * (1.0 + 1e-9) + exact.abs() * 1e-15);
    }

    /// A float register with neither scale nor offset reads in its own type's shortest form.
    #[test]
    fn floats_read_in_their_own_shortest_form(f in any::<f32>(), g in any::<f64>()) {
        prop_assume!(f.is_finite() && g.is_finite());
        let t32 = Tag::holding("f", 0, DataType::F32(ByteOrder::Abcd));
        prop_assert_eq!(t32.present_f32(f).to_string(), f.to_string());
        let t64 = Tag::holding("g", 0, DataType::F64(ByteOrder::Abcd));
        prop_assert_eq!(t64.present(g).to_bits(), g.to_bits());
    }

    /// Writes round-trip without noise: the value a raw number is presented as writes that raw
    /// number, and reads back as the same value.
    #[test]
    fn presented_values_write_back_their_raw_number(
        raw in -30_000i16..=30_000,
        k in 1i128..=1_000,
        a in 0u32..=4,
        m in -100_000i128..=100_000,
        b in 0u32..=4,
    ) {
        let tag = Tag::holding("t", 0, DataType::I16).scale(dec(k, a)).offset(dec(m, b)).writable();
        let (profile, _) = generic(tag.clone());
        let value = tag.present_int(i128::from(raw));
        let words = profile.encode(&tag, value).unwrap();
        prop_assert_eq!(words, vec![raw as u16]);
        prop_assert_eq!(profile.decode(&tag, &[raw as u16]).0, Value::Float(value));
    }
}
