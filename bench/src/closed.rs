//! The closed-loop rows: fair use of the bus under load from outside.
//!
//! One device on a paced 19200 Bd link, its four holding registers 0..3 polled every 200 ms and
//! served over Modbus TCP. Three clients run at once for the plan's window:
//!
//! - a closed-loop writer: FC 06 to register 100 of the device, the next write as soon as the last
//!   one is answered;
//! - a closed-loop on-demand reader: FC 03 of register 1000, which no poll group reads, so each
//!   read goes to the device;
//! - a cached reader: FC 03 of the polled registers every 10 ms, answered from the image.
//!
//! Without fair scheduling the writer and the on-demand reader take the bus from the polls, the
//! cached values age beyond the image's stale limit, and the cached reads are answered 0Bh. The
//! rows say how many cached reads succeeded, the oldest cached value seen (sampled from the image
//! every 20 ms) against the poll group's stated bound, and the achieved poll cycle (the longest)
//! against the planned period, within the bound.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, SystemTime};

use gateway::image::Table;
use tokio_util::sync::CancellationToken;

use crate::device::FlatDevice;
use crate::mbap::Client;
use crate::poll::{polled, rig, trouble};
use crate::report::{Row, Target};
use crate::stats::ms;
use crate::tcp::serve_gateway;
use crate::Plan;

/// The device's slave address and unit id.
const UNIT: u8 = 1;
/// The baud rate of the line.
const BAUD: u32 = 19_200;
/// The poll period of the device's group.
const PERIOD: Duration = Duration::from_millis(200);
/// The registers the group polls (0..COUNT).
const COUNT: u16 = 4;
/// The register the writer writes.
const WRITTEN: u16 = 100;
/// The register the on-demand reader reads (no group polls it).
const ON_DEMAND: u16 = 1000;
/// The pause of the cached reader between reads.
const CACHED_PAUSE: Duration = Duration::from_millis(10);
/// How often the image's age is sampled.
const AGE_SAMPLE: Duration = Duration::from_millis(20);

