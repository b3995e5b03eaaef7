//! Register-map models of the supported devices.
//!
//! A [`DeviceProfile`] describes one device type: its [`Tag`]s (name, table, address, data type,
//! fix point decimals, bit fields, unit, scale, writable), the request limits the device accepts,
//! the function codes it supports, the special values it reports instead of a measurement, and
//! whether a keep-alive write is needed. Everything here is plain data and pure functions: the
//! poller merges reads within [`RequestLimits`], and [`DeviceProfile::decode`] turns the words it
//! read into a [`Value`] and a [`Quality`].
//!
//! Profiles, listed by name in [`registry::PROFILES`]:
//! - [`altivar`]: Schneider Altivar 61/71 with integrated Modbus (seed manual 002);
//! - [`ksvario`]: PMA KS vario controller system, Modbus RTU (seed manual 001);
//! - [`DeviceProfile::generic`]: any Modbus device described by a tag list.

pub mod altivar;
pub mod ksvario;
pub mod registry;

mod quality;
mod tag;

use core::time::Duration;

use crate::modbus::pdu::FunctionCode;

pub use quality::Quality;
pub use tag::{BitField, DataType, Tag, WordOrder};

pub use crate::modbus::Table;

/// A decoded tag value.
///
/// Integer tags without decimals or scale decode to `Int`, bit tags to `Bool`, everything else to
/// `Float` in engineering units. When the quality is not good, the value is the raw number the
/// device sent (e.g. `Int(31000)`), so that it can still be shown.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Value {
    /// A whole number.
    Int(i64),
    /// A number in engineering units.
    Float(f64),
    /// A coil or discrete input.
    Bool(bool),
}

// === impl Value ===

impl Value {
    /// The value as a float (true = 1.0).
    pub fn as_f64(self) -> f64 {
        match self {
            Self::Int(v) => v as f64,
            Self::Float(v) => v,
            Self::Bool(v) => f64::from(u8::from(v)),
        }
    }
}

/// How a device marks a datum it cannot deliver.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum SpecialValues {
    /// No special values: every word is a value.
    #[default]
    None,
    /// Altivar 61/71: 16#8000 in place of a parameter that does not exist or is protected
    /// (002 "Lesen nicht vorhandener oder geschützter Parameter").
    Altivar,
    /// KS vario: 31000 not defined, 32000 switched off, 0x8000 out of the integer range in the
    /// integer and fix point formats, 1.5E37 not defined in the float format (001 4.1).
    KsVario,
}

// === impl SpecialValues ===

impl SpecialValues {
    /// The quality a raw word means for a 16-bit tag, `None` when it is a value.
    pub const fn classify_word(self, raw: u16) -> Option<Quality> {
        match self {
            Self::None => None,
            Self::Altivar => match raw {
                altivar::NOT_AVAILABLE => Some(Quality::NotDefined),
                _ => None,
            },
            Self::KsVario => match raw {
                ksvario::NOT_DEFINED => Some(Quality::NotDefined),
                ksvario::OFF => Some(Quality::Off),
                ksvario::OUT_OF_RANGE => Some(Quality::OutOfRange),
                _ => None,
            },
        }
    }

    /// The quality a float means, `None` when it is a value.
    pub fn classify_float(self, value: f32) -> Option<Quality> {
        match self {
            Self::KsVario if ksvario::is_float_not_defined(value) => Some(Quality::NotDefined),
            _ => None,
        }
    }
}

/// The largest requests a device accepts, in registers or bits a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct RequestLimits {
    /// FC 01 / 02 (0 = not supported).
    pub read_bits: u16,
    /// FC 03 / 04.
    pub read_registers: u16,
    /// FC 15 (0 = not supported).
    pub write_bits: u16,
    /// FC 16.
    pub write_registers: u16,
    /// FC 23 read and write quantities, `None` when the device has no FC 23.
    pub read_write: Option<ReadWriteLimits>,
    /// The longest ADU (address to CRC) the device accepts; a longer request is not answered.
    pub max_adu_len: usize,
}

/// The quantities of one FC 23 exchange.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ReadWriteLimits {
    /// Registers read.
    pub read: u16,
    /// Registers written.
    pub write: u16,
}

// === impl RequestLimits ===

impl RequestLimits {
    /// The limits of the Modbus Application Protocol V1.1b3 (6.1 to 6.17) and the 256-byte RTU
    /// ADU of Modbus over Serial Line V1.02 (2.5.1.1): what a device without a manual accepts.
    pub const MODBUS: Self = Self {
        read_bits: 2000,
        read_registers: 125,
        write_bits: 1968,
        write_registers: 123,
        read_write: Some(ReadWriteLimits {
            read: 125,
            write: 121,
        }),
        max_adu_len: 256,
    };

