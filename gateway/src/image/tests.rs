use std::time::Duration;

use tokio::sync::broadcast::error::TryRecvError;

use super::*;

impl ProcessImage {
    /// Stores values with an explicit quality (a profile marking special values, for example).
    fn store_with_quality(
        &self,
        unit: u8,
        table: Table,
        start: u16,
        values: &[u16],
        quality: Quality,
        period: Option<Duration>,
    ) {
        self.store(unit, table, start, values.iter().copied(), quality, period);
    }
}

#[tokio::test(start_paused = true)]
async fn a_stored_range_reads_back_good_and_turns_stale_after_factor_periods() {
    let image = ProcessImage::new(ImageConfig {
        stale_factor: 3,
        notify_capacity: 8,
    });
    let period = Duration::from_millis(100);
    image.store_words(
        2,
        Table::HoldingRegisters,
        3102,
        &[40, 600, 500, 0],
        Some(period),
    );

    let read = image
        .read_words(2, Table::HoldingRegisters, 3102, 4)
        .unwrap();
    assert_eq!(read.values, vec![40, 600, 500, 0]);
    assert_eq!(read.quality, Quality::Good);

    tokio::time::advance(Duration::from_millis(300)).await;
    assert_eq!(
        image
            .read_words(2, Table::HoldingRegisters, 3103, 2)
            .unwrap()
            .quality,
        Quality::Good
    );
    tokio::time::advance(Duration::from_millis(1)).await;
    assert_eq!(
        image
            .read_words(2, Table::HoldingRegisters, 3103, 2)
            .unwrap()
            .quality,
        Quality::Stale
    );

    // A fresh store of part of the range: the worst quality and the oldest time still come from
    // the old part.
    image.store_words(2, Table::HoldingRegisters, 3102, &[41], Some(period));
    let read = image
        .read_words(2, Table::HoldingRegisters, 3102, 2)
        .unwrap();
    assert_eq!(read.values, vec![41, 600]);
    assert_eq!(read.quality, Quality::Stale);
    assert_eq!(
        image
            .read_words(2, Table::HoldingRegisters, 3102, 1)
            .unwrap()
            .quality,
        Quality::Good
    );
    let fresh = image
        .read_words(2, Table::HoldingRegisters, 3102, 1)
        .unwrap()
        .oldest_at;
    assert!(read.oldest_at < fresh);
}

#[test]
fn unpolled_values_never_turn_stale_and_tables_are_separate() {
    let image = ProcessImage::default();
    image.store_bits(5, Table::Coils, 10, &[true, false, true], None);
    assert_eq!(
        image.read_bits(5, Table::Coils, 10, 3).unwrap().values,
        vec![true, false, true]
    );
    assert_eq!(
        image.read_bits(5, Table::DiscreteInputs, 10, 1),
        Err(ImageError::Missing {
            unit: 5,
            table: Table::DiscreteInputs,
            address: 10
        })
    );
    assert_eq!(
        image.read_words(6, Table::Coils, 10, 1),
        Err(ImageError::UnknownUnit(6))
    );
}

#[test]
fn a_gap_or_a_range_past_the_end_is_reported() {
    let image = ProcessImage::default();
    image.store_words(1, Table::InputRegisters, 0, &[1, 2], None);
    image.store_words(1, Table::InputRegisters, 3, &[4], None);
    assert_eq!(
        image.read_words(1, Table::InputRegisters, 0, 4),
        Err(ImageError::Missing {
            unit: 1,
            table: Table::InputRegisters,
            address: 2
        })
    );
    assert_eq!(
        image.read_words(1, Table::InputRegisters, 3, 2),
        Err(ImageError::Missing {
            unit: 1,
            table: Table::InputRegisters,
            address: 4
        })
    );
    assert_eq!(
        image.read_words(1, Table::InputRegisters, 0xFFFF, 2),
        Err(ImageError::InvalidRange {
            start: 0xFFFF,
            count: 2
        })
    );
    assert_eq!(
        image.read_words(1, Table::InputRegisters, 0, 0),
        Err(ImageError::InvalidRange { start: 0, count: 0 })
    );
    // Storing at the top of the address space stops at 65535 instead of wrapping.
    image.store_words(1, Table::InputRegisters, 0xFFFF, &[7, 8], None);
    assert_eq!(
        image
            .read_words(1, Table::InputRegisters, 0xFFFF, 1)
            .unwrap()
            .values,
        vec![7]
    );
    assert_eq!(
        image
            .read_words(1, Table::InputRegisters, 0, 1)
            .unwrap()
            .values,
        vec![1]
    );
}

