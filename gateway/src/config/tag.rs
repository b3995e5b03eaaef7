//! A tag of a device: its table, address, type, byte order, scale and texts as the configuration
//! spells them, the address ranges of write policies, and their readers.

use std::mem::size_of;

use proto_core::modbus::Table;
use serde::{Deserialize, Serialize};

use super::reader::{check_name, serde_name, Cx, Fields};

/// A tag value is `raw * scale`, by default the raw value.
pub const DEFAULT_SCALE: f64 = 1.0;
/// Most decimals a tag may declare (`decimals` only rounds what is presented; without it a value
/// has the places its scale and offset imply).
pub const MAX_DECIMALS: u8 = 9;
/// 32 and 64-bit values: high word first, high byte first, the Modbus convention (001: KS vario
/// floats in "Motorola format"); strings: the first character in the high byte.
pub const DEFAULT_BYTE_ORDER: ByteOrder = ByteOrder::Abcd;
/// A tag value is `raw * scale + offset`, by default no offset.
pub const DEFAULT_OFFSET: f64 = 0.0;
/// Most registers of a string tag: what one FC 16 writes (Modbus Application Protocol V1.1b3
/// 6.12: 1..123 registers).
pub const MAX_STRING_REGISTERS: u16 = 123;
/// Bits of a register a bit tag may name (0 the least significant).
pub const MAX_BIT: u8 = 15;

/// A Modbus data table as the configuration spells it; [`Table`] is the table itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ModbusTable {
    /// Holding registers (FC 03, 06, 16, 23).
    Holding,
    /// Input registers (FC 04).
    Input,
    /// Coils (FC 01, 05, 15).
    Coil,
    /// Discrete inputs (FC 02).
    Discrete,
}

impl ModbusTable {
    /// Every table, holding registers first.
    pub const ALL: [Self; 4] = [Self::Holding, Self::Input, Self::Coil, Self::Discrete];

    /// Registers (16-bit) rather than bits.
    pub fn is_register(self) -> bool {
        matches!(self, Self::Holding | Self::Input)
    }

    /// Whether Modbus can write this table (coils with FC 05/15, holding registers with FC 06/16).
    pub fn is_writable(self) -> bool {
        matches!(self, Self::Coil | Self::Holding)
    }
}

impl From<ModbusTable> for Table {
    fn from(t: ModbusTable) -> Self {
        match t {
            ModbusTable::Holding => Self::HoldingRegisters,
            ModbusTable::Input => Self::InputRegisters,
            ModbusTable::Coil => Self::Coils,
            ModbusTable::Discrete => Self::DiscreteInputs,
        }
    }
}

/// `count` consecutive addresses of one table from `start`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct AddressRange {
    pub table: ModbusTable,
    pub start: u16,
    pub count: u32,
}

impl AddressRange {
    /// Whether `[start, start + count)` lies inside this range.
    pub fn covers(&self, table: ModbusTable, start: u16, count: u32) -> bool {
        self.table == table
            && start >= self.start
            && u32::from(start) + count <= u32::from(self.start) + self.count
    }
}

/// The type of a tag's value.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DataType {
    /// One coil or discrete input, or with `bit` one bit of a register.
    Bool,
    U16,
    I16,
    /// Two registers.
    U32,
    /// Two registers.
    I32,
    /// Two registers, IEEE 754.
    F32,
    /// Four registers.
    U64,
    /// Four registers.
    I64,
    /// Four registers, IEEE 754.
    F64,
    /// ASCII text over `registers` registers, two characters a register.
    String,
}

impl DataType {
    /// Registers the type occupies (1 for bool), `None` for a string (its `registers`).
    pub fn fixed_width(self) -> Option<u32> {
        match self {
            Self::Bool | Self::U16 | Self::I16 => Some(1),
            Self::U32 | Self::I32 | Self::F32 => Some(2),
            Self::U64 | Self::I64 | Self::F64 => Some(4),
            Self::String => None,
        }
    }

