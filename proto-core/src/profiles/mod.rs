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

mod decimal;
mod quality;
mod tag;

use core::time::Duration;

use crate::modbus::pdu::FunctionCode;

pub use quality::Quality;
pub use tag::{BitField, ByteOrder, CharOrder, DataType, Tag};

pub use crate::modbus::Table;

/// A decoded tag value.
///
/// Integer tags without scale or offset decode to `Int` (`UInt` for `u64`, which may exceed
/// `i64`), bit tags to `Bool`, strings to `Text`, everything else to `Float` in engineering
/// units, as presented ([`Tag::present`]: the decimal raw x scale + offset rounded to the tag's
/// places, so that its shortest form is 19.95 and not 19.950000000000045). When the quality is not good, the value is the raw number the device sent
/// (e.g. `Int(31000)`), so that it can still be shown. A value to write is one of these too.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    /// A whole number.
    Int(i64),
    /// A whole number above `i64::MAX` or of a `u64` tag.
    UInt(u64),
    /// A number in engineering units.
    Float(f64),
    /// A coil, a discrete input or a bit of a register.
    Bool(bool),
    /// The text of a string tag.
    Text(String),
}

// === impl Value ===

impl Value {
    /// The value as a float (true = 1.0; a text is not a number: NaN).
    pub fn as_f64(&self) -> f64 {
        match self {
            Self::Int(v) => *v as f64,
            Self::UInt(v) => *v as f64,
            Self::Float(v) => *v,
            Self::Bool(v) => f64::from(u8::from(*v)),
            Self::Text(_) => f64::NAN,
        }
    }

    /// The value as an exact integer, if it is a whole number (a bool is 0 or 1).
    pub fn as_i128(&self) -> Option<i128> {
        match self {
            Self::Int(v) => Some(i128::from(*v)),
            Self::UInt(v) => Some(i128::from(*v)),
            Self::Bool(v) => Some(i128::from(u8::from(*v))),
            Self::Float(_) | Self::Text(_) => None,
        }
    }
}

impl core::fmt::Display for Value {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Int(v) => write!(f, "{v}"),
            Self::UInt(v) => write!(f, "{v}"),
            Self::Float(v) => write!(f, "{v}"),
            Self::Bool(v) => write!(f, "{v}"),
            Self::Text(v) => write!(f, "{v:?}"),
        }
    }
}

/// How a device marks a datum it cannot deliver, and the ranges it accepts in writes: data each
/// profile gives ([`altivar::SPECIAL_VALUES`], [`ksvario::SPECIAL_VALUES`]), so that a new
/// profile adds no variant here.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SpecialValues {
    /// 16-bit words that stand for a quality instead of a value.
    pub words: &'static [(u16, Quality)],
    /// A float (within a relative 1e-6) that means "not defined".
    pub float_not_defined: Option<f32>,
    /// The range a 16-bit signed integer may be written in, when narrower than the type's.
    pub i16_write_range: Option<(i32, i32)>,
    /// The magnitude an f32 may be written with, when smaller than the type's.
    pub f32_write_limit: Option<f64>,
}

// === impl SpecialValues ===

impl SpecialValues {
    /// No special values: every word is a value, every value of the type may be written.
    pub const NONE: Self = Self {
        words: &[],
        float_not_defined: None,
        i16_write_range: None,
        f32_write_limit: None,
    };

    /// Whether the device has no special values at all.
    pub fn is_none(&self) -> bool {
        *self == Self::NONE
    }

    /// The quality a raw word means for a 16-bit tag, `None` when it is a value.
    pub fn classify_word(self, raw: u16) -> Option<Quality> {
        self.words
            .iter()
            .find(|(word, _)| *word == raw)
            .map(|(_, quality)| *quality)
    }

