//! The stored values of one table of one unit, as runs of consecutive addresses.
//!
//! A polled range is stored and read as a whole, so the slots of consecutive addresses live in
//! one vector: a range read is one map lookup and a walk over a slice, and a poll that stores the
//! range again overwrites it in place. Runs are maximal: no two overlap or touch (a store that
//! would make them touch merges them), so the address just past a run is never stored and a
//! range read that leaves its run has found the first missing address.
//!
//! A run also knows when all its slots were stored at once with one quality and freshness limit
//! (a poll of the whole run): then the quality of any range in it is the quality of one slot.

use std::collections::BTreeMap;

use super::Slot;

/// The runs of one table, keyed by their first address. No run is empty.
#[derive(Debug, Default)]
pub(super) struct Runs {
    runs: BTreeMap<u16, Run>,
}

/// Consecutive stored slots.
#[derive(Debug)]
struct Run {
    slots: Vec<Slot>,
    /// Every slot has the quality, times and freshness limit of the first (only the values
    /// differ). `false` is always safe: it only means "look at each slot".
    uniform: bool,
}

/// A stored range: its slots, and whether they share one quality, time and freshness limit.
#[derive(Clone, Copy, Debug)]
pub(super) struct Stored<'a> {
    pub(super) slots: &'a [Slot],
    pub(super) uniform: bool,
}

/// Whether two slots were stored together: same quality, times and freshness limit.
fn same_stamp(a: &Slot, b: &Slot) -> bool {
    a.quality == b.quality && a.at == b.at && a.updated == b.updated && a.max_age == b.max_age
}

/// One past the last address of a run starting at `first` with `len` slots.
fn run_end(first: u16, len: usize) -> u32 {
    u32::from(first) + u32::try_from(len).unwrap_or(u32::MAX)
}

// === impl Runs ===

impl Runs {
    /// The run holding `address`: its first address and the run.
    fn run_at(&self, address: u16) -> Option<(u16, &Run)> {
        let (&first, run) = self.runs.range(..=address).next_back()?;
        (u32::from(address) < run_end(first, run.slots.len())).then_some((first, run))
    }

    /// The slot of `address`, if stored.
    #[cfg(test)]
    fn get(&self, address: u16) -> Option<&Slot> {
        let (first, run) = self.run_at(address)?;
        run.slots.get(usize::from(address - first))
    }

