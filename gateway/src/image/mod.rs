//! The process image: the live register maps of the polled devices.
//!
//! Per unit id and [`Table`], per address: the value (a register, or a bit stored as 0/1), its
//! [`Quality`] and when it was read (wall clock for display, monotonic clock for its age). The line
//! tasks write it after each poll; the Modbus TCP server, REST and zenoh read it. Reads take a shared
//! lock for the time of one range copy, writes an exclusive lock for one range.
//!
//! A value is stale when it is older than `stale_factor` times the poll period it was stored with;
//! staleness is computed when the value is read, so no task has to sweep the image.
//!
//! A slot keeps its times as integers (24 bytes a value, see `slot.rs`): wall times to the
//! microsecond, a time before 1970 as the epoch; freshness limits in whole milliseconds, rounded
//! up, at most about 49.7 days.
//!
//! Every store or quality change that alters something is announced on a bounded broadcast channel
//! ([`ProcessImage::subscribe`]); a receiver that falls behind loses the oldest changes and learns
//! how many from `RecvError::Lagged` (tokio's broadcast policy), so nothing is dropped silently.

mod read;
mod runs;
mod slot;

use std::collections::HashMap;
use std::sync::{Arc, PoisonError, RwLock, RwLockReadGuard, RwLockWriteGuard};
use std::time::{Duration, SystemTime};

use tokio::sync::broadcast;
use tokio::time::Instant;

pub use proto_core::modbus::Table;
pub use proto_core::profiles::Quality;
use runs::Runs;
use slot::{Clock, Slot};

/// How many poll periods a value stays fresh by default.
pub const DEFAULT_STALE_FACTOR: u32 = 3;
/// Capacity of the change broadcast channel by default.
pub const DEFAULT_NOTIFY_CAPACITY: usize = 1024;

/// Settings of a [`ProcessImage`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageConfig {
    /// A value older than this many times its poll period reads as [`Quality::Stale`].
    pub stale_factor: u32,
    /// Capacity of the change notification channel (changes a slow subscriber may lag behind).
    pub notify_capacity: usize,
}

impl Default for ImageConfig {
    fn default() -> Self {
        Self {
            stale_factor: DEFAULT_STALE_FACTOR,
            notify_capacity: DEFAULT_NOTIFY_CAPACITY,
        }
    }
}

/// The four tables of one unit.
#[derive(Debug, Default)]
struct UnitImage {
    tables: [Runs; 4],
}

impl UnitImage {
    fn table(&self, table: Table) -> &Runs {
        &self.tables[table_index(table)]
    }

    fn table_mut(&mut self, table: Table) -> &mut Runs {
        &mut self.tables[table_index(table)]
    }
}

const fn table_index(table: Table) -> usize {
    match table {
        Table::Coils => 0,
        Table::DiscreteInputs => 1,
        Table::HoldingRegisters => 2,
        Table::InputRegisters => 3,
    }
}

/// The result of a range read: every value, the worst quality and the oldest read time.
#[derive(Clone, Debug, PartialEq)]
pub struct RangeRead<T> {
    /// The values, one per address from the start of the range.
    pub values: Vec<T>,
    /// The worst quality in the range (staleness included).
    pub quality: Quality,
    /// Wall-clock time of the oldest value.
    pub oldest: SystemTime,
    /// Monotonic time of the oldest value.
    pub oldest_at: Instant,
}

/// One value as shown by [`ProcessImage::snapshot`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SlotView {
    /// The address in its table.
    pub address: u16,
    /// The register value, or 0/1 for a bit.
    pub value: u16,
    /// The quality, staleness included.
    pub quality: Quality,
    /// Wall-clock time of the read.
    pub updated: SystemTime,
}

/// Why a range read could not be answered from the image.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ImageError {
    /// Nothing is stored for this unit.
    #[error("unit {0} has no values in the image")]
    UnknownUnit(u8),
    /// An address of the range has never been stored.
    #[error("unit {unit} {table} address {address} has no value in the image")]
    Missing {
        /// The unit id.
        unit: u8,
        /// The table.
        table: Table,
        /// The first missing address.
        address: u16,
    },
    /// The range is empty or runs past address 65535.
    #[error("invalid range: start {start}, count {count}")]
    InvalidRange {
        /// First address.
        start: u16,
        /// Number of addresses.
        count: u16,
    },
}

/// A change announced to subscribers: a range of one table of one unit after a store or a quality
/// change, with the values and quality as they are now.
#[derive(Clone, Debug, PartialEq)]
pub struct Change {
    /// The unit id.
    pub unit: u8,
    /// The table.
    pub table: Table,
    /// First address of the range.
    pub start: u16,
    /// The values of the range (0/1 for bits).
    pub values: Vec<u16>,
    /// The quality of the whole range.
    pub quality: Quality,
    /// Wall-clock time of the change.
    pub time: SystemTime,
}

