//! Serial lines: the line runtime drives one protocol adapter per line.
//!
//! [`runtime`] owns what every line does: opening the port ([`PortOpener`]), the driver loop,
//! reopening with back-off, the port events, the status and one [`LineHandle`]. The protocols are
//! adapters over it:
//! - `modbus_master` ([`spawn_modbus_master_line`]): polls its devices on a schedule, keeps their
//!   registers in the [`ProcessImage`](crate::image::ProcessImage), and carries writes and
//!   on-demand reads from the Modbus TCP server ([`DeviceUnit`]) through a bounded command queue;
//! - `modbus_slave` ([`spawn_modbus_slave_line`]): the Modbus slave RTU line serving the CP memory;
//! - `modbus_tap` ([`spawn_modbus_tap_line`]): a listen-only line that stores what another
//!   master's requests and the devices' answers show, never transmitting;
//! - [`telegram`]: ASCII and 3964(R) lines with their mailboxes.
//!
//! What the Modbus master adapter builds on:
//! - [`plan`]: merging polled ranges into the fewest reads within a device's limits (pure);
//! - `scheduler`: which request goes next (writes, on-demand reads, due polls within the fairness
//!   rule, reads riding on a due poll, offline after failed polls, back-off);
//! - `scanner`: the Altivar communication scanner, one FC 23 exchange per cycle;
//! - `probe`: how a device that stopped answering is probed (one attempt, a short wait derived
//!   from its own reply delay, every n-th probe the full reply monitoring time);
//! - `command`: the bounded command queue and the error-to-exception mapping;
//! - `writeback`: the image refresh after a confirmed write, the broadcast echo;
//! - `device_unit`: a polled device as a Modbus TCP unit;
//! - `transparent`: unit ids nobody claims forwarded to the slave of the same address, with the
//!   dead-device rules per address.
//!
//! Shared by every line:
//! - `status`: diagnostic buffer, event counters, STATUS word, device states;
//! - `line_metrics`: the line's counters ([`LineTraffic`]) and its Prometheus metrics (events,
//!   port state, traffic, requests);
//! - [`monitor`]: the frame monitor (every frame with its times, bytes and line errors, in a
//!   bounded ring), fed by the runtime where bytes pass;
//! - [`pcapng`]: the monitor's frames as a pcapng file for Wireshark;
//! - `driver`: clock conversion and timer helpers of the driver loop.

mod command;
mod device_unit;
mod driver;
mod line_metrics;
mod modbus_master;
mod modbus_slave;
mod modbus_tap;
pub mod monitor;
pub mod pcapng;
pub mod plan;
mod probe;
mod registers32;
pub mod runtime;
mod scanner;
mod scheduler;
mod status;
pub mod telegram;
#[cfg(test)]
mod testing;
mod transparent;
mod writeback;

use std::time::Duration;

use proto_core::modbus::master::{Framing, MasterConfig};
use proto_core::modbus::rtu::CharTiming;

pub use command::{
    exception_for, exception_for_queue, CommandError, CommandResult, LineClient, QueueError,
};
pub use device_unit::DeviceUnit;
pub use line_metrics::LineTraffic;
pub use modbus_master::spawn_modbus_master_line;
pub use modbus_slave::{spawn_modbus_slave_line, CpMemoryView, SlaveCounters, SlaveLineSettings};
pub use modbus_tap::{spawn_modbus_tap_line, TapLineSettings, TAP_PROTOCOL};
pub use monitor::{Frame, FrameMonitor, DEFAULT_MONITOR_FRAMES, MAX_MONITOR_FRAMES};
pub use plan::{merge_ranges, AddrRange, DeviceLimits, ReadBlock};
pub use probe::{ProbeSettings, PROBE_TIMEOUT_FACTOR};
pub use runtime::{
    LineHandle, LinePort, PortOpener, SerialOpener, EVENT_PORT_LOST, EVENT_PORT_SETUP,
};
pub use scanner::{ScannerSettings, SCANNER_WORDS};
pub use status::{DeviceStatus, LineEvent, LineStatus, DEFAULT_DIAG_DEPTH};
pub use transparent::{TransparentSettings, TransparentUnit};

use crate::config::{
    DEFAULT_COMMANDS_IN_ROW, DEFAULT_OFFLINE_AFTER, DEFAULT_OFFLINE_BACKOFF_MAX,
    DEFAULT_OFFLINE_BACKOFF_MIN, FULL_PROBE_EVERY_RANGE, OFFLINE_AFTER_RANGE,
    PROBE_TIMEOUT_MIN_RANGE,
};
use crate::image::Table;
use crate::metrics::Metrics;
use crate::serial::PortSettings;