    /// The slots of `count` addresses from `start` when every one is stored, else the first
    /// address of the range that is not (as `u32`: it may be 65536 for a range past the end).
    pub(super) fn range(&self, start: u16, count: u16) -> Result<Stored<'_>, u32> {
        let Some((first, run)) = self.run_at(start) else {
            return Err(u32::from(start));
        };
        let from = run
            .slots
            .get(usize::from(start - first)..)
            .unwrap_or_default();
        let slots = from
            .get(..usize::from(count))
            .ok_or_else(|| run_end(first, run.slots.len()))?;
        Ok(Stored {
            slots,
            uniform: run.uniform,
        })
    }

    /// Every stored slot, in address order.
    pub(super) fn iter(&self) -> impl Iterator<Item = (u16, &Slot)> + '_ {
        self.runs
            .iter()
            .flat_map(|(&first, run)| (first..=u16::MAX).zip(run.slots.iter()))
    }

    /// Every stored slot, in address order, to change.
    pub(super) fn iter_mut(&mut self) -> impl Iterator<Item = (u16, &mut Slot)> + '_ {
        self.runs.iter_mut().flat_map(|(&first, run)| {
            run.uniform = false;
            (first..=u16::MAX).zip(run.slots.iter_mut())
        })
    }

    /// The first address of the run holding `start`, or `start` when none does: where the runs
    /// that share addresses with a range from `start` begin.
    fn first_key_from(&self, start: u16) -> u16 {
        self.run_at(start).map_or(start, |(first, _)| first)
    }

    /// The part of the run `first`, `len` inside `start..end`: offsets into the run.
    fn overlap(first: u16, len: usize, start: u16, end: u32) -> std::ops::Range<usize> {
        let lo = usize::from(start.saturating_sub(first)).min(len);
        let hi = usize::try_from(end.saturating_sub(u32::from(first)))
            .unwrap_or(usize::MAX)
            .min(len);
        lo..hi.max(lo)
    }

    /// The stored slots of the addresses `start..end`, in address order, to change.
    pub(super) fn stored_mut(
        &mut self,
        start: u16,
        end: u32,
    ) -> impl Iterator<Item = (u16, &mut Slot)> + '_ {
        let from = self.first_key_from(start);
        self.runs
            .range_mut(from..)
            .take_while(move |(&first, _)| u32::from(first) < end)
            .flat_map(move |(&first, run)| {
                run.uniform = false;
                let part = Self::overlap(first, run.slots.len(), start, end);
                // `first + part.start` <= 65535: the run ends at 65536 at the latest.
                let address = first.saturating_add(u16::try_from(part.start).unwrap_or(u16::MAX));
                (address..=u16::MAX).zip(run.slots.get_mut(part).unwrap_or_default())
            })
    }

    /// What is stored at each of `len` addresses from `start` (`None`: nothing).
    pub(super) fn stored(&self, start: u16, len: usize) -> Vec<Option<Slot>> {
        let mut out = vec![None; len];
        let end = run_end(start, len);
        let from = self.first_key_from(start);
        for (&first, run) in self
            .runs
            .range(from..)
            .take_while(|(&first, _)| u32::from(first) < end)
        {
            let slots = &run.slots;
            let part = Self::overlap(first, slots.len(), start, end);
            // Offset of the part in `out`: its address minus `start`.
            let at = (usize::from(first) + part.start).saturating_sub(usize::from(start));
            let part = slots.get(part).unwrap_or_default();
            let dst = out.get_mut(at..).unwrap_or_default();
            for (entry, slot) in dst.iter_mut().zip(part) {
                *entry = Some(*slot);
            }
        }
        out
    }

    /// Stores `slots` at consecutive addresses from `start` (at most up to 65535), replacing what
    /// was there and merging the runs the range overlaps or touches into one.
    pub(super) fn put(&mut self, start: u16, slots: &[Slot]) {
        let len = slots.len().min(usize::from(u16::MAX - start) + 1);
        let Some(slots) = slots.get(..len).filter(|s| !s.is_empty()) else {
            return;
        };
        let end = run_end(start, len);
        let uniform = slots.windows(2).all(|pair| match pair {
            [a, b] => same_stamp(a, b),
            _ => true,
        });
        // A poll storing its range again: overwrite in place.
        if let Some((&first, run)) = self.runs.range_mut(..=start).next_back() {
            let whole = first == start && run.slots.len() == len;
            let dst = run
                .slots
                .get_mut(usize::from(start - first)..)
                .and_then(|rest| rest.get_mut(..len));
            if let Some(dst) = dst {
                dst.copy_from_slice(slots);
                // A store of part of the run leaves it mixed (until the whole is stored again).
                run.uniform = whole && uniform;
                return;
            }
        }
        // The runs to merge: those overlapping or touching start..end. Runs are sorted and apart,
        // so only the first can begin before `start` and only the last can reach past `end`.
        let last_key = u16::try_from(end).unwrap_or(u16::MAX);
        let keys: Vec<u16> = self
            .runs
            .range(..=last_key)
            .rev()
            .take_while(|(&first, run)| run_end(first, run.slots.len()) >= u32::from(start))
            .map(|(&first, _)| first)
            .collect();
        let mut old: Vec<(u16, Run)> = keys
            .iter()
            .rev()
            .filter_map(|key| self.runs.remove(key).map(|run| (*key, run)))
            .collect();
        let head = old.first().filter(|(first, _)| *first < start);
        let merged_first = head.map_or(start, |(first, _)| *first);
        let mut merged = Vec::new();
        if let Some((first, run)) = head {
            let before = usize::from(start - first);
            merged.extend_from_slice(run.slots.get(..before).unwrap_or(&run.slots));
        }
        merged.extend_from_slice(slots);
        if let Some((first, run)) = old.pop() {
            // Slots of the last run past `end`, if it reaches that far.
            let skip = usize::try_from(end.saturating_sub(u32::from(first))).unwrap_or(usize::MAX);
            merged.extend_from_slice(run.slots.get(skip..).unwrap_or_default());
        }
        merged.shrink_to_fit();
        let uniform = uniform && merged.len() == len;
        self.runs.insert(
            merged_first,
            Run {
                slots: merged,
                uniform,
            },
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::slot::NEVER_STALE;
    use crate::image::Quality;

    /// Slots stored together: one quality, one time.
    fn slots(values: impl IntoIterator<Item = u16>) -> Vec<Slot> {
        values
            .into_iter()
            .map(|value| Slot {
                value,
                quality: Quality::Good,
                updated: 0,
                at: 0,
                max_age: NEVER_STALE,
            })
            .collect()
    }

    fn values(runs: &Runs) -> Vec<(u16, u16)> {
        runs.iter().map(|(a, s)| (a, s.value)).collect()
    }

    fn shape(runs: &Runs) -> Vec<(u16, usize)> {
        runs.runs.iter().map(|(&f, r)| (f, r.slots.len())).collect()
    }

    #[test]
    fn touching_and_overlapping_stores_merge_into_one_run() {
        let mut runs = Runs::default();
        runs.put(10, &slots([10, 11]));
        runs.put(20, &slots([20]));
        assert_eq!(shape(&runs), [(10, 2), (20, 1)]);
        // Touches the first run, leaves a gap before the second.
        runs.put(12, &slots([12, 13]));
        assert_eq!(shape(&runs), [(10, 4), (20, 1)]);
        // Fills the gap: one run from 10 to 20.
        runs.put(14, &slots(14..20));
        assert_eq!(shape(&runs), [(10, 11)]);
        // Overlaps the end and reaches past it.
        runs.put(19, &slots([119, 120, 121]));
        assert_eq!(shape(&runs), [(10, 12)]);
        // Covers everything and more on both sides.
        runs.put(5, &slots(105..130));
        assert_eq!(shape(&runs), [(5, 25)]);
        assert_eq!(runs.get(5).map(|s| s.value), Some(105));
        assert_eq!(runs.get(29).map(|s| s.value), Some(129));
        assert!(runs.get(30).is_none());
        assert!(runs.get(4).is_none());
    }

    #[test]
    fn a_store_inside_a_run_overwrites_in_place() {
        let mut runs = Runs::default();
        runs.put(0, &slots(0..10));
        runs.put(3, &slots([33, 44]));
        assert_eq!(shape(&runs), [(0, 10)]);
        assert_eq!(
            values(&runs),
            [0, 1, 2, 33, 44, 5, 6, 7, 8, 9]
                .iter()
                .enumerate()
                .map(|(a, &v)| (a as u16, v))
                .collect::<Vec<_>>()
        );
    }

    #[test]
    fn a_run_is_uniform_only_while_stored_whole_at_once() {
        let uniform = |runs: &Runs, at| runs.range(at, 1).map(|s| s.uniform);
        let mut runs = Runs::default();
        runs.put(0, &slots(0..10));
        assert_eq!(uniform(&runs, 0), Ok(true));
        runs.put(2, &slots([1]));
        assert_eq!(uniform(&runs, 0), Ok(false), "part stored later");
        runs.put(0, &slots(0..10));
        assert_eq!(uniform(&runs, 0), Ok(true), "whole stored again");
        runs.put(10, &slots([10]));
        assert_eq!(uniform(&runs, 0), Ok(false), "merged with a later store");
        runs.put(0, &slots(0..11));
        assert_eq!(uniform(&runs, 10), Ok(true));
        for (_, slot) in runs.stored_mut(3, 4) {
            slot.value = 0;
        }
        assert_eq!(uniform(&runs, 10), Ok(false), "changed in place");
        let mut mixed = slots(20..25);
        mixed[3].quality = Quality::Rejected;
        runs.put(20, &mixed);
        assert_eq!(uniform(&runs, 20), Ok(false), "stored with two qualities");
        runs.put(20, &slots(20..25));
        assert_eq!(uniform(&runs, 20), Ok(true));
        runs.iter_mut()
            .for_each(|(_, slot)| slot.quality = Quality::Stale);
        assert_eq!(uniform(&runs, 20), Ok(false));
    }

    #[test]
    fn a_range_read_names_the_first_missing_address() {
        let mut runs = Runs::default();
        runs.put(0, &slots([1, 2]));
        runs.put(3, &slots([4]));
        let len = |r: Result<Stored<'_>, u32>| r.map(|s| s.slots.len());
        assert_eq!(len(runs.range(0, 4)), Err(2));
        assert_eq!(len(runs.range(2, 1)), Err(2));
        assert_eq!(len(runs.range(3, 2)), Err(4));
        assert_eq!(runs.range(1, 1).map(|s| s.slots[0].value), Ok(2));
        runs.put(u16::MAX, &slots([7, 8]));
        assert_eq!(shape(&runs), [(0, 2), (3, 1), (u16::MAX, 1)]);
        assert_eq!(len(runs.range(u16::MAX, 2)), Err(65536));
    }

    #[test]
    fn stored_lists_what_is_there_and_stored_mut_touches_only_it() {
        let mut runs = Runs::default();
        runs.put(2, &slots([2, 3]));
        runs.put(6, &slots([6]));
        let seen: Vec<Option<u16>> = runs
            .stored(1, 7)
            .iter()
            .map(|s| s.map(|s| s.value))
            .collect();
        assert_eq!(seen, [None, Some(2), Some(3), None, None, Some(6), None]);
        for (address, slot) in runs.stored_mut(3, 7) {
            slot.value = address + 100;
        }
        assert_eq!(values(&runs), [(2, 2), (3, 103), (6, 106)]);
    }
}