/// The shared process image; clones are cheap and see the same data.
#[derive(Clone, Debug)]
pub struct ProcessImage {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    units: RwLock<HashMap<u8, UnitImage>>,
    changes: broadcast::Sender<Change>,
    stale_factor: u32,
    /// The monotonic clock the slots' read times count from.
    clock: Clock,
}

impl Default for ProcessImage {
    fn default() -> Self {
        Self::new(ImageConfig::default())
    }
}

// === impl ProcessImage ===

impl ProcessImage {
    /// An empty image.
    pub fn new(config: ImageConfig) -> Self {
        let (changes, _) = broadcast::channel(config.notify_capacity.max(1));
        Self {
            inner: Arc::new(Inner {
                units: RwLock::new(HashMap::new()),
                changes,
                stale_factor: config.stale_factor,
                clock: Clock::new(),
            }),
        }
    }

    /// How many poll periods a value stays fresh.
    pub fn stale_factor(&self) -> u32 {
        self.inner.stale_factor
    }

    /// Subscribes to changes (bounded; a lagging receiver is told how many it missed).
    pub fn subscribe(&self) -> broadcast::Receiver<Change> {
        self.inner.changes.subscribe()
    }

    /// Stores registers read from the device with quality `Good`. `period` is the poll period of
    /// the range (`None` for a value that is not polled: it never turns stale).
    pub fn store_words(
        &self,
        unit: u8,
        table: Table,
        start: u16,
        values: &[u16],
        period: Option<Duration>,
    ) {
        self.store(
            unit,
            table,
            start,
            values.iter().copied(),
            Quality::Good,
            period,
        );
    }

    /// Stores bits read from the device with quality `Good` (see [`Self::store_words`]).
    pub fn store_bits(
        &self,
        unit: u8,
        table: Table,
        start: u16,
        values: &[bool],
        period: Option<Duration>,
    ) {
        self.store(
            unit,
            table,
            start,
            values.iter().map(|&b| u16::from(b)),
            Quality::Good,
            period,
        );
    }

    /// Updates registers that are already in the image (after a write through to the device or an
    /// on-demand read), keeping their poll period; addresses not in the image are left out.
    pub fn refresh_words(&self, unit: u8, table: Table, start: u16, values: &[u16]) {
        let values = values.iter().copied();
        self.store_inner(unit, table, start, values, Quality::Good, None, true);
    }

    /// Updates bits that are already in the image (see [`Self::refresh_words`]).
    pub fn refresh_bits(&self, unit: u8, table: Table, start: u16, values: &[bool]) {
        let values = values.iter().map(|&b| u16::from(b));
        self.store_inner(unit, table, start, values, Quality::Good, None, true);
    }

    fn store(
        &self,
        unit: u8,
        table: Table,
        start: u16,
        values: impl Iterator<Item = u16>,
        quality: Quality,
        period: Option<Duration>,
    ) {
        self.store_inner(unit, table, start, values, quality, period, false);
    }

    /// Stores `values` from `start`; with `existing_only`, only addresses already in the image are
    /// updated and keep their freshness limit. Announces each run of consecutive stored addresses
    /// in which something changed.
    #[allow(clippy::too_many_arguments)] // private: the public shapes above fix the flags
    fn store_inner(
        &self,
        unit: u8,
        table: Table,
        start: u16,
        values: impl Iterator<Item = u16>,
        quality: Quality,
        period: Option<Duration>,
        existing_only: bool,
    ) {
        let now = self.inner.clock.ticks(Instant::now());
        // The time as the slots keep it (to the microsecond), so that a change announces the
        // time a snapshot shows afterwards.
        let updated = slot::wall_micros(SystemTime::now());
        let wall = slot::wall_time(updated);
        let max_age =
            slot::max_age_millis(period.map(|p| p.saturating_mul(self.inner.stale_factor)));
        // Stores stop at the last address instead of wrapping.
        let values: Vec<u16> = (start..=u16::MAX).zip(values).map(|(_, v)| v).collect();
        let end = u32::from(start) + u32::try_from(values.len()).unwrap_or(u32::MAX);
        let mut changes: Vec<Change> = Vec::new();
        {
            let mut units = self.write_units();
            if existing_only && !units.contains_key(&unit) {
                return;
            }
            let slots = units.entry(unit).or_default().table_mut(table);
            let old = slots.stored(start, values.len());
            let new: Vec<Option<Slot>> = values
                .iter()
                .zip(&old)
                .map(|(&value, old)| {
                    let max_age = match old {
                        Some(old) if existing_only => old.max_age,
                        None if existing_only => return None,
                        _ => max_age,
                    };
                    Some(Slot {
                        value,
                        quality,
                        updated,
                        at: now,
                        max_age,
                    })
                })
                .collect();
            if existing_only {
                for (address, slot) in slots.stored_mut(start, end) {
                    if let Some(Some(new)) = new.get(usize::from(address - start)) {
                        *slot = *new;
                    }
                }
            } else {
                let new: Vec<Slot> = new.iter().flatten().copied().collect();
                slots.put(start, &new);
            }
            // The run of consecutive stored addresses being built, and whether it changed.
            let mut run: Option<(Change, bool)> = None;
            for ((address, new), old) in (start..=u16::MAX).zip(&new).zip(&old) {
                let Some(new) = new else {
                    changes.extend(run.take().filter(|(_, changed)| *changed).map(|(c, _)| c));
                    continue;
                };
                let value = new.value;
                let changed =
                    old.is_none_or(|o| o.value != value || o.effective_quality(now) != quality);
                match run.as_mut() {
                    Some((c, run_changed)) => {
                        c.values.push(value);
                        *run_changed |= changed;
                    }
                    None => {
                        let c = Change {
                            unit,
                            table,
                            start: address,
                            values: vec![value],
                            quality,
                            time: wall,
                        };
                        run = Some((c, changed));
                    }
                }
            }
            changes.extend(run.filter(|(_, changed)| *changed).map(|(c, _)| c));
        }
        for change in changes {
            self.announce(change);
        }
    }

