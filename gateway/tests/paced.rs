//! The paced link on real ptys: bytes arrive intact, in order, both ways, never before their
//! character time; a Modbus RTU exchange (tokio-modbus master, proto-core slave engine) works
//! through it.

use std::sync::Arc;
use std::time::Duration;

use gateway::paced::{self, Direction, FaultAction, PacedLink, PacedSettings};
use proto_core::cpmem::{AddressMap, CpMemory, OperatingMode, SlaveParams, WriteLimits};
use proto_core::modbus::rtu::CharTiming;
use proto_core::modbus::slave::Slave as RtuSlave;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::time::{timeout, Instant};
use tokio_serial::{SerialPortBuilderExt, SerialStream};
use tokio_util::sync::CancellationToken;

/// Opens one end of the link as the gateway or a simulator would.
fn open(path: &str, settings: PacedSettings) -> SerialStream {
    tokio_serial::new(path, settings.baud)
        .open_native_async()
        .unwrap_or_else(|e| panic!("open {path}: {e}"))
}

async fn start(settings: PacedSettings) -> (PacedLink, CancellationToken) {
    let shutdown = CancellationToken::new();
    let (link, _task) = paced::spawn(settings, shutdown.clone())
        .await
        .expect("paced link");
    (link, shutdown)
}

/// Reads `n` bytes, noting when each one was read (relative to `t0`).
async fn read_timed(
    port: &mut SerialStream,
    n: usize,
    t0: Instant,
    limit: Duration,
) -> (Vec<u8>, Vec<Duration>) {
    let mut data = Vec::with_capacity(n);
    let mut times = Vec::with_capacity(n);
    let mut buf = [0u8; 512];
    timeout(limit, async {
        while data.len() < n {
            let got = port.read(&mut buf).await.expect("read");
            assert!(got > 0, "end of stream after {} bytes", data.len());
            let at = t0.elapsed();
            data.extend_from_slice(&buf[..got]);
            times.extend(std::iter::repeat_n(at, got));
        }
    })
    .await
    .unwrap_or_else(|_| panic!("only {} of {n} bytes within {limit:?}", data.len()));
    (data, times)
}

fn pattern(n: usize, salt: u8) -> Vec<u8> {
    (0..n)
        .map(|k| u8::try_from(k % 251).expect("< 251") ^ salt)
        .collect()
}

#[tokio::test]
async fn bytes_arrive_intact_and_in_order_both_ways_at_once() {
    let settings = PacedSettings::from_frame(115_200, 8, true, 1);
    let (link, shutdown) = start(settings).await;
    let a = open(&link.a, settings);
    let mut b = open(&link.b, settings);
    let to_b = pattern(3000, 0x00);
    let to_a = pattern(2000, 0x5A);
    let t0 = Instant::now();
    let limit = Duration::from_secs(10);
    let (sent_a, sent_b) = (to_b.clone(), to_a.clone());
    let writer_a = tokio::spawn(async move {
        let mut a = a;
        a.write_all(&sent_a).await.expect("write a");
        read_timed(&mut a, 2000, t0, limit).await
    });
    let writer_b = tokio::spawn(async move {
        b.write_all(&sent_b).await.expect("write b");
        read_timed(&mut b, 3000, t0, limit).await
    });
    let (at_a, _) = writer_a.await.expect("side a");
    let (at_b, _) = writer_b.await.expect("side b");
    assert_eq!(at_b, to_b, "a -> b");
    assert_eq!(at_a, to_a, "b -> a");

    let ab = link.counters.direction(Direction::AToB);
    let ba = link.counters.direction(Direction::BToA);
    assert_eq!((ab.received, ab.delivered, ab.dropped), (3000, 3000, 0));
    assert_eq!((ba.received, ba.delivered, ba.dropped), (2000, 2000, 0));
    shutdown.cancel();
}

