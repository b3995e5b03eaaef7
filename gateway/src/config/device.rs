//! Devices polled by a Modbus master line: profile, addresses, request limits, back-off, tags and
//! poll groups. The profiles themselves, their limits and tags are proto-core's
//! (`proto_core::profiles::registry`); the config names them and may only lower the limits.

mod check;

use std::time::Duration;

use proto_core::modbus::Table;
use proto_core::profiles::registry;
use proto_core::profiles::{
    DeviceProfile, ReadWriteLimits, Registered, RequestLimits, ScannerSpec,
};
use serde::{Deserialize, Serialize};

use super::check::{needs, Needs};
use super::reader::{check_name, int_value, string_value, Cx, Fields};
use super::tag::{read_range, read_tag, AddressRange, ModbusTable, TagConfig};

/// Modbus Application Protocol V1.1b3, 4.4 / Modbus over Serial Line V1.02 2.2: unicast
/// addresses are 1..=247; 0 is broadcast. 002 (Altivar, "Adressen") agrees: 1..247.
pub const MAX_DEVICE_ADDRESS: u8 = 247;
/// First wait before a device that stopped answering is probed (the seeds are silent on offline
/// devices; the policy is the gateway's).
pub const DEFAULT_OFFLINE_BACKOFF_MIN: Duration = Duration::from_secs(1);
/// Longest wait between probes of a device that does not answer: a short probe costs the line
/// about [`DEFAULT_PROBE_TIMEOUT_MIN`], so the device can be asked every 5 s and is found again
/// within 5 s of its return.
pub const DEFAULT_OFFLINE_BACKOFF_MAX: Duration = Duration::from_secs(5);
/// The least a short probe of an offline device waits for the start of a reply by default: well
/// above a reply delay seen through USB adapters and a busy host (tens of milliseconds), well
/// below the CP's 2 s.
pub const DEFAULT_PROBE_TIMEOUT_MIN: Duration = Duration::from_millis(100);
/// Range of `probe_timeout_min`: the reply monitoring time's (003 6.4.2.1: "Range:
/// 5 ... 65500ms"); a floor at or above the line's reply monitoring time makes every probe full.
pub const PROBE_TIMEOUT_MIN_RANGE: (Duration, Duration) =
    (Duration::from_millis(5), Duration::from_millis(65_500));
/// Every this many probes of an offline device, one waits the line's full reply monitoring time
/// by default: about once a minute at the default back-off of at most 5 s.
pub const DEFAULT_FULL_PROBE_EVERY: u32 = 12;
/// Range of `full_probe_every`: 1 (every probe waits the full time) to 1000 (the seeds are
/// silent).
pub const FULL_PROBE_EVERY_RANGE: (u32, u32) = (1, 1000);
/// Polls in a row without a valid answer that put a device offline by default: the CP gives up
/// a transfer after 6 attempts (003 6.3.3 "Transmission attempts", default 6, its only retry
/// count; the Modbus master itself sends each request once, 003 6.4.2.1), so a device is given
/// up after as many failed polls. One corrupted or lost reply only ages the values.
pub const DEFAULT_OFFLINE_AFTER: u32 = 6;
/// Range of `offline_after` (003 6.3.3: "Range of values: 1...255").
pub const OFFLINE_AFTER_RANGE: (u32, u32) = (1, 255);
/// Unpolled addresses a merged read may include: none by default, because the Altivar and the
/// KS vario answer exception 02 when the first word of a read is undefined (002, 001).
pub const DEFAULT_BRIDGE_GAP: u16 = 0;
/// Back-off bounds accepted in the config.
pub const BACKOFF_RANGE: (Duration, Duration) =
    (Duration::from_millis(10), Duration::from_secs(3600));
/// Shortest and longest poll period.
pub const POLL_PERIOD_RANGE: (Duration, Duration) =
    (Duration::from_millis(10), Duration::from_secs(86_400));

/// A device's type: a profile of proto-core's registry
/// ([`registry::PROFILES`]: `altivar71`, `ksvario`, ...) or `generic` (any Modbus device
/// described by the config's tag list). Not a closed list: a profile added to the registry is
/// known here by its name, with its capabilities ([`Registered::scanner`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Profile {
    /// The registry's name, or [`GENERIC_PROFILE`].
    name: &'static str,
}