    /// Sets the quality of the stored values in a range (values and times unchanged); addresses
    /// never stored are skipped.
    pub fn set_quality(&self, unit: u8, table: Table, start: u16, count: u16, quality: Quality) {
        let end = u32::from(start) + u32::from(count);
        let Some(last) = end.checked_sub(1).and_then(|e| u16::try_from(e).ok()) else {
            return;
        };
        if count == 0 {
            return;
        }
        self.set_quality_where(unit, quality, |t, a| {
            t == table && (start..=last).contains(&a)
        });
    }

    /// Sets the quality of every stored value of a unit (a device gone offline).
    pub fn set_unit_quality(&self, unit: u8, quality: Quality) {
        self.set_quality_where(unit, quality, |_, _| true);
    }

    fn set_quality_where(&self, unit: u8, quality: Quality, select: impl Fn(Table, u16) -> bool) {
        let now = self.inner.clock.ticks(Instant::now());
        let wall = SystemTime::now();
        let mut changes = Vec::new();
        {
            let mut units = self.write_units();
            let Some(image) = units.get_mut(&unit) else {
                return;
            };
            for table in Table::ALL {
                // Collect runs of consecutive changed addresses into one change each.
                let mut run: Option<Change> = None;
                for (address, slot) in image.table_mut(table).iter_mut() {
                    if !select(table, address) || slot.effective_quality(now) == quality {
                        continue;
                    }
                    slot.quality = quality;
                    match run.as_mut() {
                        Some(c)
                            if usize::from(address) == usize::from(c.start) + c.values.len() =>
                        {
                            c.values.push(slot.value);
                        }
                        _ => {
                            changes.extend(run.take());
                            run = Some(Change {
                                unit,
                                table,
                                start: address,
                                values: vec![slot.value],
                                quality,
                                time: wall,
                            });
                        }
                    }
                }
                changes.extend(run);
            }
        }
        for change in changes {
            self.announce(change);
        }
    }

    fn announce(&self, change: Change) {
        // An error only means that nobody subscribes right now: there is no one to lose it.
        let _ = self.inner.changes.send(change);
    }

    /// Every stored value of one table of a unit, in address order (for REST and diagnostics).
    pub fn snapshot(&self, unit: u8, table: Table) -> Vec<SlotView> {
        let now = self.inner.clock.ticks(Instant::now());
        let units = self.read_units();
        units.get(&unit).map_or_else(Vec::new, |image| {
            image
                .table(table)
                .iter()
                .map(|(address, slot)| SlotView {
                    address,
                    value: slot.value,
                    quality: slot.effective_quality(now),
                    updated: slot.updated(),
                })
                .collect()
        })
    }

    /// When the oldest polled value of `unit` was read (values stored with a poll period; those
    /// written on demand only are left out); `None` when the unit has no polled value.
    pub fn oldest_polled(&self, unit: u8) -> Option<Instant> {
        let units = self.read_units();
        let image = units.get(&unit)?;
        Table::ALL
            .into_iter()
            .flat_map(|table| image.table(table).iter())
            .filter(|(_, slot)| slot.polled())
            .map(|(_, slot)| slot.at)
            .min()
            .map(|at| self.inner.clock.instant(at))
    }

    /// The units under the read lock. A poisoned lock is taken as it is: a writer that panicked
    /// leaves whole slot values, at worst some of a range newer than the rest.
    fn read_units(&self) -> RwLockReadGuard<'_, HashMap<u8, UnitImage>> {
        self.inner
            .units
            .read()
            .unwrap_or_else(PoisonError::into_inner)
    }

    /// The units under the write lock (poisoning as for [`Self::read_units`]).
    fn write_units(&self) -> RwLockWriteGuard<'_, HashMap<u8, UnitImage>> {
        self.inner
            .units
            .write()
            .unwrap_or_else(PoisonError::into_inner)
    }

    /// The unit ids with values in the image, sorted.
    pub fn units(&self) -> Vec<u8> {
        let units = self.read_units();
        let mut ids: Vec<u8> = units.keys().copied().collect();
        ids.sort_unstable();
        ids
    }
}

#[cfg(test)]
mod tests;
