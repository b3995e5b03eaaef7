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
//! Names: a tag name compares without letter case (ASCII) wherever the gateway looks one up:
//! poll groups in the config, REST paths, zenoh queries and sets (`acc` finds `ACC`). Every
//! answer and every key the gateway writes uses the one spelling the profile or the config gives
//! the tag (`ACC`, `SFr`), so two tags of one device may not differ only in case. A zenoh
//! subscription is matched by zenoh itself, which compares keys exactly: subscribe with that
//! spelling (or a wildcard).
//!
//! Values: a write is refused unless the tag holds the value exactly: a value between two steps
//! of the tag's fix point and scale (4.55 where the tag holds tenths) or outside its range (200
//! where it holds 0..=100) is refused with the nearest values it can hold, never rounded or
//! clipped. Float tags (`f32`) hold what the float holds.

use std::sync::Arc;
use std::time::SystemTime;

use proto_core::modbus::pdu::{ExceptionCode, Request};
use proto_core::profiles::{self, DeviceProfile, EncodeError, Tag, Value};

use crate::config::{self, Config, DeviceConfig};
use crate::image::{ProcessImage, Table};

/// One tag of one device on one line.
#[derive(Clone, Debug)]
pub struct TagEntry {
    /// The line's name.
    pub line: String,
    /// The device's name.
    pub device: String,
    /// The unit id the device is kept under.
    pub unit_id: u8,
    /// The device's profile (shared by its tags), for decoding and encoding; its tag list is
    /// empty (each entry holds its own tag).
    pub profile: Arc<DeviceProfile>,
    /// The tag.
    pub tag: Tag,
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
        value: f64,
        reason: String,
    },
    /// The device (or the gateway's policy) answered with an exception.
    #[error("the write was answered with exception {0:?}")]
    Exception(ExceptionCode),
}

/// Every tag of the configured devices.
#[derive(Clone, Debug, Default)]
pub struct TagDirectory {
    entries: Vec<TagEntry>,
}

// === impl TagDirectory ===

impl TagDirectory {
    /// The tags of every polled device in `config`: the profile's tags, or the config's tag list
    /// for generic devices (plus any config tags on a profiled device).
    pub fn from_config(config: &Config) -> Self {
        let mut entries = Vec::new();
        for (line_name, line) in &config.lines {
            if let config::ProtocolConfig::ModbusSlaveRtu(slave) = &line.protocol {
                entries.extend(cp_memory_tags(config, line_name, slave));
            }
            for (device_name, device) in line.devices() {
                let (profile, tags) = shared(profile_of(device_name, device));
                entries.extend(tags.into_iter().map(|tag| TagEntry {
                    line: line_name.clone(),
                    device: device_name.clone(),
                    unit_id: device.unit_id,
                    profile: Arc::clone(&profile),
                    tag,
                }));
            }
        }
        // Kept for the life of the config: no spare capacity (10 000 tags, 2 MiB).
        entries.shrink_to_fit();
        Self { entries }
    }

    /// All tags.
    pub fn iter(&self) -> impl Iterator<Item = &TagEntry> {
        self.entries.iter()
    }

    /// One tag by line, device and name (names compare without case: `eta` finds `ETA`).
    pub fn find(&self, line: &str, device: &str, tag: &str) -> Option<&TagEntry> {
        self.entries
            .iter()
            .find(|e| e.line == line && e.device == device && e.tag.name.eq_ignore_ascii_case(tag))
    }

    /// The tags that overlap registers `start..start + count` of `table` of `unit`.
    pub fn overlapping(
        &self,
        unit: u8,
        table: Table,
        start: u16,
        count: u16,
    ) -> impl Iterator<Item = &TagEntry> {
        let end = u32::from(start) + u32::from(count);
        self.entries.iter().filter(move |e| {
            let t_start = u32::from(e.tag.address);
            let t_end = t_start + u32::from(e.tag.data_type.words());
            e.unit_id == unit && e.tag.table == table && t_start < end && u32::from(start) < t_end
        })
    }

    /// The tag's value from the image; `None` while its registers are not in the image (nobody
    /// polls them, or no poll has answered yet).
    pub fn read(&self, image: &ProcessImage, entry: &TagEntry) -> Option<TagReading> {
        let table = entry.tag.table;
        let words = entry.tag.data_type.words();
        let read = match table {
            Table::Coils | Table::DiscreteInputs => {
                let r = image
                    .read_bits(entry.unit_id, table, entry.tag.address, words)
                    .ok()?;
                crate::image::RangeRead {
                    values: r.values.iter().map(|&b| u16::from(b)).collect(),
                    quality: r.quality,
                    oldest: r.oldest,
                    oldest_at: r.oldest_at,
                }
            }
            Table::HoldingRegisters | Table::InputRegisters => image
                .read_words(entry.unit_id, table, entry.tag.address, words)
                .ok()?,
        };
        let (value, device_quality) = entry.profile.decode(&entry.tag, &read.values);
        let quality = read.quality.worst(device_quality);
        Some(TagReading {
            value,
            unit: entry.tag.unit.clone(),
            quality: quality.as_str(),
            timestamp: read.oldest,
        })
    }