/// The name of the profile of a device known only by its tags.
pub const GENERIC_PROFILE: &str = "generic";

/// How much one request may carry: the profile's [`RequestLimits`], which the config may only
/// lower (0 means the device does not support the function). Written back under the config's
/// keys (`read_registers`, `write_registers`, `rw_read_registers`, `rw_write_registers`,
/// `read_bits`, `write_bits`).
fn serialize_limits<S: serde::Serializer>(l: &RequestLimits, s: S) -> Result<S::Ok, S::Error> {
    use serde::ser::SerializeStruct;
    let mut st = s.serialize_struct("RequestLimits", 6)?;
    st.serialize_field("read_registers", &l.read_registers)?;
    st.serialize_field("write_registers", &l.write_registers)?;
    st.serialize_field("rw_read_registers", &rw_read(l))?;
    st.serialize_field("rw_write_registers", &rw_write(l))?;
    st.serialize_field("read_bits", &l.read_bits)?;
    st.serialize_field("write_bits", &l.write_bits)?;
    st.end()
}

/// Registers one FC 23 may read (0: no FC 23).
fn rw_read(l: &RequestLimits) -> u16 {
    l.read_write.map_or(0, |rw| rw.read)
}

/// Registers one FC 23 may write (0: no FC 23).
fn rw_write(l: &RequestLimits) -> u16 {
    l.read_write.map_or(0, |rw| rw.write)
}

// === impl Profile ===

impl Profile {
    /// A device described by the config's tags only.
    pub const GENERIC: Self = Self {
        name: GENERIC_PROFILE,
    };

    /// The profile named `name` (ASCII case ignored): the registry's, or `generic`.
    pub fn named(name: &str) -> Option<Self> {
        if name.eq_ignore_ascii_case(GENERIC_PROFILE) {
            return Some(Self::GENERIC);
        }
        registry::lookup(name).map(|r| Self { name: r.name })
    }

    /// Every name a config may give: the registry's, then `generic`.
    pub fn names() -> Vec<&'static str> {
        registry::names()
            .chain(std::iter::once(GENERIC_PROFILE))
            .collect()
    }

    /// The names as a message lists them: `altivar71, ksvario or generic`.
    pub fn names_listed() -> String {
        let names = Self::names();
        match names.split_last() {
            Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
            _ => names.join(""),
        }
    }

    /// The profile's entry in proto-core's registry, `None` for `generic`.
    pub fn registered(self) -> Option<&'static Registered> {
        registry::lookup(self.name)
    }

    /// The configuration's name of the profile (`altivar71`, `ksvario`, `generic`).
    pub const fn name(self) -> &'static str {
        self.name
    }

    /// The device's communication scanner, if its profile has one.
    pub fn scanner(self) -> Option<ScannerSpec> {
        self.registered().and_then(|r| r.scanner)
    }

    /// The register map of the device, `None` for `generic` (built from the config's tags).
    pub fn device_profile(self) -> Option<DeviceProfile> {
        self.registered().map(|r| (r.build)())
    }

    /// The device's own limits: the profile's, or those of the Modbus Application Protocol
    /// V1.1b3 for a generic device (the CP master itself goes to 127 registers / 2040 bits,
    /// 003 6.4.4, but a device that follows the specification refuses more).
    pub fn max_limits(self) -> RequestLimits {
        self.registered()
            .map_or(RequestLimits::MODBUS, |r| r.limits)
    }

    /// Where the limits come from, for messages.
    fn limits_source(self) -> String {
        self.registered().map_or_else(
            || "Modbus Application Protocol V1.1b3".to_owned(),
            |r| format!("the {} profile, {}", r.name, r.source),
        )
    }

    /// The tables the device serves: those its profile's read functions reach (FC 01..04),
    /// every table for a generic device.
    pub fn tables(self) -> Vec<ModbusTable> {
        let Some(profile) = self.device_profile() else {
            return ModbusTable::ALL.to_vec();
        };
        ModbusTable::ALL
            .into_iter()
            .filter(|t| {
                profile
                    .functions
                    .iter()
                    .any(|f| Table::read_by(f.0) == Some(Table::from(*t)))
            })
            .collect()
    }

    /// Tag names the profile defines (lower case), which poll groups may name and the config's
    /// own tags may not reuse.
    pub fn tag_names(self) -> Vec<String> {
        self.device_profile().map_or_else(Vec::new, |p| {
            p.tags.iter().map(|t| t.name.to_ascii_lowercase()).collect()
        })
    }
}