/// Depth of a line's command queue by default.
pub const DEFAULT_QUEUE_DEPTH: usize = 16;
/// First delay before reopening a failed port by default.
pub const DEFAULT_REOPEN_MIN: Duration = Duration::from_millis(500);
/// Longest delay between reopen attempts by default.
pub const DEFAULT_REOPEN_MAX: Duration = Duration::from_secs(30);
/// Slack on top of the master's own reply monitoring for a command's deadline by default.
pub const DEFAULT_COMMAND_SLACK: Duration = Duration::from_secs(1);

/// The character timing of the gateway's Modbus RTU lines, master and slave: 1.5 and 3.5
/// character times at every baud rate, as the CP 341 computes them (003 6.4.3, "Time_Out for
/// message end": 76800 -> 0.5 ms, 38400 -> 1 ms, 19200 -> 2 ms, 9600 -> 4 ms ... 300 -> 128 ms),
/// not the fixed 1.75 ms of the Modbus over Serial Line specification above 19200 Bd. The line's
/// "multiplier character delay time" (003 6.4.2.1, 1..10) multiplies t3.5 on top, for a partner
/// that needs longer (a device that follows the fixed 1.75 ms above 19200 Bd: 2 at 38400 Bd).
pub fn rtu_timing(port: &PortSettings) -> CharTiming {
    CharTiming::exact(port.baud, port.bits_per_char())
}

/// Settings of one Modbus master line.
#[derive(Clone, Debug)]
pub struct LineSettings {
    /// The line's name (logs, status, keys).
    pub name: String,
    /// The serial port.
    pub port: PortSettings,
    /// The master engine: framing, reply monitoring time, retries, operating mode.
    pub master: MasterConfig,
    /// How many commands may wait or be in flight on the line (one more answers 0x06).
    pub queue_depth: usize,
    /// Depth of the diagnostic buffer (the CP keeps 9).
    pub diag_depth: usize,
    /// First delay before reopening a failed port.
    pub reopen_min: Duration,
    /// Longest delay between reopen attempts.
    pub reopen_max: Duration,
    /// How long a command waits for its answer, queueing included (`None`: the master's reply
    /// monitoring time x (retries + 1) + [`DEFAULT_COMMAND_SLACK`]).
    pub command_deadline: Option<Duration>,
    /// Where the line counts its events, traffic and requests (`None`: nowhere).
    pub metrics: Option<Metrics>,
    /// While a poll is due, at most this many commands go in a row (the fairness rule of the
    /// bus, see `scheduler`).
    pub commands_in_row: u32,
    /// Transparent forwarding of unit ids nobody claims (`None`: off; see `transparent`).
    pub transparent: Option<TransparentSettings>,
}

// === impl LineSettings ===

impl LineSettings {
    /// A Modbus master RTU line on `port` with the master's defaults for its baud rate and frame.
    pub fn rtu(name: impl Into<String>, port: PortSettings) -> Self {
        let master = MasterConfig {
            framing: Framing::Rtu {
                timing: rtu_timing(&port),
            },
            ..MasterConfig::rtu(port.baud, port.bits_per_char())
        };
        Self {
            name: name.into(),
            port,
            master,
            queue_depth: DEFAULT_QUEUE_DEPTH,
            diag_depth: DEFAULT_DIAG_DEPTH,
            reopen_min: DEFAULT_REOPEN_MIN,
            reopen_max: DEFAULT_REOPEN_MAX,
            command_deadline: None,
            metrics: None,
            commands_in_row: DEFAULT_COMMANDS_IN_ROW,
            transparent: None,
        }
    }

    /// The `protocol` label of the line: the config's key for its framing.
    fn protocol(&self) -> &'static str {
        match self.master.framing {
            Framing::Rtu { .. } => "modbus-master-rtu",
            Framing::Ascii { .. } => "modbus-master-ascii",
        }
    }

    /// How long a command waits for its answer.
    pub fn command_deadline(&self) -> Duration {
        self.command_deadline.unwrap_or_else(|| {
            let attempts = u32::from(self.master.retries) + 1;
            self.master.reply_timeout.saturating_mul(attempts) + DEFAULT_COMMAND_SLACK
        })
    }
}

