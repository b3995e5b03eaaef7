//! Planning reads: merging a device's polled ranges into the fewest requests within its limits.
//!
//! Pure functions, no time and no I/O: the scheduler calls them once when a line starts.

use std::time::Duration;

use proto_core::modbus::pdu::Request;
use proto_core::profiles::{self, RequestLimits};

use crate::image::Table;

/// A range of addresses in one table: `start`, `start + 1`, ... `start + count - 1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct AddrRange {
    /// First address.
    pub start: u16,
    /// Number of addresses.
    pub count: u16,
}

// === impl AddrRange ===

impl AddrRange {
    /// The range `start .. start + count`.
    pub const fn new(start: u16, count: u16) -> Self {
        Self { start, count }
    }

    /// One past the last address (as u32: a range may end at 65536).
    pub fn end(self) -> u32 {
        u32::from(self.start) + u32::from(self.count)
    }

    /// Whether `other` lies completely inside this range.
    pub fn contains(self, other: Self) -> bool {
        other.start >= self.start && other.end() <= self.end()
    }

    /// Whether the ranges share an address.
    pub fn overlaps(self, other: Self) -> bool {
        u32::from(self.start) < other.end() && u32::from(other.start) < self.end()
    }
}

/// What the planner may put in one request to a device: its [`RequestLimits`] (FC 23 and the
/// ADU length are not planned with) and how far a merged read may bridge.
///
/// The presets take their numbers from proto-core's limits, which cite their manuals;
/// "bridging" lets a merged read include up to `bridge_gap` addresses nobody polls, which only
/// works on devices that answer such addresses (the Altivar reads a missing word as 0x8000 and
/// the KS vario a gap as 31000, but both answer exception 02 when the first word is undefined), so
/// it is off unless configured.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct DeviceLimits {
    /// Registers in one FC03/FC04 read.
    pub max_read_regs: u16,
    /// Registers in one FC16 write.
    pub max_write_regs: u16,
    /// Bits in one FC01/FC02 read.
    pub max_read_bits: u16,
    /// Bits in one FC15 write.
    pub max_write_bits: u16,
    /// Largest run of unpolled addresses a merged read may include (0: never bridge a gap).
    pub bridge_gap: u16,
}

// === impl DeviceLimits ===

impl DeviceLimits {
    /// What the CP 341 master itself allows ([`RequestLimits::CP341`], 003 6.4.4).
    pub const CP341: Self = Self::from_request(RequestLimits::CP341, 0);

    /// Altivar 61/71 ([`profiles::altivar::LIMITS`], 002). The drive has no bit functions; the
    /// bit limits stay the CP's.
    pub const ALTIVAR: Self = Self::registers_of(profiles::altivar::LIMITS);

    /// KS vario ([`profiles::ksvario::LIMITS`], 001 3.1). No bit functions; the bit limits stay
    /// the CP's.
    pub const KS_VARIO: Self = Self::registers_of(profiles::ksvario::LIMITS);

    /// The planner's limits of a device that accepts `limits`, bridging up to `bridge_gap`.
    pub const fn from_request(limits: RequestLimits, bridge_gap: u16) -> Self {
        Self {
            max_read_regs: limits.read_registers,
            max_write_regs: limits.write_registers,
            max_read_bits: limits.read_bits,
            max_write_bits: limits.write_bits,
            bridge_gap,
        }
    }

    /// The register limits of `limits` with the CP's bit limits, no bridging.
    const fn registers_of(limits: RequestLimits) -> Self {
        Self {
            max_read_regs: limits.read_registers,
            max_write_regs: limits.write_registers,
            ..Self::CP341
        }
    }

    /// The largest read of `table` in one request (at least 1).
    pub fn max_read(&self, table: Table) -> u16 {
        let max = if table.is_bits() {
            self.max_read_bits
        } else {
            self.max_read_regs
        };
        max.max(1)
    }
}

impl Default for DeviceLimits {
    fn default() -> Self {
        Self::CP341
    }
}

/// One read the scheduler issues: a table range and the poll period it serves.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ReadBlock {
    /// The table read.
    pub table: Table,
    /// The addresses read.
    pub range: AddrRange,
    /// How often.
    pub period: Duration,
}

// === impl ReadBlock ===

impl ReadBlock {
    /// The request that reads this block.
    pub fn request(&self) -> Request {
        let AddrRange {
            start: address,
            count: quantity,
        } = self.range;
        match self.table {
            Table::Coils => Request::ReadCoils { address, quantity },
            Table::DiscreteInputs => Request::ReadDiscreteInputs { address, quantity },
            Table::HoldingRegisters => Request::ReadHoldingRegisters { address, quantity },
            Table::InputRegisters => Request::ReadInputRegisters { address, quantity },
        }
    }
}

/// Merges `ranges` of one table into the fewest reads of at most `max` addresses each, bridging
/// gaps of at most `bridge_gap` unpolled addresses. Overlapping and adjacent ranges always merge;
/// a range longer than `max` is split. Empty ranges are ignored, ranges past 65535 clipped.
///
/// Greedy from the lowest address: each read starts at the first address not yet covered and
/// takes in everything that fits, which gives the fewest reads for covering with bounded windows.
pub fn merge_ranges(ranges: &[AddrRange], max: u16, bridge_gap: u16) -> Vec<AddrRange> {
    let max = u32::from(max.max(1));
    let gap = u32::from(bridge_gap);
    let mut sorted: Vec<(u32, u32)> = ranges
        .iter()
        .filter(|r| r.count > 0)
        .map(|r| (u32::from(r.start), r.end().min(0x1_0000)))
        .collect();
    sorted.sort_unstable();

    let mut out: Vec<(u32, u32)> = Vec::new();
    // The read being built: [start, end).
    let mut cur: Option<(u32, u32)> = None;
    for (mut s, e) in sorted {
        if let Some((bs, be)) = cur {
            if e <= be {
                continue; // already covered
            }
            if s <= be {
                // Overlapping or adjacent: grow the read up to its limit, the rest starts anew.
                let grown = e.min(bs + max);
                if grown == e {
                    cur = Some((bs, grown));
                    continue;
                }
                out.push((bs, grown));
                s = grown;
            } else if s - be <= gap && e - bs <= max {
                cur = Some((bs, e));
                continue;
            } else {
                out.push((bs, be));
            }
        }
        while e - s > max {
            out.push((s, s + max));
            s += max;
        }
        cur = Some((s, e));
    }
    out.extend(cur);
    out.into_iter()
        .filter_map(|(s, e)| {
            Some(AddrRange::new(
                u16::try_from(s).ok()?,
                u16::try_from(e - s).ok()?,
            ))
        })
        .collect()
}

#[cfg(test)]
mod tests;
