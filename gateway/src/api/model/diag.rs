//! A line's diagnostic buffer (003 7.3): newest first, each entry with the catalog's texts.

use std::time::{Duration, SystemTime};

use proto_core::event::{DiagEntry, EventId};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::{EventView, Timestamp};

/// One entry as the backend keeps it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DiagRecord {
    pub id: EventId,
    /// When it occurred.
    pub at: SystemTime,
    /// The first occurrence the entry stands for (`at` for a single event).
    pub first_at: SystemTime,
    /// Occurrences the entry stands for: 1, since the buffer keeps every event as an entry of
    /// its own (003 7.3).
    pub count: u32,
}

// === impl DiagRecord ===

impl DiagRecord {
    /// A buffer entry whose instants count microseconds from `origin` (the line's start).
    pub fn from_entry(entry: &DiagEntry, origin: SystemTime) -> Self {
        let wall = |i: proto_core::time::Instant| origin + Duration::from_micros(i.as_micros());
        Self {
            id: entry.id,
            at: wall(entry.at),
            first_at: wall(entry.first_at),
            count: entry.count,
        }
    }
}

/// A line's diagnostic buffer (`GET /api/v1/lines/{line}/diag`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct DiagView {
    pub line: String,
    /// Entries kept at most (`[gateway] diag_buffer_depth`, the CP keeps 9).
    pub depth: usize,
    /// Newest first.
    pub entries: Vec<DiagEntryView>,
}

/// One entry of the diagnostic buffer.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct DiagEntryView {
    /// When it occurred.
    pub time: Timestamp,
    /// The first occurrence the entry stands for (`time`: every event is an entry of its own,
    /// repeats included, as on the CP).
    pub first_time: Timestamp,
    /// How many occurrences the entry stands for (1).
    pub count: u32,
    /// Class, number, STATUS word, class name, description and remedy from the catalog.
    #[serde(flatten)]
    pub event: EventView,
}

impl From<&DiagRecord> for DiagEntryView {
    fn from(r: &DiagRecord) -> Self {
        Self {
            time: Timestamp(r.at),
            first_time: Timestamp(r.first_at),
            count: r.count,
            event: EventView::new(r.id),
        }
    }
}

/// What the backend returns for a line's buffer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DiagSnapshot {
    pub depth: usize,
    /// Newest first.
    pub entries: Vec<DiagRecord>,
}

// === impl DiagView ===

impl DiagView {
    pub fn new(line: &str, snapshot: &DiagSnapshot) -> Self {
        Self {
            line: line.to_owned(),
            depth: snapshot.depth,
            entries: snapshot.entries.iter().map(DiagEntryView::from).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use proto_core::time::Instant;

    use super::*;

    #[test]
    fn entries_get_wall_clock_times_and_catalog_texts() {
        let origin = SystemTime::UNIX_EPOCH + Duration::from_secs(1_000);
        let mut entry = DiagEntry::new(EventId::new(0x08, 0x30), Instant::from_millis(1_500));
        entry.at = Instant::from_millis(2_500);
        entry.count = 3;
        let record = DiagRecord::from_entry(&entry, origin);
        assert_eq!(record.first_at, origin + Duration::from_millis(1_500));
        let view = DiagView::new(
            "drive",
            &DiagSnapshot {
                depth: 9,
                entries: vec![record],
            },
        );
        let json = serde_json::to_value(&view).unwrap();
        let e = &json["entries"][0];
        assert_eq!(e["time"], "1970-01-01T00:16:42.500Z");
        assert_eq!(e["first_time"], "1970-01-01T00:16:41.500Z");
        assert_eq!(e["count"], 3);
        assert_eq!(e["class"], 8);
        assert_eq!(e["number"], 0x30);
        assert_eq!(e["code"], "0830");
        assert_eq!(e["class_name"], "receive error");
        assert!(e["remedy"].as_str().is_some_and(|r| !r.is_empty()));
    }
}
