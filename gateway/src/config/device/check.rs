//! A device's checks across its keys, as read: the back-off bounds, the bridge gap against the
//! read limit, each tag against its table, type and the device's limits, no two tags over the
//! same registers, and the poll groups' names and references.

use std::collections::{BTreeMap, BTreeSet, HashMap};

use crate::config::check::{Check, Device};
use crate::config::reader::{serde_name, show_duration, Cx};
use crate::config::tag::{DataType, ModbusTable, TagConfig};

use super::DeviceConfig;

impl Check<Device<'_>> for DeviceConfig {
    fn check(&self, device: &Device<'_>, cx: &mut Cx) {
        let path = device.path;
        check_bounds(cx, path, self);
        let names = check_tags(cx, path, self);
        check_overlaps(cx, path, self);
        check_poll_groups(cx, path, self, &names);
    }
}

/// The back-off bounds in order, and the bridge gap below the read limit.
fn check_bounds(cx: &mut Cx, path: &str, dev: &DeviceConfig) {
    if dev.offline_backoff_min > dev.offline_backoff_max {
        cx.issue(
            format!("{path}.offline_backoff_min"),
            format!(
                "{} is longer than offline_backoff_max = {}",
                show_duration(dev.offline_backoff_min),
                show_duration(dev.offline_backoff_max)
            ),
        );
    }
    if dev.bridge_gap >= dev.limits.read_registers {
        cx.issue(
            format!("{path}.bridge_gap"),
            format!(
                "must be below the read limit of {} registers, found {}",
                dev.limits.read_registers, dev.bridge_gap
            ),
        );
    }
}

/// Every config tag of the device ([`check_tag`]), and no name twice; returns the names of the
/// device's tags and its profile's, in lower case.
fn check_tags(cx: &mut Cx, path: &str, dev: &DeviceConfig) -> BTreeSet<String> {
    let profile = serde_name(dev.profile);
    // Tag names compare without letter case (ASCII), here as in REST and zenoh: `ETA` in a
    // poll group is the profile's `eta`, and a device may not have two tags that differ only
    // in case.
    let mut names: BTreeSet<String> = dev
        .profile
        .tag_names()
        .iter()
        .map(|n| n.to_ascii_lowercase())
        .collect();
    for (i, tag) in dev.tags.iter().enumerate() {
        let p = format!("{path}.tags[{i}]");
        if !names.insert(tag.name.to_ascii_lowercase()) {
            cx.issue(
                format!("{p}.name"),
                format!(
                    "tag {:?} is defined twice (or by the {profile} profile; names compare without letter case)",
                    tag.name
                ),
            );
        }
        check_tag(cx, &p, dev, tag);
    }
    names
}

/// One config tag at `p`: its table one of the profile's, its type one its table holds, a bit
/// only of a register, its registers within one read, writable only where Modbus writes, and
/// inside the address space.
fn check_tag(cx: &mut Cx, p: &str, dev: &DeviceConfig, tag: &TagConfig) {
    let profile = serde_name(dev.profile);
    if !dev.profile.tables().contains(&tag.table) {
        cx.issue(
            format!("{p}.table"),
            format!(
                "the {profile} profile has no {} table",
                serde_name(tag.table)
            ),
        );
    }
    // A bool with a bit is a register's bit; on a bit table the bit is refused below.
    let is_bool =
        tag.data_type == DataType::Bool && (tag.bit.is_none() || !tag.table.is_register());
    if is_bool == tag.table.is_register() {
        let want = if tag.table.is_register() {
            "u16, i16, u32, i32, u64, i64, f32, f64, string, or bool with a bit"
        } else {
            "bool (a string or a number needs registers)"
        };
        cx.issue(
            format!("{p}.type"),
            format!("a {} tag must be {want}", serde_name(tag.table)),
        );
    }
    if tag.bit.is_some() {
        if !tag.table.is_register() {
            cx.issue(
                format!("{p}.bit"),
                format!(
                    "a {} is a bit already; bit names a bit of a holding or input register",
                    serde_name(tag.table)
                ),
            );
        } else if tag.data_type != DataType::Bool {
            cx.issue(
                format!("{p}.type"),
                "a bit of a register is a bool: leave type out or give \"bool\"",
            );
        }
    }
    if tag.words_exceed(dev.limits.read_registers) && tag.table.is_register() {
        cx.issue(
            format!("{p}.registers"),
            format!(
                "the value takes more registers than one read of this device carries (limits.read_registers = {})",
                dev.limits.read_registers
            ),
        );
    }
    if tag.writable && !tag.table.is_writable() {
        cx.issue(
            format!("{p}.writable"),
            format!("{} addresses cannot be written", serde_name(tag.table)),
        );
    }
    if u32::from(tag.address) + tag.width() > 65_536 {
        cx.issue(format!("{p}.address"), "the value runs past address 65535");
    }
}

/// The poll groups: no name twice, every tag one of `names`, every range on a table of the
/// profile.
fn check_poll_groups(cx: &mut Cx, path: &str, dev: &DeviceConfig, names: &BTreeSet<String>) {
    let tables = dev.profile.tables();
    let profile = serde_name(dev.profile);
    let mut groups = BTreeSet::new();
    for (i, group) in dev.poll.iter().enumerate() {
        let p = format!("{path}.poll[{i}]");
        if !groups.insert(group.name.as_str()) {
            cx.issue(
                format!("{p}.name"),
                format!("poll group {:?} is defined twice", group.name),
            );
        }
        for (j, tag) in group.tags.iter().enumerate() {
            if !names.contains(&tag.to_ascii_lowercase()) {
                cx.issue(
                    format!("{p}.tags[{j}]"),
                    format!("no tag {tag:?} in this device's tags or the {profile} profile"),
                );
            }
        }
        for (j, r) in group.ranges.iter().enumerate() {
            if !tables.contains(&r.table) {
                cx.issue(
                    format!("{p}.ranges[{j}].table"),
                    format!("the {profile} profile has no {} table", serde_name(r.table)),
                );
            }
        }
    }
}