    /// What the CP 341 master itself allows (003 6.4.4, the "FC 01" .. "FC 16" parameter
    /// ranges, and 003 7.2 events 0E 45h / 0E 46h): 1..2040 bits, 1..127 registers a request, no
    /// FC 23; the 256-byte RTU ADU.
    pub const CP341: Self = Self {
        read_bits: 2040,
        read_registers: 127,
        write_bits: 2040,
        write_registers: 127,
        read_write: None,
        max_adu_len: 256,
    };

    /// The most registers of `table` one read request may carry (bits for the bit tables).
    pub const fn max_read(&self, table: Table) -> u16 {
        match table {
            Table::Coils | Table::DiscreteInputs => self.read_bits,
            Table::InputRegisters | Table::HoldingRegisters => self.read_registers,
        }
    }
}

/// A write that must be repeated so that the device does not fault on a communication timeout.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct KeepAlive {
    /// The tag to rewrite with its last value.
    pub tag: String,
    /// The device's timeout without a request.
    pub timeout: Duration,
    /// How often to rewrite: well inside the timeout.
    pub period: Duration,
}

/// What kind of device a profile describes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ProfileKind {
    /// Schneider Altivar 61/71 ([`altivar`]).
    Altivar71,
    /// PMA KS vario ([`ksvario`]).
    KsVario,
    /// A device described by a tag list only.
    Generic,
}

/// The register map of one device type.
#[derive(Clone, Debug, PartialEq)]
pub struct DeviceProfile {
    /// Which device.
    pub kind: ProfileKind,
    /// A short name (`altivar71`, `ksvario`, or the generic device's name).
    pub name: String,
    /// The slave address the device has in the demo and the simulator.
    pub default_address: u8,
    /// The named data.
    pub tags: Vec<Tag>,
    /// The largest requests the device accepts.
    pub limits: RequestLimits,
    /// The function codes the device answers (others give exception 01).
    pub functions: Vec<FunctionCode>,
    /// How the device marks data it cannot deliver.
    pub special_values: SpecialValues,
    /// A write to repeat so that the device does not fault, if any.
    pub keep_alive: Option<KeepAlive>,
}

/// Why a value cannot be written to a tag.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum EncodeError {
    /// The tag is read-only.
    #[error("tag {0} is read-only")]
    ReadOnly(String),
    /// The value does not fit the tag's raw range.
    #[error("value {value} is outside the range {min}..={max} of tag {tag}")]
    OutOfRange {
        tag: String,
        value: f64,
        min: f64,
        max: f64,
    },
    /// The value is not a finite number.
    #[error("value of tag {0} is not a finite number")]
    NotFinite(String),
}

// === impl DeviceProfile ===

impl DeviceProfile {
    /// The Altivar 61/71 profile ([`altivar::profile`]).
    pub fn altivar71() -> Self {
        altivar::profile()
    }

    /// The KS vario profile ([`ksvario::profile`]).
    pub fn ksvario() -> Self {
        ksvario::profile()
    }

    /// A device known only by its tags: Modbus specification limits, the common function codes,
    /// no special values.
    pub fn generic(name: impl Into<String>, default_address: u8, tags: Vec<Tag>) -> Self {
        Self {
            kind: ProfileKind::Generic,
            name: name.into(),
            default_address,
            tags,
            limits: RequestLimits::MODBUS,
            functions: [0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x0F, 0x10]
                .map(FunctionCode)
                .to_vec(),
            special_values: SpecialValues::None,
            keep_alive: None,
        }
    }

    /// The tag named `name`, compared without regard to ASCII case (manuals write `tFr`, `SFr`).
    pub fn tag(&self, name: &str) -> Option<&Tag> {
        self.tags.iter().find(|t| t.name.eq_ignore_ascii_case(name))
    }

    /// Whether the device answers function `code`.
    pub fn supports(&self, code: FunctionCode) -> bool {
        self.functions.contains(&code)
    }

    /// Decodes the words read for `tag` (`raw[0]` is the word at `tag.address`) into a value and
    /// its quality. Fewer words than the tag needs give [`Quality::CommFailure`]; extra words are
    /// ignored.
    pub fn decode(&self, tag: &Tag, raw: &[u16]) -> (Value, Quality) {
        decode_with(self.special_values, tag, raw)
    }

