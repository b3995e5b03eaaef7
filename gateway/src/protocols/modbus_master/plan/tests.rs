use std::time::Duration;

use proptest::prelude::*;

use super::*;

fn r(start: u16, count: u16) -> AddrRange {
    AddrRange::new(start, count)
}

#[test]
fn adjacent_and_overlapping_ranges_merge_into_one_read() {
    // Altivar: SFr..LSP (W3102..W3105) and ETA, LCR, OTR (W3201, W3204, W3205) are two reads
    // without bridging, the first polled in two pieces.
    let ranges = [r(3104, 2), r(3102, 2), r(3201, 1), r(3204, 2), r(3103, 1)];
    assert_eq!(
        merge_ranges(&ranges, 63, 0),
        vec![r(3102, 4), r(3201, 1), r(3204, 2)]
    );
}

#[test]
fn gaps_are_bridged_only_up_to_the_configured_size() {
    let ranges = [r(3201, 1), r(3204, 2), r(3207, 1), r(3209, 1)];
    assert_eq!(
        merge_ranges(&ranges, 63, 0),
        vec![r(3201, 1), r(3204, 2), r(3207, 1), r(3209, 1)]
    );
    assert_eq!(merge_ranges(&ranges, 63, 1), vec![r(3201, 1), r(3204, 6)]);
    assert_eq!(merge_ranges(&ranges, 63, 2), vec![r(3201, 9)]);
}

#[test]
fn a_merged_read_never_exceeds_the_device_limit() {
    // The Altivar reads at most 63 words: 100 contiguous words are two reads, 63 + 37.
    assert_eq!(
        merge_ranges(&[r(8000, 100)], 63, 0),
        vec![r(8000, 63), r(8063, 37)]
    );
    // Adjacent ranges that together exceed the limit split at the limit, the rest merges on.
    assert_eq!(
        merge_ranges(&[r(0, 60), r(60, 10), r(70, 5)], 63, 0),
        vec![r(0, 63), r(63, 12)]
    );
    // A bridge that would exceed the limit is not taken.
    assert_eq!(
        merge_ranges(&[r(0, 60), r(62, 4)], 63, 5),
        vec![r(0, 60), r(62, 4)]
    );
    // KS vario: 120 integer values a message (001 3.1).
    let ks = merge_ranges(&[r(1000, 250)], DeviceLimits::KS_VARIO.max_read_regs, 0);
    assert_eq!(ks, vec![r(1000, 120), r(1120, 120), r(1240, 10)]);
}

#[test]
fn empty_ranges_are_ignored_and_the_top_of_the_address_space_is_kept() {
    assert_eq!(merge_ranges(&[r(5, 0)], 10, 0), vec![]);
    assert_eq!(
        merge_ranges(&[r(65530, 6), r(65535, 1)], 125, 0),
        vec![r(65530, 6)]
    );
    assert_eq!(merge_ranges(&[r(65535, 1)], 1, 0), vec![r(65535, 1)]);
}

#[test]
fn read_blocks_build_the_request_of_their_table() {
    let block = ReadBlock {
        table: Table::InputRegisters,
        range: r(1004, 3),
        period: Duration::from_secs(1),
    };
    assert_eq!(
        block.request(),
        Request::ReadInputRegisters {
            address: 1004,
            quantity: 3
        }
    );
    let block = ReadBlock {
        table: Table::Coils,
        ..block
    };
    assert_eq!(
        block.request(),
        Request::ReadCoils {
            address: 1004,
            quantity: 3
        }
    );
    assert_eq!(DeviceLimits::ALTIVAR.max_read(Table::HoldingRegisters), 63);
    assert_eq!(DeviceLimits::CP341.max_read(Table::Coils), 2040);
}

proptest! {
    /// Every polled address is read, no read exceeds the limit, reads do not overlap, and no read
    /// includes a run of unpolled addresses longer than the bridge.
    #[test]
    fn merged_reads_cover_exactly_within_limits(
        ranges in prop::collection::vec((0u16..2000, 0u16..200), 0..12),
        max in 1u16..130,
        bridge in 0u16..6,
    ) {
        let ranges: Vec<AddrRange> = ranges.into_iter().map(|(s, c)| r(s, c)).collect();
        let reads = merge_ranges(&ranges, max, bridge);
        let polled = |a: u32| ranges.iter().any(|x| u32::from(x.start) <= a && a < x.end());
        for read in &reads {
            prop_assert!(read.count >= 1 && read.count <= max);
            prop_assert!(polled(u32::from(read.start)));
            prop_assert!(polled(read.end() - 1));
            let mut gap = 0;
            for a in u32::from(read.start)..read.end() {
                gap = if polled(a) { 0 } else { gap + 1 };
                prop_assert!(gap <= u32::from(bridge), "read {read:?} bridges more than {bridge}");
            }
        }
        for pair in reads.windows(2) {
            prop_assert!(pair[0].end() <= u32::from(pair[1].start));
        }
        for range in &ranges {
            for a in u32::from(range.start)..range.end() {
                prop_assert!(reads.iter().any(|x| u32::from(x.start) <= a && a < x.end()));
            }
        }
        // Fewest reads: never more than one per polled range plus the splits a long range needs.
        let bound: usize = ranges.iter().filter(|x| x.count > 0).map(|x| usize::from(x.count.div_ceil(max))).sum();
        prop_assert!(reads.len() <= bound);
    }
}

#[test]
fn groups_of_one_table_and_period_merge_and_other_periods_stay_apart() {
    use crate::protocols::{DeviceSettings, PollGroup};
    let fast = Duration::from_millis(100);
    let slow = Duration::from_secs(1);
    let group = |period, table, ranges| PollGroup {
        period,
        table,
        ranges,
    };
    let mut d = DeviceSettings::new("ks", 17, 17);
    d.limits = DeviceLimits::KS_VARIO;
    d.groups = vec![
        group(fast, Table::InputRegisters, vec![r(1004, 2)]),
        group(fast, Table::InputRegisters, vec![r(1006, 1)]),
        group(slow, Table::InputRegisters, vec![r(1007, 1)]),
        group(fast, Table::HoldingRegisters, vec![r(1004, 3)]),
    ];
    let blocks: Vec<(Table, AddrRange, Duration)> = d
        .read_blocks()
        .iter()
        .map(|b| (b.table, b.range, b.period))
        .collect();
    assert_eq!(
        blocks,
        vec![
            (Table::HoldingRegisters, r(1004, 3), fast),
            (Table::InputRegisters, r(1004, 3), fast),
            (Table::InputRegisters, r(1007, 1), slow),
        ]
    );
    assert_eq!(d.poll_period(Table::InputRegisters, 1006), Some(fast));
    assert_eq!(d.poll_period(Table::InputRegisters, 1008), None);
    assert!(d.is_polled(Table::InputRegisters, r(1004, 4)));
    assert!(!d.is_polled(Table::InputRegisters, r(1004, 5)));
    assert!(!d.is_polled(Table::Coils, r(1004, 1)));
}