impl Serialize for Profile {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name)
    }
}

impl<'de> Deserialize<'de> for Profile {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        Self::named(&name).ok_or_else(|| {
            let expected: Vec<String> = Self::names().iter().map(|n| format!("`{n}`")).collect();
            serde::de::Error::custom(format!(
                "unknown variant `{name}`, expected one of {}",
                expected.join(", ")
            ))
        })
    }
}

/// Addresses read together at one period.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PollGroup {
    pub name: String,
    #[serde(with = "humantime_serde")]
    pub period: Duration,
    /// Tag names (the config's tags and the profile's); boxed, as they are never grown.
    pub tags: Vec<Box<str>>,
    /// Address ranges read as they are.
    pub ranges: Vec<AddressRange>,
}

/// One device on a Modbus master line.
///
/// Written out (`Serialize`) with every key, except a device read from a template: its
/// `template` and only the keys whose values differ from the template's, as an operator writes
/// it (reading that back gives the same device).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(remote = "Self")]
pub struct DeviceConfig {
    /// The template the device was read from (`template = "NAME"`), if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub template: Option<String>,
    /// The template read alone and written out: what the device is written back against.
    #[serde(skip)]
    pub template_base: Option<std::sync::Arc<toml::Table>>,
    pub profile: Profile,
    /// Slave address on the serial line, 1..=247.
    pub address: u8,
    /// Unit id on Modbus TCP, 1..=255, unique in the gateway; defaults to `address`.
    pub unit_id: u8,
    /// Effective request limits: the profile's, lowered by the config.
    #[serde(serialize_with = "serialize_limits")]
    pub limits: RequestLimits,
    /// First wait after the device stopped answering.
    #[serde(with = "humantime_serde")]
    pub offline_backoff_min: Duration,
    /// The wait doubles up to this bound while the device stays silent.
    #[serde(with = "humantime_serde")]
    pub offline_backoff_max: Duration,
    /// The least a short probe waits: it waits 4 x the device's slowest recent reply delay (and
    /// 4 x t3.5), at least this, at most the line's `reply_timeout`.
    #[serde(with = "humantime_serde")]
    pub probe_timeout_min: Duration,
    /// Every this many probes, one waits the line's full `reply_timeout` (1: every probe).
    pub full_probe_every: u32,
    /// Polls in a row without a valid answer that put the device offline (commands never do).
    pub offline_after: u32,
    /// Largest run of addresses nobody polls that a merged read may include (0: never).
    pub bridge_gap: u16,
    pub tags: Vec<TagConfig>,
    pub poll: Vec<PollGroup>,
    /// The Altivar communication scanner, exchanged with one FC 23 a cycle (absent: off).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scanner: Option<ScannerConfig>,
}

/// The Altivar 61/71 communication scanner (002 "Kommunikationsscanner"): NM1..NM`inputs` read
/// and NC1..NC`outputs` written with one FC 23 every `period`, when `enabled`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ScannerConfig {
    /// Off by default: the table alone changes nothing.
    pub enabled: bool,
    /// Input words NM1.. read each cycle, 1..8.
    pub inputs: u16,
    /// Output words NC1.. written each cycle, 1..8.
    pub outputs: u16,
    #[serde(with = "humantime_serde")]
    pub period: Duration,
}

/// The scanner's cycle by default.
pub const DEFAULT_SCANNER_PERIOD: Duration = Duration::from_millis(100);
/// Scanner words in each direction by default: the factory assignment's (002: NCA1 = CMD,
/// NCA2 = LFRD; NMA1 = ETA, NMA2 = RFRD).
pub const DEFAULT_SCANNER_WORDS: u16 = 2;

/// Where the scanner's words and their number come from, for a profile without a scanner (whose
/// `scanner` table is refused anyway).
const SCANNER_CITE: &str = "002 Kommunikationsscanner: NM1..NM8, NC1..NC8";
/// Scanner words in each direction at most, for a profile without a scanner.
const MAX_SCANNER_WORDS: u16 = 8;