/// Writes `n` bytes at once from `a` and checks when each arrives at `b`: byte k (from 0) cannot
/// be complete before (k + 1) character times after the write began; the whole transfer takes
/// less than three times its wire time plus 50 ms.
async fn check_timing(settings: PacedSettings, n: usize) {
    let (link, shutdown) = start(settings).await;
    let mut a = open(&link.a, settings);
    let mut b = open(&link.b, settings);
    let data = pattern(n, 0x33);
    let wire = settings.transmit_time(u64::try_from(n).expect("small"));
    let t0 = Instant::now();
    a.write_all(&data).await.expect("write");
    let (got, times) = read_timed(&mut b, n, t0, wire * 3 + Duration::from_secs(5)).await;
    let total = t0.elapsed();
    assert_eq!(got, data);
    for (k, at) in times.iter().enumerate() {
        let earliest = settings.transmit_time(u64::try_from(k + 1).expect("small"));
        assert!(
            *at >= earliest,
            "byte {k} arrived after {at:?}, before its time {earliest:?}"
        );
    }
    assert!(total >= wire, "{n} bytes in {total:?} < {wire:?}");
    assert!(
        total < wire * 3 + Duration::from_millis(50),
        "{n} bytes in {total:?}, wire time {wire:?}"
    );
    let stats = link.counters.direction(Direction::AToB);
    eprintln!(
        "{} Bd x {} bits, {n} bytes: wire {wire:?}, measured {total:?}, {} writes, \
         max lateness {:?}",
        settings.baud, settings.bits_per_char, stats.batches, stats.max_lateness
    );
    shutdown.cancel();
}

#[tokio::test]
async fn bytes_take_their_character_time_at_9600_8n1() {
    check_timing(PacedSettings::from_frame(9600, 8, false, 1), 200).await;
}

#[tokio::test]
async fn bytes_take_their_character_time_at_115200_8e1() {
    // 95.5 us a character: several bytes are due at each timer tick and go out together.
    check_timing(PacedSettings::from_frame(115_200, 8, true, 1), 4000).await;
}

#[tokio::test]
async fn a_gap_in_the_sending_is_not_made_up_for() {
    // 19200 8E1: 573 us a character. Two bursts of 20 bytes 100 ms apart: the second burst still
    // takes its full wire time after it was written.
    let settings = PacedSettings::from_frame(19_200, 8, true, 1);
    let (link, shutdown) = start(settings).await;
    let mut a = open(&link.a, settings);
    let mut b = open(&link.b, settings);
    let burst = settings.transmit_time(20);
    let t0 = Instant::now();
    a.write_all(&pattern(20, 1)).await.expect("write");
    let (first, _) = read_timed(&mut b, 20, t0, Duration::from_secs(5)).await;
    assert_eq!(first, pattern(20, 1));
    tokio::time::sleep(Duration::from_millis(100)).await;
    let t1 = Instant::now();
    a.write_all(&pattern(20, 2)).await.expect("write");
    let (second, times) = read_timed(&mut b, 20, t1, Duration::from_secs(5)).await;
    assert_eq!(second, pattern(20, 2));
    let last = times.last().copied().unwrap_or_default();
    assert!(last >= burst, "second burst in {last:?} < {burst:?}");
    shutdown.cancel();
}

#[tokio::test]
async fn the_fault_hook_drops_and_corrupts_bytes() {
    let settings = PacedSettings::from_frame(115_200, 8, false, 1);
    let shutdown = CancellationToken::new();
    // Drop byte 3 and replace byte 5 of a -> b; leave b -> a alone.
    let hook = |direction, index, byte: u8| match (direction, index) {
        (Direction::AToB, 3) => FaultAction::Drop,
        (Direction::AToB, 5) => FaultAction::Replace(!byte),
        _ => FaultAction::Deliver,
    };
    let (link, _task) = paced::spawn_with(settings, Some(Arc::new(hook)), shutdown.clone())
        .await
        .expect("paced link");
    let mut a = open(&link.a, settings);
    let mut b = open(&link.b, settings);
    let t0 = Instant::now();
    a.write_all(&[0, 1, 2, 3, 4, 5, 6, 7]).await.expect("write");
    let (got, _) = read_timed(&mut b, 7, t0, Duration::from_secs(5)).await;
    assert_eq!(got, [0, 1, 2, 4, !5, 6, 7]);
    b.write_all(&[9, 8, 7, 6, 5, 4]).await.expect("write");
    let (back, _) = read_timed(&mut a, 6, t0, Duration::from_secs(5)).await;
    assert_eq!(back, [9, 8, 7, 6, 5, 4]);
    let ab = link.counters.direction(Direction::AToB);
    assert_eq!(
        (ab.received, ab.delivered, ab.dropped, ab.corrupted),
        (8, 7, 1, 1)
    );
    shutdown.cancel();
}

#[tokio::test]
async fn the_paths_survive_a_side_closing_and_reopening() {
    let settings = PacedSettings::from_frame(115_200, 8, false, 1);
    let (link, shutdown) = start(settings).await;
    let b = open(&link.b, settings);
    {
        let mut a = open(&link.a, settings);
        a.write_all(b"first").await.expect("write");
        a.flush().await.expect("flush");
    }
    let mut b = b;
    let t0 = Instant::now();
    let (got, _) = read_timed(&mut b, 5, t0, Duration::from_secs(5)).await;
    assert_eq!(got, b"first");
    let mut a = open(&link.a, settings);
    a.write_all(b"again").await.expect("write");
    let (got, _) = read_timed(&mut b, 5, t0, Duration::from_secs(5)).await;
    assert_eq!(got, b"again");
    shutdown.cancel();
}

