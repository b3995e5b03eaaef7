//! One direction of a paced line: read from one end, deliver to the other on schedule.
//!
//! Two halves run concurrently in one future:
//! - the reader stamps every chunk with the instant it was read and passes it on (a bounded
//!   channel: when the writer's queue is full the reader stops reading, so the sender's writes
//!   block as a full UART buffer would block them);
//! - the writer schedules each byte ([`Schedule`]), sleeps until the first one is due and then
//!   writes every byte whose delivery time has passed, in one write. It sleeps on a
//!   [`LineTimer`] (a timerfd on Linux), which wakes within tens of microseconds of the deadline
//!   when a core is free, so each byte goes out on its own at its time and a gap inside a frame
//!   is one character time plus that jitter (tokio's millisecond timer left gaps longer than
//!   t3.5 inside a frame at high baud rates). When the writer wakes late (a busy machine), the
//!   bytes due by then go out together; none goes out before its time, because the writer
//!   compares with the clock itself, not with the timer.

use std::collections::VecDeque;
use std::sync::Arc;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::mpsc;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use super::schedule::Schedule;
use super::{Direction, DirectionCounters, FaultAction, FaultHook, PacedSettings};
use crate::timer::LineTimer;

/// The largest chunk read at once.
const READ_CHUNK: usize = 1024;
/// Chunks between reader and writer.
const CHANNEL_CHUNKS: usize = 16;
/// Bytes the writer queues before the reader stops: a generous UART transmit buffer.
const MAX_PENDING: usize = 16 * 1024;

/// The buffer of each in-process stream pair of [`super::paced_duplex`]: about a pty's.
pub(crate) const DUPLEX_BUFFER: usize = 4096;

/// What the reader hands to the writer: when the bytes were read, and the bytes.
type Chunk = (Instant, Vec<u8>);

/// Everything one direction needs besides its two ends.
#[derive(Clone)]
pub(crate) struct RelayParts {
    pub(crate) settings: PacedSettings,
    pub(crate) direction: Direction,
    pub(crate) faults: Option<Arc<dyn FaultHook>>,
    pub(crate) counters: Arc<DirectionCounters>,
    pub(crate) shutdown: CancellationToken,
}

/// Relays `src` to `dst` paced by the settings' character time until `shutdown`, an error, or the
/// end of `src` (then the bytes still queued are delivered on time and `dst` is shut down).
pub(crate) async fn pace<R, W>(src: R, dst: W, parts: RelayParts) -> std::io::Result<()>
where
    R: AsyncRead + Unpin,
    W: AsyncWrite + Unpin,
{
    let (tx, rx) = mpsc::channel(CHANNEL_CHUNKS);
    let reader = read_side(src, tx, parts.clone());
    let writer = write_side(dst, rx, parts);
    tokio::try_join!(reader, writer).map(|_| ())
}

/// Reads chunks and stamps them with their arrival.
async fn read_side<R: AsyncRead + Unpin>(
    mut src: R,
    tx: mpsc::Sender<Chunk>,
    parts: RelayParts,
) -> std::io::Result<()> {
    let mut buf = vec![0u8; READ_CHUNK];
    loop {
        let n = tokio::select! {
            () = parts.shutdown.cancelled() => return Ok(()),
            read = src.read(&mut buf) => read?,
        };
        if n == 0 {
            // End of stream: dropping `tx` tells the writer to finish.
            return Ok(());
        }
        let arrival = Instant::now();
        parts.counters.add_received(n);
        let chunk = buf.get(..n).unwrap_or_default().to_vec();
        tokio::select! {
            () = parts.shutdown.cancelled() => return Ok(()),
            sent = tx.send((arrival, chunk)) => {
                if sent.is_err() {
                    // The writer stopped (its error is the one reported).
                    return Ok(());
                }
            }
        }
    }
}

/// Queues the bytes on their schedule and writes them when due.
async fn write_side<W: AsyncWrite + Unpin>(
    mut dst: W,
    mut rx: mpsc::Receiver<Chunk>,
    parts: RelayParts,
) -> std::io::Result<()> {
    let mut schedule = Schedule::new(parts.settings);
    let mut pending: VecDeque<(Instant, u8)> = VecDeque::new();
    let mut out = Vec::with_capacity(READ_CHUNK);
    let mut index: u64 = 0;
    let mut source_open = true;
    let mut timer = LineTimer::new();
    loop {
        let head = pending.front().map(|&(due, _)| due);
        if !source_open && head.is_none() {
            return dst.shutdown().await;
        }
        tokio::select! {
            biased;
            () = parts.shutdown.cancelled() => return Ok(()),
            () = timer.sleep_until_opt(head), if head.is_some() => {
                collect_due(&mut pending, &mut out, &mut index, &parts);
                if !out.is_empty() {
                    // No flush: neither a pty nor an in-process stream buffers in user space,
                    // and a serial stream's flush is tcdrain(3), a blocking call on a runtime
                    // thread (once per delivered byte here).
                    dst.write_all(&out).await?;
                    parts.counters.add_delivered(out.len());
                }
            }
            chunk = rx.recv(), if source_open && pending.len() < MAX_PENDING => match chunk {
                Some((arrival, bytes)) => {
                    pending.extend(bytes.into_iter().map(|b| (schedule.next(arrival), b)));
                }
                None => source_open = false,
            },
        }
    }
}

/// Moves every byte whose delivery time has passed into `out` (after the fault hook), and records
/// how late the batch is.
fn collect_due(
    pending: &mut VecDeque<(Instant, u8)>,
    out: &mut Vec<u8>,
    index: &mut u64,
    parts: &RelayParts,
) {
    out.clear();
    let now = Instant::now();
    let mut first_due = None;
    while let Some(&(due, byte)) = pending.front() {
        if due > now {
            break;
        }
        pending.pop_front();
        first_due.get_or_insert(due);
        let action = parts.faults.as_ref().map_or(FaultAction::Deliver, |hook| {
            hook.on_byte(parts.direction, *index, byte)
        });
        *index += 1;
        match action {
            FaultAction::Deliver => out.push(byte),
            FaultAction::Drop => parts.counters.add_dropped(),
            FaultAction::Replace(other) => {
                parts.counters.add_corrupted();
                out.push(other);
            }
        }
    }
    if let Some(due) = first_due {
        parts
            .counters
            .record_batch(now.saturating_duration_since(due));
    }
}
