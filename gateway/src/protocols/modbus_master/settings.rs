//! The settings of a Modbus master line and its polled devices: what the line's config section
//! becomes (the config checks them; these types hold them).

use super::transparent::TransparentSettings;
use std::time::Duration;

use proto_core::modbus::master::{Framing, MasterConfig};

use super::plan::{merge_ranges, AddrRange, DeviceLimits, ReadBlock};
use super::probe::ProbeSettings;
use super::scanner::ScannerSettings;
use crate::config::{
    DEFAULT_OFFLINE_AFTER, DEFAULT_OFFLINE_BACKOFF_MAX, DEFAULT_OFFLINE_BACKOFF_MIN,
};
use crate::image::Table;
use crate::line::metrics::LineFamilies;
use crate::line::status::DEFAULT_DIAG_DEPTH;
use crate::line::{
    rtu_timing, DEFAULT_COMMAND_SLACK, DEFAULT_QUEUE_DEPTH, DEFAULT_REOPEN_MAX, DEFAULT_REOPEN_MIN,
};
use crate::protocols::DEFAULT_COMMANDS_IN_ROW;
use crate::serial::PortSettings;

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
    pub metrics: Option<LineFamilies>,
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
    pub(super) fn protocol(&self) -> &'static str {
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