    /// The Modbus request that writes `value` (engineering units) to the tag, checked against
    /// the tag's type, range and write permission.
    pub fn write_request(entry: &TagEntry, value: f64) -> Result<Request, TagWriteError> {
        let name = || format!("{}/{}/{}", entry.line, entry.device, entry.tag.name);
        if !entry.tag.writable {
            return Err(TagWriteError::ReadOnly(name()));
        }
        let refused = |reason: String| TagWriteError::Value {
            tag: name(),
            value,
            reason,
        };
        let words = entry
            .profile
            .encode(&entry.tag, value)
            .map_err(|e| match e {
                EncodeError::OutOfRange { min, max, .. } => {
                    let nearest = if value < min { min } else { max };
                    refused(format!(
                        "outside the range {}..={} of the tag; nearest: {}",
                        show(&entry.tag, min),
                        show(&entry.tag, max),
                        show(&entry.tag, nearest)
                    ))
                }
                other => refused(other.to_string()),
            })?;
        if let Some(nearest) = inexact(entry, value) {
            let shown: Vec<String> = nearest.iter().map(|&v| show(&entry.tag, v)).collect();
            return Err(refused(format!(
                "the tag holds steps of {}; nearest: {}",
                show(&entry.tag, entry.tag.factor()),
                shown.join(" or ")
            )));
        }
        let address = entry.tag.address;
        Ok(match (entry.tag.table, words.as_slice()) {
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
        })
    }
}

/// The nearest values the tag holds when it cannot hold `value` exactly (between two steps of
/// its fix point and scale); `None` when it holds it. Only neighbours the tag accepts (its range)
/// are named. Floats hold any value in their range.
fn inexact(entry: &TagEntry, value: f64) -> Option<Vec<f64>> {
    if matches!(entry.tag.data_type, profiles::DataType::F32(_)) {
        return None;
    }
    let factor = entry.tag.factor();
    let raw = value / factor;
    // A decimal value such as 4.5 is not exactly 45 x 0.1 in binary: compare with a tolerance
    // far below one step.
    if (raw - raw.round()).abs() <= 1e-9 * raw.abs().max(1.0) {
        return None;
    }
    let nearest: Vec<f64> = [raw.floor(), raw.ceil()]
        .into_iter()
        .map(|r| r * factor)
        .filter(|&v| entry.profile.encode(&entry.tag, v).is_ok())
        .collect();
    Some(nearest)
}

/// An engineering value with as many decimals as the tag's steps have (4.6, not
/// 4.6000000000000005).
fn show(tag: &Tag, value: f64) -> String {
    let factor = tag.factor().abs();
    let decimals = (0..=9usize)
        .find(|&d| {
            let scaled = factor * 10f64.powi(i32::try_from(d).unwrap_or(0));
            (scaled - scaled.round()).abs() < 1e-9 * scaled.max(1.0)
        })
        .unwrap_or(9);
    format!("{value:.decimals$}")
}

/// The device name of a slave line's CP memory in tag keys (`<line>/memory/DB800.DBW20`).
pub const CP_MEMORY_DEVICE: &str = "memory";

/// The data words of the CP memory a slave line serves under its unit id, as tags named the
/// PLC way (`DB800.DBW20`): register `(n - base) x 512 + w` of the holding table is word `w` of
/// DB `n` (003 6.4.8). Writable where the line's write enables ("Limits") allow FC 06/16.
fn cp_memory_tags(
    config: &Config,
    line: &str,
    slave: &config::ModbusSlaveRtuConfig,
) -> Vec<TagEntry> {
    let Some(unit_id) = slave.unit_id else {
        return Vec::new();
    };
    let blocks: Vec<(u16, u16)> = config
        .cp_memory
        .data_blocks
        .iter()
        .map(|b| (b.db, b.words))
        .collect();
    let layout = crate::cpmem::config::memory_layout(
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
                profiles::DataType::U16,
            );
            if writable(base + w) {
                tag = tag.writable();
            }
            tags.push(tag);
        }
    }
    let (profile, tags) = shared(DeviceProfile::generic(
        CP_MEMORY_DEVICE,
        slave.address,
        tags,
    ));
    tags.into_iter()
        .map(|tag| TagEntry {
            line: line.to_owned(),
            device: CP_MEMORY_DEVICE.to_owned(),
            unit_id,
            profile: Arc::clone(&profile),
            tag,
        })
        .collect()
}