/// The device's `scanner` table, if present: only an Altivar has one, and its words must fit
/// one FC 23 within the device's limits.
fn read_scanner(
    cx: &mut Cx,
    f: &mut Fields<'_>,
    profile: Option<Profile>,
    limits: &RequestLimits,
) -> Option<ScannerConfig> {
    let mut t = f.table(cx, "scanner")?;
    let spec = profile.map(Profile::scanner);
    let other = matches!(spec, Some(None));
    if other {
        let with: Vec<String> = registry::PROFILES
            .iter()
            .filter(|r| r.scanner.is_some())
            .map(|r| format!("profile = {:?}", r.name))
            .collect();
        cx.issue(
            t.path().to_owned(),
            format!(
                "the communication scanner is the Altivar's (002); only with {}",
                with.join(" or ")
            ),
        );
    }
    let (max, cite) = spec
        .flatten()
        .map_or((MAX_SCANNER_WORDS, SCANNER_CITE), |s| {
            (s.max_words, s.source)
        });
    let enabled = t.bool_or(cx, "enabled", false);
    let inputs = t.int_or(cx, "inputs", 1..=max, DEFAULT_SCANNER_WORDS, cite);
    let outputs = t.int_or(cx, "outputs", 1..=max, DEFAULT_SCANNER_WORDS, cite);
    let (lo, hi) = POLL_PERIOD_RANGE;
    let period = t.duration_or(cx, "period", lo..=hi, DEFAULT_SCANNER_PERIOD, "");
    if enabled && !other && (inputs > rw_read(limits) || outputs > rw_write(limits)) {
        cx.issue(
            t.path().to_owned(),
            format!(
                "{inputs} input and {outputs} output words do not fit one FC 23 of this device \
                 (limits rw_read_registers {}, rw_write_registers {})",
                rw_read(limits),
                rw_write(limits)
            ),
        );
    }
    t.finish(cx);
    Some(ScannerConfig {
        enabled,
        inputs,
        outputs,
        period,
    })
}

// === readers ===

fn read_limits(cx: &mut Cx, f: &mut Fields<'_>, profile: Profile) -> RequestLimits {
    let max = profile.max_limits();
    let Some(mut t) = f.table(cx, "limits") else {
        return max;
    };
    let cite = profile.limits_source();
    let mut one = |cx: &mut Cx, key: &'static str, hi: u16, min: u16| -> u16 {
        let lo = min.min(hi);
        t.int_or(cx, key, lo..=hi, hi, &cite)
    };
    let read_registers = one(cx, "read_registers", max.read_registers, 1);
    let write_registers = one(cx, "write_registers", max.write_registers, 1);
    let read_write = ReadWriteLimits {
        read: one(cx, "rw_read_registers", rw_read(&max), 0),
        write: one(cx, "rw_write_registers", rw_write(&max), 0),
    };
    let limits = RequestLimits {
        read_registers,
        write_registers,
        read_bits: one(cx, "read_bits", max.read_bits, 0),
        write_bits: one(cx, "write_bits", max.write_bits, 0),
        // A profile without FC 23 keeps none; 0 / 0 in the config leaves the quantities 0.
        read_write: max.read_write.map(|_| read_write),
        max_adu_len: max.max_adu_len,
    };
    t.finish(cx);
    limits
}

fn read_poll(cx: &mut Cx, path: &str, value: &toml::Value) -> Option<PollGroup> {
    let mut f = Fields::of(cx, value, path.to_owned())?;
    let name = f.required_string(cx, "name");
    if let Some(n) = &name {
        check_name(cx, &f.at("name"), n);
    }
    let (lo, hi) = POLL_PERIOD_RANGE;
    let period = f.duration(cx, "period", lo..=hi, "");
    if !f.has("period") {
        cx.issue(f.at("period"), "missing required key");
    }
    let raw_tags = f.array(cx, "tags");
    let raw_ranges = f.array(cx, "ranges");
    if raw_tags.is_empty() && raw_ranges.is_empty() {
        cx.issue(f.path().to_owned(), "a poll group needs tags or ranges");
    }
    // Sized to the file's lists: a device's lists are kept as long as it is in force.
    let mut tags = Vec::with_capacity(raw_tags.len());
    for (p, v) in raw_tags {
        tags.extend(string_value(cx, v, &p).map(String::into_boxed_str));
    }
    let mut ranges = Vec::with_capacity(raw_ranges.len());
    for (p, v) in raw_ranges {
        ranges.extend(read_range(cx, &p, v));
    }
    f.finish(cx);
    Some(PollGroup {
        name: name?,
        period: period?,
        tags,
        ranges,
    })
}