    /// Whether the type has more than one register to order (32 and 64-bit numbers).
    pub fn is_multi_word(self) -> bool {
        self.fixed_width().is_some_and(|w| w > 1)
    }
}

/// Where the bytes of a 32 or 64-bit value sit in its registers (docs/tags.md has the table).
/// The letters name the value's bytes from the most significant down, as they appear on the
/// wire from the tag's address on; for 64-bit values the four names stand for ABCDEFGH,
/// GHEFCDAB, BADCFEHG and HGFEDCBA, which are accepted as well. For a string, `ABCD`
/// (`high-first`) puts the first character of each register in its high byte, `BADC`
/// (`low-first`) in its low byte.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum ByteOrder {
    /// Big endian (the Modbus convention): high word first, high byte first.
    #[default]
    #[serde(rename = "ABCD", alias = "ABCDEFGH", alias = "high-first")]
    Abcd,
    /// The registers in reverse order (low word first), each big endian.
    #[serde(rename = "CDAB", alias = "GHEFCDAB", alias = "low-first")]
    Cdab,
    /// The registers in order, the bytes of each swapped.
    #[serde(rename = "BADC", alias = "BADCFEHG")]
    Badc,
    /// Little endian: registers reversed and bytes swapped.
    #[serde(rename = "DCBA", alias = "HGFEDCBA")]
    Dcba,
}

/// A named value of a device. Its name is boxed (no spare capacity, 8 bytes less), its unit and
/// description share one pointer ([`TagTexts`]): a large gateway keeps a hundred thousand tags
/// for as long as they are in force (56 bytes a tag, was 104).
///
/// Written out (`Serialize`) as `name, table, address, type, byte_order?, registers?, bit?,
/// scale, offset, decimals?, unit, writable, description?` (`?`: only when given).
#[derive(Debug, Clone, PartialEq)]
pub struct TagConfig {
    pub name: Box<str>,
    pub table: ModbusTable,
    pub address: u16,
    /// Defaults to `bool` for coils and discrete inputs (and for a `bit`), `u16` for registers.
    pub data_type: DataType,
    /// The byte order of a 32/64-bit value or the character order of a string; absent: ABCD.
    pub byte_order: Option<ByteOrder>,
    /// The registers of a string (required for strings; others may only give their width).
    pub registers: Option<u16>,
    /// A bit (0..=15) of a holding or input register, read as a bool.
    pub bit: Option<u8>,
    /// The value is `raw * scale + offset`.
    pub scale: f64,
    /// Added after the scale.
    pub offset: f64,
    /// The places a value is presented with and a write is checked at, 0..=9; absent: the
    /// places scale and offset imply. Rounds only: the value is `raw * scale + offset`.
    pub decimals: Option<u8>,
    /// Writes from Modbus TCP, zenoh or REST are accepted (holding registers and coils only).
    pub writable: bool,
    /// The engineering unit (free text, `unit`) and what the value is (free text for people:
    /// REST, zenoh, the status page; `description`).
    pub texts: TagTexts,
}

// A hundred thousand of them stay in memory (docs/benchmarks.md, the ceiling rows).
const _: () = assert!(size_of::<TagConfig>() <= 56);

/// A tag's unit and description behind one pointer: none for a tag that has neither (the
/// common case in a large list of plain registers), 8 bytes a tag instead of 32.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TagTexts(Option<Box<UnitAndDescription>>);

/// The unit (empty: none) and the description of a tag that has either.
type UnitAndDescription = (Box<str>, Option<Box<str>>);

// === impl TagTexts ===

impl TagTexts {
    /// A unit (empty: none) and a description.
    pub fn new(unit: &str, description: Option<&str>) -> Self {
        if unit.is_empty() && description.is_none() {
            Self(None)
        } else {
            Self(Some(Box::new((unit.into(), description.map(Into::into)))))
        }
    }

    /// The engineering unit, empty for none.
    pub fn unit(&self) -> &str {
        self.0.as_ref().map_or("", |t| &t.0)
    }

