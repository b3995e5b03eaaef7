//! Checks that span several keys (duplicates across lines, protocol versus interface, timing
//! minimums by baud rate, references between tags and poll groups). Every problem is reported;
//! nothing stops at the first one.

use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;

use super::device::{serde_name, DataType, DeviceConfig};
use super::line::{LineConfig, ProtocolConfig};
use super::modbus::{BitArea, ModbusSlaveRtuConfig};
use super::reader::{show_duration, Cx};
use super::serial::{DataBits, Interface};
use super::tap::ModbusRtuTapConfig;
use super::telegram::{
    min_3964_time, min_ascii_character_delay, AsciiConfig, EndCriterion, FlowControl,
    Proc3964Config,
};
use super::{Config, ConfigIssue};

/// Every cross-field problem of `config`.
pub fn validate(config: &Config) -> Vec<ConfigIssue> {
    let mut cx = Cx::default();
    check(&mut cx, config);
    cx.issues
}

pub(crate) fn check(cx: &mut Cx, config: &Config) {
    let mut ports: BTreeMap<&str, String> = BTreeMap::new();
    let mut units: BTreeMap<u8, String> = BTreeMap::new();
    for (name, line) in &config.lines {
        let path = format!("lines.{name}");
        if let Some(first) = ports.get(line.serial.port.as_str()) {
            cx.issue(
                format!("{path}.port"),
                format!("port {:?} is already used by {first}", line.serial.port),
            );
        } else {
            ports.insert(&line.serial.port, path.clone());
        }
        if let Some(port_b) = line.second_port().filter(|p| !p.is_empty()) {
            if port_b == line.serial.port {
                cx.issue(
                    format!("{path}.port_b"),
                    "port_b must be another port than port: each receives one direction of the \
                     link (one partner's transmit line)",
                );
            } else if let Some(first) = ports.get(port_b) {
                cx.issue(
                    format!("{path}.port_b"),
                    format!("port {port_b:?} is already used by {first}"),
                );
            } else {
                ports.insert(port_b, path.clone());
            }
        }
        if let Some(unit) = line.unit_id() {
            claim_unit(cx, &mut units, unit, format!("{path}.unit_id"), &path);
        }
        let mut addresses: BTreeMap<u8, String> = BTreeMap::new();
        for (dev_name, dev) in line.devices() {
            let dev_path = format!("{path}.devices.{dev_name}");
            claim_unit(
                cx,
                &mut units,
                dev.unit_id,
                format!("{dev_path}.unit_id"),
                &dev_path,
            );
            if let Some(first) = addresses.get(&dev.address) {
                cx.issue(
                    format!("{dev_path}.address"),
                    format!(
                        "slave address {} is already used by {first} on this line",
                        dev.address
                    ),
                );
            } else {
                addresses.insert(dev.address, dev_path.clone());
            }
            check_device(cx, &dev_path, dev);
        }
        check_line(cx, &path, line);
    }
    if let Some(unit) = config.modbus_tcp.diagnostic_unit {
        claim_unit(
            cx,
            &mut units,
            unit,
            "modbus_tcp.diagnostic_unit".to_owned(),
            "modbus_tcp.diagnostic_unit",
        );
    }
    for (i, r) in config.modbus_tcp.write_ranges.iter().enumerate() {
        if config.modbus_tcp.diagnostic_unit == Some(r.unit_id) {
            cx.issue(
                format!("modbus_tcp.write_ranges[{i}].unit_id"),
                format!(
                    "unit id {} is the diagnostic unit, which is read-only",
                    r.unit_id
                ),
            );
        } else if !units.contains_key(&r.unit_id) {
            cx.issue(
                format!("modbus_tcp.write_ranges[{i}].unit_id"),
                format!("no device or line is served as unit id {}", r.unit_id),
            );
        }
    }
    if let Some(tls) = &config.modbus_tcp.tls {
        let plain = config.modbus_tcp.listen;
        if config.modbus_tcp.enabled && tls.listen.port() != 0 && tls.listen == plain {
            cx.issue(
                "modbus_tcp.tls.listen",
                format!(
                    "the same address as modbus_tcp.listen ({plain}): Modbus/TCP Security needs \
                     its own port (802)"
                ),
            );
        }
    }
}