/// The registers (or bits) one value takes.
struct Span<'a> {
    name: &'a str,
    table: ModbusTable,
    start: u32,
    end: u32,
    data_type: String,
}

impl Span<'_> {
    /// `"name" (type at table first..last)`.
    fn show(&self) -> String {
        let last = self.end - 1;
        let at = if last == self.start {
            format!("{}", self.start)
        } else {
            format!("{}..{last}", self.start)
        };
        format!(
            "{:?} ({} at {} {at})",
            self.name,
            self.data_type,
            serde_name(self.table)
        )
    }

    /// Whether `self` and `other` are two values over some of the same registers: not the same
    /// name (a duplicate name is reported as such) and not an alias (the same registers read as
    /// the same type under another name, with another scale, offset or decimals).
    fn overlaps(&self, other: &Span<'_>) -> bool {
        let same_name = other.name.eq_ignore_ascii_case(self.name);
        let alias = other.table == self.table
            && other.start == self.start
            && other.end == self.end
            && other.data_type == self.data_type;
        other.table == self.table
            && self.start < other.end
            && other.start < self.end
            && !same_name
            && !alias
    }
}

/// The spans seen so far, by table and first register, and the widest of them: a new span is
/// compared only with the spans that can reach it (first register within the widest width
/// below its end), not with every tag before it (100 000 tags were 5 * 10^9 comparisons).
struct Spans<'a> {
    spans: Vec<Span<'a>>,
    /// How many of the first spans are the profile's tags.
    from_profile: usize,
    by_start: HashMap<ModbusTable, BTreeMap<u32, Vec<usize>>>,
    widest: u32,
}

impl<'a> Spans<'a> {
    /// The spans of a profile's tags.
    fn of_profile(tags: &'a [proto_core::profiles::Tag]) -> Self {
        use proto_core::profiles::Table as T;
        let mut spans = Self {
            spans: Vec::new(),
            from_profile: 0,
            by_start: HashMap::new(),
            widest: 1,
        };
        for t in tags {
            spans.push(Span {
                name: &t.name,
                table: match t.table {
                    T::Coils => ModbusTable::Coil,
                    T::DiscreteInputs => ModbusTable::Discrete,
                    T::InputRegisters => ModbusTable::Input,
                    T::HoldingRegisters => ModbusTable::Holding,
                },
                start: u32::from(t.address),
                end: u32::from(t.address) + u32::from(t.words().max(1)),
                data_type: format!("{:?}", t.data_type).to_ascii_lowercase(),
            });
        }
        spans.from_profile = spans.spans.len();
        spans
    }

    fn push(&mut self, span: Span<'a>) {
        self.widest = self.widest.max(span.end - span.start);
        self.by_start
            .entry(span.table)
            .or_default()
            .entry(span.start)
            .or_default()
            .push(self.spans.len());
        self.spans.push(span);
    }

    /// The spans `span` overlaps ([`Span::overlaps`]), in the order they came, each with
    /// whether it is the profile's.
    fn overlapped(&self, span: &Span<'_>) -> Vec<(&Span<'a>, bool)> {
        let mut near: Vec<usize> = self
            .by_start
            .get(&span.table)
            .map(|starts| {
                starts
                    .range(span.start.saturating_sub(self.widest - 1)..span.end)
                    .flat_map(|(_, js)| js.iter().copied())
                    .collect()
            })
            .unwrap_or_default();
        near.sort_unstable();
        near.into_iter()
            .filter_map(|j| self.spans.get(j).map(|o| (o, j < self.from_profile)))
            .filter(|(other, _)| span.overlaps(other))
            .collect()
    }
}

/// Two values of one device over the same registers (or bits): a write of one changes the
/// other and each read shows part of the other's value. A tag with `bit` names one bit of a
/// register and may share it (a status word and its bits), and so may a tag of the same type
/// over exactly the same registers (an alias: the value with another scale or decimals); every
/// other tag is checked against the device's other tags and its profile's, and the later config
/// tag is named with both.
fn check_overlaps(cx: &mut Cx, path: &str, dev: &DeviceConfig) {
    let profile = dev.profile.device_profile();
    let mut spans = Spans::of_profile(profile.as_ref().map_or(&[], |p| p.tags.as_slice()));
    for (i, tag) in dev.tags.iter().enumerate() {
        if tag.bit.is_some() && tag.table.is_register() {
            continue;
        }
        let span = Span {
            name: &tag.name,
            table: tag.table,
            start: u32::from(tag.address),
            end: u32::from(tag.address) + tag.width().max(1),
            data_type: serde_name(tag.data_type),
        };
        for (other, from_profile) in spans.overlapped(&span) {
            let whose = if from_profile {
                format!("the {} profile's tag", serde_name(dev.profile))
            } else {
                "tag".to_owned()
            };
            cx.issue(
                format!("{path}.tags[{i}].address"),
                format!(
                    "tag {} overlaps {whose} {}: two values cannot share registers (a bit \
                     of a register is a bool tag with `bit`)",
                    span.show(),
                    other.show()
                ),
            );
        }
        spans.push(span);
    }
}