impl DeviceConfig {
    pub(crate) fn read(cx: &mut Cx, path: &str, value: &toml::Value) -> Option<Self> {
        let mut f = Fields::of(cx, value, path.to_owned())?;
        let profile = f.choice::<Profile>(cx, "profile");
        if !f.has("profile") {
            cx.issue(
                f.at("profile"),
                format!("missing required key ({})", Profile::names_listed()),
            );
        }
        let address = read_address(cx, &mut f);
        let unit_id = f.int(cx, "unit_id", 1..=u8::MAX, "");
        let limits = read_limits(cx, &mut f, profile.unwrap_or(Profile::GENERIC));
        let (blo, bhi) = BACKOFF_RANGE;
        let (plo, phi) = PROBE_TIMEOUT_MIN_RANGE;
        let (flo, fhi) = FULL_PROBE_EVERY_RANGE;
        let (olo, ohi) = OFFLINE_AFTER_RANGE;
        let mut device = Self {
            template: None,
            template_base: None,
            // A bad profile is reported above; generic stands in (it accepts every table).
            profile: profile.unwrap_or(Profile::GENERIC),
            address: address.unwrap_or_default(),
            unit_id: unit_id.or(address).unwrap_or_default(),
            offline_backoff_min: f.duration_or(
                cx,
                "offline_backoff_min",
                blo..=bhi,
                DEFAULT_OFFLINE_BACKOFF_MIN,
                "",
            ),
            offline_backoff_max: f.duration_or(
                cx,
                "offline_backoff_max",
                blo..=bhi,
                DEFAULT_OFFLINE_BACKOFF_MAX,
                "",
            ),
            probe_timeout_min: f.duration_or(
                cx,
                "probe_timeout_min",
                plo..=phi,
                DEFAULT_PROBE_TIMEOUT_MIN,
                "003 6.4.2.1",
            ),
            full_probe_every: f.int_or(
                cx,
                "full_probe_every",
                flo..=fhi,
                DEFAULT_FULL_PROBE_EVERY,
                "",
            ),
            offline_after: f.int_or(
                cx,
                "offline_after",
                olo..=ohi,
                DEFAULT_OFFLINE_AFTER,
                "003 6.3.3",
            ),
            bridge_gap: f.int_or(cx, "bridge_gap", 0..=u16::MAX, DEFAULT_BRIDGE_GAP, ""),
            scanner: read_scanner(cx, &mut f, profile, &limits),
            limits,
            tags: Vec::new(),
            poll: Vec::new(),
        };
        (device.tags, device.poll) = read_tags_and_poll(cx, &mut f, profile);
        f.finish(cx);
        address?;
        Some(device)
    }
}

/// The `address` key: a unicast address, 1..247.
fn read_address(cx: &mut Cx, f: &mut Fields<'_>) -> Option<u8> {
    match f.raw("address") {
        None => {
            cx.issue(f.at("address"), "missing required key");
            None
        }
        Some(toml::Value::Integer(0)) => {
            cx.issue(
                f.at("address"),
                "0 is the broadcast address, not a device; use 1..247",
            );
            None
        }
        Some(v) => int_value(
            cx,
            v,
            &f.at("address"),
            1..=MAX_DEVICE_ADDRESS,
            "Modbus over Serial Line V1.02 2.2",
        ),
    }
}

/// The `tags` and `poll` lists of a device.
fn read_tags_and_poll(
    cx: &mut Cx,
    f: &mut Fields<'_>,
    profile: Option<Profile>,
) -> (Vec<TagConfig>, Vec<PollGroup>) {
    let raw_tags = f.array(cx, "tags");
    if profile == Some(Profile::GENERIC) && raw_tags.is_empty() {
        cx.issue(f.at("tags"), "a generic device needs a tag list");
    }
    // Sized to the file's lists: they are kept as long as the device is in force (a
    // hundred thousand tags in a large gateway).
    let mut tags = Vec::with_capacity(raw_tags.len());
    for (p, v) in raw_tags {
        tags.extend(read_tag(cx, &p, v));
    }
    let raw_poll = f.array(cx, "poll");
    let mut poll = Vec::with_capacity(raw_poll.len());
    for (p, v) in raw_poll {
        poll.extend(read_poll(cx, &p, v));
    }
    (tags, poll)
}

