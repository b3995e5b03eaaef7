//! The tag model: one named datum of a device.

use super::Value;
use crate::modbus::Table;

/// The order of the two registers of a 32-bit value.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum WordOrder {
    /// The high word at the lower address ("Motorola format", KS vario 001 4.5).
    #[default]
    HighFirst,
    /// The low word at the lower address.
    LowFirst,
}

/// How the words of a tag are read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DataType {
    /// One coil or discrete input.
    Bool,
    /// One register, unsigned.
    U16,
    /// One register, two's complement.
    I16,
    /// Two registers, unsigned.
    U32(WordOrder),
    /// Two registers, two's complement.
    I32(WordOrder),
    /// Two registers, IEEE-754 single precision.
    F32(WordOrder),
}

// === impl DataType ===

impl DataType {
    /// How many registers (or bits) the type occupies.
    pub const fn words(self) -> u16 {
        match self {
            Self::Bool | Self::U16 | Self::I16 => 1,
            Self::U32(_) | Self::I32(_) | Self::F32(_) => 2,
        }
    }

    /// The smallest and largest raw number of an integer type (the float range for `F32`).
    pub fn raw_bounds(self) -> (f64, f64) {
        match self {
            Self::Bool => (0.0, 1.0),
            Self::U16 => (0.0, f64::from(u16::MAX)),
            Self::I16 => (f64::from(i16::MIN), f64::from(i16::MAX)),
            Self::U32(_) => (0.0, f64::from(u32::MAX)),
            Self::I32(_) => (f64::from(i32::MIN), f64::from(i32::MAX)),
            Self::F32(_) => (f64::from(f32::MIN), f64::from(f32::MAX)),
        }
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
    /// Fix point decimals: the engineering value is the raw number / 10^decimals.
    pub decimals: u8,
    /// A factor applied after the decimals (1.0 when the decimals say it all).
    pub scale: f64,
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
            decimals: 0,
            scale: 1.0,
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

    /// Sets the fix point decimals.
    #[must_use]
    pub fn decimals(mut self, decimals: u8) -> Self {
        self.decimals = decimals;
        self
    }

    /// Sets the scale factor.
    #[must_use]
    pub fn scale(mut self, scale: f64) -> Self {
        self.scale = scale;
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

    /// The factor from raw number to engineering value: scale / 10^decimals.
    pub fn factor(&self) -> f64 {
        self.scale / 10f64.powi(i32::from(self.decimals))
    }

    /// Whether a raw number is shown as is (no decimals, scale 1).
    pub fn is_plain(&self) -> bool {
        self.decimals == 0 && self.scale == 1.0
    }

    /// The bit field named `name`.
    pub fn bit_field(&self, name: &str) -> Option<&BitField> {
        self.bits.iter().find(|b| b.name == name)
    }

    /// The engineering value of a raw integer.
    pub(crate) fn engineering(&self, raw: i64) -> Value {
        if self.is_plain() {
            Value::Int(raw)
        } else {
            Value::Float(raw as f64 * self.factor())
        }
    }
}
