//! Instruments on both ends of a paced line.
//!
//! ```text
//!  master line ═ pty ═ MasterTap ─ paced link (in-process a ⇄ b) ─ device_relay ─ simulated device
//! ```
//!
//! - [`MasterTap`] sits between the gateway's line and the paced link: the line opens the slave end
//!   of a pty pair of its own, as it would open a real serial port, and the tap relays its master
//!   end to the link's `a` end. It sees the moment the master wrote a request and the moment a
//!   response's last byte was handed to the master, so it measures what the master itself does:
//!   the silence it leaves after a response before its next request (which must be at least t3.5),
//!   and the time a request spent on the serial side (wire, device, link) until its answer was
//!   back. The tap hands the master each answer whole, at the moment its last byte arrived (the
//!   length comes from the function code and byte count), as a UART's receive FIFO delivers in
//!   bursts; the master ends a reply by its length, not by a gap.
//! - [`device_relay`] sits between the link's `b` end and the simulated device (an in-process
//!   stream): it hands the device each request whole, and the time from there to the first byte
//!   of the answer is the device's turnaround.
//!
//! The link's ends are in-process streams ([`gateway::paced::paced_duplex`]), not two more pty
//! pairs: a pty hop is a kernel worker and a reader to wake, which on the shared machine cost
//! tenths of a millisecond each way that belong to neither the gateway nor the wire. The pty
//! between the line and the tap is the gateway's own port and stays.
//!
//! The tap's own latency (a pty read and write, tens of microseconds) only ever lengthens the
//! silences it measures, so a master that leaves too short a gap cannot look correct by it, except
//! by less than that latency.

use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use proto_core::modbus::rtu::{self, FrameLen};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, DuplexStream};
use tokio_serial::SerialStream;
use tokio_util::sync::CancellationToken;

/// How long a tap waits for the rest of a frame it cannot see the end of yet (far longer than
/// any stall of the shared machine; only a truncated frame waits this long).
const FLUSH_AFTER: Duration = Duration::from_secs(1);

/// One request and its answer as the master saw them.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Exchange {
    /// When the master wrote the request.
    pub(crate) sent: Instant,
    /// The slave address it was sent to (its first byte).
    pub(crate) slave: Option<u8>,
    /// When the last byte of the answer reached the master, if one came.
    pub(crate) answered: Option<Instant>,
}

/// What the master tap has seen.
#[derive(Debug, Default)]
pub(crate) struct MasterLog {
    /// Every request frame, in order.
    pub(crate) exchanges: Vec<Exchange>,
    /// Request frames that started less than t3.5 after the end of the previous frame.
    pub(crate) violations: u64,
    /// The master's silence between the end of an answer and its next request.
    pub(crate) gaps: Vec<Duration>,
    /// The end of the last request on the wire (its write plus its characters).
    request_end: Option<Instant>,
    /// Whether the line's last frame was an answer (else a request).
    last_was_answer: bool,
}

/// The counters of a [`MasterTap`], shared with the benchmark.
pub(crate) type SharedLog = Arc<Mutex<MasterLog>>;

/// Locks a log (a poisoned lock still holds valid counters).
pub(crate) fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// The relay between the master's pty and the paced link's `a` end.
#[derive(Debug)]
pub(crate) struct MasterTap {
    /// The path the master line opens.
    pub(crate) path: String,
    /// What was seen.
    pub(crate) log: SharedLog,
}

// === impl MasterTap ===

impl MasterTap {
    /// Relays between a new pty pair and the link's `a` end until `shutdown`. `char_time` is the
    /// line's character time and `t35` its end-of-frame silence.
    pub(crate) fn spawn<L>(
        link: L,
        char_time: Duration,
        t35: Duration,
        shutdown: CancellationToken,
    ) -> std::io::Result<Self>
    where
        L: AsyncRead + AsyncWrite + Send + 'static,
    {
        let (master, slave) = SerialStream::pair().map_err(std::io::Error::from)?;
        let path = tokio_serial::SerialPort::name(&slave)
            .ok_or_else(|| std::io::Error::other("the pty has no path"))?;
        let log: SharedLog = Arc::default();
        let (mut from_master, mut to_master) = tokio::io::split(master);
        let (mut from_link, mut to_link) = tokio::io::split(link);
        let up_log = Arc::clone(&log);
        let down_log = Arc::clone(&log);
        let up_stop = shutdown.clone();
        tokio::spawn(async move {
            let _keep = slave;
            let mut buf = [0u8; 512];
            loop {
                let n = tokio::select! {
                    () = up_stop.cancelled() => return,
                    read = from_master.read(&mut buf) => match read { Ok(0) | Err(_) => return, Ok(n) => n },
                };
                let now = Instant::now();
                let first = buf.first().copied().filter(|_| n > 0);
                lock(&up_log).request_bytes(now, n, first, char_time, t35);
                if to_link
                    .write_all(buf.get(..n).unwrap_or_default())
                    .await
                    .is_err()
                {
                    return;
                }
            }
        });
        tokio::spawn(async move {
            let mut buf = [0u8; 512];
            let mut pending: Vec<u8> = Vec::new();
            while let Some(answer) = next_frame(
                &mut from_link,
                &mut buf,
                &mut pending,
                &shutdown,
                rtu::expected_response_len,
            )
            .await
            {
                if to_master.write_all(&answer).await.is_err() {
                    return;
                }
                lock(&down_log).answer_bytes(Instant::now());
            }
        });
        Ok(Self { path, log })
    }
}

