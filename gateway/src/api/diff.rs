//! What changed between two configurations, at the grain the supervisor restarts things: a
//! line (serial or protocol settings), a device on a line that keeps running, a server.
//!
//! A line whose only change is in its `devices` table keeps its port and its other devices;
//! only the devices added, removed or changed are (re)started. A change of
//! `[gateway] diag_buffer_depth` restarts every line (the buffer is sized at start); a change of
//! `[gateway] name` renames the zenoh prefix, so zenoh restarts. Every other top-level section
//! (`[cp_memory]`, `[http]`, `[zenoh]`, ...) is compared as a whole and named in
//! `sections_changed`; [`ConfigDiff::report`] lists those as pending a restart of the process,
//! and a backend that applies one of them live says so in its own report.

use std::collections::BTreeMap;

use super::model::ApplyReport;
use crate::config::DeviceConfig;
use crate::plant::Config;
use crate::protocols::LineConfig;

/// The changes from one configuration to the next.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ConfigDiff {
    pub lines_added: Vec<String>,
    pub lines_removed: Vec<String>,
    /// Lines present in both whose serial or protocol settings changed.
    pub lines_changed: Vec<String>,
    /// Devices `(line, device)` added, removed or changed on lines not in `lines_changed`.
    pub devices_changed: Vec<(String, String)>,
    /// `[modbus_tcp]` changed.
    pub modbus_tcp_changed: bool,
    /// `[gateway] name` changed (the zenoh prefix).
    pub name_changed: bool,
    /// Other top-level sections that changed, by name, sorted.
    pub sections_changed: Vec<String>,
}

// === impl ConfigDiff ===

impl ConfigDiff {
    /// The changes from `old` to `new`.
    pub fn between(old: &Config, new: &Config) -> Self {
        let mut diff = Self {
            modbus_tcp_changed: old.modbus_tcp != new.modbus_tcp,
            name_changed: old.gateway.name != new.gateway.name,
            ..Self::default()
        };
        let depth_changed = old.gateway.diag_buffer_depth != new.gateway.diag_buffer_depth;
        for (name, line) in &new.lines {
            match old.lines.get(name) {
                None => diff.lines_added.push(name.clone()),
                Some(before)
                    if depth_changed || without_devices(before) != without_devices(line) =>
                {
                    diff.lines_changed.push(name.clone());
                }
                Some(before) => {
                    for device in changed_devices(devices(before), devices(line)) {
                        diff.devices_changed.push((name.clone(), device));
                    }
                }
            }
        }
        diff.sections_changed = other_sections_changed(old, new);
        diff.lines_removed = old
            .lines
            .keys()
            .filter(|n| !new.lines.contains_key(*n))
            .cloned()
            .collect();
        diff
    }

    /// Whether nothing changed that needs a restart.
    pub fn is_empty(&self) -> bool {
        self.lines_added.is_empty()
            && self.lines_removed.is_empty()
            && self.lines_changed.is_empty()
            && self.devices_changed.is_empty()
            && !self.modbus_tcp_changed
            && !self.name_changed
            && self.sections_changed.is_empty()
    }

    /// The report of applying exactly these changes.
    pub fn report(&self) -> ApplyReport {
        let mut servers = Vec::new();
        if self.modbus_tcp_changed {
            servers.push("modbus_tcp".to_owned());
        }
        if self.name_changed {
            servers.push("zenoh".to_owned());
        }
        ApplyReport {
            lines_started: self.lines_added.clone(),
            lines_stopped: self.lines_removed.clone(),
            lines_restarted: self.lines_changed.clone(),
            devices_restarted: self
                .devices_changed
                .iter()
                .map(|(l, d)| format!("{l}/{d}"))
                .collect(),
            servers_restarted: servers,
            pending_restart: self.sections_changed.clone(),
        }
    }
}

