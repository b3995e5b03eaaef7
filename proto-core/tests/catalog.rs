//! The CP 341 event catalog against the manual's tables (003 7.2, 000 7.2) and the diagnostic
//! buffer against 7.3.

use std::collections::{BTreeMap, HashSet};

use proptest::prelude::*;
use proto_core::event::{self, ids, DiagBuffer, DiagEntry, EventId, Status, DEFAULT_DEPTH};
use proto_core::time::Instant;

/// Events per class as counted in the tables of 003 7.2 (000 7.2 lists the same ids).
const EXPECTED_PER_CLASS: &[(u8, usize)] = &[
    (0x00, 4),
    (0x01, 4),
    (0x02, 1),
    (0x03, 1),
    (0x04, 5),
    (0x05, 5),
    (0x07, 9),
    (0x08, 16),
    (0x0E, 31),
    (0x1E, 4),
];

/// The ids of the manual's tables, class by class (003 7.2).
const MANUAL_IDS: &[(u8, &[u8])] = &[
    (0x00, &[0x03, 0x04, 0x07, 0x08]),
    (0x01, &[0x01, 0x02, 0x03, 0x10]),
    (0x02, &[0x0F]),
    (0x03, &[0x01]),
    (0x04, &[0x03, 0x07, 0x08, 0x09, 0x0A]),
    (0x05, &[0x01, 0x02, 0x14, 0x17, 0x18]),
    (
        0x07,
        &[0x01, 0x02, 0x03, 0x04, 0x06, 0x07, 0x08, 0x09, 0x0A],
    ),
    (
        0x08,
        &[
            0x01, 0x02, 0x05, 0x06, 0x08, 0x0A, 0x0C, 0x0D, 0x15, 0x16, 0x18, 0x30, 0x31, 0x32,
            0x33, 0x34,
        ],
    ),
    (
        0x0E,
        &[
            0x31, 0x38, 0x39, 0x40, 0x41, 0x42, 0x43, 0x44, 0x45, 0x46, 0x47, 0x48, 0x49, 0x4A,
            0x4F, 0x50, 0x51, 0x52, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x61, 0x62, 0x63, 0x64,
            0x65, 0x66, 0x67,
        ],
    ),
    (0x1E, &[0x0D, 0x0E, 0x0F, 0x41]),
];

#[test]
fn every_entry_has_description_and_class_name() {
    assert_eq!(event::all().len(), 80);
    for info in event::all() {
        assert!(
            !info.description.trim().is_empty(),
            "{} has no description",
            info.id
        );
        let name = event::class_name(info.id.class)
            .unwrap_or_else(|| panic!("{} has no class name", info.id));
        assert!(!name.is_empty());
        assert_eq!(name, name.to_lowercase(), "class names are lower case");
        assert_eq!(event::lookup(info.id), Some(info));
        assert_eq!(EventId::from_status_word(info.id.status_word()), info.id);
    }
}

#[test]
fn ids_are_unique() {
    let mut seen = HashSet::new();
    for info in event::all() {
        assert!(seen.insert(info.id), "{} listed twice", info.id);
    }
    let mut texts = HashSet::new();
    for info in event::all() {
        assert!(
            texts.insert(info.description),
            "{} repeats another description",
            info.id
        );
    }
}

#[test]
fn counts_per_class_match_the_manual() {
    let mut counts = BTreeMap::new();
    for info in event::all() {
        *counts.entry(info.id.class).or_insert(0usize) += 1;
    }
    let expected: BTreeMap<u8, usize> = EXPECTED_PER_CLASS.iter().copied().collect();
    assert_eq!(counts, expected);
    let classes: Vec<u8> = event::classes().iter().map(|(c, _)| *c).collect();
    assert_eq!(classes, expected.keys().copied().collect::<Vec<_>>());
}

#[test]
fn catalog_is_exactly_the_manual_list() {
    let manual: Vec<EventId> = MANUAL_IDS
        .iter()
        .flat_map(|(class, numbers)| numbers.iter().map(move |n| EventId::new(*class, *n)))
        .collect();
    let ours: Vec<EventId> = event::all().iter().map(|info| info.id).collect();
    assert_eq!(ours, manual);
    assert_eq!(event::lookup(EventId::new(0x08, 0x03)), None);
    assert_eq!(event::lookup(EventId::new(0x06, 0x01)), None);
}

#[test]
fn class_names_used_as_labels() {
    assert_eq!(event::class_name(0x00), Some("cp start-up"));
    assert_eq!(event::class_name(0x07), Some("send error"));
    assert_eq!(event::class_name(0x08), Some("receive error"));
    assert_eq!(
        event::class_name(0x1E),
        Some("error during communication between cp and cpu via backplane bus")
    );
    assert_eq!(event::class_name(0x06), None);
}