/// The device with every key, as the derived serialization writes it.
struct Whole<'a>(&'a DeviceConfig);

impl Serialize for Whole<'_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        DeviceConfig::serialize(self.0, s)
    }
}

impl Serialize for DeviceConfig {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let Some(base) = self.template_base.as_deref() else {
            return Self::serialize(self, s);
        };
        let whole = self.written_whole().map_err(serde::ser::Error::custom)?;
        written_against(whole, base).serialize(s)
    }
}

impl DeviceConfig {
    /// Every key of the device (the template's merged in), as a table.
    pub(crate) fn written_whole(&self) -> Result<toml::Table, toml::ser::Error> {
        toml::Table::try_from(Whole(self))
    }
}

/// The keys of `whole` that differ from the template's `base`: `address`, `unit_id` and
/// `template` always, a tag or poll group when the template has none of its name or another,
/// a key of `limits` or `scanner` when it differs.
fn written_against(whole: toml::Table, base: &toml::Table) -> toml::Table {
    let named = |v: &toml::Value| {
        v.get("name")
            .and_then(toml::Value::as_str)
            .map(str::to_ascii_lowercase)
    };
    let mut out = toml::Table::new();
    for (key, value) in whole {
        let theirs = base.get(&key);
        let kept = match (key.as_str(), value, theirs) {
            ("address" | "unit_id" | "template", v, _) => Some(v),
            ("tags" | "poll", toml::Value::Array(mine), Some(toml::Value::Array(theirs))) => {
                let own: Vec<toml::Value> = mine
                    .into_iter()
                    .filter(|v| {
                        !theirs
                            .iter()
                            .any(|t| named(t).is_some() && named(t) == named(v) && t == v)
                    })
                    .collect();
                (!own.is_empty()).then_some(toml::Value::Array(own))
            }
            ("limits" | "scanner", toml::Value::Table(mine), Some(toml::Value::Table(theirs))) => {
                let own: toml::Table = mine
                    .into_iter()
                    .filter(|(k, v)| theirs.get(k) != Some(v))
                    .collect();
                (!own.is_empty()).then_some(toml::Value::Table(own))
            }
            (_, v, Some(t)) if *t == v => None,
            (_, v, _) => Some(v),
        };
        if let Some(v) = kept {
            out.insert(key, v);
        }
    }
    out
}

/// The communication scanner's settings, read only when it runs, with their defaults (above):
/// the rules by which `validate::ignored_keys` finds them without effect in a file.
pub(crate) const SCANNER_NEEDS: &[Needs] = &[
    needs("inputs", Some("2"), "enabled", &["true"], "false"),
    needs("outputs", Some("2"), "enabled", &["true"], "false"),
    needs("period", Some("100ms"), "enabled", &["true"], "false"),
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn profile_limits_follow_the_manuals() {
        // 002 "Modbus-Funktionen": FC03 63, FC16 61, FC23 20/20.
        let a = Profile::named("altivar71")
            .expect("registered")
            .max_limits();
        assert_eq!(
            (
                a.read_registers,
                a.write_registers,
                rw_read(&a),
                rw_write(&a)
            ),
            (63, 61, 20, 20)
        );
        // 001 3.1: 120 integer values a message.
        assert_eq!(
            Profile::named("ksvario")
                .expect("registered")
                .max_limits()
                .read_registers,
            120
        );
        // Modbus Application Protocol: 125 / 123.
        let g = Profile::GENERIC.max_limits();
        assert_eq!(
            (g.read_registers, g.write_registers, g.read_bits),
            (125, 123, 2000)
        );
    }

    #[test]
    fn range_cover() {
        let r = AddressRange {
            table: ModbusTable::Holding,
            start: 100,
            count: 10,
        };
        assert!(r.covers(ModbusTable::Holding, 100, 10));
        assert!(r.covers(ModbusTable::Holding, 105, 5));
        assert!(!r.covers(ModbusTable::Holding, 105, 6));
        assert!(!r.covers(ModbusTable::Holding, 99, 1));
        assert!(!r.covers(ModbusTable::Coil, 100, 1));
    }
}
