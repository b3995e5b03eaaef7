//! What a configuration change does, as data: [`Plan::new`] compares the configuration in force
//! with the new one ([`ConfigDiff`]) and says which lines stop, which start, which restart,
//! whether the slave lines keep the CP memory in force or get a new one, and which servers follow
//! the change. `Supervisor::apply` carries the plan out step by step; nothing here starts or
//! stops anything.
//!
//! A line whose serial or protocol settings or devices changed restarts as a whole (a line task
//! takes its device list at start); a new CP memory layout restarts every slave line that ran.

use std::collections::BTreeSet;

use proto_core::cpmem::MemoryLayout;

use crate::api::model::ApplyReport;
use crate::api::ConfigDiff;
use crate::app::lines::slave_layout;
use crate::plant::Config;

/// A line the change stops: removed, or restarted under its new settings.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct LineStop {
    pub(crate) name: String,
    /// It starts again: it hands its waiting telegrams and numbers to the new task, and its port
    /// counts as opened before.
    pub(crate) restarts: bool,
    /// Its devices the new configuration no longer has on it: their series go.
    pub(crate) devices_gone: Vec<String>,
    /// The protocol the line's series are labelled with, when they go: the line goes, or comes
    /// back under another protocol (the new line's series start from zero).
    pub(crate) series_gone: Option<&'static str>,
}

/// The CP memory the slave lines serve after the change.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum CpMemory {
    /// No slave line serves one (a memory in force stays as it is).
    Unused,
    /// The memory in force has the layout the slave lines need.
    Kept,
    /// A new memory of this layout; every slave line that ran restarts on it.
    New(MemoryLayout),
}

/// What a configuration change stops, starts and tells the servers, in the order it is done.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Plan {
    /// The removed lines, then the restarted ones: stopped first, their ports closed.
    pub(crate) stop: Vec<LineStop>,
    /// The added lines, then the restarted ones.
    pub(crate) start: Vec<String>,
    pub(crate) cp_memory: CpMemory,
    /// `[modbus_tcp]` changed: its limits go in force, its listeners follow their addresses.
    pub(crate) modbus_tcp: bool,
    /// The gateway's name changed: the zenoh session restarts under the new one.
    pub(crate) rename: bool,
    /// The report of the change; the servers it restarts are added as they restart.
    pub(crate) report: ApplyReport,
}

// === impl Plan ===

impl Plan {
    /// What putting `new` in force in place of `in_force` does, the CP memory in force having
    /// `memory`'s layout.
    pub(crate) fn new(in_force: &Config, new: &Config, memory: Option<&MemoryLayout>) -> Self {
        let diff = ConfigDiff::between(in_force, new);
        // A line task takes its devices at start: a device change restarts its line.
        let mut restart: BTreeSet<String> = diff.lines_changed.iter().cloned().collect();
        restart.extend(diff.devices_changed.iter().map(|(line, _)| line.clone()));
        let cp_memory = match slave_layout(new) {
            None => CpMemory::Unused,
            Some(layout) if memory == Some(&layout) => CpMemory::Kept,
            Some(layout) => {
                let slaves = new.lines.iter().filter(|(name, line)| {
                    line.protocol.cp_memory_slave().is_some() && in_force.lines.contains_key(*name)
                });
                restart.extend(slaves.map(|(name, _)| name.clone()));
                CpMemory::New(layout)
            }
        };
        let mut report = diff.report();
        report.devices_restarted.clear();
        report.servers_restarted.clear();
        report.lines_restarted = restart.iter().cloned().collect();
        Self {
            stop: (diff.lines_removed.iter().chain(&restart))
                .map(|name| line_stop(name, in_force, new))
                .collect(),
            start: diff.lines_added.iter().chain(&restart).cloned().collect(),
            cp_memory,
            modbus_tcp: diff.modbus_tcp_changed,
            rename: diff.name_changed,
            report,
        }
    }
}