    /// The quality a float means, `None` when it is a value.
    pub fn classify_float(self, value: f32) -> Option<Quality> {
        let target = f64::from(self.float_not_defined?);
        ((f64::from(value) - target).abs() <= target.abs() * 1e-6).then_some(Quality::NotDefined)
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

/// One known device type: what the configuration names (`profile = "altivar71"`) and what the
/// gateway may do with it beyond polling tags. Each profile module defines its own
/// (`altivar::REGISTERED`); [`registry::PROFILES`] lists them. A template read from a file
/// builds on one of these and reaches the line the same way: as a [`DeviceProfile`].
#[derive(Clone, Copy, Debug)]
pub struct Registered {
    /// The name a configuration uses (`profile = "altivar71"`).
    pub name: &'static str,
    /// The manual the profile follows, for messages (e.g. on request limits).
    pub source: &'static str,
    /// Builds the profile.
    pub build: fn() -> DeviceProfile,
    /// The device's request limits (the same as `build().limits`, without building the tags).
    pub limits: RequestLimits,
    /// The device's cyclic scanner exchanged with one FC 23, if it has one.
    pub scanner: Option<ScannerSpec>,
}

/// A device's communication scanner: input words read and output words written with one FC 23
/// (the Altivar's, 002 "Kommunikationsscanner").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ScannerSpec {
    /// The first input word (NM1 on the Altivar).
    pub inputs_at: u16,
    /// The first output word (NC1 on the Altivar).
    pub outputs_at: u16,
    /// Most words in each direction.
    pub max_words: u16,
    /// The manual section, for messages.
    pub source: &'static str,
}

/// The register map of one device type.
#[derive(Clone, Debug, PartialEq)]
pub struct DeviceProfile {
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
    /// A text for a number tag, or a number for a string tag.
    #[error("tag {tag} holds {holds}, not {given}")]
    WrongKind {
        tag: String,
        holds: &'static str,
        given: &'static str,
    },
    /// A text longer than the string tag's registers hold, or not ASCII.
    #[error("tag {tag} holds at most {max} ASCII characters; the text has {len} bytes{ascii}")]
    TextTooLong {
        tag: String,
        len: usize,
        max: usize,
        ascii: &'static str,
    },
}

/// The change a write of a bit tag makes to its register: keep the bits of `and`, then set
/// those of `or` (the Modbus mask write, Modbus Application Protocol V1.1b3 6.16:
/// result = (current AND and) OR (or AND NOT and)).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BitUpdate {
    /// The register.
    pub address: u16,
    /// The bits kept.
    pub and: u16,
    /// The bits set (within those not kept).
    pub or: u16,
}

// === impl BitUpdate ===

impl BitUpdate {
    /// The register's new content from its current one.
    pub const fn apply(self, current: u16) -> u16 {
        (current & self.and) | (self.or & !self.and)
    }
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
            name: name.into(),
            default_address,
            tags,
            limits: RequestLimits::MODBUS,
            functions: [0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x0F, 0x10]
                .map(FunctionCode)
                .to_vec(),
            special_values: SpecialValues::NONE,
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

    /// The raw words that write `value` to `tag`: a text to a string tag (NUL padded), a whole
    /// number to an integer tag exactly (also beyond 2^53), any other number in engineering
    /// units as [`Self::encode`]. A bit tag is written with [`Self::bit_update`].
    pub fn encode_value(&self, tag: &Tag, value: &Value) -> Result<Vec<u16>, EncodeError> {
        if !tag.writable {
            return Err(EncodeError::ReadOnly(tag.name.clone()));
        }
        let wrong = |holds, given| EncodeError::WrongKind {
            tag: tag.name.clone(),
            holds,
            given,
        };
        match (tag.data_type, value) {
            (DataType::String { registers, order }, Value::Text(text)) => {
                encode_text(tag, text, registers, order)
            }
            (DataType::String { .. }, _) => Err(wrong("text", "a number")),
            (_, Value::Text(_)) => Err(wrong("a number", "a text")),
            (DataType::Bit(_), _) => Err(wrong("a bit of a register", "a whole register")),
            (data_type, value) => match (data_type.int_bounds(), value.as_i128()) {
                (Some(bounds), Some(raw))
                    if tag.is_plain()
                        && tag.raw_range.is_none()
                        && self.special_values.is_none() =>
                {
                    encode_int(tag, raw, bounds)
                }
                _ => encode_with(self.special_values, tag, value.as_f64()),
            },
        }
    }