#[test]
fn named_constants_point_at_their_entries() {
    let info = event::lookup(ids::MODBUS_NO_REPLY).expect("08 30h");
    assert!(info.description.contains("reply monitoring time"));
    assert_eq!(ids::MODBUS_NO_REPLY.status_word(), 0x0830);
    assert_eq!(ids::PTP_PARAMS_ACCEPTED, EventId::new(0x00, 0x03));
    assert!(event::lookup(ids::DSR_OR_CTS_OFF).is_some_and(|i| i.description.contains("DSR = OFF")));
    assert!(event::lookup(ids::SLAVE_DB_ERROR)
        .is_some_and(|i| i.description.contains("FC 03, 04, 06 or 16")));
    for code in 1..=7u8 {
        let id = event::master_exception_event(code).expect("exception 01..07");
        assert!(event::lookup(id)
            .is_some_and(|i| i.description.contains(&format!("exception code {code:02}"))));
    }
}

#[test]
fn status_word_round_trip() {
    let status = Status::from(ids::BCC_ERROR);
    assert_eq!(status.0, 0x0808);
    assert_eq!(status.event(), Some(ids::BCC_ERROR));
    assert_eq!(Status::NONE.event(), None);
}

fn at(ms: u64) -> Instant {
    Instant::from_millis(ms)
}

#[test]
fn buffer_keeps_newest_first_and_the_cp_depth() {
    let mut buf = DiagBuffer::default();
    assert_eq!(buf.depth(), DEFAULT_DEPTH);
    assert_eq!(DEFAULT_DEPTH, 9);
    let events: Vec<EventId> = event::all()
        .iter()
        .map(|i| i.id)
        .filter(|id| id.class != 0x03)
        .take(12)
        .collect();
    for (n, id) in events.iter().enumerate() {
        assert!(buf.push(DiagEntry::new(*id, at(n as u64))));
    }
    assert_eq!(buf.len(), 9);
    let got: Vec<EventId> = buf.iter().map(|e| e.id).collect();
    let want: Vec<EventId> = events.iter().rev().take(9).copied().collect();
    assert_eq!(got, want, "newest first, the three oldest deleted");
    assert!(buf.iter().zip(buf.iter().skip(1)).all(|(a, b)| a.at > b.at));
    buf.clear();
    assert!(buf.is_empty());
}

/// 003 7.3: every diagnostic event is entered in the order it occurs, in a ring of N entries,
/// newest first; repeats are not merged (class 03h is not entered at all, 7.2).
#[test]
fn buffer_skips_class_03_and_keeps_every_repeat() {
    let mut buf = DiagBuffer::new(2);
    assert!(!buf.push(DiagEntry::new(ids::INVALID_FB_PARAMETERS, at(0))));
    for t in 1..=5 {
        buf.push(DiagEntry::new(ids::CHARACTER_ERROR, at(t)));
    }
    assert_eq!(buf.len(), 2);
    let entries: Vec<_> = buf
        .iter()
        .map(|e| (e.id, e.count, e.first_at, e.at))
        .collect();
    assert_eq!(
        entries,
        [
            (ids::CHARACTER_ERROR, 1, at(5), at(5)),
            (ids::CHARACTER_ERROR, 1, at(4), at(4)),
        ]
    );
}

proptest! {
    #[test]
    fn buffer_never_exceeds_depth(depth in 0usize..20, pushes in proptest::collection::vec((0usize..80, 0u64..1000), 0..200)) {
        let mut buf = DiagBuffer::new(depth);
        let catalog = event::all();
        let mut recorded_ids = Vec::new();
        for (index, ms) in pushes {
            let id = catalog[index].id;
            let recorded = buf.push(DiagEntry::new(id, at(ms)));
            prop_assert_eq!(recorded, id.class != 0x03);
            prop_assert!(buf.len() <= depth.max(1));
            if recorded {
                recorded_ids.push(id);
            }
            prop_assert_eq!(buf.newest().map(|e| e.id), recorded_ids.last().copied());
            // Every recorded event is an entry (repeats included), newest first, the oldest
            // deleted beyond the depth (003 7.3).
            let want: Vec<EventId> = recorded_ids.iter().rev().take(depth.max(1)).copied().collect();
            let got: Vec<EventId> = buf.iter().map(|e| e.id).collect();
            prop_assert_eq!(got, want);
        }
    }
}
