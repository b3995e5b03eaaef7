//! The tag model: one named datum of a device.

use super::decimal::{self, Decimal};
use super::Value;
use crate::modbus::Table;

/// The most places implied by a scale or offset (a scale of 1e-30 is presented with 30).
const MAX_IMPLIED_PLACES: u32 = 30;

/// Where the bytes of a 32 or 64-bit value sit in its registers. The letters name the value's
/// bytes from the most significant (A) down, in the order they appear on the wire from the
/// register at the tag's address on (each register sends its high byte first, Modbus Application
/// Protocol V1.1b3 4.2):
///
/// | order  | 32-bit registers | 64-bit registers      | 64-bit name  |
/// |--------|------------------|-----------------------|--------------|
/// | `Abcd` | AB CD            | AB CD EF GH           | ABCDEFGH     |
/// | `Cdab` | CD AB            | GH EF CD AB           | GHEFCDAB     |
/// | `Badc` | BA DC            | BA DC FE HG           | BADCFEHG     |
/// | `Dcba` | DC BA            | HG FE DC BA           | HGFEDCBA     |
///
/// `Cdab` reverses the order of the registers, `Badc` swaps the two bytes inside each register,
/// `Dcba` does both (the whole value little endian).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum ByteOrder {
    /// Big endian: the high word at the lower address, its high byte first ("Motorola format",
    /// KS vario 001 4.5). The config's `high-first`.
    #[default]
    Abcd,
    /// The registers in reverse order (the low word at the lower address), each big endian. The
    /// config's `low-first`.
    Cdab,
    /// The registers in order, the two bytes of each swapped.
    Badc,
    /// Little endian: the registers in reverse order and the bytes of each swapped.
    Dcba,
}

// === impl ByteOrder ===

impl ByteOrder {
    /// Whether the registers come in reverse order (the low word first).
    pub const fn words_reversed(self) -> bool {
        matches!(self, Self::Cdab | Self::Dcba)
    }

    /// Whether the two bytes of each register are swapped.
    pub const fn bytes_swapped(self) -> bool {
        matches!(self, Self::Badc | Self::Dcba)
    }

    /// The registers that carry `bytes` (most significant byte first, an even number of them).
    pub fn registers(self, bytes: &[u8]) -> Vec<u16> {
        let mut words: Vec<u16> = bytes
            .chunks(2)
            .map(|c| {
                let w = u16::from_be_bytes([
                    c.first().copied().unwrap_or(0),
                    c.get(1).copied().unwrap_or(0),
                ]);
                if self.bytes_swapped() {
                    w.swap_bytes()
                } else {
                    w
                }
            })
            .collect();
        if self.words_reversed() {
            words.reverse();
        }
        words
    }

    /// The value's bytes, most significant first, from its registers: the inverse of
    /// [`Self::registers`].
    pub fn bytes(self, registers: &[u16]) -> Vec<u8> {
        let mut words = registers.to_vec();
        if self.words_reversed() {
            words.reverse();
        }
        words
            .into_iter()
            .flat_map(|w| {
                if self.bytes_swapped() {
                    w.swap_bytes()
                } else {
                    w
                }
                .to_be_bytes()
            })
            .collect()
    }
}

/// The order of the two characters of a string in each register.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum CharOrder {
    /// The first character in the high byte (sent first on the wire). The config's `high-first`.
    #[default]
    HighFirst,
    /// The first character in the low byte. The config's `low-first`.
    LowFirst,
}

/// How the words of a tag are read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DataType {
    /// One coil or discrete input.
    Bool,
    /// One bit (0..=15, 0 the least significant) of a register, as a bool.
    Bit(u8),
    /// One register, unsigned.
    U16,
    /// One register, two's complement.
    I16,
    /// Two registers, unsigned.
    U32(ByteOrder),
    /// Two registers, two's complement.
    I32(ByteOrder),
    /// Two registers, IEEE-754 single precision.
    F32(ByteOrder),
    /// Four registers, unsigned.
    U64(ByteOrder),
    /// Four registers, two's complement.
    I64(ByteOrder),
    /// Four registers, IEEE-754 double precision.
    F64(ByteOrder),
    /// ASCII text, two characters a register; trailing NUL and space are not part of the value.
    String {
        /// The registers the text occupies (its longest length is twice this).
        registers: u16,
        /// Which byte of a register holds the first of its two characters.
        order: CharOrder,
    },
}

// === impl DataType ===

