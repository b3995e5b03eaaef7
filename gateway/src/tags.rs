//! Named tags over the process image: which device datum lives at which registers, and its
//! engineering value, unit and quality.
//!
//! The image keeps raw registers with the quality of the communication (good, stale, comm
//! failure). A tag adds the device's meaning: data type, fix point and scale, unit, and the
//! device's special values (KS vario 31000 "not defined", 32000 "off", 0x8000 "out of range";
//! Altivar 0x8000 "not available"), decoded by the device profile in proto-core. The reported
//! quality is the worse of the two.
//!
//! The directory is built once from the config; zenoh and REST read tags through it, and write
//! them through the same unit service as a Modbus TCP write.
//!
//! Size and speed: one gateway may hold 100 000 tags. An entry keeps only its name and address
//! and shares the rest: its line, device, unit id and profile with the device's other tags, its
//! kind (type, scale, unit, description, ...) with every tag alike; about 50 bytes a tag where a
//! full copy of each took 200. The zenoh feed asks the directory for the tags of every image
//! change; an index by unit, table and address answers with a binary search and the tags in the
//! range, not a look at each of the 100 000.
//!
//! Names: a tag name compares without letter case (ASCII) wherever the gateway looks one up:
//! poll groups in the config, REST paths, zenoh queries and sets (`acc` finds `ACC`). Every
//! answer and every key the gateway writes uses the one spelling the profile or the config gives
//! the tag (`ACC`, `SFr`), so two tags of one device may not differ only in case. A zenoh
//! subscription is matched by zenoh itself, which compares keys exactly: subscribe with that
//! spelling (or a wildcard).
//!
//! Values: value = raw x scale + offset, presented at the tag's places (`decimals`, else those
//! scale and offset imply) by the profile's decode. A write is refused unless the tag holds the
//! value exactly: raw = round((value - offset) / scale) must present as the value written. A value
//! between two steps (4.55 where the tag holds tenths) or outside its range (200 where it holds
//! 0..=100) is refused with the nearest values it can hold, never rounded or clipped. Float tags
//! hold what the float holds (at their `decimals` places, when set).

use std::collections::{HashMap, HashSet};
use std::hash::{Hash, Hasher};
use std::ops::Range;
use std::sync::Arc;
use std::time::SystemTime;

use proto_core::modbus::pdu::{ExceptionCode, Request};
use proto_core::profiles::{
    self, BitUpdate, DataType, DeviceProfile, EncodeError, Quality, Tag, Value,
};

use crate::config::{self, DeviceConfig};
use crate::image::{ProcessImage, Table};
use crate::plant::Config;

mod metrics;

pub use metrics::TagValues;

/// One tag of one device on one line.
///
/// A gateway may hold 100 000 of them, so an entry keeps only what is its own (its name and
/// address) and shares the rest: its device (line, device name, unit id, profile) with the
/// device's other tags, and its kind (table, type, scale, unit, description, ...) with every
/// tag alike (a device of 500 `u16` holding registers has one kind).
#[derive(Clone, Debug)]
pub struct TagEntry {
    device: Arc<DeviceOfTags>,
    /// The tag without its name and address (its name is empty, its address 0: the entry
    /// keeps its own).
    kind: Arc<Tag>,
    name: Box<str>,
    address: u16,
}

/// What the tags of one device share.
#[derive(Debug)]
struct DeviceOfTags {
    line: String,
    device: String,
    unit_id: u8,
    /// The device's profile, for decoding and encoding; its tag list is empty (the entries
    /// hold the tags).
    profile: DeviceProfile,
}

// === impl TagEntry ===

impl TagEntry {
    /// The line's name.
    pub fn line(&self) -> &str {
        &self.device.line
    }

    /// The device's name.
    pub fn device(&self) -> &str {
        &self.device.device
    }

    /// The unit id the device is kept under.
    pub fn unit_id(&self) -> u8 {
        self.device.unit_id
    }

    /// The tag's name, spelled as the profile or the config gives it.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The Modbus table.
    pub fn table(&self) -> Table {
        self.kind.table
    }

    /// The address of the first register (or bit).
    pub fn address(&self) -> u16 {
        self.address
    }

    /// How the words are read.
    pub fn data_type(&self) -> DataType {
        self.kind.data_type
    }

    /// How many registers (or bits) the tag occupies.
    pub fn words(&self) -> u16 {
        self.kind.data_type.words()
    }

    /// The engineering unit, empty for plain numbers.
    pub fn unit(&self) -> &str {
        &self.kind.unit
    }

    /// What the datum is, in a few words (empty when the profile or config says nothing).
    pub fn description(&self) -> &str {
        &self.kind.description
    }

    /// Whether the gateway may write the tag.
    pub fn writable(&self) -> bool {
        self.kind.writable
    }

    /// The whole tag, as the profile or the config gives it (a copy: for writes and checks).
    pub fn tag(&self) -> Tag {
        Tag {
            name: self.name.to_string(),
            address: self.address,
            ..Tag::clone(&self.kind)
        }
    }

    /// The value and the device's quality of the tag's words (`raw[0]` is the word at its
    /// address), decoded by the device's profile.
    pub fn decode(&self, raw: &[u16]) -> (Value, Quality) {
        // Decoding reads neither the name nor the address.
        self.device.profile.decode(&self.kind, raw)
    }

    /// The address after the tag's last register, as a `u32` so that it cannot overflow.
    fn end(&self) -> u32 {
        u32::from(self.address) + u32::from(self.words())
    }

    /// Whether the tag overlaps registers `start..end` of its table: the test
    /// [`TagDirectory::overlapping`] applies.
    fn overlaps(&self, start: u32, end: u32) -> bool {
        u32::from(self.address) < end && start < self.end()
    }
}

/// A tag's current value.
#[derive(Clone, Debug, PartialEq)]
pub struct TagReading {
    /// The engineering value (the raw number when the quality is not good).
    pub value: Value,
    /// The engineering unit, empty for plain numbers.
    pub unit: String,
    /// The worse of the image's quality and the device's special-value quality.
    pub quality: &'static str,
    /// When the oldest register of the tag was read from the device.
    pub timestamp: SystemTime,
}