    /// The description, if there is one.
    pub fn description(&self) -> Option<&str> {
        self.0.as_ref().and_then(|t| t.1.as_deref())
    }
}

impl Serialize for TagConfig {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let mut s = serializer.serialize_struct("TagConfig", 13)?;
        s.serialize_field("name", &self.name)?;
        s.serialize_field("table", &self.table)?;
        s.serialize_field("address", &self.address)?;
        s.serialize_field("type", &self.data_type)?;
        if let Some(order) = &self.byte_order {
            s.serialize_field("byte_order", order)?;
        }
        if let Some(registers) = &self.registers {
            s.serialize_field("registers", registers)?;
        }
        if let Some(bit) = &self.bit {
            s.serialize_field("bit", bit)?;
        }
        s.serialize_field("scale", &self.scale)?;
        s.serialize_field("offset", &self.offset)?;
        if let Some(decimals) = &self.decimals {
            s.serialize_field("decimals", decimals)?;
        }
        s.serialize_field("unit", self.texts.unit())?;
        s.serialize_field("writable", &self.writable)?;
        if let Some(description) = self.texts.description() {
            s.serialize_field("description", description)?;
        }
        s.end()
    }
}

impl TagConfig {
    /// The engineering unit, empty for none.
    pub fn unit(&self) -> &str {
        self.texts.unit()
    }

    /// The description, if there is one.
    pub fn description(&self) -> Option<&str> {
        self.texts.description()
    }

    /// The byte order in effect (ABCD unless given).
    pub fn byte_order(&self) -> ByteOrder {
        self.byte_order.unwrap_or(DEFAULT_BYTE_ORDER)
    }

    /// Whether the value occupies more than `registers` registers.
    pub fn words_exceed(&self, registers: u16) -> bool {
        self.width() > u32::from(registers)
    }

    /// Registers (or bits) the value occupies.
    pub fn width(&self) -> u32 {
        self.data_type
            .fixed_width()
            .unwrap_or_else(|| u32::from(self.registers.unwrap_or(1)))
    }
}

// === readers ===

pub(crate) fn read_range(cx: &mut Cx, path: &str, value: &toml::Value) -> Option<AddressRange> {
    let mut f = Fields::of(cx, value, path.to_owned())?;
    let r = range_fields(cx, &mut f);
    f.finish(cx);
    r
}

/// The `table`, `start` and `count` keys of a range table that may hold further keys.
pub(crate) fn range_fields(cx: &mut Cx, f: &mut Fields<'_>) -> Option<AddressRange> {
    let table = f.choice::<ModbusTable>(cx, "table");
    if !f.has("table") {
        cx.issue(f.at("table"), "missing required key");
    }
    let start = f.required_int::<u16>(cx, "start", 0..=u16::MAX, "");
    let count = f.required_int::<u32>(cx, "count", 1..=65_536, "");
    let r = AddressRange {
        table: table?,
        start: start?,
        count: count?,
    };
    if u32::from(r.start) + r.count > 65_536 {
        cx.issue(
            f.at("count"),
            format!("range {}+{} runs past address 65535", r.start, r.count),
        );
        return None;
    }
    Some(r)
}