#[test]
fn quality_changes_mark_stored_values_only_and_are_announced_in_runs() {
    let image = ProcessImage::default();
    image.store_words(3, Table::HoldingRegisters, 100, &[1, 2, 3], None);
    image.store_words(3, Table::HoldingRegisters, 200, &[9], None);
    let mut rx = image.subscribe();

    image.set_unit_quality(3, Quality::CommFailure);
    let first = rx.try_recv().unwrap();
    assert_eq!(
        (first.start, first.values.clone(), first.quality),
        (100, vec![1, 2, 3], Quality::CommFailure)
    );
    let second = rx.try_recv().unwrap();
    assert_eq!((second.start, second.values), (200, vec![9]));
    assert_eq!(rx.try_recv(), Err(TryRecvError::Empty));
    let read = image
        .read_words(3, Table::HoldingRegisters, 100, 3)
        .unwrap();
    assert_eq!(
        (read.values, read.quality),
        (vec![1, 2, 3], Quality::CommFailure)
    );

    // Setting the same quality again changes nothing and announces nothing.
    image.set_quality(3, Table::HoldingRegisters, 100, 3, Quality::CommFailure);
    assert_eq!(rx.try_recv(), Err(TryRecvError::Empty));
    // An unknown unit or range is a no-op.
    image.set_quality(9, Table::HoldingRegisters, 0, 10, Quality::Stale);
    image.set_quality(3, Table::HoldingRegisters, 0xFFFF, 0, Quality::Stale);

    image.set_quality(3, Table::HoldingRegisters, 101, 1, Quality::Good);
    let change = rx.try_recv().unwrap();
    assert_eq!(
        (change.start, change.values, change.quality),
        (101, vec![2], Quality::Good)
    );
}

#[test]
fn stores_announce_only_what_changed() {
    let image = ProcessImage::default();
    let mut rx = image.subscribe();
    image.store_words(1, Table::HoldingRegisters, 0, &[5, 6], None);
    assert_eq!(rx.try_recv().unwrap().values, vec![5, 6]);
    image.store_words(1, Table::HoldingRegisters, 0, &[5, 6], None);
    assert_eq!(rx.try_recv(), Err(TryRecvError::Empty));
    image.store_words(1, Table::HoldingRegisters, 1, &[7], None);
    let change = rx.try_recv().unwrap();
    assert_eq!(
        (change.unit, change.table, change.start, change.values),
        (1, Table::HoldingRegisters, 1, vec![7])
    );
}

#[test]
fn a_lagging_subscriber_learns_how_many_changes_it_missed() {
    let image = ProcessImage::new(ImageConfig {
        stale_factor: 3,
        notify_capacity: 2,
    });
    let mut rx = image.subscribe();
    for v in 0..5 {
        image.store_words(1, Table::HoldingRegisters, 0, &[v], None);
    }
    assert_eq!(rx.try_recv(), Err(TryRecvError::Lagged(3)));
    assert_eq!(rx.try_recv().unwrap().values, vec![3]);
}

#[test]
fn snapshot_lists_a_table_in_address_order() {
    let image = ProcessImage::default();
    image.store_words(4, Table::InputRegisters, 1004, &[1066, 140, 4158], None);
    image.store_words(4, Table::InputRegisters, 10, &[1], None);
    let snap = image.snapshot(4, Table::InputRegisters);
    let addrs: Vec<(u16, u16)> = snap.iter().map(|s| (s.address, s.value)).collect();
    assert_eq!(
        addrs,
        vec![(10, 1), (1004, 1066), (1005, 140), (1006, 4158)]
    );
    assert_eq!(image.units(), vec![4]);
    assert!(image.snapshot(5, Table::Coils).is_empty());
}