/// A set of ranges of one table polled at one period.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PollGroup {
    /// How often the ranges are read.
    pub period: Duration,
    /// The table read.
    pub table: Table,
    /// The polled ranges (merged by [`merge_ranges`] within the device's limits).
    pub ranges: Vec<AddrRange>,
}

/// One polled device on a Modbus master line.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DeviceSettings {
    /// Name for logs, status and keys.
    pub name: String,
    /// Its Modbus address on the serial line (1..247).
    pub slave: u8,
    /// The unit id under which the image and the Modbus TCP server keep it.
    pub unit_id: u8,
    /// What it accepts in one request.
    pub limits: DeviceLimits,
    /// What is polled and how often.
    pub groups: Vec<PollGroup>,
    /// First delay before probing the device after it stopped answering.
    pub backoff_min: Duration,
    /// Longest delay between probes of an offline device.
    pub backoff_max: Duration,
    /// How an offline device is probed.
    pub probe: ProbeSettings,
    /// Polls in a row without a valid answer that put it offline.
    pub offline_after: u32,
    /// The Altivar communication scanner exchanged with FC 23 each cycle (`None`: off).
    pub scanner: Option<ScannerSettings>,
}

// === impl DeviceSettings ===

impl DeviceSettings {
    /// A device with no poll groups, the CP's limits and the default back-off and probes.
    pub fn new(name: impl Into<String>, slave: u8, unit_id: u8) -> Self {
        Self {
            name: name.into(),
            slave,
            unit_id,
            limits: DeviceLimits::default(),
            groups: Vec::new(),
            backoff_min: DEFAULT_OFFLINE_BACKOFF_MIN,
            backoff_max: DEFAULT_OFFLINE_BACKOFF_MAX,
            probe: ProbeSettings::default(),
            offline_after: DEFAULT_OFFLINE_AFTER,
            scanner: None,
        }
    }

    /// The holding register ranges the scanner keeps in the image: its input and output words.
    pub fn scanner_ranges(&self) -> Vec<AddrRange> {
        self.scanner
            .map(|s| vec![s.input_range(), s.output_range()])
            .unwrap_or_default()
    }

    /// The reads that serve every poll group: groups of the same table and period are merged
    /// together, each within the device's limits.
    pub fn read_blocks(&self) -> Vec<ReadBlock> {
        let mut keys: Vec<(Table, Duration)> =
            self.groups.iter().map(|g| (g.table, g.period)).collect();
        keys.sort_unstable();
        keys.dedup();
        let mut blocks = Vec::new();
        for (table, period) in keys {
            let ranges: Vec<AddrRange> = self
                .groups
                .iter()
                .filter(|g| g.table == table && g.period == period)
                .flat_map(|g| g.ranges.iter().copied())
                .collect();
            let max = self.limits.max_read(table);
            blocks.extend(
                merge_ranges(&ranges, max, self.limits.bridge_gap)
                    .into_iter()
                    .map(|range| ReadBlock {
                        table,
                        range,
                        period,
                    }),
            );
        }
        blocks
    }

    /// Every problem of the settings, all at once (empty: valid): slave address 1..247 (003 6.4.3
    /// "ADDR": 0 is broadcast, which is never polled), limits within the CP's (1..127 registers,
    /// 1..2040 bits, 003 6.4.4), periods above zero, ranges inside the address space and the
    /// back-off bounds ordered, probes with a wait of at least 5 ms (the shortest reply monitoring
    /// time, 003 6.4.2.1) and a full probe at least every 1000.
    pub fn validate(&self) -> Vec<String> {
        let mut issues = Vec::new();
        let name = &self.name;
        if !(1..=247).contains(&self.slave) {
            issues.push(format!(
                "device {name}: slave address {} is outside 1..247",
                self.slave
            ));
        }
        let cp = DeviceLimits::CP341;
        for (what, value, max) in [
            ("max_read_regs", self.limits.max_read_regs, cp.max_read_regs),
            (
                "max_write_regs",
                self.limits.max_write_regs,
                cp.max_write_regs,
            ),
            ("max_read_bits", self.limits.max_read_bits, cp.max_read_bits),
            (
                "max_write_bits",
                self.limits.max_write_bits,
                cp.max_write_bits,
            ),
        ] {
            if !(1..=max).contains(&value) {
                issues.push(format!(
                    "device {name}: {what} {value} is outside 1..{max} (the CP master's limit)"
                ));
            }
        }
        for (i, group) in self.groups.iter().enumerate() {
            if group.period.is_zero() {
                issues.push(format!(
                    "device {name}: poll group {i} has a period of zero"
                ));
            }
            if group.ranges.is_empty() {
                issues.push(format!("device {name}: poll group {i} has no ranges"));
            }
            for range in &group.ranges {
                if range.count == 0 || range.end() > 0x1_0000 {
                    issues.push(format!(
                        "device {name}: poll group {i} range {}+{} is empty or runs past 65535",
                        range.start, range.count
                    ));
                }
            }
        }
        if let Some(scanner) = &self.scanner {
            issues.extend(scanner.validate(name));
        }
        if let Err(err) = crate::serial::Backoff::try_new(self.backoff_min, self.backoff_max) {
            issues.push(format!("device {name}: back-off: {err}"));
        }
        let (lo, hi) = PROBE_TIMEOUT_MIN_RANGE;
        if !(lo..=hi).contains(&self.probe.timeout_min) {
            issues.push(format!(
                "device {name}: probe_timeout_min {:?} is outside 5..65500 ms",
                self.probe.timeout_min
            ));
        }
        let (lo, hi) = OFFLINE_AFTER_RANGE;
        if !(lo..=hi).contains(&self.offline_after) {
            issues.push(format!(
                "device {name}: offline_after {} is outside {lo}..{hi}",
                self.offline_after
            ));
        }
        let (lo, hi) = FULL_PROBE_EVERY_RANGE;
        if !(lo..=hi).contains(&self.probe.full_every) {
            issues.push(format!(
                "device {name}: full_probe_every {} is outside {lo}..{hi}",
                self.probe.full_every
            ));
        }
        issues
    }