    /// The raw words that write `value` (engineering units) to `tag`.
    pub fn encode(&self, tag: &Tag, value: f64) -> Result<Vec<u16>, EncodeError> {
        encode_with(self.special_values, tag, value)
    }
}

fn decode_with(special: SpecialValues, tag: &Tag, raw: &[u16]) -> (Value, Quality) {
    let words = usize::from(tag.data_type.words());
    let Some(raw) = raw.get(..words) else {
        return (Value::Int(0), Quality::CommFailure);
    };
    match tag.data_type {
        DataType::Bool => (
            Value::Bool(raw.first().is_some_and(|w| *w != 0)),
            Quality::Good,
        ),
        DataType::U16 | DataType::I16 => {
            let word = raw.first().copied().unwrap_or_default();
            let number = if tag.data_type == DataType::I16 {
                i64::from(word as i16)
            } else {
                i64::from(word)
            };
            match special.classify_word(word) {
                Some(quality) => (Value::Int(number), quality),
                None => (tag.engineering(number), Quality::Good),
            }
        }
        DataType::U32(order) => (tag.engineering(i64::from(join(raw, order))), Quality::Good),
        DataType::I32(order) => (
            tag.engineering(i64::from(join(raw, order) as i32)),
            Quality::Good,
        ),
        DataType::F32(order) => {
            let value = f32::from_bits(join(raw, order));
            match special.classify_float(value) {
                Some(quality) => (Value::Float(f64::from(value)), quality),
                None => (Value::Float(f64::from(value) * tag.factor()), Quality::Good),
            }
        }
    }
}

fn encode_with(special: SpecialValues, tag: &Tag, value: f64) -> Result<Vec<u16>, EncodeError> {
    if !tag.writable {
        return Err(EncodeError::ReadOnly(tag.name.clone()));
    }
    if !value.is_finite() {
        return Err(EncodeError::NotFinite(tag.name.clone()));
    }
    let raw = value / tag.factor();
    if let DataType::F32(order) = tag.data_type {
        let (min, max) = match (tag.raw_range, special) {
            (Some((min, max)), _) => (f64::from(min), f64::from(max)),
            (None, SpecialValues::KsVario) => (-ksvario::FLOAT_LIMIT, ksvario::FLOAT_LIMIT),
            (None, _) => (f64::from(f32::MIN), f64::from(f32::MAX)),
        };
        check_range(tag, raw, min, max)?;
        return Ok(split((raw as f32).to_bits(), order));
    }
    let raw = raw.round();
    let (type_min, type_max) = tag.data_type.raw_bounds();
    let (min, max) = match (tag.raw_range, special, tag.data_type) {
        (Some((min, max)), _, _) => (f64::from(min), f64::from(max)),
        (None, SpecialValues::KsVario, DataType::I16) => {
            (f64::from(ksvario::INT_MIN), f64::from(ksvario::INT_MAX))
        }
        (None, _, _) => (type_min, type_max),
    };
    check_range(tag, raw, min.max(type_min), max.min(type_max))?;
    // In range of the type, so the casts below are exact.
    let number = raw as i64;
    Ok(match tag.data_type {
        DataType::Bool => vec![u16::from(number != 0)],
        DataType::U16 | DataType::I16 => vec![number as u16],
        DataType::U32(order) | DataType::I32(order) => split(number as u32, order),
        DataType::F32(_) => Vec::new(),
    })
}

fn check_range(tag: &Tag, raw: f64, min: f64, max: f64) -> Result<(), EncodeError> {
    if raw < min || raw > max {
        let factor = tag.factor();
        return Err(EncodeError::OutOfRange {
            tag: tag.name.clone(),
            value: raw * factor,
            min: min * factor,
            max: max * factor,
        });
    }
    Ok(())
}

/// Joins two registers into 32 bits in the given word order.
pub fn join(words: &[u16], order: WordOrder) -> u32 {
    let first = u32::from(words.first().copied().unwrap_or_default());
    let second = u32::from(words.get(1).copied().unwrap_or_default());
    match order {
        WordOrder::HighFirst => (first << 16) | second,
        WordOrder::LowFirst => (second << 16) | first,
    }
}

/// Splits 32 bits into two registers in the given word order.
pub fn split(value: u32, order: WordOrder) -> Vec<u16> {
    let high = (value >> 16) as u16;
    let low = value as u16;
    match order {
        WordOrder::HighFirst => vec![high, low],
        WordOrder::LowFirst => vec![low, high],
    }
}