/// Why a tag could not be written.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TagWriteError {
    /// No such tag.
    #[error("no tag {0}")]
    UnknownTag(String),
    /// The tag is read-only.
    #[error("tag {0} is read-only")]
    ReadOnly(String),
    /// The value does not fit the tag.
    #[error("value {value} does not fit tag {tag}: {reason}")]
    Value {
        tag: String,
        /// The value as given (a text in quotes).
        value: String,
        reason: String,
    },
    /// The device (or the gateway's policy) answered with an exception.
    #[error("the write was answered with exception {0:?}")]
    Exception(ExceptionCode),
}

/// What a tag write sends to the device.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TagWriteOp {
    /// One request (FC 05, 06 or 16).
    Request(Request),
    /// A bit tag: a read-modify-write of its register, one job on the line.
    Bit(BitUpdate),
}

// === impl TagWriteOp ===

impl TagWriteOp {
    /// The request the server's write policy (read-only mode, write ranges) is checked against:
    /// a bit write writes its whole register (FC 06).
    pub fn policy_request(&self) -> Request {
        match self {
            Self::Request(r) => r.clone(),
            Self::Bit(update) => Request::WriteSingleRegister {
                address: update.address,
                value: 0,
            },
        }
    }
}

/// Every tag of the configured devices, in the config's order, with an index by address.
#[derive(Clone, Debug, Default)]
pub struct TagDirectory {
    /// The tags, each device's together, in the order of the config.
    entries: Vec<TagEntry>,
    /// Each device with its tags, a range of `entries`, for [`Self::find`].
    devices: Vec<(Arc<DeviceOfTags>, Range<usize>)>,
    /// Every entry by unit, table and address, for [`Self::overlapping`]: an image change
    /// finds its tags by binary search instead of a look at every tag (100 000 tags and ~800
    /// changes a second would be 80 million comparisons a second).
    by_address: Vec<Slot>,
    /// The most registers (or bits) a tag of a unit's table occupies: how far before a range
    /// a tag may start and still reach into it.
    longest: Vec<((u8, Table), u16)>,
}

/// Where an entry sits in the image: the key of [`TagDirectory::by_address`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
struct Slot {
    unit: u8,
    table: Table,
    address: u16,
    /// The index of the entry.
    entry: u32,
}

// === impl TagDirectory ===

impl TagDirectory {
    /// The tags of every polled device in `config`: the profile's tags, or the config's tag list
    /// for generic devices (plus any config tags on a profiled device).
    pub fn from_config(config: &Config) -> Self {
        let mut builder = Builder::default();
        for (line_name, line) in &config.lines {
            if let Some(slave) = line.protocol.cp_memory_slave() {
                if let Some((unit_id, tags)) = cp_memory_tags(config, slave) {
                    builder.device(
                        line_name,
                        CP_MEMORY_DEVICE,
                        unit_id,
                        DeviceProfile::generic(CP_MEMORY_DEVICE, slave.address, tags),
                    );
                }
            }
            for (device_name, device) in line.devices() {
                builder.device(
                    line_name,
                    device_name,
                    device.unit_id,
                    profile_of(device_name, device),
                );
            }
        }
        builder.build()
    }

    /// All tags, in the config's order (each device's tags together).
    pub fn iter(&self) -> impl Iterator<Item = &TagEntry> {
        self.entries.iter()
    }

    /// One tag by line, device and name (names compare without case: `eta` finds `ETA`).
    pub fn find(&self, line: &str, device: &str, tag: &str) -> Option<&TagEntry> {
        self.devices
            .iter()
            .filter(|(d, _)| d.line == line && d.device == device)
            .filter_map(|(_, range)| self.entries.get(range.clone()))
            .find_map(|tags| tags.iter().find(|e| e.name.eq_ignore_ascii_case(tag)))
    }

    /// The tags that overlap registers `start..start + count` of `table` of `unit`, in the
    /// directory's order: a binary search for the first tag that can reach into the range,
    /// then the tags up to its end.
    pub fn overlapping(
        &self,
        unit: u8,
        table: Table,
        start: u16,
        count: u16,
    ) -> impl Iterator<Item = &TagEntry> {
        let (start, end) = (u32::from(start), u32::from(start) + u32::from(count));
        // A tag reaches into the range when it starts less than its length before it.
        let longest = self
            .longest
            .binary_search_by_key(&(unit, table), |&(key, _)| key)
            .map_or(0, |i| self.longest[i].1);
        let from = (start + 1).saturating_sub(u32::from(longest));
        let first = self.by_address.partition_point(|s| {
            (s.unit, s.table) < (unit, table)
                || ((s.unit, s.table) == (unit, table) && u32::from(s.address) < from)
        });
        let mut hits: Vec<u32> = self.by_address[first..]
            .iter()
            .take_while(|s| s.unit == unit && s.table == table && u32::from(s.address) < end)
            .filter(|s| self.entry(s.entry).overlaps(start, end))
            .map(|s| s.entry)
            .collect();
        hits.sort_unstable();
        hits.into_iter().map(|i| self.entry(i))
    }

    /// The entry at `index` of [`Self::by_address`].
    fn entry(&self, index: u32) -> &TagEntry {
        &self.entries[index as usize]
    }

    /// The tag's value from the image; `None` while its registers are not in the image (nobody
    /// polls them, or no poll has answered yet).
    pub fn read(&self, image: &ProcessImage, entry: &TagEntry) -> Option<TagReading> {
        let table = entry.table();
        let (address, words) = (entry.address(), entry.words());
        let read = match table {
            Table::Coils | Table::DiscreteInputs => {
                let r = image
                    .read_bits(entry.unit_id(), table, address, words)
                    .ok()?;
                crate::image::RangeRead {
                    values: r.values.iter().map(|&b| u16::from(b)).collect(),
                    quality: r.quality,
                    oldest: r.oldest,
                    oldest_at: r.oldest_at,
                }
            }
            Table::HoldingRegisters | Table::InputRegisters => image
                .read_words(entry.unit_id(), table, address, words)
                .ok()?,
        };
        let (value, device_quality) = entry.decode(&read.values);
        let quality = read.quality.worst(device_quality);
        Some(TagReading {
            value,
            unit: entry.unit().to_owned(),
            quality: quality.as_str(),
            timestamp: read.oldest,
        })
    }