#[tokio::test(start_paused = true)]
async fn refresh_updates_only_values_already_in_the_image_and_keeps_their_period() {
    let image = ProcessImage::new(ImageConfig {
        stale_factor: 2,
        notify_capacity: 8,
    });
    image.store_words(
        2,
        Table::HoldingRegisters,
        9001,
        &[10, 20],
        Some(Duration::from_millis(100)),
    );
    let mut rx = image.subscribe();
    tokio::time::advance(Duration::from_millis(150)).await;
    // A write of 9000..9002 through to the device: 9000 is not polled and stays out.
    image.refresh_words(2, Table::HoldingRegisters, 9000, &[1, 13, 20]);
    assert_eq!(
        image.read_words(2, Table::HoldingRegisters, 9000, 1),
        Err(ImageError::Missing {
            unit: 2,
            table: Table::HoldingRegisters,
            address: 9000
        })
    );
    let read = image
        .read_words(2, Table::HoldingRegisters, 9001, 2)
        .unwrap();
    assert_eq!((read.values, read.quality), (vec![13, 20], Quality::Good));
    // One change for the run that changed (9001, value 13; 9002 is in the same run).
    let change = rx.try_recv().unwrap();
    assert_eq!((change.start, change.values), (9001, vec![13, 20]));
    assert_eq!(rx.try_recv(), Err(TryRecvError::Empty));
    // Still the poll period's freshness limit (2 x 100 ms).
    tokio::time::advance(Duration::from_millis(201)).await;
    assert_eq!(
        image
            .read_words(2, Table::HoldingRegisters, 9001, 2)
            .unwrap()
            .quality,
        Quality::Stale
    );
    // An unknown unit is left alone.
    image.refresh_bits(3, Table::Coils, 0, &[true]);
    assert_eq!(image.units(), vec![2]);
}

/// A read response's PDU (0xEE for the function code) and quality, or why there is none.
type Encoded = Result<(Vec<u8>, Quality), ImageError>;

/// `encode_read` of a range: the response data and quality, checked against `read_words` or
/// `read_bits` encoded by proto-core.
fn encoded_and_expected(
    image: &ProcessImage,
    table: Table,
    start: u16,
    count: u16,
) -> (Encoded, Encoded) {
    use proto_core::modbus::pdu::Response;
    let mut out = vec![0xEE];
    let encoded = image
        .encode_read(7, table, start, count, &mut out)
        .map(|quality| (out.clone(), quality));
    if encoded.is_err() {
        assert_eq!(out, [0xEE], "nothing appended on an error");
    }
    let expected = if table.is_bits() {
        image.read_bits(7, table, start, count).map(|r| {
            let mut pdu = Vec::new();
            Response::ReadCoils(r.values).encode(&mut pdu);
            (pdu, r.quality)
        })
    } else {
        image.read_words(7, table, start, count).map(|r| {
            let mut pdu = Vec::new();
            Response::ReadHoldingRegisters(r.values).encode(&mut pdu);
            (pdu, r.quality)
        })
    };
    // The function code in front: 0xEE stood for it.
    let expected = expected.map(|(mut pdu, quality)| {
        pdu[0] = 0xEE;
        (pdu, quality)
    });
    (encoded, expected)
}

#[tokio::test(start_paused = true)]
async fn encoded_reads_are_the_responses_of_the_range_reads() {
    let image = ProcessImage::new(ImageConfig {
        stale_factor: 2,
        notify_capacity: 8,
    });
    let fast = Some(Duration::from_millis(100));
    let slow = Some(Duration::from_millis(1000));
    let words: Vec<u16> = (0..135).map(|v| (v * 0x0101) ^ 0x8000).collect();
    image.store_words(7, Table::InputRegisters, 0, &words, fast);
    image.store_words(7, Table::InputRegisters, 200, &[1, 2, 3], slow);
    image.store_words(7, Table::InputRegisters, 203, &[4, 5], fast);
    image.store_with_quality(
        7,
        Table::InputRegisters,
        300,
        &[9, 9],
        Quality::OutOfRange,
        fast,
    );
    image.store_words(7, Table::InputRegisters, 302, &[8], None);
    let bits: Vec<bool> = (0..2041).map(|i| i % 3 == 0 || i % 7 == 0).collect();
    image.store_bits(7, Table::Coils, 10, &bits, fast);
    image.set_quality(7, Table::Coils, 20, 1, Quality::Rejected);

    let ranges = [
        (Table::InputRegisters, 0, 125),
        (Table::InputRegisters, 5, 127),
        (Table::InputRegisters, 200, 5),
        (Table::InputRegisters, 300, 3),
        (Table::Coils, 10, 1),
        (Table::Coils, 10, 9),
        (Table::Coils, 11, 2000),
        (Table::Coils, 21, 2000),
    ];
    for step in [0, 150, 100, 1000] {
        tokio::time::advance(Duration::from_millis(step)).await;
        for (table, start, count) in ranges {
            let (encoded, expected) = encoded_and_expected(&image, table, start, count);
            assert!(expected.is_ok(), "{table} {start}+{count}");
            assert_eq!(encoded, expected, "{table} {start}+{count} after {step} ms");
        }
    }
    // After 1250 ms the good values polled are stale; a special value keeps its quality.
    let quality = |start, count| {
        let (encoded, _) = encoded_and_expected(&image, Table::InputRegisters, start, count);
        encoded.map(|(_, q)| q)
    };
    assert_eq!(quality(0, 125), Ok(Quality::Stale));
    assert_eq!(quality(300, 3), Ok(Quality::OutOfRange));

    for (table, start, count) in [
        (Table::InputRegisters, 133, 5),
        (Table::InputRegisters, 199, 2),
        (Table::HoldingRegisters, 0, 1),
        (Table::InputRegisters, 0xFFFF, 2),
        (Table::InputRegisters, 0, 0),
    ] {
        let (encoded, expected) = encoded_and_expected(&image, table, start, count);
        assert!(expected.is_err());
        assert_eq!(
            encoded.map(|_| ()),
            expected.map(|_| ()),
            "{table} {start}+{count}"
        );
    }
    let mut out = Vec::new();
    assert_eq!(
        image.encode_read(8, Table::InputRegisters, 0, 1, &mut out),
        Err(ImageError::UnknownUnit(8))
    );
    // Byte counts that do not fit their byte.
    for (table, count) in [(Table::InputRegisters, 128), (Table::Coils, 2041)] {
        assert_eq!(
            image.encode_read(7, table, 0, count, &mut out),
            Err(ImageError::InvalidRange { start: 0, count })
        );
    }
    assert!(out.is_empty());
}