    /// The register change that writes `value` (a bool, or 0 / 1) to bit tag `tag`; `None` for
    /// a tag that is not a bit of a register.
    pub fn bit_update(&self, tag: &Tag, value: &Value) -> Option<Result<BitUpdate, EncodeError>> {
        let DataType::Bit(bit) = tag.data_type else {
            return None;
        };
        if !tag.writable {
            return Some(Err(EncodeError::ReadOnly(tag.name.clone())));
        }
        let on = match value {
            Value::Bool(b) => *b,
            Value::Text(_) => {
                return Some(Err(EncodeError::WrongKind {
                    tag: tag.name.clone(),
                    holds: "a bit",
                    given: "a text",
                }))
            }
            other => match other.as_i128() {
                Some(0) => false,
                Some(1) => true,
                _ if other.as_f64() == 0.0 => false,
                _ if other.as_f64() == 1.0 => true,
                _ => {
                    return Some(Err(EncodeError::OutOfRange {
                        tag: tag.name.clone(),
                        value: other.as_f64(),
                        min: 0.0,
                        max: 1.0,
                    }))
                }
            },
        };
        let mask = 1u16.checked_shl(u32::from(bit)).unwrap_or(0);
        Some(Ok(BitUpdate {
            address: tag.address,
            and: !mask,
            or: if on { mask } else { 0 },
        }))
    }
}

/// The registers of a text: two ASCII characters each, padded with NUL.
fn encode_text(
    tag: &Tag,
    text: &str,
    registers: u16,
    order: CharOrder,
) -> Result<Vec<u16>, EncodeError> {
    let max = usize::from(registers) * 2;
    if text.len() > max || !text.is_ascii() {
        return Err(EncodeError::TextTooLong {
            tag: tag.name.clone(),
            len: text.len(),
            max,
            ascii: if text.is_ascii() {
                ""
            } else {
                " and is not ASCII"
            },
        });
    }
    let mut bytes = text.as_bytes().to_vec();
    bytes.resize(max, 0);
    Ok(bytes
        .chunks(2)
        .map(|c| {
            let (first, second) = (
                c.first().copied().unwrap_or(0),
                c.get(1).copied().unwrap_or(0),
            );
            match order {
                CharOrder::HighFirst => u16::from_be_bytes([first, second]),
                CharOrder::LowFirst => u16::from_le_bytes([first, second]),
            }
        })
        .collect())
}

/// The text of a string tag's registers, trailing NUL and space removed; a byte outside ASCII
/// is shown as U+FFFD.
fn decode_text(raw: &[u16], order: CharOrder) -> String {
    let bytes: Vec<u8> = raw
        .iter()
        .flat_map(|w| match order {
            CharOrder::HighFirst => w.to_be_bytes(),
            CharOrder::LowFirst => w.to_le_bytes(),
        })
        .collect();
    let end = bytes
        .iter()
        .rposition(|b| *b != 0 && *b != b' ')
        .map_or(0, |i| i + 1);
    bytes
        .get(..end)
        .unwrap_or_default()
        .iter()
        .map(|&b| {
            if b.is_ascii() {
                char::from(b)
            } else {
                '\u{FFFD}'
            }
        })
        .collect()
}

/// The registers of an exact whole number on a plain integer tag.
fn encode_int(tag: &Tag, raw: i128, (min, max): (i128, i128)) -> Result<Vec<u16>, EncodeError> {
    if raw < min || raw > max {
        return Err(EncodeError::OutOfRange {
            tag: tag.name.clone(),
            value: raw as f64,
            min: min as f64,
            max: max as f64,
        });
    }
    Ok(int_words(tag.data_type, raw))
}

/// The registers of a raw integer already checked against the type's bounds.
fn int_words(data_type: DataType, raw: i128) -> Vec<u16> {
    match data_type {
        DataType::Bool | DataType::Bit(_) => vec![u16::from(raw != 0)],
        DataType::U16 | DataType::I16 => vec![raw as u16],
        DataType::U32(order) | DataType::I32(order) => order.registers(&(raw as u32).to_be_bytes()),
        DataType::U64(order) | DataType::I64(order) => order.registers(&(raw as u64).to_be_bytes()),
        DataType::F32(_) | DataType::F64(_) | DataType::String { .. } => Vec::new(),
    }
}

fn decode_with(special: SpecialValues, tag: &Tag, raw: &[u16]) -> (Value, Quality) {
    let words = usize::from(tag.data_type.words());
    let Some(raw) = raw.get(..words) else {
        return (Value::Int(0), Quality::CommFailure);
    };
    let word = raw.first().copied().unwrap_or_default();
    match tag.data_type {
        DataType::Bool => (Value::Bool(word != 0), Quality::Good),
        DataType::Bit(bit) => (
            Value::Bool(word.checked_shr(u32::from(bit)).unwrap_or(0) & 1 == 1),
            Quality::Good,
        ),
        DataType::U16 | DataType::I16 => {
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
                Some(quality) => (Value::Float(decimal::f32_shortest(value)), quality),
                None => (Value::Float(tag.present_f32(value)), Quality::Good),
            }
        }
        DataType::U64(order) => (tag.engineering_u64(join64(raw, order)), Quality::Good),
        DataType::I64(order) => (tag.engineering(join64(raw, order) as i64), Quality::Good),
        DataType::F64(order) => (
            Value::Float(tag.present(f64::from_bits(join64(raw, order)))),
            Quality::Good,
        ),
        DataType::String { order, .. } => (Value::Text(decode_text(raw, order)), Quality::Good),
    }
}