/// Runs proto-core's slave engine on a port until `shutdown`.
async fn serve(mut port: SerialStream, mut slave: RtuSlave, shutdown: CancellationToken) {
    let origin = Instant::now();
    let now = move || {
        proto_core::time::Instant::from_micros(
            u64::try_from(origin.elapsed().as_micros()).expect("short test"),
        )
    };
    let mut buf = [0u8; 512];
    loop {
        while let Some(frame) = slave.poll_transmit() {
            port.write_all(&frame).await.expect("slave write");
        }
        while slave.poll_event().is_some() {}
        let deadline = slave
            .poll_timeout()
            .map(|at| origin + Duration::from_micros(at.as_micros()));
        // Bytes already waiting are read before a deadline is acted on: a late wake-up must not
        // cut a frame whose bytes arrived in time.
        tokio::select! {
            biased;
            () = shutdown.cancelled() => return,
            read = port.read(&mut buf) => {
                let n = read.expect("slave read");
                slave.handle_rx(now(), &buf[..n]);
            }
            () = tokio::time::sleep_until(deadline.unwrap_or_else(Instant::now)),
                if deadline.is_some() => slave.handle_timeout(now()),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_modbus_rtu_exchange_works_through_the_link() {
    use tokio_modbus::prelude::*;

    // 19200 8E1 (003 6.4.5.1: 8 data bits, even parity, 1 stop bit): 11 bits a character. The
    // relay delivers on the tokio timer's millisecond ticks and this machine is shared, so gaps of
    // a few milliseconds occur inside a frame; the slave uses the CP's multiplier of the character
    // delay time (003 6.4.5.1, "for partners that cannot meet the timing", range 1..10) to stretch
    // its end-of-frame time t3.5 from 2 ms to 20 ms.
    let settings = PacedSettings::from_frame(19_200, 8, true, 1);
    let (link, shutdown) = start(settings).await;

    let map = AddressMap::manual_example()
        .with_limits(WriteLimits {
            memory: None,
            outputs: None,
            data_blocks: Some((800, 800)),
        })
        .expect("limits");
    let params = SlaveParams::new(17, OperatingMode::Normal, 10, map).expect("params");
    let mut memory = CpMemory::default();
    let db = memory.db_mut(800).expect("DB 800");
    for (k, word) in db.iter_mut().take(10).enumerate() {
        *word = 1000 + u16::try_from(k).expect("small");
    }
    let timing = CharTiming::exact(settings.baud, settings.bits_per_char);
    let slave = RtuSlave::new(params, timing, memory);
    tokio::spawn(serve(open(&link.b, settings), slave, shutdown.clone()));

    let mut master = rtu::attach_slave(open(&link.a, settings), Slave(17));
    let t0 = Instant::now();
    let words = timeout(Duration::from_secs(5), master.read_holding_registers(0, 10))
        .await
        .expect("answer in time")
        .expect("transport")
        .expect("no exception");
    let round_trip = t0.elapsed();
    assert_eq!(words, (1000..1010).collect::<Vec<u16>>());
    // Request 8 bytes, answer 5 + 20 bytes, and the slave's t3.5 silence in between.
    let least = settings.transmit_time(8 + 25) + timing.with_multiplier(10).t35;
    assert!(round_trip >= least, "round trip {round_trip:?} < {least:?}");

    timeout(
        Duration::from_secs(5),
        master.write_single_register(3, 0xBEEF),
    )
    .await
    .expect("answer in time")
    .expect("transport")
    .expect("no exception");
    let words = timeout(Duration::from_secs(5), master.read_holding_registers(2, 2))
        .await
        .expect("answer in time")
        .expect("transport")
        .expect("no exception");
    assert_eq!(words, [1002, 0xBEEF]);

    // A register outside the map answers an exception through the link as well.
    let refused = timeout(
        Duration::from_secs(5),
        master.write_single_register(0x3000, 1),
    )
    .await
    .expect("answer in time")
    .expect("transport");
    assert!(refused.is_err(), "write outside the limits: {refused:?}");
    eprintln!(
        "FC03 x 10 at 19200 8E1 through the paced link: {round_trip:?} (wire + t3.5 = {least:?})"
    );
    shutdown.cancel();
}
