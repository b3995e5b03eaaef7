//! Checks that span several keys (duplicates across lines, protocol versus interface, timing
//! minimums by baud rate, references between tags and poll groups). Every problem is reported;
//! nothing stops at the first one.

use std::collections::BTreeMap;

use super::Config;
use crate::config::check::{Check, Device, Line, Needs};
use crate::config::reader::Cx;
use crate::config::{ConfigIssue, SCANNER_NEEDS};
use crate::protocols::telegram::config::ASCII_NEEDS;
use crate::protocols::{transparent_units, LineConfig};

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
        claim_ports(cx, &mut ports, &path, line);
        if let Some(unit) = line.unit_id() {
            claim_unit(cx, &mut units, unit, format!("{path}.unit_id"), &path);
        }
        check_devices(cx, &mut units, &path, line);
        let scope = Line {
            path: &path,
            serial: &line.serial,
        };
        line.protocol.section().check(&scope, cx);
    }
    check_modbus_tcp(cx, config, &mut units);
}

/// The line's ports (`port`, `port_b`), each used by no line before it in `ports`.
fn claim_ports<'a>(
    cx: &mut Cx,
    ports: &mut BTreeMap<&'a str, String>,
    path: &str,
    line: &'a LineConfig,
) {
    if let Some(first) = ports.get(line.serial.port.as_str()) {
        cx.issue(
            format!("{path}.port"),
            format!("port {:?} is already used by {first}", line.serial.port),
        );
    } else {
        ports.insert(&line.serial.port, path.to_owned());
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
            ports.insert(port_b, path.to_owned());
        }
    }
}