/// Runs the three clients for `plan.closed_window` and returns the three rows.
pub(crate) async fn closed_loop(plan: &Plan) -> std::io::Result<Vec<Row>> {
    let rig = rig(
        BAUD,
        FlatDevice::new(UNIT),
        vec![polled("d1", UNIT, COUNT, PERIOD)],
        Some(Duration::from_millis(300)),
    )
    .await?;
    let shutdown = CancellationToken::new();
    let _stop_server = shutdown.clone().drop_guard();
    let addr = serve_gateway(&rig.line, shutdown).await?;

    // The first polls fill the image.
    let mut cached = Client::connect(addr).await?;
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    while cached.read_one(UNIT, 0).await.is_err() {
        if tokio::time::Instant::now() > deadline {
            return Err(std::io::Error::other(format!(
                "the device was never polled{}",
                trouble(&rig.line)
            )));
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }

    let stop = Arc::new(AtomicBool::new(false));
    let writes = Arc::new(AtomicU64::new(0));
    let write_errors = Arc::new(AtomicU64::new(0));
    let mut writer = Client::connect(addr).await?;
    let writer = tokio::spawn({
        let (stop, writes, errors) = (
            Arc::clone(&stop),
            Arc::clone(&writes),
            Arc::clone(&write_errors),
        );
        async move {
            let mut value = 0u16;
            while !stop.load(Ordering::Relaxed) {
                value = value.wrapping_add(1);
                match writer.write_one(UNIT, WRITTEN, value).await {
                    Ok(()) => writes.fetch_add(1, Ordering::Relaxed),
                    // An exception is an answer: the loop goes on.
                    Err(_) => errors.fetch_add(1, Ordering::Relaxed),
                };
            }
        }
    });
    let reads = Arc::new(AtomicU64::new(0));
    let read_errors = Arc::new(AtomicU64::new(0));
    let mut reader = Client::connect(addr).await?;
    let reader = tokio::spawn({
        let (stop, reads, errors) = (
            Arc::clone(&stop),
            Arc::clone(&reads),
            Arc::clone(&read_errors),
        );
        async move {
            while !stop.load(Ordering::Relaxed) {
                match reader.read_one(UNIT, ON_DEMAND).await {
                    Ok(_) => reads.fetch_add(1, Ordering::Relaxed),
                    Err(_) => errors.fetch_add(1, Ordering::Relaxed),
                };
            }
        }
    });
    let image = rig.image.clone();
    let watcher = tokio::spawn({
        let stop = Arc::clone(&stop);
        async move {
            let mut oldest = Duration::ZERO;
            while !stop.load(Ordering::Relaxed) {
                let now = SystemTime::now();
                for slot in image.snapshot(UNIT, Table::HoldingRegisters) {
                    if slot.address < COUNT {
                        let age = now.duration_since(slot.updated).unwrap_or_default();
                        oldest = oldest.max(age);
                    }
                }
                tokio::time::sleep(AGE_SAMPLE).await;
            }
            oldest
        }
    });

    let (mut cached_reads, mut cached_failed) = (0u64, 0u64);
    let end = tokio::time::Instant::now() + plan.closed_window;
    while tokio::time::Instant::now() < end {
        cached_reads += 1;
        match cached.read_one(UNIT, 0).await {
            Ok(_) => {}
            Err(e) if e.kind() == std::io::ErrorKind::Other => cached_failed += 1,
            // The connection is gone: the rest of the window counts as failed.
            Err(e) => return Err(e),
        }
        tokio::time::sleep(CACHED_PAUSE).await;
    }
    stop.store(true, Ordering::Relaxed);
    let oldest = watcher.await.map_err(std::io::Error::other)?;
    // Each client ends after its current request (answered within the reply monitoring time).
    let _ = tokio::time::timeout(Duration::from_secs(5), writer).await;
    let _ = tokio::time::timeout(Duration::from_secs(5), reader).await;

    let status = rig.line.status();
    let cycle = status
        .devices
        .first()
        .and_then(|d| d.cycles.first().cloned())
        .ok_or_else(|| std::io::Error::other("the device has no poll cycle in its status"))?;
    let trouble = trouble(&rig.line);
    drop(rig);

    let window = plan.closed_window.as_secs_f64();
    let (writes, write_errors) = (
        writes.load(Ordering::Relaxed),
        write_errors.load(Ordering::Relaxed),
    );
    let (reads, read_errors) = (
        reads.load(Ordering::Relaxed),
        read_errors.load(Ordering::Relaxed),
    );
    let load = format!(
        "{window:.0} s at {BAUD} Bd, registers 0..{} polled every {}: {writes} FC 06 writes \
         ({write_errors} failed) and {reads} on-demand reads ({read_errors} failed) in closed \
         loops{trouble}",
        COUNT - 1,
        ms(PERIOD),
    );
    let success = if cached_reads == 0 {
        f64::NAN
    } else {
        (cached_reads - cached_failed) as f64 / cached_reads as f64
    };
    let achieved_max = cycle.achieved_max.unwrap_or(Duration::MAX);
    let ratio = |d: Duration| d.as_secs_f64() / cycle.bound.as_secs_f64();
    Ok(vec![
        Row {
            name: "closed loop: cached reads answered".into(),
            measured: format!("{:.1} %", success * 100.0),
            reference: format!("of {cached_reads}"),
            score: success,
            target: Target::at_least(1.0),
            note: format!(
                "{cached_failed} of {cached_reads} cached FC 03 reads (one every {}) failed; \
                 {load}",
                ms(CACHED_PAUSE)
            ),
        },
        Row {
            name: "closed loop: oldest cached value / the group's bound".into(),
            measured: ms(oldest),
            reference: ms(cycle.bound),
            score: ratio(oldest),
            target: Target::at_most(1.0),
            note: format!(
                "the oldest read time of registers 0..{} in the image, sampled every {}; the \
                 bound is the longest cycle the line's fairness rule allows the group",
                COUNT - 1,
                ms(AGE_SAMPLE)
            ),
        },
        Row {
            name: "closed loop: achieved poll cycle (longest) / planned".into(),
            measured: ms(achieved_max),
            reference: ms(cycle.planned),
            score: achieved_max.as_secs_f64() / cycle.planned.as_secs_f64(),
            // Within the bound: the bound as a factor of the planned period.
            target: Target::at_most(cycle.bound.as_secs_f64() / cycle.planned.as_secs_f64()),
            note: format!(
                "planned {}, last achieved {}, longest achieved {} (since the line started), \
                 bound {} (the target: bound / planned)",
                ms(cycle.planned),
                cycle.achieved.map_or_else(|| "-".into(), ms),
                ms(achieved_max),
                ms(cycle.bound)
            ),
        },
    ])
}