impl DataType {
    /// How many registers (or bits) the type occupies.
    pub const fn words(self) -> u16 {
        match self {
            Self::Bool | Self::Bit(_) | Self::U16 | Self::I16 => 1,
            Self::U32(_) | Self::I32(_) | Self::F32(_) => 2,
            Self::U64(_) | Self::I64(_) | Self::F64(_) => 4,
            Self::String { registers, .. } => registers,
        }
    }

    /// The smallest and largest raw number of an integer type (the float range for floats, 0..1
    /// for bits and 0..0 for strings).
    pub fn raw_bounds(self) -> (f64, f64) {
        match self {
            Self::Bool | Self::Bit(_) => (0.0, 1.0),
            Self::U16 => (0.0, f64::from(u16::MAX)),
            Self::I16 => (f64::from(i16::MIN), f64::from(i16::MAX)),
            Self::U32(_) => (0.0, f64::from(u32::MAX)),
            Self::I32(_) => (f64::from(i32::MIN), f64::from(i32::MAX)),
            Self::F32(_) => (f64::from(f32::MIN), f64::from(f32::MAX)),
            // The nearest doubles inside the range (2^64 - 2048 and 2^63 - 1024).
            Self::U64(_) => (0.0, 18_446_744_073_709_549_568.0),
            Self::I64(_) => (-9_223_372_036_854_775_808.0, 9_223_372_036_854_774_784.0),
            Self::F64(_) => (f64::MIN, f64::MAX),
            Self::String { .. } => (0.0, 0.0),
        }
    }

    /// The smallest and largest raw number of an integer type, exactly; `None` for floats,
    /// strings and bits.
    pub const fn int_bounds(self) -> Option<(i128, i128)> {
        Some(match self {
            Self::U16 => (0, u16::MAX as i128),
            Self::I16 => (i16::MIN as i128, i16::MAX as i128),
            Self::U32(_) => (0, u32::MAX as i128),
            Self::I32(_) => (i32::MIN as i128, i32::MAX as i128),
            Self::U64(_) => (0, u64::MAX as i128),
            Self::I64(_) => (i64::MIN as i128, i64::MAX as i128),
            _ => return None,
        })
    }

    /// Whether the type is a float (any value in its range, no steps).
    pub const fn is_float(self) -> bool {
        matches!(self, Self::F32(_) | Self::F64(_))
    }
}

/// A named group of bits inside a register (status and control words).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct BitField {
    /// The field's name, e.g. `operation_enabled`.
    pub name: String,
    /// The lowest bit, 0..=15 (0..=31 for 32-bit tags).
    pub bit: u8,
    /// How many bits, at least 1.
    pub width: u8,
}

// === impl BitField ===

impl BitField {
    /// A one-bit field.
    pub fn flag(name: impl Into<String>, bit: u8) -> Self {
        Self {
            name: name.into(),
            bit,
            width: 1,
        }
    }

    /// The field's value in `raw`.
    pub fn extract(&self, raw: u32) -> u32 {
        let shifted = raw.checked_shr(u32::from(self.bit)).unwrap_or(0);
        let mask = 1u32
            .checked_shl(u32::from(self.width))
            .map_or(u32::MAX, |m| m - 1);
        shifted & mask
    }
}

/// One named datum of a device.
#[derive(Clone, Debug, PartialEq)]
pub struct Tag {
    /// The name the device manual uses (`ETA`, `LFRD`), unique within a profile.
    pub name: String,
    /// What the datum is, in a few words.
    pub description: String,
    /// The Modbus table.
    pub table: Table,
    /// The address of the first register (or bit) as sent on the wire.
    pub address: u16,
    /// How the words are read.
    pub data_type: DataType,
    /// The places a value is presented with (REST, zenoh) and a write is checked at; `None`:
    /// the places scale and offset imply ([`Self::places`]). Only rounds, never scales.
    pub decimals: Option<u8>,
    /// The factor from raw number to engineering value: value = raw x scale + offset.
    pub scale: f64,
    /// Added after the scale (0.0 by default).
    pub offset: f64,
    /// The engineering unit, empty for plain numbers.
    pub unit: String,
    /// Whether the gateway may write the tag.
    pub writable: bool,
    /// The raw numbers the device accepts in a write, if narrower than the data type.
    pub raw_range: Option<(i32, i32)>,
    /// Named bit groups of a status or control word.
    pub bits: Vec<BitField>,
}

// === impl Tag ===

impl Tag {
    /// A read-only tag without decimals, scale, unit or bit fields.
    pub fn new(name: impl Into<String>, table: Table, address: u16, data_type: DataType) -> Self {
        Self {
            name: name.into(),
            description: String::new(),
            table,
            address,
            data_type,
            decimals: None,
            scale: 1.0,
            offset: 0.0,
            unit: String::new(),
            writable: false,
            raw_range: None,
            bits: Vec::new(),
        }
    }