/// The line's devices: each unit id unique in the gateway, each slave address unique on the
/// line, and each device's own checks ([`Device`] scope, `config/device/check.rs`).
fn check_devices(cx: &mut Cx, units: &mut BTreeMap<u8, String>, path: &str, line: &LineConfig) {
    let mut addresses: BTreeMap<u8, String> = BTreeMap::new();
    for (dev_name, dev) in line.devices() {
        let dev_path = format!("{path}.devices.{dev_name}");
        claim_unit(
            cx,
            units,
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
        dev.check(&Device { path: &dev_path }, cx);
    }
}

/// `[modbus_tcp]` against the lines: the diagnostic unit's id unique, the transparent units,
/// every write range on a unit someone serves (not the read-only diagnostic unit), and the TLS
/// listener on an address of its own.
fn check_modbus_tcp(cx: &mut Cx, config: &Config, units: &mut BTreeMap<u8, String>) {
    if let Some(unit) = config.modbus_tcp.diagnostic_unit {
        claim_unit(
            cx,
            units,
            unit,
            "modbus_tcp.diagnostic_unit".to_owned(),
            "modbus_tcp.diagnostic_unit",
        );
    }
    check_transparent(cx, config, units);
    for (i, r) in config.modbus_tcp.write_ranges.iter().enumerate() {
        if config.modbus_tcp.diagnostic_unit == Some(r.unit_id) {
            cx.issue(
                format!("modbus_tcp.write_ranges[{i}].unit_id"),
                format!(
                    "unit id {} is the diagnostic unit, which is read-only",
                    r.unit_id
                ),
            );
        } else if !units.contains_key(&r.unit_id)
            && !config
                .lines
                .values()
                .filter_map(transparent_units)
                .any(|t| t.contains(&r.unit_id))
        {
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

/// Whether a value the file gives is `default` (numbers and durations compared by value).
fn is_default(value: &toml::Value, default: &str) -> bool {
    match value {
        toml::Value::Integer(n) => default.parse::<i64>() == Ok(*n),
        toml::Value::Float(x) => default.parse::<f64>() == Ok(*x),
        toml::Value::String(s) => {
            s == default
                || matches!(
                    (humantime::parse_duration(s), humantime::parse_duration(default)),
                    (Ok(a), Ok(b)) if a == b
                )
        }
        _ => false,
    }
}

/// Keys a file gives that take no effect because of another key's value (an ASCII line's
/// `end_chars` with another end criterion, a value transformation on a bool or string tag, a
/// save interval without a persistence file, ...), each a warning at its path: the file is
/// valid, but says something the gateway does not do. Read from the file's own table, so that
/// only keys the file gives are reported.
pub fn ignored_keys(table: &toml::Table) -> Vec<ConfigIssue> {
    let mut cx = Cx::default();
    for (name, line) in table_at(table, "lines").unwrap_or_default() {
        if let Some(line) = line.as_table() {
            ignored_in_line(&mut cx, &format!("lines.{name}"), line);
        }
    }
    ignored_in_sections(&mut cx, table);
    cx.issues
}

/// The table at `key` of `t`, if it is one.
fn table_at(t: &toml::Table, key: &str) -> Option<toml::Table> {
    t.get(key).and_then(toml::Value::as_table).cloned()
}

/// An ASCII line's keys its end criterion or flow control leaves without effect, and its
/// devices' (the scanner's settings while it is off, a bool or string tag's transformation).
fn ignored_in_line(cx: &mut Cx, path: &str, line: &toml::Table) {
    if line.get("protocol").and_then(toml::Value::as_str) == Some("ascii") {
        ignored_by_rules(cx, line, path, ASCII_NEEDS);
    }
    for (dev_name, dev) in table_at(line, "devices").unwrap_or_default() {
        let Some(dev) = dev.as_table() else {
            continue;
        };
        let dev_path = format!("{path}.devices.{dev_name}");
        if let Some(scanner) = table_at(dev, "scanner") {
            ignored_by_rules(cx, &scanner, &format!("{dev_path}.scanner"), SCANNER_NEEDS);
        }
        ignored_in_tags(cx, &dev_path, dev);
    }
}

/// The keys of `t` (at `path`) that a rule of `list` finds without effect: given, not at their
/// own default, and the key they need not at one of its values.
fn ignored_by_rules(cx: &mut Cx, t: &toml::Table, path: &str, list: &[Needs]) {
    let text = |v: &toml::Value| match v {
        toml::Value::String(s) => s.clone(),
        other => other.to_string(),
    };
    let shown = |v: &str| match v {
        "true" | "false" => v.to_owned(),
        _ => format!("{v:?}"),
    };
    for rule in list {
        let Some(given) = t.get(rule.key) else {
            continue;
        };
        if rule.key_default.is_some_and(|d| is_default(given, d)) {
            continue;
        }
        let value = t
            .get(rule.needs)
            .map_or_else(|| rule.default.to_owned(), text);
        if rule.values.contains(&value.as_str()) {
            continue;
        }
        let wanted = rule
            .values
            .iter()
            .map(|v| shown(v))
            .collect::<Vec<_>>()
            .join(" or ");
        cx.issue(
            format!("{path}.{}", rule.key),
            format!(
                "has no effect: {} is read only with {} = {wanted}, and {} is {}{}",
                rule.key,
                rule.needs,
                rule.needs,
                shown(&value),
                if t.contains_key(rule.needs) {
                    ""
                } else {
                    " (its default)"
                }
            ),
        );
    }
}

/// A bool or string tag's `scale`, `offset` and `decimals` other than their defaults: they
/// apply to numbers only.
fn ignored_in_tags(cx: &mut Cx, dev_path: &str, dev: &toml::Table) {
    use toml::Value;
    let tags = dev.get("tags").and_then(Value::as_array);
    for (i, tag) in tags.into_iter().flatten().enumerate() {
        let Some(tag) = tag.as_table() else {
            continue;
        };
        let bit_table = matches!(
            tag.get("table").and_then(Value::as_str),
            Some("coil" | "discrete")
        );
        let kind = match tag.get("type").and_then(Value::as_str) {
            Some(t @ ("bool" | "string")) => t,
            None if bit_table || tag.contains_key("bit") => "bool",
            _ => continue,
        };
        for (key, default) in [("scale", "1"), ("offset", "0"), ("decimals", "0")] {
            if tag.get(key).is_some_and(|v| !is_default(v, default)) {
                cx.issue(
                    format!("{dev_path}.tags[{i}].{key}"),
                    format!(
                        "has no effect: a {kind} tag is not a number (scale, offset and \
                         decimals apply to numbers)"
                    ),
                );
            }
        }
    }
}

/// `[cp_memory] save_interval` without a persistence file, and
/// `insecure_allow_unauthenticated_changes` with a token.
fn ignored_in_sections(cx: &mut Cx, table: &toml::Table) {
    use toml::Value;
    if let Some(cp) = table_at(table, "cp_memory") {
        if cp.contains_key("save_interval") && !cp.contains_key("persist_file") {
            cx.issue(
                "cp_memory.save_interval",
                "has no effect: the CP memory is saved only with persist_file",
            );
        }
    }
    if let Some(http) = table_at(table, "http") {
        let tokens = http.contains_key("token_file")
            || http.contains_key("token_env")
            || http
                .get("tokens")
                .and_then(Value::as_table)
                .is_some_and(|t| !t.is_empty());
        if tokens
            && http
                .get("insecure_allow_unauthenticated_changes")
                .and_then(Value::as_bool)
                == Some(true)
        {
            cx.issue(
                "http.insecure_allow_unauthenticated_changes",
                "has no effect: a token is configured, so every change needs a token",
            );
        }
    }
}

/// Two transparent lines may not claim the same unit id; where a device or unit of the gateway
/// (`claimed`) holds the id, it wins and the overlap is harmless.
fn check_transparent(cx: &mut Cx, config: &Config, claimed: &BTreeMap<u8, String>) {
    let transparent: Vec<(&String, std::ops::RangeInclusive<u8>)> = config
        .lines
        .iter()
        .filter_map(|(name, line)| transparent_units(line).map(|units| (name, units)))
        .collect();
    for (i, (name, units)) in transparent.iter().enumerate() {
        for (first, other) in transparent.iter().take(i) {
            let shared: Vec<u8> = units
                .clone()
                .filter(|u| other.contains(u) && !claimed.contains_key(u))
                .collect();
            if !shared.is_empty() {
                cx.issue(
                    format!("lines.{name}.transparent_units"),
                    format!(
                        "unit ids {} are forwarded by lines.{first} too: two transparent lines \
                         may not claim the same unit id (narrow transparent_units)",
                        show_ids(&shared)
                    ),
                );
            }
        }
    }
}

/// Unit ids as runs: `1..=9, 11, 13..=247`.
fn show_ids(ids: &[u8]) -> String {
    let mut runs: Vec<(u8, u8)> = Vec::new();
    for &id in ids {
        match runs.last_mut() {
            Some((_, last)) if last.checked_add(1) == Some(id) => *last = id,
            _ => runs.push((id, id)),
        }
    }
    runs.iter()
        .map(|&(a, b)| {
            if a == b {
                a.to_string()
            } else {
                format!("{a}..={b}")
            }
        })
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::reader::serde_name;
    use crate::config::{ModbusTable, Profile};

    #[test]
    fn the_ignored_keys_defaults_are_the_readers() {
        use crate::config::{DEFAULT_SCANNER_PERIOD, DEFAULT_SCANNER_WORDS};
        use crate::protocols::{
            DEFAULT_ASCII_FIXED_LENGTH, DEFAULT_DATA_OUTPUT_WAIT, DEFAULT_RTS_HOLD_TIME,
            DEFAULT_XOFF_CODE, DEFAULT_XON_CODE, DEFAULT_XON_WAIT,
        };
        let default = |list: &[Needs], key: &str| {
            let rule = list.iter().find(|r| r.key == key).expect("rule");
            rule.key_default.expect("a default")
        };
        let duration = |s: &str| humantime::parse_duration(s).expect("duration");
        let int = |s: &str| s.parse::<u16>().expect("integer");
        assert_eq!(
            int(default(ASCII_NEEDS, "fixed_length")),
            DEFAULT_ASCII_FIXED_LENGTH
        );
        assert_eq!(
            int(default(ASCII_NEEDS, "xon_code")),
            u16::from(DEFAULT_XON_CODE)
        );
        assert_eq!(
            int(default(ASCII_NEEDS, "xoff_code")),
            u16::from(DEFAULT_XOFF_CODE)
        );
        assert_eq!(duration(default(ASCII_NEEDS, "xon_wait")), DEFAULT_XON_WAIT);
        assert_eq!(
            duration(default(ASCII_NEEDS, "rts_hold_time")),
            DEFAULT_RTS_HOLD_TIME
        );
        assert_eq!(
            duration(default(ASCII_NEEDS, "data_output_wait")),
            DEFAULT_DATA_OUTPUT_WAIT
        );
        assert_eq!(int(default(SCANNER_NEEDS, "inputs")), DEFAULT_SCANNER_WORDS);
        assert_eq!(
            int(default(SCANNER_NEEDS, "outputs")),
            DEFAULT_SCANNER_WORDS
        );
        assert_eq!(
            duration(default(SCANNER_NEEDS, "period")),
            DEFAULT_SCANNER_PERIOD
        );
    }

    #[test]
    fn keys_left_without_effect_are_found_with_their_paths() {
        let table: toml::Table = "[cp_memory]\nsave_interval = \"5s\"\n\
             [http]\ntoken_env = \"T\"\ninsecure_allow_unauthenticated_changes = true\n\
             [lines.a]\nprotocol = \"ascii\"\nend_chars = [3]\nxon_code = 17\nxoff_code = 20\n\
             end_criterion = \"char-delay\"\n\
             [lines.b]\nprotocol = \"ascii\"\nend_criterion = \"end-chars\"\nend_chars = [3]\n\
             flow_control = \"auto-v24\"\nrts_hold_time = \"20ms\"\nxon_wait = \"1s\"\n\
             [lines.m]\nprotocol = \"modbus-master-rtu\"\n\
             [lines.m.devices.d]\nprofile = \"altivar71\"\naddress = 1\n\
             tags = [{ name = \"s\", table = \"holding\", address = 9, type = \"string\", registers = 2, scale = 2.0 },\
                     { name = \"c\", table = \"coil\", address = 1, decimals = 0 }]\n\
             [lines.m.devices.d.scanner]\nperiod = \"1s\"\ninputs = 2\n"
            .parse()
            .expect("TOML");
        let found = ignored_keys(&table);
        let paths: Vec<&str> = found.iter().map(|i| i.path.as_str()).collect();
        assert_eq!(
            paths,
            [
                "lines.a.end_chars",
                "lines.a.xoff_code",
                "lines.b.xon_wait",
                "lines.m.devices.d.scanner.period",
                "lines.m.devices.d.tags[0].scale",
                "cp_memory.save_interval",
                "http.insecure_allow_unauthenticated_changes",
            ],
            "{found:#?}"
        );
        assert_eq!(
            found[0].message,
            "has no effect: end_chars is read only with end_criterion = \"end-chars\", and \
             end_criterion is \"char-delay\""
        );
        assert_eq!(
            found[3].message,
            "has no effect: period is read only with enabled = true, and enabled is false (its \
             default)"
        );
    }

    #[test]
    fn serde_names() {
        assert_eq!(serde_name(ModbusTable::Discrete), "discrete");
        assert_eq!(
            serde_name(Profile::named("altivar71").expect("registered")),
            "altivar71"
        );
    }

    /// Every problem of a polled device at once, where a user meets them (the config): its
    /// address (003 6.4.3 "ADDR": 0 is broadcast, never polled), a limit above what the device
    /// takes, a poll period of zero, a range past the address space or empty; and the back-off
    /// bounds out of order. (These cases were `DeviceSettings::validate`'s, which only its test
    /// called.)
    #[test]
    fn a_devices_problems_are_reported_at_once() {
        let device = |address: u8, read_registers: u16, backoff_min: &str, zero: &str| {
            format!(
                "[lines.m]\nport = \"/dev/null\"\nbaud = 19200\nprotocol = \"modbus-master-rtu\"\n\
                 [lines.m.devices.atv]\nprofile = \"altivar71\"\naddress = {address}\n\
                 offline_backoff_min = \"{backoff_min}\"\noffline_backoff_max = \"1s\"\n\
                 [lines.m.devices.atv.limits]\nread_registers = {read_registers}\n\
                 [[lines.m.devices.atv.poll]]\nname = \"fast\"\nperiod = \"100ms\"\n\
                 ranges = [{{ table = \"holding\", start = 3201, count = 1 }}]\n{zero}"
            )
        };
        let zero = "[[lines.m.devices.atv.poll]]\nname = \"zero\"\nperiod = \"0s\"\n\
             ranges = [{ table = \"holding\", start = 65535, count = 2 }, \
             { table = \"holding\", start = 1, count = 0 }]\n";
        assert!(crate::plant::parse(&device(2, 63, "1s", "")).is_ok());
        let issues = crate::plant::parse(&device(0, 200, "1s", zero))
            .expect_err("refused")
            .issues;
        let shown: Vec<String> = issues
            .iter()
            .map(|i| format!("{}: {}", i.path, i.message))
            .collect();
        assert_eq!(issues.len(), 5, "{shown:#?}");
        assert!(
            shown[0].contains("address: 0 is the broadcast address"),
            "{shown:#?}"
        );
        assert!(
            shown[1].contains("read_registers: must be between 1 and 63"),
            "{shown:#?}"
        );
        assert!(shown[2].contains("poll[1].period"), "{shown:#?}");
        assert!(
            shown[3].contains("range 65535+2 runs past address 65535"),
            "{shown:#?}"
        );
        assert!(shown[4].contains("poll[1].ranges[1].count"), "{shown:#?}");
        let issues = crate::plant::parse(&device(2, 63, "5s", ""))
            .expect_err("refused")
            .issues;
        assert_eq!(issues.len(), 1, "{issues:#?}");
        assert!(
            issues[0].path.ends_with("offline_backoff_min"),
            "{issues:#?}"
        );
    }
}