    /// What writes `value` to the tag: a number in engineering units, a whole number (exact up
    /// to 64 bits), a bool, or a text for a string tag; checked against the tag's type, range
    /// and write permission.
    pub fn write_op(entry: &TagEntry, value: &Value) -> Result<TagWriteOp, TagWriteError> {
        let name = || full_name(entry);
        if !entry.writable() {
            return Err(TagWriteError::ReadOnly(name()));
        }
        let refused = |reason: String| TagWriteError::Value {
            tag: name(),
            value: value.to_string(),
            reason,
        };
        let tag = &entry.tag();
        let profile = &entry.device.profile;
        let explain = |e: EncodeError| match e {
            EncodeError::OutOfRange { min, max, .. } => {
                let number = value.as_f64();
                let (lo, hi) = match exact_bounds(profile, tag) {
                    Some((lo, hi)) => (lo.to_string(), hi.to_string()),
                    None => (show(tag, min), show(tag, max)),
                };
                let nearest = if number < min { &lo } else { &hi };
                refused(format!(
                    "outside the range {lo}..={hi} of the tag; nearest: {nearest}"
                ))
            }
            other => refused(other.to_string()),
        };
        if let Some(update) = profile.bit_update(tag, value) {
            if tag.table != Table::HoldingRegisters {
                return Err(TagWriteError::ReadOnly(name()));
            }
            return update.map(TagWriteOp::Bit).map_err(explain);
        }
        let words = profile.encode_value(tag, value).map_err(explain)?;
        let exact = value.as_i128().is_some() && exact_bounds(profile, tag).is_some();
        if !exact {
            if let Some(nearest) = inexact(profile, tag, value.as_f64()) {
                let shown: Vec<String> = nearest.iter().map(|&v| show(tag, v)).collect();
                return Err(refused(format!(
                    "{}; nearest: {}",
                    steps(tag),
                    shown.join(" or ")
                )));
            }
        }
        let address = tag.address;
        Ok(TagWriteOp::Request(match (tag.table, words.as_slice()) {
            (Table::Coils, [w]) => Request::WriteSingleCoil {
                address,
                value: *w != 0,
            },
            (Table::HoldingRegisters, [w]) => Request::WriteSingleRegister { address, value: *w },
            (Table::HoldingRegisters, _) => Request::WriteMultipleRegisters {
                address,
                values: words,
            },
            _ => return Err(TagWriteError::ReadOnly(name())),
        }))
    }
}

/// `line/device/tag`, for messages.
fn full_name(entry: &TagEntry) -> String {
    format!("{}/{}/{}", entry.line(), entry.device(), entry.name())
}

/// The exact raw range of a plain integer tag (no scale, offset or device range),
/// whose whole numbers are written without a detour through floats.
fn exact_bounds(profile: &DeviceProfile, tag: &Tag) -> Option<(i128, i128)> {
    let plain = tag.is_plain() && tag.raw_range.is_none() && profile.special_values.is_none();
    plain.then(|| tag.data_type.int_bounds()).flatten()
}

/// The nearest values the tag holds when it cannot hold `value` exactly; `None` when it holds
/// it. The check is the conversion a write makes: raw = round((value - offset) / scale) on the
/// decimals of the three numbers, and the value that raw number is presented as must be `value`
/// itself (at the tag's places: 4.6 on a tag of 0.1 steps is raw 46, presented 4.6; 4.55 would
/// be raw 46 too, presented 4.6, so it is refused). With `decimals` coarser than the steps, the
/// value must have no more places than `decimals`. Only neighbours the tag accepts (its range)
/// are named. Floats hold any value in their range, at their `decimals` places when set.
fn inexact(profile: &DeviceProfile, tag: &Tag, value: f64) -> Option<Vec<f64>> {
    if matches!(tag.data_type, DataType::String { .. } | DataType::Bit(_)) || !value.is_finite() {
        return None;
    }
    let accepted = |v: &f64| profile.encode(tag, *v).is_ok();
    let at_places = |v: f64| {
        let (below, above) = tag.neighbours_at_places(v);
        let mut nearest = vec![below];
        if above != below {
            nearest.push(above);
        }
        nearest.into_iter().filter(accepted).collect::<Vec<f64>>()
    };
    if tag.data_type.is_float() {
        return match tag.decimals {
            Some(_) if !tag.fits_places(value) => Some(at_places(value)),
            _ => None,
        };
    }
    let raw = tag.to_raw_rounded(value)?;
    if tag.present(raw) == value {
        return None;
    }
    // Steps finer than the places presented: the neighbours are the decimals at those places
    // (each one some raw number presents); else the neighbouring raw numbers.
    let steps_finer = tag
        .decimals
        .is_some_and(|d| tag.implied_places() > u32::from(d));
    if steps_finer {
        return Some(at_places(value));
    }
    let exact = tag.to_raw(value);
    let mut nearest: Vec<f64> = [exact.floor(), exact.ceil()]
        .into_iter()
        .map(|r| tag.present(r))
        .filter(accepted)
        .collect();
    nearest.dedup();
    Some(nearest)
}

/// An engineering value with the places the tag presents (4.6, not 4.6000000000000005; 30.0
/// for a tag of 0.5 steps).
fn show(tag: &Tag, value: f64) -> String {
    let places = usize::try_from(tag.places()).unwrap_or(0);
    format!("{:.places$}", tag.round_to_places(value))
}

/// What the tag holds, for a refusal: its steps (the scale, with the scale's places), or the
/// places it presents when they are coarser than the steps.
fn steps(tag: &Tag) -> String {
    match tag.decimals {
        Some(d) if tag.data_type.is_float() || tag.implied_places() > u32::from(d) => {
            let plural = if d == 1 { "" } else { "s" };
            format!("the tag holds values with at most {d} decimal{plural}")
        }
        _ => {
            let step = Tag::new("", tag.table, 0, tag.data_type).scale(tag.scale);
            format!("the tag holds steps of {}", show(&step, tag.scale.abs()))
        }
    }
}