// === impl MasterLog ===

impl MasterLog {
    /// `n` request bytes written by the master at `now`, the first of them `first`.
    fn request_bytes(
        &mut self,
        now: Instant,
        n: usize,
        first: Option<u8>,
        char_time: Duration,
        t35: Duration,
    ) {
        let on_wire = char_time * u32::try_from(n).unwrap_or(u32::MAX);
        // Bytes that come while the request is still on the wire are the rest of it.
        if !self.last_was_answer && self.request_end.is_some_and(|end| now < end) {
            self.request_end = self.request_end.map(|end| end + on_wire);
            return;
        }
        let previous_end = if self.last_was_answer {
            self.exchanges.last().and_then(|e| e.answered)
        } else {
            self.request_end
        };
        if let Some(end) = previous_end {
            let gap = now.saturating_duration_since(end);
            if gap < t35 {
                self.violations += 1;
            }
            if self.last_was_answer {
                self.gaps.push(gap);
            }
        }
        self.exchanges.push(Exchange {
            sent: now,
            slave: first,
            answered: None,
        });
        self.request_end = Some(now + on_wire);
        self.last_was_answer = false;
    }

    /// Answer bytes handed to the master at `now`.
    fn answer_bytes(&mut self, now: Instant) {
        if let Some(last) = self.exchanges.last_mut() {
            last.answered = Some(now);
        }
        self.last_was_answer = true;
    }
}

/// What the device tap has seen.
#[derive(Debug, Default)]
pub(crate) struct DeviceLog {
    /// Request end to answer start, one per answer.
    pub(crate) turnarounds: Vec<Duration>,
    /// When the last request bytes arrived, until the answer starts.
    pending: Option<Instant>,
}

/// Relays between the device's end of a link and an in-process stream the simulated device serves
/// on: hands the device each request whole, as the master tap hands the master each answer, and
/// records the device's turnaround.
pub(crate) fn device_relay<L>(
    link: L,
    shutdown: CancellationToken,
) -> (DuplexStream, Arc<Mutex<DeviceLog>>)
where
    L: AsyncRead + AsyncWrite + Send + 'static,
{
    let (device, ours) = tokio::io::duplex(4096);
    let log: Arc<Mutex<DeviceLog>> = Arc::default();
    let (mut from_link, mut to_link) = tokio::io::split(link);
    let (mut from_device, mut to_device) = tokio::io::split(ours);
    let down_log = Arc::clone(&log);
    let down_stop = shutdown.clone();
    tokio::spawn(async move {
        let mut buf = [0u8; 512];
        let mut pending: Vec<u8> = Vec::new();
        while let Some(request) = next_frame(
            &mut from_link,
            &mut buf,
            &mut pending,
            &down_stop,
            rtu::expected_request_len,
        )
        .await
        {
            if to_device.write_all(&request).await.is_err() {
                return;
            }
            lock(&down_log).pending = Some(Instant::now());
        }
    });
    let up_log = Arc::clone(&log);
    tokio::spawn(async move {
        let mut buf = [0u8; 512];
        loop {
            let n = tokio::select! {
                () = shutdown.cancelled() => return,
                read = from_device.read(&mut buf) => match read { Ok(0) | Err(_) => return, Ok(n) => n },
            };
            {
                let mut log = lock(&up_log);
                if let Some(at) = log.pending.take() {
                    log.turnarounds.push(at.elapsed());
                }
            }
            if to_link
                .write_all(buf.get(..n).unwrap_or_default())
                .await
                .is_err()
            {
                return;
            }
        }
    });
    (device, log)
}

/// The next whole RTU frame read from `from`, its length told by `frame_len` (the function code
/// and byte count); bytes of an unfinished frame are handed on after a silence of `FLUSH_AFTER`
/// all the same. `None` when the stream ends or fails, or `stop` fires.
async fn next_frame<R: AsyncRead + Unpin>(
    from: &mut R,
    buf: &mut [u8],
    pending: &mut Vec<u8>,
    stop: &CancellationToken,
    frame_len: fn(&[u8]) -> FrameLen,
) -> Option<Vec<u8>> {
    loop {
        let limit = if pending.is_empty() {
            Duration::MAX
        } else {
            FLUSH_AFTER
        };
        let read = tokio::select! {
            () = stop.cancelled() => return None,
            read = tokio::time::timeout(limit, from.read(buf)) => read,
        };
        let whole = match read {
            Ok(Ok(0) | Err(_)) => return None,
            Ok(Ok(n)) => {
                pending.extend_from_slice(buf.get(..n).unwrap_or_default());
                match frame_len(pending) {
                    FrameLen::Complete(len) => len,
                    FrameLen::NeedMore(_) => continue,
                    FrameLen::Unknown => pending.len(),
                }
            }
            Err(_) => pending.len(),
        };
        return Some(pending.drain(..whole.min(pending.len())).collect());
    }
}
