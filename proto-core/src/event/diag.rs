//! The diagnostic buffer of a line (manual 003 7.3; 000 7.3 says the same).
//!
//! What the manual says:
//! - "The CP has its own diagnostic buffer. There all the diagnostic events of the CP are entered
//!   in the order in which they occur."
//! - "The diagnostic buffer is a ring buffer for a maximum of 9 diagnostic entries. When the
//!   diagnostic buffer is full, the oldest entry is deleted when a new entry is recorded. This means
//!   that the most recent entry is always the first."
//! - "The contents of the diagnostic buffer are lost in the event of a PowerOFF or when the CP is
//!   re-parameterized" ([`DiagBuffer::clear`]).
//! - Class 03h "Error parameterization of FBs" is "not displayed in diagnostic buffer" (7.2), so
//!   [`DiagBuffer::push`] does not record it.
//!
//! As on the CP, every event gets its own entry, repeats included: a burst of nine identical
//! errors (a CRC storm on a noisy line) pushes every older entry out. The caller's event counters
//! count every occurrence over the line's life; the buffer shows the last N in order.
//! [`DiagEntry::count`] and [`DiagEntry::first_at`] describe one entry: an entry recorded by
//! [`DiagBuffer::push`] stands for the occurrences it was built with (one, for
//! [`DiagEntry::new`]).

use std::collections::VecDeque;

use super::EventId;
use crate::time::Instant;

/// The CP's buffer depth (003 7.3: "a ring buffer for a maximum of 9 diagnostic entries").
pub const DEFAULT_DEPTH: usize = 9;

/// The class the manual keeps out of the diagnostic buffer (7.2, class 03h heading).
const CLASS_NOT_BUFFERED: u8 = 0x03;

/// One entry of the diagnostic buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DiagEntry {
    /// The event.
    pub id: EventId,
    /// When the event occurred last (the time of the entry for a single occurrence).
    pub at: Instant,
    /// When the first of the merged consecutive occurrences happened.
    pub first_at: Instant,
    /// How many consecutive occurrences this entry stands for (at least 1, saturating).
    pub count: u32,
}

// === impl DiagEntry ===

impl DiagEntry {
    /// A single occurrence of `id` at `at`.
    pub const fn new(id: EventId, at: Instant) -> Self {
        Self {
            id,
            at,
            first_at: at,
            count: 1,
        }
    }
}

/// The newest-first ring buffer of diagnostic entries of one line.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DiagBuffer {
    /// Newest entry at the front; never longer than `depth`.
    entries: VecDeque<DiagEntry>,
    /// The maximum number of entries, at least 1.
    depth: usize,
}

// === impl DiagBuffer ===

impl DiagBuffer {
    /// An empty buffer that keeps at most `depth` entries; a depth of 0 is taken as 1, because a
    /// buffer that keeps nothing would lose every event silently.
    pub fn new(depth: usize) -> Self {
        Self {
            entries: VecDeque::new(),
            depth: depth.max(1),
        }
    }

    /// The maximum number of entries.
    pub fn depth(&self) -> usize {
        self.depth
    }

    /// Records an entry as the newest one and returns whether it was recorded.
    ///
    /// Class 03h events are not recorded (7.2). Every other entry is kept as an entry of its own,
    /// a repeat of the newest one too; when the buffer is full, the oldest entry is deleted (7.3).
    /// An entry with `count` 0 counts as one occurrence.
    pub fn push(&mut self, entry: DiagEntry) -> bool {
        if entry.id.class == CLASS_NOT_BUFFERED {
            return false;
        }
        let count = entry.count.max(1);
        self.entries.truncate(self.depth - 1);
        self.entries.push_front(DiagEntry { count, ..entry });
        true
    }

    /// The entries, newest first.
    pub fn iter(&self) -> std::collections::vec_deque::Iter<'_, DiagEntry> {
        self.entries.iter()
    }

    /// The newest entry.
    pub fn newest(&self) -> Option<&DiagEntry> {
        self.entries.front()
    }

    /// The number of entries.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether the buffer holds no entry.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Deletes every entry (7.3: power off or re-parameterization).
    pub fn clear(&mut self) {
        self.entries.clear();
    }
}

impl Default for DiagBuffer {
    /// A buffer of the CP's depth ([`DEFAULT_DEPTH`]).
    fn default() -> Self {
        Self::new(DEFAULT_DEPTH)
    }
}

impl<'a> IntoIterator for &'a DiagBuffer {
    type Item = &'a DiagEntry;
    type IntoIter = std::collections::vec_deque::Iter<'a, DiagEntry>;

    fn into_iter(self) -> Self::IntoIter {
        self.iter()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::event::ids;

    #[test]
    fn keeps_every_entry_newest_first_repeats_included() {
        let mut buf = DiagBuffer::new(3);
        assert!(buf.push(DiagEntry::new(
            ids::MODBUS_NO_REPLY,
            Instant::from_millis(1)
        )));
        assert!(buf.push(DiagEntry::new(
            ids::MODBUS_NO_REPLY,
            Instant::from_millis(2)
        )));
        assert!(buf.push(DiagEntry::new(
            ids::CHARACTER_ERROR,
            Instant::from_millis(3)
        )));
        assert!(buf.push(DiagEntry::new(
            ids::MODBUS_NO_REPLY,
            Instant::from_millis(4)
        )));
        let got: Vec<_> = buf
            .iter()
            .map(|e| (e.id, e.count, e.first_at.as_micros(), e.at.as_micros()))
            .collect();
        // 003 7.3: a ring of three, newest first; the repeat at 2 ms is an entry of its own and
        // the first entry (1 ms) was deleted for the fourth.
        assert_eq!(
            got,
            vec![
                (ids::MODBUS_NO_REPLY, 1, 4000, 4000),
                (ids::CHARACTER_ERROR, 1, 3000, 3000),
                (ids::MODBUS_NO_REPLY, 1, 2000, 2000),
            ]
        );
    }

    #[test]
    fn class_03_not_buffered_and_zero_depth_is_one() {
        let mut buf = DiagBuffer::new(0);
        assert_eq!(buf.depth(), 1);
        assert!(!buf.push(DiagEntry::new(ids::INVALID_FB_PARAMETERS, Instant::ZERO)));
        assert!(buf.is_empty());
        buf.push(DiagEntry::new(ids::BCC_ERROR, Instant::ZERO));
        buf.push(DiagEntry::new(ids::LINE_BREAK, Instant::ZERO));
        assert_eq!(buf.len(), 1);
        assert_eq!(buf.newest().map(|e| e.id), Some(ids::LINE_BREAK));
    }
}