/// Top-level sections other than `gateway`, `modbus_tcp` and `lines` whose contents differ.
fn other_sections_changed(old: &Config, new: &Config) -> Vec<String> {
    const OWN_RULES: [&str; 3] = ["gateway", "modbus_tcp", "lines"];
    let (Ok(old), Ok(new)) = (toml::Table::try_from(old), toml::Table::try_from(new)) else {
        return Vec::new();
    };
    let mut names: Vec<String> = old
        .keys()
        .chain(new.keys())
        .filter(|k| !OWN_RULES.contains(&k.as_str()) && old.get(*k) != new.get(*k))
        .cloned()
        .collect();
    names.sort();
    names.dedup();
    names
}

fn devices(line: &LineConfig) -> &BTreeMap<String, DeviceConfig> {
    static NONE: BTreeMap<String, DeviceConfig> = BTreeMap::new();
    line.protocol.section().devices().unwrap_or(&NONE)
}

/// The line with an empty device table: what a device change leaves alone.
fn without_devices(line: &LineConfig) -> LineConfig {
    let mut line = line.clone();
    if let Some(devices) = line.protocol.section_mut().devices_mut() {
        devices.clear();
    }
    line
}

/// Names of devices added, removed or changed, sorted.
fn changed_devices(
    old: &BTreeMap<String, DeviceConfig>,
    new: &BTreeMap<String, DeviceConfig>,
) -> Vec<String> {
    let mut names: Vec<String> = new
        .iter()
        .filter(|(n, d)| old.get(*n) != Some(*d))
        .map(|(n, _)| n.clone())
        .chain(old.keys().filter(|n| !new.contains_key(*n)).cloned())
        .collect();
    names.sort();
    names
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Baud;
    use crate::plant::demo;

    #[test]
    fn no_change_is_empty() {
        let d = ConfigDiff::between(&demo(), &demo());
        assert!(d.is_empty());
        assert!(d.report().is_empty());
    }

    #[test]
    fn a_baud_rate_restarts_only_its_line() {
        let old = demo();
        let mut new = old.clone();
        new.lines.get_mut("drive").unwrap().serial.baud = Baud::try_new(9600).unwrap();
        let d = ConfigDiff::between(&old, &new);
        assert_eq!(d.lines_changed, ["drive"]);
        assert!(d.devices_changed.is_empty() && !d.modbus_tcp_changed);
        assert_eq!(d.report().lines_restarted, ["drive"]);
    }

    #[test]
    fn a_device_change_keeps_the_line() {
        let old = demo();
        let mut new = old.clone();
        let line = new.lines.get_mut("ksvario").unwrap();
        let devices = line.protocol.section_mut().devices_mut();
        let devices = devices.expect("the demo's ksvario line is a Modbus master");
        devices.get_mut("ksvario").unwrap().unit_id = 18;
        new.lines.remove("ascii");
        new.modbus_tcp.max_connections += 1;
        let d = ConfigDiff::between(&old, &new);
        assert!(d.lines_changed.is_empty());
        assert_eq!(
            d.devices_changed,
            [("ksvario".to_owned(), "ksvario".to_owned())]
        );
        assert_eq!(d.lines_removed, ["ascii"]);
        let r = d.report();
        assert_eq!(r.devices_restarted, ["ksvario/ksvario"]);
        assert_eq!(r.servers_restarted, ["modbus_tcp"]);
    }

    #[test]
    fn other_sections_are_named_and_pending() {
        let old = demo();
        let mut new = old.clone();
        new.cp_memory.persist_file = Some("/var/lib/gateway/cp.bin".into());
        let d = ConfigDiff::between(&old, &new);
        assert_eq!(d.sections_changed, ["cp_memory"]);
        assert!(!d.is_empty());
        assert_eq!(d.report().pending_restart, ["cp_memory"]);
    }

    #[test]
    fn the_buffer_depth_restarts_every_line() {
        let old = demo();
        let mut new = old.clone();
        new.gateway.diag_buffer_depth = 20;
        let d = ConfigDiff::between(&old, &new);
        assert_eq!(d.lines_changed.len(), old.lines.len());
    }
}