fn claim_unit(cx: &mut Cx, units: &mut BTreeMap<u8, String>, unit: u8, path: String, owner: &str) {
    if let Some(first) = units.get(&unit) {
        cx.issue(
            path,
            format!(
                "unit id {unit} is already used by {first}; unit ids must be unique in the gateway"
            ),
        );
    } else {
        units.insert(unit, owner.to_owned());
    }
}

fn check_line(cx: &mut Cx, path: &str, line: &LineConfig) {
    let serial = &line.serial;
    match &line.protocol {
        ProtocolConfig::ModbusMasterRtu(_)
        | ProtocolConfig::ModbusSlaveRtu(_)
        | ProtocolConfig::ModbusRtuTap(_)
            if serial.data_bits != DataBits::Eight =>
        {
            cx.issue(
                format!("{path}.data_bits"),
                "Modbus RTU uses 8 data bits (003 6.4.2.1: \"8 (fix)\")",
            );
        }
        _ => {}
    }
    match &line.protocol {
        ProtocolConfig::Proc3964(p) => check_3964(cx, path, line, p),
        ProtocolConfig::Proc3964Tap(t) => {
            check_3964_link(cx, path, line, (t.character_delay, t.ack_delay));
        }
        ProtocolConfig::Ascii(a) => check_ascii(cx, path, line, a),
        ProtocolConfig::ModbusSlaveRtu(s) => check_slave(cx, path, s),
        ProtocolConfig::ModbusRtuTap(t) => check_tap(cx, path, t),
        ProtocolConfig::ModbusMasterRtu(_) | ProtocolConfig::ModbusMasterAscii(_) => {}
    }
}

/// A tap line never transmits: its devices have no poll groups and no communication scanner.
fn check_tap(cx: &mut Cx, path: &str, tap: &ModbusRtuTapConfig) {
    for (name, device) in &tap.devices {
        let dev_path = format!("{path}.devices.{name}");
        if !device.poll.is_empty() {
            cx.issue(
                format!("{dev_path}.poll"),
                "a modbus-rtu-tap line only listens: its devices have no poll groups (it stores \
                 what another master reads and writes)",
            );
        }
        if device.scanner.is_some_and(|s| s.enabled) {
            cx.issue(
                format!("{dev_path}.scanner"),
                "a modbus-rtu-tap line only listens: it cannot run a communication scanner",
            );
        }
    }
}

fn check_3964(cx: &mut Cx, path: &str, line: &LineConfig, p: &Proc3964Config) {
    check_3964_link(cx, path, line, (p.character_delay, p.ack_delay));
}

/// The checks a 3964(R) line and a 3964(R) tap share: a full-duplex link, and the character
/// and acknowledgement delay times (`times`) at least the baud rate's minimum.
fn check_3964_link(cx: &mut Cx, path: &str, line: &LineConfig, times: (Duration, Duration)) {
    if line.serial.interface == Interface::Rs485 {
        cx.issue(
            format!("{path}.interface"),
            "3964(R) needs a full-duplex line (rs232 or rs422): the procedure is not possible in two-wire \
             (RS485 half-duplex) mode (003 6.3.3: \"Half-duplex (RS485) - This setting is not available with 3964(R)\")",
        );
    }
    let min = min_3964_time(line.serial.baud);
    for (key, d) in [("character_delay", times.0), ("ack_delay", times.1)] {
        if d < min {
            cx.issue(
                format!("{path}.{key}"),
                format!(
                    "at {} baud must be at least {} (003 6.3.3), found {}",
                    line.serial.baud,
                    show_duration(min),
                    show_duration(d)
                ),
            );
        }
    }
}