pub(super) fn read_tag(cx: &mut Cx, path: &str, value: &toml::Value) -> Option<TagConfig> {
    let mut f = Fields::of(cx, value, path.to_owned())?;
    let name = f.required_string(cx, "name");
    if let Some(n) = &name {
        check_name(cx, &f.at("name"), n);
    }
    let table = f.choice::<ModbusTable>(cx, "table");
    if !f.has("table") {
        cx.issue(f.at("table"), "missing required key");
    }
    let address = f.required_int::<u16>(cx, "address", 0..=u16::MAX, "");
    let data_type = f.choice::<DataType>(cx, "type");
    let bit = f.int::<u8>(cx, "bit", 0..=MAX_BIT, "a register has bits 0..15");
    // A missing or bad table is reported above; the stand-in keeps the tag (so that poll groups
    // naming it raise nothing more) and agrees with its type.
    let table_or_standin = table.unwrap_or(match data_type {
        Some(DataType::Bool) if bit.is_none() => ModbusTable::Coil,
        _ => ModbusTable::Holding,
    });
    // A bad bit is reported above; the stand-in type raises nothing more.
    let data_type = data_type.unwrap_or(if table_or_standin.is_register() && bit.is_none() {
        DataType::U16
    } else {
        DataType::Bool
    });
    let registers = f.int::<u16>(cx, "registers", 1..=MAX_STRING_REGISTERS, "FC 16: 1..123");
    match (data_type.fixed_width(), registers) {
        (None, None) => cx.issue(
            f.at("registers"),
            "a string tag needs registers = N (two characters a register)",
        ),
        (Some(width), Some(given)) if u32::from(given) != width => cx.issue(
            f.at("registers"),
            format!(
                "a {} value occupies {width} register{}, not {given}",
                serde_name(data_type),
                if width == 1 { "" } else { "s" }
            ),
        ),
        _ => {}
    }
    let byte_order = read_byte_order(cx, &mut f, data_type);
    let scale = f.float_or(cx, "scale", DEFAULT_SCALE);
    if scale == 0.0 {
        cx.issue(
            f.at("scale"),
            "scale 0 makes every raw value 0 and cannot be written back",
        );
    }
    // Read in the order the keys are listed (the order of their issues).
    let offset = f.float_or(cx, "offset", DEFAULT_OFFSET);
    let decimals = f.int::<u8>(cx, "decimals", 0..=MAX_DECIMALS, "");
    let unit = f.string_or(cx, "unit", "");
    let writable = f.bool_or(cx, "writable", false);
    let description = f.string(cx, "description");
    let tag = TagConfig {
        table: table_or_standin,
        address: address.unwrap_or_default(),
        data_type,
        byte_order,
        registers,
        bit,
        scale,
        offset,
        decimals,
        texts: TagTexts::new(&unit, description.as_deref()),
        writable,
        name: name.clone().unwrap_or_default().into_boxed_str(),
    };
    f.finish(cx);
    name.map(|_| tag)
}

/// The `byte_order` key (or its older name `word_order`): one of the four orders for 32 and
/// 64-bit values; `high-first` / `low-first` (ABCD / BADC) for a string; for a 16-bit value or a
/// bool only the order the wire has anyway (ABCD, `high-first`), since one register carries its
/// high byte first (Modbus Application Protocol V1.1b3 4.2) and there is no word to order.
fn read_byte_order(cx: &mut Cx, f: &mut Fields<'_>, data_type: DataType) -> Option<ByteOrder> {
    let key = match (f.has("byte_order"), f.has("word_order")) {
        (true, true) => {
            cx.issue(
                f.at("word_order"),
                "give byte_order or its older name word_order, not both",
            );
            f.raw("word_order");
            "byte_order"
        }
        (false, true) => "word_order",
        _ => "byte_order",
    };
    let raw = f.raw(key)?;
    let at = f.at(key);
    if data_type == DataType::String {
        return match raw.as_str() {
            Some("high-first" | "ABCD") => Some(ByteOrder::Abcd),
            Some("low-first" | "BADC") => Some(ByteOrder::Badc),
            _ => {
                cx.issue(
                    at,
                    "a string's order is \"high-first\" (first character in the high byte, \
                     ABCD) or \"low-first\" (in the low byte, BADC)",
                );
                None
            }
        };
    }
    let order = super::reader::choice_value::<ByteOrder>(cx, raw, &at)?;
    if !data_type.is_multi_word() && order != ByteOrder::Abcd {
        cx.issue(
            at,
            format!(
                "a {} value is one register sent high byte first; only ABCD (high-first) applies",
                serde_name(data_type)
            ),
        );
        return None;
    }
    Some(order)
}