    /// A holding register tag of type `data_type`.
    pub fn holding(name: impl Into<String>, address: u16, data_type: DataType) -> Self {
        Self::new(name, Table::HoldingRegisters, address, data_type)
    }

    /// Sets the description.
    #[must_use]
    pub fn describe(mut self, description: impl Into<String>) -> Self {
        self.description = description.into();
        self
    }

    /// Sets the places a value is presented with (rounding only: the value stays
    /// raw x scale + offset).
    #[must_use]
    pub fn decimals(mut self, decimals: u8) -> Self {
        self.decimals = Some(decimals);
        self
    }

    /// A fix point register with `decimals` places: scale 10^-decimals, presented with as many
    /// places (KS vario "Fix Point 1", 001 4.2: raw 1234 = 123.4).
    #[must_use]
    pub fn fix_point(self, decimals: u8) -> Self {
        // "1e-N" reads as the float nearest 10^-N, whose shortest form is that decimal.
        let scale = format!("1e-{decimals}").parse().unwrap_or(1.0);
        self.scale(scale).decimals(decimals)
    }

    /// Sets the scale factor.
    #[must_use]
    pub fn scale(mut self, scale: f64) -> Self {
        self.scale = scale;
        self
    }

    /// Sets the offset added after the scale.
    #[must_use]
    pub fn offset(mut self, offset: f64) -> Self {
        self.offset = offset;
        self
    }

    /// Sets the unit.
    #[must_use]
    pub fn unit(mut self, unit: impl Into<String>) -> Self {
        self.unit = unit.into();
        self
    }

    /// Makes the tag writable.
    #[must_use]
    pub fn writable(mut self) -> Self {
        self.writable = true;
        self
    }

    /// Makes the tag writable within `min..=max` (raw numbers).
    #[must_use]
    pub fn writable_within(mut self, min: i32, max: i32) -> Self {
        self.writable = true;
        self.raw_range = Some((min, max));
        self
    }

    /// Sets the bit fields.
    #[must_use]
    pub fn bits(mut self, bits: Vec<BitField>) -> Self {
        self.bits = bits;
        self
    }

    /// How many registers (or bits) the tag occupies.
    pub const fn words(&self) -> u16 {
        self.data_type.words()
    }

    /// The address after the tag's last register, as a `u32` so that it cannot overflow.
    pub const fn end(&self) -> u32 {
        self.address as u32 + self.data_type.words() as u32
    }

    /// The factor from raw number to engineering value: the scale (`decimals` does not scale).
    pub fn factor(&self) -> f64 {
        self.scale
    }

    /// Whether a raw number is shown as is (scale 1, offset 0): an integer stays a whole
    /// number; `decimals` cannot change a whole number.
    pub fn is_plain(&self) -> bool {
        self.scale == 1.0 && self.offset == 0.0
    }

    /// The places a whole raw number's value has: those of the scale or the offset, whichever
    /// has more (scale 0.1 and offset -273.15 give 2; scale 0.5 and offset -20 give 1).
    pub fn implied_places(&self) -> u32 {
        let of = |x: f64| decimal::places_of(x).unwrap_or(MAX_IMPLIED_PLACES);
        of(self.scale).max(of(self.offset)).min(MAX_IMPLIED_PLACES)
    }

    /// The places a whole raw number's value is presented with: `decimals`, else
    /// [`Self::implied_places`].
    pub fn places(&self) -> u32 {
        self.decimals
            .map_or_else(|| self.implied_places(), u32::from)
    }

    /// The value of a raw number as presented: raw x scale + offset, computed on the decimals
    /// of the three numbers and rounded to `decimals` places, or without `decimals` to the places
    /// the raw number, scale and offset imply (raw 2931 x 0.1 - 273.15 = 19.95, never
    /// 19.950000000000045). A whole raw number implies none; a float register's value has the
    /// places of its own shortest form (pass an `f32` through [`Self::present_f32`]).
    pub fn present(&self, raw: f64) -> f64 {
        if self.is_plain() && self.decimals.is_none() {
            return raw;
        }
        match Decimal::from_f64(raw) {
            Some(raw) => self.present_decimal(raw, raw.places()),
            None => self.present_float(raw),
        }
    }

    /// The value of a raw `f32` as presented: its shortest form (0.95, not 0.949999988079071),
    /// then as [`Self::present`].
    pub fn present_f32(&self, raw: f32) -> f64 {
        if self.is_plain() && self.decimals.is_none() {
            return decimal::f32_shortest(raw);
        }
        match Decimal::from_f32(raw) {
            Some(raw) => self.present_decimal(raw, raw.places()),
            None => self.present(decimal::f32_shortest(raw)),
        }
    }