/// The device name of a slave line's CP memory in tag keys (`<line>/memory/DB800.DBW20`).
pub const CP_MEMORY_DEVICE: &str = "memory";

/// The data words of the CP memory a slave line serves under its unit id, as tags named the
/// PLC way (`DB800.DBW20`): register `(n - base) x 512 + w` of the holding table is word `w` of
/// DB `n` (003 6.4.8), with the unit id; `None` when the line serves no unit. Writable where
/// the line's write enables ("Limits") allow FC 06/16.
fn cp_memory_tags(
    config: &Config,
    slave: &crate::protocols::ModbusSlaveRtuConfig,
) -> Option<(u8, Vec<Tag>)> {
    let unit_id = slave.unit_id?;
    let blocks: Vec<(u16, u16)> = config
        .cp_memory
        .data_blocks
        .iter()
        .map(|b| (b.db, b.words))
        .collect();
    let layout = crate::protocols::modbus_slave::cpmem::memory_layout(
        [slave],
        (!blocks.is_empty()).then_some(blocks.as_slice()),
    );
    let words_per_db = u32::from(proto_core::cpmem::WORDS_PER_DB);
    let writable = |register: u32| {
        slave.write_enable.iter().any(|r| {
            r.table == config::ModbusTable::Holding
                && register >= u32::from(r.start)
                && register < u32::from(r.start) + r.count
        })
    };
    let mut tags = Vec::new();
    for &(db, words) in &layout.data_blocks {
        let Some(offset) = db.checked_sub(slave.holding_db) else {
            continue;
        };
        let base = u32::from(offset) * words_per_db;
        for w in 0..u32::from(words).min(words_per_db) {
            let Ok(address) = u16::try_from(base + w) else {
                break;
            };
            let mut tag = Tag::new(
                format!("DB{db}.DBW{}", w * 2),
                Table::HoldingRegisters,
                address,
                DataType::U16,
            );
            if writable(base + w) {
                tag = tag.writable();
            }
            tags.push(tag);
        }
    }
    Some((unit_id, tags))
}

/// Builds a directory: the entries of each device share it, and tags alike share their kind.
#[derive(Default)]
struct Builder {
    entries: Vec<TagEntry>,
    devices: Vec<(Arc<DeviceOfTags>, Range<usize>)>,
    kinds: HashSet<SameKind>,
}

/// A tag compared by its kind: everything but its name and address (floats by their bits).
struct SameKind(Arc<Tag>);

// === impl Builder ===

impl Builder {
    /// Adds the tags of `profile` (taken out of it: the entries hold them) as a device's.
    fn device(&mut self, line: &str, device: &str, unit_id: u8, mut profile: DeviceProfile) {
        let tags = std::mem::take(&mut profile.tags);
        let shared = Arc::new(DeviceOfTags {
            line: line.to_owned(),
            device: device.to_owned(),
            unit_id,
            profile,
        });
        let first = self.entries.len();
        for mut tag in tags {
            let name = std::mem::take(&mut tag.name).into_boxed_str();
            let address = std::mem::take(&mut tag.address);
            let kind = self.kind(tag);
            self.entries.push(TagEntry {
                device: Arc::clone(&shared),
                kind,
                name,
                address,
            });
        }
        self.devices.push((shared, first..self.entries.len()));
    }

    /// The kind of `tag` (without name and address): the one of the first tag alike.
    fn kind(&mut self, tag: Tag) -> Arc<Tag> {
        let probe = SameKind(Arc::new(tag));
        if let Some(SameKind(kind)) = self.kinds.get(&probe) {
            return Arc::clone(kind);
        }
        let kind = Arc::clone(&probe.0);
        self.kinds.insert(probe);
        kind
    }

    fn build(mut self) -> TagDirectory {
        // Kept for the life of the config: no spare capacity.
        self.entries.shrink_to_fit();
        self.devices.shrink_to_fit();
        // A directory of 2^32 tags would not fit in memory (each entry is 40 bytes).
        let mut by_address: Vec<Slot> = (0..=u32::MAX)
            .zip(&self.entries)
            .map(|(entry, e)| Slot {
                unit: e.unit_id(),
                table: e.table(),
                address: e.address,
                entry,
            })
            .collect();
        by_address.sort_unstable();
        let mut longest: HashMap<(u8, Table), u16> = HashMap::new();
        for e in &self.entries {
            let most = longest.entry((e.unit_id(), e.table())).or_default();
            *most = (*most).max(e.words());
        }
        let mut longest: Vec<_> = longest.into_iter().collect();
        longest.sort_unstable();
        TagDirectory {
            entries: self.entries,
            devices: self.devices,
            by_address,
            longest,
        }
    }
}

// === impl SameKind ===

impl SameKind {
    /// What two tags of a kind have in common: every field of [`Tag`] but the name and the
    /// address (a field added to `Tag` must be named here).
    fn key(&self) -> impl Hash + Eq + '_ {
        let Tag {
            name: _,
            address: _,
            description,
            table,
            data_type,
            decimals,
            scale,
            offset,
            unit,
            writable,
            raw_range,
            bits,
        } = &*self.0;
        (
            description,
            table,
            data_type,
            decimals,
            (scale.to_bits(), offset.to_bits()),
            unit,
            writable,
            raw_range,
            bits,
        )
    }
}

impl PartialEq for SameKind {
    fn eq(&self, other: &Self) -> bool {
        self.key() == other.key()
    }
}

impl Eq for SameKind {}

impl Hash for SameKind {
    fn hash<H: Hasher>(&self, state: &mut H) {
        self.key().hash(state);
    }
}

/// The profile of a configured device, with the config's own tags added.
fn profile_of(name: &str, device: &DeviceConfig) -> DeviceProfile {
    let config_tags: Vec<Tag> = device.tags.iter().map(tag_of).collect();
    let Some(mut profile) = device.profile.device_profile() else {
        return DeviceProfile::generic(name, device.address, config_tags);
    };
    profile.tags.extend(config_tags);
    profile
}