/// The profile shared by a device's entries, and its tags for the entries to own: each entry
/// holds its tag, and the profile is only asked to decode and encode (its special values), so
/// it keeps no second copy of them.
fn shared(mut profile: DeviceProfile) -> (Arc<DeviceProfile>, Vec<Tag>) {
    let tags = std::mem::take(&mut profile.tags);
    (Arc::new(profile), tags)
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
    use profiles::{DataType as D, WordOrder as W};
    let order = match t.word_order {
        config::WordOrder::HighFirst => W::HighFirst,
        config::WordOrder::LowFirst => W::LowFirst,
    };
    let data_type = match t.data_type {
        config::DataType::Bool => D::Bool,
        config::DataType::U16 => D::U16,
        config::DataType::I16 => D::I16,
        config::DataType::U32 => D::U32(order),
        config::DataType::I32 => D::I32(order),
        config::DataType::F32 => D::F32(order),
    };
    let mut tag = Tag::new(t.name.clone(), t.table.into(), t.address, data_type)
        .decimals(t.decimals)
        .scale(t.scale)
        .unit(t.unit.clone());
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

    #[tokio::test]
    async fn demo_tags_decode_values_units_and_special_values() {
        let config = config::demo();
        let dir = TagDirectory::from_config(&config);
        let eta = dir
            .find("drive", "atv71", "eta")
            .expect("ETA in the Altivar profile");
        assert_eq!(eta.tag.address, 3201);
        assert_eq!(eta.unit_id, 2);

        let image = ProcessImage::new(ImageConfig::default());
        assert_eq!(dir.read(&image, eta), None, "nothing polled yet");

        let acc = dir.find("drive", "atv71", "ACC").expect("ACC");
        image.store_words(
            2,
            Table::HoldingRegisters,
            acc.tag.address,
            &[13],
            Some(Duration::from_secs(5)),
        );
        let reading = dir.read(&image, acc).expect("ACC in the image");
        assert_eq!(reading.quality, "good");
        assert!(
            (reading.value.as_f64() - 13.0 * acc.tag.factor()).abs() < 1e-9,
            "{reading:?}"
        );
        assert_eq!(reading.unit, acc.tag.unit);

        // 0x8000 is the Altivar's "not available".
        image.store_words(
            2,
            Table::HoldingRegisters,
            eta.tag.address,
            &[0x8000],
            Some(Duration::from_secs(5)),
        );
        assert_ne!(dir.read(&image, eta).expect("ETA").quality, "good");

        let hits: Vec<_> = dir
            .overlapping(2, Table::HoldingRegisters, 9000, 3)
            .map(|e| e.tag.name.as_str())
            .collect();
        assert!(hits.contains(&"ACC") && hits.contains(&"DEC"), "{hits:?}");
    }

    #[tokio::test]
    async fn the_cp_memory_of_a_slave_line_is_tags_named_the_plc_way() {
        let config = config::demo();
        let dir = TagDirectory::from_config(&config);
        let word = dir
            .find("hmi", CP_MEMORY_DEVICE, "DB800.DBW20")
            .expect("DB 800 word 10");
        assert_eq!((word.unit_id, word.tag.address), (50, 10));
        assert!(word.tag.writable, "the demo write-enables DB 800");
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
            other => panic!("{value} on {}: {other:?}", entry.tag.name),
        }
    }

    #[test]
    fn a_value_the_tag_cannot_hold_exactly_is_refused_with_the_nearest_values() {
        let dir = TagDirectory::from_config(&config::demo());
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
        let text = config::demo_toml().replace(
            "[lines.ksvario.devices.ksvario]\nprofile = \"ksvario\"\naddress = 17\nunit_id = 17\n",
            "[lines.ksvario.devices.ksvario]\nprofile = \"ksvario\"\naddress = 17\nunit_id = 17\n\
             tags = [{ name = \"mode\", table = \"holding\", address = 3415, type = \"u16\", writable = true, scale = 0.5 }]\n",
        );
        let config = config::parse(&text).expect("valid");
        let dir = TagDirectory::from_config(&config);
        let mode = dir.find("ksvario", "ksvario", "mode").expect("mode");
        assert_eq!(
            refusal(mode, 0.25),
            "the tag holds steps of 0.5; nearest: 0.0 or 0.5"
        );
        assert!(TagDirectory::write_request(mode, 1.5).is_ok());
    }

    #[test]
    fn names_compare_without_case_and_answer_with_the_profiles_spelling() {
        let dir = TagDirectory::from_config(&config::demo());
        for asked in ["sfr", "SFR", "SFr"] {
            let entry = dir.find("drive", "atv71", asked).expect("SFr");
            assert_eq!(entry.tag.name, "SFr");
        }
    }

    #[test]
    fn writes_are_checked_against_the_tag() {
        let dir = TagDirectory::from_config(&config::demo());
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