#[tokio::test(start_paused = true)]
async fn the_oldest_polled_value_leaves_out_values_written_on_demand() {
    let image = ProcessImage::default();
    assert_eq!(image.oldest_polled(2), None);
    image.store_words(2, Table::HoldingRegisters, 9001, &[13], None);
    assert_eq!(image.oldest_polled(2), None, "a value without poll period");
    let period = Some(Duration::from_millis(100));
    let first = Instant::now();
    image.store_words(2, Table::InputRegisters, 10, &[1, 2], period);
    tokio::time::advance(Duration::from_millis(500)).await;
    image.store_bits(2, Table::Coils, 0, &[true], period);
    image.store_words(2, Table::InputRegisters, 11, &[3], period);
    assert_eq!(
        image.oldest_polled(2),
        Some(first),
        "register 10 was read first"
    );
    image.store_words(2, Table::InputRegisters, 10, &[4], period);
    assert_eq!(image.oldest_polled(2), Some(Instant::now()));
    assert_eq!(image.oldest_polled(3), None);
}

#[tokio::test(start_paused = true)]
async fn a_store_shows_one_time_in_its_change_snapshot_and_range_read() {
    let image = ProcessImage::default();
    let mut changes = image.subscribe();
    let before = SystemTime::now();
    let at = Instant::now();
    image.store_words(4, Table::InputRegisters, 7, &[70, 80], None);
    let after = SystemTime::now();
    let change = changes.try_recv().unwrap();
    let read = image.read_words(4, Table::InputRegisters, 7, 2).unwrap();
    let view = image.snapshot(4, Table::InputRegisters);
    assert_eq!(read.oldest, change.time);
    assert_eq!(view[0].updated, change.time);
    assert_eq!(view[1].updated, change.time);
    assert_eq!(read.oldest_at, at, "the monotonic time comes back exactly");
    // Kept to the microsecond: at most 1 µs before the clock read before the store.
    assert!(change.time + Duration::from_micros(1) > before && change.time <= after);
    let micros = change
        .time
        .duration_since(SystemTime::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos()
        % 1000;
    assert_eq!(micros, 0, "whole microseconds");
    // Not polled: never stale, however old.
    tokio::time::advance(Duration::from_secs(400 * 86_400)).await;
    let read = image.read_words(4, Table::InputRegisters, 7, 2).unwrap();
    assert_eq!(read.quality, Quality::Good);
}

#[tokio::test(start_paused = true)]
async fn a_poll_period_too_long_to_keep_still_turns_stale() {
    let image = ProcessImage::default();
    // 30 days times 3: past the longest freshness limit a slot keeps (about 49.7 days).
    let period = Some(Duration::from_secs(30 * 86_400));
    image.store_words(5, Table::HoldingRegisters, 0, &[1], period);
    let quality = |image: &ProcessImage| {
        image
            .read_words(5, Table::HoldingRegisters, 0, 1)
            .unwrap()
            .quality
    };
    let limit = Duration::from_millis(u64::from(slot::MAX_AGE_MS_LIMIT));
    tokio::time::advance(limit).await;
    assert_eq!(quality(&image), Quality::Good);
    tokio::time::advance(Duration::from_millis(1)).await;
    assert_eq!(
        quality(&image),
        Quality::Stale,
        "clamped to the longest limit"
    );
    assert_eq!(
        image.snapshot(5, Table::HoldingRegisters)[0].quality,
        Quality::Stale
    );
}