fn encode_with(special: SpecialValues, tag: &Tag, value: f64) -> Result<Vec<u16>, EncodeError> {
    if !tag.writable {
        return Err(EncodeError::ReadOnly(tag.name.clone()));
    }
    if !value.is_finite() {
        return Err(EncodeError::NotFinite(tag.name.clone()));
    }
    let raw = tag.to_raw(value);
    if !raw.is_finite() {
        return Err(EncodeError::NotFinite(tag.name.clone()));
    }
    match tag.data_type {
        DataType::F32(order) => {
            let (min, max) = match (tag.raw_range, special) {
                (Some((min, max)), _) => (f64::from(min), f64::from(max)),
                (None, _) => special
                    .f32_write_limit
                    .map_or((f64::from(f32::MIN), f64::from(f32::MAX)), |l| (-l, l)),
            };
            check_range(tag, raw, min, max)?;
            return Ok(split((raw as f32).to_bits(), order));
        }
        DataType::F64(order) => {
            let (min, max) = match tag.raw_range {
                Some((min, max)) => (f64::from(min), f64::from(max)),
                None => (f64::MIN, f64::MAX),
            };
            check_range(tag, raw, min, max)?;
            return Ok(order.registers(&raw.to_bits().to_be_bytes()));
        }
        DataType::String { .. } => {
            return Err(EncodeError::WrongKind {
                tag: tag.name.clone(),
                holds: "text",
                given: "a number",
            })
        }
        _ => {}
    }
    // value -> raw on the decimals of value, offset and scale: 4.6 / 0.1 is 46 exactly.
    let raw = tag
        .to_raw_rounded(value)
        .ok_or_else(|| EncodeError::NotFinite(tag.name.clone()))?;
    let (type_min, type_max) = tag.data_type.raw_bounds();
    let (min, max) = match (tag.raw_range, special.i16_write_range, tag.data_type) {
        (Some((min, max)), _, _) => (f64::from(min), f64::from(max)),
        (None, Some((min, max)), DataType::I16) => (f64::from(min), f64::from(max)),
        (None, _, _) => (type_min, type_max),
    };
    check_range(tag, raw, min.max(type_min), max.min(type_max))?;
    // In range of the type, so the cast is exact.
    Ok(int_words(tag.data_type, raw as i128))
}

fn check_range(tag: &Tag, raw: f64, min: f64, max: f64) -> Result<(), EncodeError> {
    if raw < min || raw > max {
        // A negative scale turns the raw range around.
        let (a, b) = (tag.present(min), tag.present(max));
        return Err(EncodeError::OutOfRange {
            tag: tag.name.clone(),
            value: tag.to_engineering(raw),
            min: a.min(b),
            max: a.max(b),
        });
    }
    Ok(())
}

/// Joins two registers into 32 bits in the given byte order.
pub fn join(words: &[u16], order: ByteOrder) -> u32 {
    let mut two = [0u16; 2];
    for (slot, w) in two.iter_mut().zip(words) {
        *slot = *w;
    }
    let bytes = order.bytes(&two);
    let mut be = [0u8; 4];
    be.copy_from_slice(bytes.get(..4).unwrap_or(&[0; 4]));
    u32::from_be_bytes(be)
}

/// Joins four registers into 64 bits in the given byte order.
pub fn join64(words: &[u16], order: ByteOrder) -> u64 {
    let mut four = [0u16; 4];
    for (slot, w) in four.iter_mut().zip(words) {
        *slot = *w;
    }
    let bytes = order.bytes(&four);
    let mut be = [0u8; 8];
    be.copy_from_slice(bytes.get(..8).unwrap_or(&[0; 8]));
    u64::from_be_bytes(be)
}

/// Splits 32 bits into two registers in the given byte order.
pub fn split(value: u32, order: ByteOrder) -> Vec<u16> {
    order.registers(&value.to_be_bytes())
}