/// How line `name` of `in_force` stops for `new`.
fn line_stop(name: &str, in_force: &Config, new: &Config) -> LineStop {
    let (before, after) = (in_force.lines.get(name), new.lines.get(name));
    let kept: BTreeSet<&String> = after
        .map(|l| l.devices().map(|(d, _)| d).collect())
        .unwrap_or_default();
    let devices_gone = before
        .into_iter()
        .flat_map(|l| l.devices().map(|(d, _)| d))
        .filter(|d| !kept.contains(d))
        .cloned()
        .collect();
    let protocol = |l: &crate::protocols::LineConfig| l.protocol.kind().as_str();
    LineStop {
        name: name.to_owned(),
        restarts: after.is_some(),
        devices_gone,
        series_gone: before
            .map(protocol)
            .filter(|p| after.map(protocol) != Some(*p)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Baud;
    use crate::plant::demo;

    fn names(plan: &Plan) -> Vec<&str> {
        plan.stop.iter().map(|s| s.name.as_str()).collect()
    }

    /// The plan from the demo to `new`, the memory in force being the demo's.
    fn plan(new: &Config) -> Plan {
        let old = demo();
        Plan::new(&old, new, slave_layout(&old).as_ref())
    }

    #[test]
    fn no_change_stops_and_starts_nothing() {
        let p = plan(&demo());
        assert!(p.stop.is_empty() && p.start.is_empty());
        assert_eq!(p.cp_memory, CpMemory::Kept);
        assert!(!p.modbus_tcp && !p.rename);
        assert!(p.report.is_empty());
    }

    #[test]
    fn a_baud_rate_restarts_its_line_with_its_devices_and_series() {
        let mut new = demo();
        new.lines.get_mut("drive").unwrap().serial.baud = Baud::try_new(9600).unwrap();
        let p = plan(&new);
        let stop = LineStop {
            name: "drive".into(),
            restarts: true,
            devices_gone: Vec::new(),
            series_gone: None,
        };
        assert_eq!(p.stop, [stop]);
        assert_eq!(p.start, ["drive"]);
        assert_eq!(p.report.lines_restarted, ["drive"]);
    }

    #[test]
    fn a_device_change_restarts_its_line_and_a_removed_line_stops_first() {
        let mut new = demo();
        let devices = new.lines.get_mut("ksvario").unwrap().protocol.section_mut();
        let devices = devices.devices_mut().expect("a Modbus master");
        devices.remove("meter");
        new.lines.remove("ascii");
        new.modbus_tcp.max_connections += 1;
        let p = plan(&new);
        assert_eq!(names(&p), ["ascii", "ksvario"]);
        assert!(!p.stop[0].restarts);
        assert_eq!(p.stop[0].series_gone, Some("ascii"));
        assert!(p.stop[1].restarts);
        assert_eq!(p.stop[1].devices_gone, ["meter"]);
        assert_eq!(p.stop[1].series_gone, None);
        assert_eq!(p.start, ["ksvario"]);
        assert!(p.modbus_tcp);
        // Devices restart with their line; servers are reported as they restart.
        assert!(p.report.devices_restarted.is_empty() && p.report.servers_restarted.is_empty());
        assert_eq!(p.report.lines_stopped, ["ascii"]);
    }

    #[test]
    fn an_added_line_only_starts() {
        let old = demo();
        let mut smaller = old.clone();
        smaller.lines.remove("r3964");
        let p = Plan::new(&smaller, &old, slave_layout(&old).as_ref());
        assert!(p.stop.is_empty());
        assert_eq!(p.start, ["r3964"]);
        assert_eq!(p.report.lines_started, ["r3964"]);
    }

    #[test]
    fn another_cp_memory_layout_restarts_every_slave_line() {
        let p = Plan::new(&demo(), &demo(), None);
        assert_eq!(p.cp_memory, CpMemory::New(slave_layout(&demo()).unwrap()));
        assert_eq!(names(&p), ["hmi"]);
        assert_eq!(p.start, ["hmi"]);
        let mut new = demo();
        new.lines.remove("hmi");
        assert_eq!(plan(&new).cp_memory, CpMemory::Unused);
    }

    #[test]
    fn a_new_name_renames_zenoh_and_restarts_no_line() {
        let mut new = demo();
        new.gateway.name = "cab2".into();
        let p = plan(&new);
        assert!(p.rename && p.stop.is_empty());
    }
}
