//! Serial lines: one task per line owns the port and a protocol engine.
//!
//! A Modbus master line ([`spawn_modbus_master_line`]) polls its devices on a schedule, keeps their
//! registers in the [`ProcessImage`](crate::image::ProcessImage), and carries writes and on-demand
//! reads from the Modbus TCP server ([`DeviceUnit`]) through a bounded command queue.
//!
//! Modules:
//! - [`plan`]: merging polled ranges into the fewest reads within a device's limits (pure);
//! - `scheduler`: which request goes next (writes, on-demand reads, due polls, offline back-off);

pub mod plan;
mod scheduler;

use std::time::Duration;

pub use plan::{merge_ranges, AddrRange, DeviceLimits, ReadBlock};

use crate::image::Table;

/// Default back-off before the first retry of a device that stopped answering.
pub const DEFAULT_DEVICE_BACKOFF_MIN: Duration = Duration::from_secs(1);
/// Default longest back-off of a device that stopped answering.
pub const DEFAULT_DEVICE_BACKOFF_MAX: Duration = Duration::from_secs(30);

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
    /// First delay before retrying the device after it stopped answering.
    pub backoff_min: Duration,
    /// Longest delay between retries of an offline device.
    pub backoff_max: Duration,
}

// === impl DeviceSettings ===

impl DeviceSettings {
    /// A device with no poll groups, the CP's limits and the default back-off.
    pub fn new(name: impl Into<String>, slave: u8, unit_id: u8) -> Self {
        Self {
            name: name.into(),
            slave,
            unit_id,
            limits: DeviceLimits::default(),
            groups: Vec::new(),
            backoff_min: DEFAULT_DEVICE_BACKOFF_MIN,
            backoff_max: DEFAULT_DEVICE_BACKOFF_MAX,
        }
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
            .min()
    }

    /// Whether every address of `range` in `table` is polled.
    pub fn is_polled(&self, table: Table, range: AddrRange) -> bool {
        (u32::from(range.start)..range.end()).all(|a| {
            u16::try_from(a).is_ok_and(|a| {
                self.groups.iter().any(|g| {
                    g.table == table && g.ranges.iter().any(|r| r.contains(AddrRange::new(a, 1)))
                })
            })
        })
    }
}