/// A config tag as a profile tag.
fn tag_of(t: &config::TagConfig) -> Tag {
    use profiles::{ByteOrder as B, CharOrder, DataType as D};
    let order = match t.byte_order() {
        config::ByteOrder::Abcd => B::Abcd,
        config::ByteOrder::Cdab => B::Cdab,
        config::ByteOrder::Badc => B::Badc,
        config::ByteOrder::Dcba => B::Dcba,
    };
    let data_type = match (t.data_type, t.bit) {
        (config::DataType::Bool, Some(bit)) => D::Bit(bit),
        (config::DataType::Bool, None) => D::Bool,
        (config::DataType::U16, _) => D::U16,
        (config::DataType::I16, _) => D::I16,
        (config::DataType::U32, _) => D::U32(order),
        (config::DataType::I32, _) => D::I32(order),
        (config::DataType::F32, _) => D::F32(order),
        (config::DataType::U64, _) => D::U64(order),
        (config::DataType::I64, _) => D::I64(order),
        (config::DataType::F64, _) => D::F64(order),
        (config::DataType::String, _) => D::String {
            registers: t.registers.unwrap_or(1),
            order: if order.bytes_swapped() {
                CharOrder::LowFirst
            } else {
                CharOrder::HighFirst
            },
        },
    };
    let mut tag = Tag::new(t.name.clone(), t.table.into(), t.address, data_type)
        .scale(t.scale)
        .offset(t.offset)
        .unit(t.unit());
    tag.decimals = t.decimals;
    if let Some(description) = t.description() {
        tag = tag.describe(description);
    }
    if t.writable {
        tag = tag.writable();
    }
    tag
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;
    use crate::image::ImageConfig;

    impl TagDirectory {
        /// The Modbus request that writes the number `value` (engineering units) to a tag that is
        /// not a bit, checked against the tag's type, range and write permission.
        fn write_request(entry: &TagEntry, value: f64) -> Result<Request, TagWriteError> {
            match Self::write_op(entry, &Value::Float(value))? {
                TagWriteOp::Request(request) => Ok(request),
                TagWriteOp::Bit(_) => Err(TagWriteError::Value {
                    tag: full_name(entry),
                    value: value.to_string(),
                    reason: "a bit tag is written by read-modify-write".to_owned(),
                }),
            }
        }
    }

    #[tokio::test]
    async fn demo_tags_decode_values_units_and_special_values() {
        let config = crate::plant::demo();
        let dir = TagDirectory::from_config(&config);
        let eta = dir
            .find("drive", "atv71", "eta")
            .expect("ETA in the Altivar profile");
        assert_eq!(eta.address(), 3201);
        assert_eq!(eta.unit_id(), 2);

        let image = ProcessImage::new(ImageConfig::default());
        assert_eq!(dir.read(&image, eta), None, "nothing polled yet");

        let acc = dir.find("drive", "atv71", "ACC").expect("ACC");
        image.store_words(
            2,
            Table::HoldingRegisters,
            acc.address(),
            &[13],
            Some(Duration::from_secs(5)),
        );
        let reading = dir.read(&image, acc).expect("ACC in the image");
        assert_eq!(reading.quality, "good");
        assert!(reading.value == Value::Float(1.3), "{reading:?}");
        assert_eq!(reading.unit, acc.unit());

        // 0x8000 is the Altivar's "not available".
        image.store_words(
            2,
            Table::HoldingRegisters,
            eta.address(),
            &[0x8000],
            Some(Duration::from_secs(5)),
        );
        assert_ne!(dir.read(&image, eta).expect("ETA").quality, "good");

        let hits: Vec<_> = dir
            .overlapping(2, Table::HoldingRegisters, 9000, 3)
            .map(|e| e.name())
            .collect();
        assert!(hits.contains(&"ACC") && hits.contains(&"DEC"), "{hits:?}");
    }

    #[tokio::test]
    async fn the_cp_memory_of_a_slave_line_is_tags_named_the_plc_way() {
        let config = crate::plant::demo();
        let dir = TagDirectory::from_config(&config);
        let word = dir
            .find("hmi", CP_MEMORY_DEVICE, "DB800.DBW20")
            .expect("DB 800 word 10");
        assert_eq!((word.unit_id(), word.address()), (50, 10));
        assert!(word.writable(), "the demo write-enables DB 800");
        let image = ProcessImage::new(ImageConfig::default());
        image.store_words(50, Table::HoldingRegisters, 10, &[1234], None);
        assert_eq!(
            dir.read(&image, word).expect("in the image").value,
            Value::Int(1234)
        );
        let request = TagDirectory::write_request(word, 7.0).expect("writable");
        assert_eq!(
            request,
            Request::WriteSingleRegister {
                address: 10,
                value: 7
            }
        );
    }

    /// The reason of a refused write.
    fn refusal(entry: &TagEntry, value: f64) -> String {
        match TagDirectory::write_request(entry, value) {
            Err(TagWriteError::Value { reason, .. }) => reason,
            other => panic!("{value} on {}: {other:?}", entry.name()),
        }
    }

    #[test]
    fn a_value_the_tag_cannot_hold_exactly_is_refused_with_the_nearest_values() {
        let dir = TagDirectory::from_config(&crate::plant::demo());
        // ACC: 0.1 s steps, 0.1..=999.9 s (raw 1..=9999).
        let acc = dir.find("drive", "atv71", "ACC").expect("ACC");
        assert_eq!(
            refusal(acc, 4.55),
            "the tag holds steps of 0.1; nearest: 4.5 or 4.6"
        );
        assert_eq!(
            TagDirectory::write_request(acc, 4.55)
                .unwrap_err()
                .to_string(),
            "value 4.55 does not fit tag drive/atv71/ACC: the tag holds steps of 0.1; nearest: 4.5 or 4.6"
        );
        assert_eq!(
            refusal(acc, 1000.0),
            "outside the range 0.1..=999.9 of the tag; nearest: 999.9"
        );
        // Only the neighbour inside the range is named.
        assert_eq!(
            refusal(acc, 0.05),
            "the tag holds steps of 0.1; nearest: 0.1"
        );
        for exact in [4.5, 4.6, 0.1, 999.9, 1.3] {
            assert!(
                TagDirectory::write_request(acc, exact).is_ok(),
                "{exact} fits ACC"
            );
        }
        // A word of the CP memory: integers 0..=65535.
        let word = dir
            .find("hmi", CP_MEMORY_DEVICE, "DB800.DBW20")
            .expect("a memory word");
        assert_eq!(
            refusal(word, 200.5),
            "the tag holds steps of 1; nearest: 200 or 201"
        );
        assert_eq!(
            refusal(word, 70000.0),
            "outside the range 0..=65535 of the tag; nearest: 65535"
        );
        assert_eq!(
            refusal(word, -1.0),
            "outside the range 0..=65535 of the tag; nearest: 0"
        );
    }

    #[test]
    fn a_config_tag_with_a_scale_names_its_steps() {
        let text = crate::plant::demo_toml().replace(
            "[lines.ksvario.devices.ksvario]\nprofile = \"ksvario\"\naddress = 17\nunit_id = 17\n",
            "[lines.ksvario.devices.ksvario]\nprofile = \"ksvario\"\naddress = 17\nunit_id = 17\n\
             tags = [{ name = \"mode\", table = \"holding\", address = 3415, type = \"u16\", writable = true, scale = 0.5 }]\n",
        );
        let config = crate::plant::parse(&text).expect("valid");
        let dir = TagDirectory::from_config(&config);
        let mode = dir.find("ksvario", "ksvario", "mode").expect("mode");
        assert_eq!(
            refusal(mode, 0.25),
            "the tag holds steps of 0.5; nearest: 0.0 or 0.5"
        );
        assert!(TagDirectory::write_request(mode, 1.5).is_ok());
    }

    /// The demo config with `tags` (inline tables) on the KS vario, and its directory.
    fn with_ksvario_tags(tags: &str) -> TagDirectory {
        let text = crate::plant::demo_toml().replace(
            "[lines.ksvario.devices.ksvario]\nprofile = \"ksvario\"\naddress = 17\nunit_id = 17\n",
            &format!(
                "[lines.ksvario.devices.ksvario]\nprofile = \"ksvario\"\naddress = 17\nunit_id = 17\n\
                 tags = [{tags}]\n"
            ),
        );
        TagDirectory::from_config(&crate::plant::parse(&text).expect("valid"))
    }

    #[test]
    fn values_are_raw_times_scale_plus_offset_and_decimals_only_round() {
        let dir = with_ksvario_tags(
            "{ name = \"t\", table = \"holding\", address = 3415, type = \"i16\", scale = 0.1, offset = -273.15, writable = true }, \
             { name = \"t2\", table = \"holding\", address = 3415, type = \"i16\", scale = 0.1, offset = -273.15, decimals = 2 }, \
             { name = \"t1\", table = \"holding\", address = 3415, type = \"i16\", scale = 0.1, offset = -273.15, decimals = 1 }, \
             { name = \"fine\", table = \"holding\", address = 3416, type = \"u16\", scale = 0.01, decimals = 1, writable = true }, \
             { name = \"pf\", table = \"holding\", address = 3417, type = \"f32\", writable = true }, \
             { name = \"pf2\", table = \"holding\", address = 3417, type = \"f32\", decimals = 2, writable = true }",
        );
        let find = |name| dir.find("ksvario", "ksvario", name).expect(name);
        assert_eq!(find("t").tag().decimals, None);
        assert_eq!(find("t2").tag().decimals, Some(2));
        let image = ProcessImage::new(ImageConfig::default());
        image.store_words(17, Table::HoldingRegisters, 3415, &[2931, 460], None);
        image.store_words(
            17,
            Table::HoldingRegisters,
            3417,
            &[(0.95f32.to_bits() >> 16) as u16, 0.95f32.to_bits() as u16],
            None,
        );
        let json = |name| {
            let value = dir.read(&image, find(name)).expect("in the image").value;
            serde_json::to_string(&crate::api::model::ScalarValue::from(value)).expect("JSON")
        };
        // Before: 19.950000000000045 (no decimals), -270.219 (decimals = 2 divided by 100).
        assert_eq!(json("t"), "19.95");
        assert_eq!(json("t2"), "19.95");
        assert_eq!(json("t1"), "20.0");
        assert_eq!(json("fine"), "4.6");
        // Before: 0.949999988079071.
        assert_eq!(json("pf"), "0.95");

        // Writes: raw = round((value - offset) / scale), presented as the value written.
        assert_eq!(
            TagDirectory::write_request(find("t"), 19.95),
            Ok(Request::WriteSingleRegister {
                address: 3415,
                value: 2931
            })
        );
        assert_eq!(
            refusal(find("t"), 19.97),
            "the tag holds steps of 0.1; nearest: 19.95 or 20.05"
        );
        // Steps of 0.01 shown with one place: a value is written at the places shown.
        assert_eq!(
            TagDirectory::write_request(find("fine"), 4.6),
            Ok(Request::WriteSingleRegister {
                address: 3416,
                value: 460
            })
        );
        assert_eq!(
            refusal(find("fine"), 4.57),
            "the tag holds values with at most 1 decimal; nearest: 4.5 or 4.6"
        );
        // A float holds any value, at its decimals when set.
        assert!(TagDirectory::write_request(find("pf"), 0.123_456).is_ok());
        assert!(TagDirectory::write_request(find("pf2"), 0.12).is_ok());
        assert_eq!(
            refusal(find("pf2"), 0.123),
            "the tag holds values with at most 2 decimals; nearest: 0.12 or 0.13"
        );
    }

    #[test]
    fn new_tag_kinds_are_written_exactly_or_refused_with_a_reason() {
        // The demo's meter has a tag of each kind.
        let dir = TagDirectory::from_config(&crate::plant::demo());
        let find = |name| dir.find("ksvario", "meter", name).expect(name);
        let op = |name, value: Value| TagDirectory::write_op(find(name), &value);
        // u64, registers reversed: exact beyond 2^53 and i64::MAX.
        assert_eq!(
            op("preset", Value::UInt(u64::MAX - 1)),
            Ok(TagWriteOp::Request(Request::WriteMultipleRegisters {
                address: 50,
                values: vec![0xFFFE, 0xFFFF, 0xFFFF, 0xFFFF]
            }))
        );
        let refused = |name, value: Value| match op(name, value) {
            Err(TagWriteError::Value { reason, .. }) => reason,
            other => panic!("{other:?}"),
        };
        assert_eq!(
            refused("preset", Value::Int(-1)),
            "outside the range 0..=18446744073709551615 of the tag; nearest: 0"
        );
        assert_eq!(
            op("serial", Value::Text("AB".into())),
            Ok(TagWriteOp::Request(Request::WriteMultipleRegisters {
                address: 20,
                values: vec![0x4142, 0, 0, 0, 0, 0, 0, 0]
            }))
        );
        assert!(refused("serial", Value::Text("0123456789ABCDEFG".into()))
            .contains("at most 16 ASCII characters"));
        assert!(refused("serial", Value::Int(5)).contains("holds text"));
        assert_eq!(
            op("relay", Value::Bool(true)),
            Ok(TagWriteOp::Bit(BitUpdate {
                address: 30,
                and: !8,
                or: 8
            }))
        );
        assert!(matches!(
            op("running", Value::Bool(true)),
            Err(TagWriteError::ReadOnly(_))
        ));
        // value = raw x 0.5 - 20: 30.25 lies between two steps.
        assert_eq!(
            refused("setpoint", Value::Float(30.25)),
            "the tag holds steps of 0.5; nearest: 30.0 or 30.5"
        );
        assert_eq!(
            op("setpoint", Value::Float(30.0)),
            Ok(TagWriteOp::Request(Request::WriteSingleRegister {
                address: 31,
                value: 100
            }))
        );
        assert_eq!(
            refused("setpoint", Value::Int(-21)),
            "outside the range -20.0..=32747.5 of the tag; nearest: -20.0"
        );
    }

    /// What `overlapping` gave before the index: every entry, in the directory's order, that
    /// is of the unit and table and shares a register with `start..start + count`.
    fn scanned(dir: &TagDirectory, unit: u8, table: Table, start: u16, count: u16) -> Vec<usize> {
        let end = u32::from(start) + u32::from(count);
        dir.iter()
            .enumerate()
            .filter(|(_, e)| {
                let t_start = u32::from(e.address());
                let t_end = t_start + u32::from(e.data_type().words());
                e.unit_id() == unit
                    && e.table() == table
                    && t_start < end
                    && u32::from(start) < t_end
            })
            .map(|(i, _)| i)
            .collect()
    }

    /// The positions in the directory of what `overlapping` gives (`at`: each entry's
    /// position by its address in memory).
    fn indexed(
        dir: &TagDirectory,
        at: &HashMap<*const TagEntry, usize>,
        (unit, table, start, count): (u8, Table, u16, u16),
    ) -> Vec<usize> {
        dir.overlapping(unit, table, start, count)
            .map(|hit| at[&std::ptr::from_ref(hit)])
            .collect()
    }

    /// The names of the tags `overlapping` gives, in its order.
    fn hit_names(dir: &TagDirectory, unit: u8, table: Table, start: u16, count: u16) -> Vec<&str> {
        dir.overlapping(unit, table, start, count)
            .map(TagEntry::name)
            .collect()
    }

    /// The demo with more tags on its meter (unit 30): of every table and length, some at the
    /// ends of the address space.
    fn with_every_kind_of_tag() -> TagDirectory {
        let tags = [
            r#"{ name = "c5", table = "coil", address = 5, type = "bool" },"#,
            r#"{ name = "c6", table = "coil", address = 6, type = "bool", writable = true },"#,
            r#"{ name = "d5", table = "discrete", address = 5, type = "bool" },"#,
            r#"{ name = "i9", table = "input", address = 9, type = "u32" },"#,
            r#"{ name = "w70", table = "holding", address = 70, type = "u16" },"#,
            r#"{ name = "l71", table = "holding", address = 71, type = "i32" },"#,
            r#"{ name = "w73", table = "holding", address = 73, type = "u16" },"#,
            r#"{ name = "s100", table = "holding", address = 100, type = "string", registers = 8 },"#,
            r#"{ name = "q110", table = "holding", address = 110, type = "u64" },"#,
            r#"{ name = "b0", table = "holding", address = 200, bit = 0 },"#,
            r#"{ name = "b15", table = "holding", address = 200, bit = 15 },"#,
            r#"{ name = "b7", table = "holding", address = 200, bit = 7 },"#,
            r#"{ name = "w201", table = "holding", address = 201, type = "u16" },"#,
            r#"{ name = "top", table = "holding", address = 65534, type = "u32" },"#,
            r#"{ name = "last", table = "input", address = 65535, type = "u16" },"#,
        ];
        let marker = "  # f32 low word first: holding 60..61";
        assert!(
            crate::plant::demo_toml().contains(marker),
            "the demo's meter changed"
        );
        let text =
            crate::plant::demo_toml().replace(marker, &format!("{}\n{marker}", tags.join("\n")));
        TagDirectory::from_config(&crate::plant::parse(&text).expect("valid"))
    }

    #[test]
    fn overlapping_gives_exactly_the_tags_a_scan_gives() {
        let dir = with_every_kind_of_tag();
        let mut units: Vec<u8> = dir.iter().map(TagEntry::unit_id).collect();
        units.sort_unstable();
        units.dedup();
        // A unit without tags too.
        units.push(255);
        let tables = [
            Table::Coils,
            Table::DiscreteInputs,
            Table::HoldingRegisters,
            Table::InputRegisters,
        ];
        let at: HashMap<*const TagEntry, usize> = (0..)
            .zip(dir.iter())
            .map(|(i, e)| (std::ptr::from_ref(e), i))
            .collect();
        let mut compared = 0;
        for &unit in &units {
            for table in tables {
                // Ranges starting at the edges of each tag of the table (and of the address
                // space), of lengths from none to all.
                let mut starts: Vec<u16> = dir
                    .iter()
                    .filter(|e| e.unit_id() == unit && e.table() == table)
                    .flat_map(|e| {
                        let (a, end) = (u32::from(e.address()), e.end());
                        [
                            a.saturating_sub(1),
                            a,
                            a + 1,
                            end.saturating_sub(1),
                            end,
                            end + 1,
                        ]
                    })
                    .filter_map(|a| u16::try_from(a).ok())
                    .chain([0, 1, 65534, 65535])
                    .collect();
                starts.sort_unstable();
                starts.dedup();
                for &start in &starts {
                    for count in [0, 1, 2, 3, 8, 125, u16::MAX] {
                        let want = scanned(&dir, unit, table, start, count);
                        assert_eq!(
                            indexed(&dir, &at, (unit, table, start, count)),
                            want,
                            "unit {unit} {table:?} {start}+{count}"
                        );
                        compared += usize::from(!want.is_empty());
                    }
                }
            }
        }
        assert!(compared > 1000, "only {compared} queries hit a tag");
    }

    #[test]
    fn overlapping_finds_long_tags_that_start_before_the_range() {
        let dir = with_every_kind_of_tag();
        let holding = |start, count| hit_names(&dir, 30, Table::HoldingRegisters, start, count);
        let none = Vec::<&str>::new();
        // A 32-bit tag reaches one register past its address.
        assert_eq!(holding(72, 1), ["l71"]);
        assert_eq!(holding(72, 2), ["l71", "w73"]);
        assert_eq!(holding(70, 2), ["w70", "l71"]);
        assert_eq!(holding(69, 1), none);
        assert_eq!(holding(74, 30), ["s100"]);
        // An 8-register string reaches seven past its address, a u64 three.
        assert_eq!(holding(107, 1), ["s100"]);
        assert_eq!(holding(107, 4), ["s100", "q110"]);
        assert_eq!(holding(108, 2), none);
        assert_eq!(holding(113, 1), ["q110"]);
        assert_eq!(holding(114, 1), none);
        // The end of the address space.
        assert_eq!(holding(65535, 1), ["top"]);
        assert_eq!(holding(65535, u16::MAX), ["top"]);
        assert_eq!(holding(65533, 1), none);
        assert_eq!(
            hit_names(&dir, 30, Table::InputRegisters, 65535, 1),
            ["last"]
        );
        assert_eq!(hit_names(&dir, 30, Table::InputRegisters, 10, 1), ["i9"]);
        // A range of no registers overlaps no tag starting at it, but one that straddles it
        // (what a scan gave).
        assert_eq!(holding(71, 0), none);
        assert_eq!(holding(72, 0), ["l71"]);
    }

    #[test]
    fn overlapping_gives_the_bits_of_a_register_and_coils_by_their_table() {
        let dir = with_every_kind_of_tag();
        // Every tag of register 200, in the config's order.
        assert_eq!(
            hit_names(&dir, 30, Table::HoldingRegisters, 200, 1),
            ["b0", "b15", "b7"]
        );
        assert_eq!(
            hit_names(&dir, 30, Table::HoldingRegisters, 200, 2),
            ["b0", "b15", "b7", "w201"]
        );
        assert_eq!(hit_names(&dir, 30, Table::Coils, 0, 10), ["c5", "c6"]);
        assert_eq!(hit_names(&dir, 30, Table::Coils, 6, 1), ["c6"]);
        assert_eq!(hit_names(&dir, 30, Table::DiscreteInputs, 5, 1), ["d5"]);
        assert!(hit_names(&dir, 30, Table::HoldingRegisters, 5, 2).is_empty());
        // Another unit's registers are not the meter's.
        assert!(hit_names(&dir, 31, Table::Coils, 0, 10).is_empty());
    }

    #[test]
    fn tags_alike_share_their_kind_and_keep_their_own_name_and_address() {
        let dir = with_every_kind_of_tag();
        let find = |name| dir.find("ksvario", "meter", name).expect(name);
        assert!(Arc::ptr_eq(&find("c5").device, &find("w70").device));
        assert!(Arc::ptr_eq(&find("w70").kind, &find("w201").kind));
        assert!(
            !Arc::ptr_eq(&find("c5").kind, &find("c6").kind),
            "c6 is writable"
        );
        assert!(
            !Arc::ptr_eq(&find("b0").kind, &find("b7").kind),
            "another bit"
        );
        let l71 = find("l71").tag();
        assert_eq!((l71.name.as_str(), l71.address), ("l71", 71));
        assert_eq!(l71.data_type, DataType::I32(profiles::ByteOrder::Abcd));
        let cp = |name| dir.find("hmi", CP_MEMORY_DEVICE, name).expect(name);
        assert!(Arc::ptr_eq(
            &cp("DB800.DBW20").kind,
            &cp("DB800.DBW22").kind
        ));
        let word = cp("DB800.DBW22").tag();
        assert_eq!((word.name.as_str(), word.address), ("DB800.DBW22", 11));
        assert_eq!(word.data_type, DataType::U16);
        assert!(word.writable);
    }

    #[test]
    fn names_compare_without_case_and_answer_with_the_profiles_spelling() {
        let dir = TagDirectory::from_config(&crate::plant::demo());
        for asked in ["sfr", "SFR", "SFr"] {
            let entry = dir.find("drive", "atv71", asked).expect("SFr");
            assert_eq!(entry.name(), "SFr");
        }
    }

    #[test]
    fn writes_are_checked_against_the_tag() {
        let dir = TagDirectory::from_config(&crate::plant::demo());
        let eta = dir.find("drive", "atv71", "ETA").expect("ETA");
        assert!(matches!(
            TagDirectory::write_request(eta, 1.0),
            Err(TagWriteError::ReadOnly(_))
        ));
        let acc = dir.find("drive", "atv71", "ACC").expect("ACC");
        let request = TagDirectory::write_request(acc, 1.3).expect("ACC is writable");
        assert!(
            matches!(request, Request::WriteSingleRegister { address: 9001, .. }),
            "{request:?}"
        );
    }
}