    /// The poll period of the fastest group that polls `address` of `table`, if any.
    pub fn poll_period(&self, table: Table, address: u16) -> Option<Duration> {
        self.groups
            .iter()
            .filter(|g| {
                g.table == table
                    && g.ranges
                        .iter()
                        .any(|r| r.contains(AddrRange::new(address, 1)))
            })
            .map(|g| g.period)
            .chain(self.scanner.map(|s| s.period).filter(|_| {
                table == Table::HoldingRegisters
                    && self
                        .scanner_ranges()
                        .iter()
                        .any(|r| r.contains(AddrRange::new(address, 1)))
            }))
            .min()
    }

    /// Whether every address of `range` in `table` is polled.
    pub fn is_polled(&self, table: Table, range: AddrRange) -> bool {
        (u32::from(range.start)..range.end()).all(|a| {
            u16::try_from(a).is_ok_and(|a| {
                let one = AddrRange::new(a, 1);
                self.groups
                    .iter()
                    .any(|g| g.table == table && g.ranges.iter().any(|r| r.contains(one)))
                    || (table == Table::HoldingRegisters
                        && self.scanner_ranges().iter().any(|r| r.contains(one)))
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 003 6.4.3 "Time_Out for message end": 76800 -> 0.5 ms, 38400 -> 1 ms, 19200 -> 2 ms,
    /// 9600 -> 4 ms, 300 -> 128 ms (3.5 characters of 11 bits, rounded in the manual).
    #[test]
    fn rtu_lines_end_a_frame_after_the_cps_time_out_at_every_baud_rate() {
        for (baud, manual_us) in [
            (76_800, 500),
            (38_400, 1_000),
            (19_200, 2_000),
            (9_600, 4_000),
            (300, 128_000),
        ] {
            let port = PortSettings::new("/dev/null", baud);
            let t35 = rtu_timing(&port).t3_5().as_micros();
            let off = t35.abs_diff(manual_us);
            assert!(off * 100 <= manual_us * 3, "{baud} Bd: {t35} us");
            // The master line and the slave line take the same timing.
            let Framing::Rtu { timing } = LineSettings::rtu("l", port.clone()).master.framing
            else {
                panic!("an RTU line");
            };
            assert_eq!(timing.t3_5().as_micros(), t35);
            let params = proto_core::cpmem::SlaveParams::new(
                1,
                proto_core::cpmem::OperatingMode::Normal,
                1,
                proto_core::cpmem::AddressMap::manual_example(),
            )
            .expect("params");
            let slave = SlaveLineSettings::new("s", port, params);
            assert_eq!(slave.timing().t3_5().as_micros(), t35);
        }
        // The multiplier (003 6.4.2.1, 1..10) on top: 2 at 38400 Bd gives 2 ms.
        let doubled = rtu_timing(&PortSettings::new("/dev/null", 38_400)).with_multiplier(2);
        assert_eq!(doubled.t3_5().as_micros(), 2_005);
    }
}