    /// The value of a raw whole number as presented, exact over 64 bits.
    pub fn present_int(&self, raw: i128) -> f64 {
        self.present_decimal(Decimal::int(raw), 0)
    }

    fn present_decimal(&self, raw: Decimal, raw_places: u32) -> f64 {
        let (scale, offset) = (
            Decimal::from_f64(self.scale),
            Decimal::from_f64(self.offset),
        );
        let places = self.decimals.map_or_else(
            || {
                let of = |d: Option<Decimal>| d.map_or(MAX_IMPLIED_PLACES, Decimal::places);
                raw_places.saturating_add(of(scale)).max(of(offset))
            },
            u32::from,
        );
        let exact = scale
            .and_then(|scale| raw.mul(scale))
            .zip(offset)
            .and_then(|(scaled, offset)| scaled.add(offset));
        match exact {
            Some(value) => value.round(places).to_f64(),
            None => decimal::round_f64(raw.to_f64() * self.scale + self.offset, places),
        }
    }

    /// raw x scale + offset in floats, rounded to the places presented.
    fn present_float(&self, raw: f64) -> f64 {
        let value = raw * self.scale + self.offset;
        match self.decimals {
            Some(places) => decimal::round_f64(value, u32::from(places)),
            None => value,
        }
    }

    /// `value` rounded to the places a whole raw number's value is presented with: what a write
    /// is compared with.
    pub fn round_to_places(&self, value: f64) -> f64 {
        match Decimal::from_f64(value) {
            Some(v) => v.round(self.places()).to_f64(),
            None => decimal::round_f64(value, self.places()),
        }
    }

    /// Whether `value` has no more places than [`Self::places`]: a decimal the tag can present.
    pub fn fits_places(&self, value: f64) -> bool {
        Decimal::from_f64(value).is_none_or(|v| v.places() <= self.places())
    }

    /// The two values at [`Self::places`] places nearest `value` (below and above; equal when
    /// `value` has no more places).
    pub fn neighbours_at_places(&self, value: f64) -> (f64, f64) {
        match Decimal::from_f64(value) {
            Some(v) => (
                v.floor(self.places()).to_f64(),
                v.ceil(self.places()).to_f64(),
            ),
            None => (value, value),
        }
    }

    /// The engineering value of a raw number in floats, unrounded (for ranges): raw x scale +
    /// offset.
    pub fn to_engineering(&self, raw: f64) -> f64 {
        raw * self.scale + self.offset
    }

    /// The raw number of an engineering value: (value - offset) / scale, computed on the
    /// decimals of the three numbers where they fit (4.6 / 0.1 = 46, not 45.99999999999999).
    pub fn to_raw(&self, value: f64) -> f64 {
        if self.is_plain() {
            return value;
        }
        self.raw_ratio(value)
            .and_then(|(v, scale)| v.div_f64(scale))
            .unwrap_or_else(|| (value - self.offset) / self.scale)
    }

    /// The whole raw number nearest (value - offset) / scale, halves away from zero; `None`
    /// for a value that is not finite.
    pub fn to_raw_rounded(&self, value: f64) -> Option<f64> {
        if !value.is_finite() {
            return None;
        }
        let exact = self
            .raw_ratio(value)
            .and_then(|(v, scale)| v.div_round(scale))
            .map(|raw| raw as f64);
        let raw = exact.unwrap_or_else(|| ((value - self.offset) / self.scale).round());
        raw.is_finite().then_some(raw)
    }

    fn raw_ratio(&self, value: f64) -> Option<(Decimal, Decimal)> {
        let v = Decimal::from_f64(value)?.sub(Decimal::from_f64(self.offset)?)?;
        Some((v, Decimal::from_f64(self.scale)?))
    }

    /// The engineering value of a raw integer.
    pub(crate) fn engineering(&self, raw: i64) -> Value {
        if self.is_plain() {
            Value::Int(raw)
        } else {
            Value::Float(self.present_int(i128::from(raw)))
        }
    }

    /// The engineering value of a raw unsigned 64-bit integer.
    pub(crate) fn engineering_u64(&self, raw: u64) -> Value {
        if self.is_plain() {
            Value::UInt(raw)
        } else {
            Value::Float(self.present_int(i128::from(raw)))
        }
    }

    /// The bit field named `name`.
    pub fn bit_field(&self, name: &str) -> Option<&BitField> {
        self.bits.iter().find(|b| b.name == name)
    }
}