fn check_ascii(cx: &mut Cx, path: &str, line: &LineConfig, a: &AsciiConfig) {
    let serial = &line.serial;
    let min = min_ascii_character_delay(serial.baud);
    if a.character_delay < min {
        cx.issue(
            format!("{path}.character_delay"),
            format!(
                "at {} baud must be at least {} (003 6.2.1), found {}",
                serial.baud,
                show_duration(min),
                show_duration(a.character_delay)
            ),
        );
    }
    match a.flow_control {
        FlowControl::None => {}
        _ if serial.interface == Interface::Rs485 => cx.issue(
            format!("{path}.flow_control"),
            "no data flow control on a half-duplex RS485 line (003 6.2.1: \"At half-duplex parameterization with \
             RS485 data flow control is not possible\")",
        ),
        FlowControl::RtsCts | FlowControl::AutoV24 if serial.interface != Interface::Rs232 => cx.issue(
            format!("{path}.flow_control"),
            "RTS/CTS and automatic V24 handling use the RS232 modem signals: set interface = \"rs232\" (000 5.4)",
        ),
        FlowControl::XonXoff if a.xon_code == a.xoff_code => {
            cx.issue(format!("{path}.xoff_code"), "XON and XOFF must be different characters");
        }
        _ => {}
    }
    let max = serial.data_bits.max_code();
    let mut codes: Vec<(String, u8)> = vec![
        (format!("{path}.xon_code"), a.xon_code),
        (format!("{path}.xoff_code"), a.xoff_code),
    ];
    codes.extend(
        a.end_chars
            .iter()
            .enumerate()
            .map(|(i, c)| (format!("{path}.end_chars[{i}]"), *c)),
    );
    for (p, code) in codes {
        if code > max {
            cx.issue(
                p,
                format!(
                    "0x{code:02X} does not fit in {} data bits: at most 0x{max:02X} (003 6.2.1)",
                    serial.data_bits.get()
                ),
            );
        }
    }
    if !a.prevent_overwrite && a.receive_buffer != 1 {
        cx.issue(
            format!("{path}.prevent_overwrite"),
            format!(
                "may be switched off only with receive_buffer = 1 (003 6.2.1 \"Prevent overwriting\"), found receive_buffer = {}",
                a.receive_buffer
            ),
        );
    }
    if a.end_criterion == EndCriterion::FixedLength && a.fixed_length > a.max_telegram_len {
        cx.issue(
            format!("{path}.fixed_length"),
            format!(
                "{} is longer than max_telegram_len = {}",
                a.fixed_length, a.max_telegram_len
            ),
        );
    }
}

fn check_slave(cx: &mut Cx, path: &str, s: &ModbusSlaveRtuConfig) {
    let c = &s.coils;
    let coil_areas = [
        ("memory", c.memory, false),
        ("outputs", c.outputs, false),
        ("timers", c.timers, true),
        ("counters", c.counters, true),
    ];
    check_areas(cx, &format!("{path}.coils"), &coil_areas);
    let i = &s.discrete_inputs;
    check_areas(
        cx,
        &format!("{path}.discrete_inputs"),
        &[("memory", i.memory, false), ("inputs", i.inputs, false)],
    );
}

/// Areas of one function-code group: inside the address space, timer/counter areas in whole
/// 16-bit words (003 6.4.8.1), the PLC addresses inside 0..=65535, and no two areas overlapping.
fn check_areas(cx: &mut Cx, path: &str, areas: &[(&str, BitArea, bool)]) {
    for (i, (name, a, words)) in areas.iter().enumerate() {
        if a.count == 0 {
            continue;
        }
        let p = format!("{path}.{name}");
        let end = u32::from(a.start) + a.count;
        if end > 65_536 {
            cx.issue(
                format!("{p}.count"),
                format!(
                    "area {}+{} runs past Modbus address 65535",
                    a.start, a.count
                ),
            );
        }
        let plc_units = if *words {
            if a.count % 16 != 0 {
                cx.issue(
                    format!("{p}.count"),
                    "timers and counters are read in 16-bit steps: count must be a multiple of 16 (003 6.4.8.1)",
                );
            }
            a.count.div_ceil(16)
        } else {
            a.count.div_ceil(8)
        };
        if u32::from(a.plc) + plc_units > 65_536 {
            cx.issue(
                format!("{p}.plc"),
                format!(
                    "the area runs past PLC address 65535 ({} + {plc_units})",
                    a.plc
                ),
            );
        }
        for (other, b, _) in &areas[..i] {
            if b.count > 0
                && u32::from(a.start) < u32::from(b.start) + b.count
                && u32::from(b.start) < end
            {
                cx.issue(format!("{p}.start"), format!("overlaps the {other} area"));
            }
        }
    }
}

fn check_device(cx: &mut Cx, path: &str, dev: &DeviceConfig) {
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
    let tables = dev.profile.tables();
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
        if !tables.contains(&tag.table) {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{ModbusTable, Profile};

    #[test]
    fn serde_names() {
        assert_eq!(serde_name(ModbusTable::Discrete), "discrete");
        assert_eq!(serde_name(Profile::Altivar71), "altivar71");
    }
}
