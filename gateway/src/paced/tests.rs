//! The relay on an in-process stream pair and tokio's paused clock: the delivery times are
//! deterministic, so the upper bound is exact (one timer tick) and not a speed test.

use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::time::Instant;

use super::*;

/// The tokio timer's resolution: a due byte waits at most this long for its tick.
const TICK: Duration = Duration::from_millis(1);

/// Reads until end of stream, noting the (virtual) time each byte was read.
async fn read_all_timed(
    stream: &mut tokio::io::DuplexStream,
    t0: Instant,
) -> (Vec<u8>, Vec<Duration>) {
    let mut data = Vec::new();
    let mut times = Vec::new();
    let mut buf = [0u8; 256];
    loop {
        let n = stream.read(&mut buf).await.expect("read");
        if n == 0 {
            return (data, times);
        }
        data.extend_from_slice(&buf[..n]);
        times.extend(std::iter::repeat_n(t0.elapsed(), n));
    }
}

#[tokio::test(start_paused = true)]
async fn every_byte_is_delivered_in_its_tick_never_before() {
    let settings = PacedSettings::from_frame(9600, 8, false, 1);
    let shutdown = CancellationToken::new();
    let (link, task) = paced_duplex(settings, None, shutdown.clone()).expect("link");
    let PacedDuplex {
        mut a,
        mut b,
        counters,
    } = link;
    let data: Vec<u8> = (0..=255).collect();
    let t0 = Instant::now();
    a.write_all(&data).await.expect("write");
    // Closing `a` ends the a -> b direction once its bytes are delivered.
    a.shutdown().await.expect("shutdown");
    let (got, times) = read_all_timed(&mut b, t0).await;
    assert_eq!(got, data);
    for (k, at) in times.iter().enumerate() {
        let due = settings.transmit_time(u64::try_from(k + 1).expect("small"));
        assert!(*at >= due, "byte {k} at {at:?} before {due:?}");
        assert!(*at <= due + TICK, "byte {k} at {at:?}, due {due:?}");
    }
    let stats = counters.direction(Direction::AToB);
    assert_eq!((stats.received, stats.delivered), (256, 256));
    assert!(stats.max_lateness <= TICK, "{stats:?}");
    // 256 bytes of 1.04 ms each go out on about 267 ticks, one write per tick at most.
    assert!(stats.batches <= 268, "{stats:?}");
    drop(b);
    shutdown.cancel();
    task.await.expect("join").expect("relay");
}

#[tokio::test(start_paused = true)]
async fn fast_lines_deliver_several_bytes_a_tick() {
    // 115200 8E1: 95.5 us a character, about 10 a tick.
    let settings = PacedSettings::from_frame(115_200, 8, true, 1);
    let shutdown = CancellationToken::new();
    let (link, _task) = paced_duplex(settings, None, shutdown.clone()).expect("link");
    let PacedDuplex {
        mut a,
        mut b,
        counters,
    } = link;
    let data: Vec<u8> = (0..2000u32).map(|k| (k % 256) as u8).collect();
    let t0 = Instant::now();
    let writer = tokio::spawn(async move {
        a.write_all(&data).await.expect("write");
        a.shutdown().await.expect("shutdown");
        data
    });
    let (got, times) = read_all_timed(&mut b, t0).await;
    let data = writer.await.expect("writer");
    assert_eq!(got, data);
    let wire = settings.transmit_time(2000);
    let last = times.last().copied().unwrap_or_default();
    assert!(last >= wire && last <= wire + TICK, "{last:?} vs {wire:?}");
    let stats = counters.direction(Direction::AToB);
    // 191 ms of wire time: at most one write per tick.
    assert!(stats.batches <= 193, "{stats:?}");
    shutdown.cancel();
}

#[tokio::test(start_paused = true)]
async fn both_directions_are_paced_independently() {
    let settings = PacedSettings::from_frame(19_200, 8, true, 1);
    let shutdown = CancellationToken::new();
    let (link, _task) = paced_duplex(settings, None, shutdown.clone()).expect("link");
    let PacedDuplex {
        mut a,
        mut b,
        counters: _,
    } = link;
    let t0 = Instant::now();
    // Both sides send 50 bytes at once: full duplex, each arrives after 50 character times, not
    // 100.
    a.write_all(&[0xA5; 50]).await.expect("write a");
    b.write_all(&[0x5A; 50]).await.expect("write b");
    a.shutdown().await.expect("shutdown a");
    b.shutdown().await.expect("shutdown b");
    let (at_b, times_b) = read_all_timed(&mut b, t0).await;
    let (at_a, times_a) = read_all_timed(&mut a, t0).await;
    assert_eq!((at_b, at_a), (vec![0xA5; 50], vec![0x5A; 50]));
    let wire = settings.transmit_time(50);
    for last in [times_a.last(), times_b.last()] {
        let last = last.copied().unwrap_or_default();
        assert!(last >= wire && last <= wire + TICK, "{last:?} vs {wire:?}");
    }
    shutdown.cancel();
}

#[tokio::test(start_paused = true)]
async fn a_dropped_byte_still_takes_its_time() {
    let settings = PacedSettings::from_frame(9600, 8, false, 1);
    let shutdown = CancellationToken::new();
    let hook = |_: Direction, index: u64, _: u8| {
        if index == 0 {
            FaultAction::Drop
        } else {
            FaultAction::Deliver
        }
    };
    let (link, _task) =
        paced_duplex(settings, Some(Arc::new(hook)), shutdown.clone()).expect("link");
    let PacedDuplex {
        mut a,
        mut b,
        counters,
    } = link;
    let t0 = Instant::now();
    a.write_all(&[1, 2]).await.expect("write");
    a.shutdown().await.expect("shutdown");
    let (got, times) = read_all_timed(&mut b, t0).await;
    assert_eq!(got, [2]);
    let due = settings.transmit_time(2);
    assert!(times[0] >= due && times[0] <= due + TICK, "{times:?}");
    assert_eq!(counters.direction(Direction::AToB).dropped, 1);
    shutdown.cancel();
}

#[test]
fn settings_count_start_data_parity_and_stop_bits() {
    assert_eq!(
        PacedSettings::from_frame(9600, 8, true, 1).bits_per_char,
        11
    );
    assert_eq!(
        PacedSettings::from_frame(9600, 7, false, 2).bits_per_char,
        10
    );
    assert_eq!(
        PacedSettings::from_frame(19_200, 8, true, 1).char_time(),
        Duration::from_nanos(572_916)
    );
    let zero = PacedSettings {
        baud: 0,
        bits_per_char: 11,
    };
    assert_eq!(
        zero.check().map_err(|e| e.kind()),
        Err(io::ErrorKind::InvalidInput)
    );
}
