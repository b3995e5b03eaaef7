//! Range reads of the process image: values with their worst quality and oldest time, or a read
//! response encoded straight into a buffer (the Modbus TCP server's cached reads).

use std::collections::HashMap;

use tokio::time::Instant;

use super::runs::Stored;
use super::{ImageError, ProcessImage, Quality, RangeRead, Slot, Table, UnitImage};

/// Staleness of many slots against one `now`: the check `now - at > max_age` as `at < now -
/// max_age`, the threshold computed once for each freshness limit in a row (the slots of a polled
/// range share theirs). Times are ticks of the image's clock.
struct StaleCheck {
    now: u64,
    /// The last freshness limit seen and `now` minus it (`None`: before the clock's origin, so
    /// nothing is that old).
    last: Option<(u64, Option<u64>)>,
}

impl StaleCheck {
    fn new(now: u64) -> Self {
        Self { now, last: None }
    }

    /// The quality of `slot` now: [`Slot::effective_quality`].
    fn quality(&mut self, slot: &Slot) -> Quality {
        match slot.max_age_nanos() {
            Some(max) if slot.quality == Quality::Good => {
                let threshold = match self.last {
                    Some((last, threshold)) if last == max => threshold,
                    _ => {
                        let threshold = self.now.checked_sub(max);
                        self.last = Some((max, threshold));
                        threshold
                    }
                };
                if threshold.is_some_and(|t| slot.at < t) {
                    Quality::Stale
                } else {
                    Quality::Good
                }
            }
            _ => slot.quality,
        }
    }
}

/// The worst quality of a stored range at `now`, staleness included.
fn worst_quality(stored: Stored<'_>, now: u64) -> Quality {
    let mut stale = StaleCheck::new(now);
    match stored.slots.first() {
        // Stored together (the usual poll of a whole range): one slot speaks for all.
        Some(first) if stored.uniform => stale.quality(first),
        _ => stored.slots.iter().fold(Quality::Good, |worst, slot| {
            worst.worst(stale.quality(slot))
        }),
    }
}

// === impl ProcessImage ===

impl ProcessImage {
    /// Reads a range of registers: all values, the worst quality and the oldest time.
    pub fn read_words(
        &self,
        unit: u8,
        table: Table,
        start: u16,
        count: u16,
    ) -> Result<RangeRead<u16>, ImageError> {
        self.read(unit, table, start, count, |v| v)
    }

    /// Reads a range of bits (see [`Self::read_words`]).
    pub fn read_bits(
        &self,
        unit: u8,
        table: Table,
        start: u16,
        count: u16,
    ) -> Result<RangeRead<bool>, ImageError> {
        self.read(unit, table, start, count, |v| v != 0)
    }

    fn read<T>(
        &self,
        unit: u8,
        table: Table,
        start: u16,
        count: u16,
        convert: impl Fn(u16) -> T,
    ) -> Result<RangeRead<T>, ImageError> {
        check_range(start, count)?;
        let now = self.inner.clock.ticks(Instant::now());
        let units = self.read_units();
        let stored = range(&units, unit, table, start, count)?;
        let values = stored
            .slots
            .iter()
            .map(|slot| convert(slot.value))
            .collect();
        let mut oldest: Option<&Slot> = None;
        for slot in stored.slots {
            if oldest.is_none_or(|o| slot.at < o.at) {
                oldest = Some(slot);
            }
            if stored.uniform {
                break;
            }
        }
        let oldest = oldest.ok_or(ImageError::InvalidRange { start, count })?;
        Ok(RangeRead {
            values,
            quality: worst_quality(stored, now),
            oldest: oldest.updated(),
            oldest_at: self.inner.clock.instant(oldest.at),
        })
    }

    /// Appends the data of a read response (FC 01 to 04) for `count` values of `table` from
    /// `start` to `out`: the byte count, then the registers big-endian, or the bits eight to a
    /// byte with the first address in the lowest bit (Modbus Application Protocol V1.1b3, 6.1 to
    /// 6.4). Returns the worst quality of the range, staleness included; appends nothing on an
    /// error. A range whose byte count would not fit its byte (more than 127 registers or 2040
    /// bits) is an [`ImageError::InvalidRange`].
    pub fn encode_read(
        &self,
        unit: u8,
        table: Table,
        start: u16,
        count: u16,
        out: &mut Vec<u8>,
    ) -> Result<Quality, ImageError> {
        check_range(start, count)?;
        let bytes = if table.is_bits() {
            usize::from(count).div_ceil(8)
        } else {
            usize::from(count) * 2
        };
        let byte_count =
            u8::try_from(bytes).map_err(|_| ImageError::InvalidRange { start, count })?;
        let now = self.inner.clock.ticks(Instant::now());
        let units = self.read_units();
        let stored = range(&units, unit, table, start, count)?;
        let slots = stored.slots;
        let at = out.len();
        out.resize(at + 1 + bytes, 0);
        let Some((count_byte, data)) = out.get_mut(at..).and_then(<[u8]>::split_first_mut) else {
            return Err(ImageError::InvalidRange { start, count });
        };
        *count_byte = byte_count;
        if table.is_bits() {
            for (byte, eight) in data.iter_mut().zip(slots.chunks(8)) {
                *byte = eight.iter().enumerate().fold(0u8, |byte, (bit, slot)| {
                    byte | u8::from(slot.value != 0) << bit
                });
            }
        } else {
            for (pair, slot) in data.chunks_exact_mut(2).zip(slots) {
                pair.copy_from_slice(&slot.value.to_be_bytes());
            }
        }
        Ok(worst_quality(stored, now))
    }
}

/// Checks a range for a read: 1 to 65536 - `start` addresses.
fn check_range(start: u16, count: u16) -> Result<(), ImageError> {
    let end = u32::from(start) + u32::from(count);
    if count == 0 || end > 0x1_0000 {
        return Err(ImageError::InvalidRange { start, count });
    }
    Ok(())
}

/// The slots of a checked range, or why there are none.
fn range<'a>(
    units: &'a HashMap<u8, UnitImage>,
    unit: u8,
    table: Table,
    start: u16,
    count: u16,
) -> Result<Stored<'a>, ImageError> {
    units
        .get(&unit)
        .ok_or(ImageError::UnknownUnit(unit))?
        .table(table)
        .range(start, count)
        .map_err(|missing| ImageError::Missing {
            unit,
            table,
            // Below 65536: the range was checked to end within the address space.
            address: u16::try_from(missing).unwrap_or(u16::MAX),
        })
}
