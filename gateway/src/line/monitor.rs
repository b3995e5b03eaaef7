//! The frame monitor of a line: every frame the line sent or received, with its times, its bytes
//! and the line errors inside it, in a bounded ring.
//!
//! The port layer records ([`Recorder`], owned by the line's task): each transmission is a frame;
//! received bytes are a frame until the protocol's end mark (the engine's
//! [`Framing`], cut by [`FrameCutter`]), a transmission, or a silence of the framing's gap (the
//! cutter's deadline, which the line's one timer waits for with the engine's). A
//! closed frame goes into the ring of the line's [`FrameMonitor`], which readers share. Nothing
//! is formatted until someone reads: the verdict and summary ([`FrameMonitor::describe`]) are
//! made from the bytes on request. A full ring reuses the buffers of the frame it lets go, so a
//! running line allocates nothing per frame once the ring is full; a live follower
//! ([`FrameMonitor::subscribe`]) gets a copy of each frame only while it listens.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, SystemTime};

use prometheus::IntCounter;
use proto_core::monitor::{describe, Description, Direction, FrameCutter, FrameKind, Framing};
use proto_core::serial_marks::LineError;
use tokio::sync::broadcast;
use tokio::time::Instant;
use tokio_util::sync::{CancellationToken, WaitForCancellationFutureOwned};

use super::driver::Clock;
use super::metrics::{LineFamilies, MonitorDrop};

/// Frames a line's monitor keeps by default (`monitor_frames`).
pub const DEFAULT_MONITOR_FRAMES: usize = crate::config::DEFAULT_MONITOR_FRAMES as usize;
/// The most frames a line's monitor may keep.
pub const MAX_MONITOR_FRAMES: usize = crate::config::MAX_MONITOR_FRAMES as usize;
/// A received frame longer than this is cut (a line without silence would grow it forever).
pub const MAX_FRAME_BYTES: usize = 4096;
/// Frames a live follower may fall behind before it misses some (counted as `lagged`).
const LIVE_DEPTH: usize = 1024;

/// A line error inside a frame: before the byte at `offset`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameLineError {
    /// Data bytes of the frame before the error.
    pub offset: usize,
    /// What the UART reported.
    pub error: LineError,
}

/// One frame as the monitor keeps it.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Sequence number on the line, from 1, without gaps (a frame let go keeps its number).
    pub seq: u64,
    /// Received or sent.
    pub direction: Direction,
    /// Wall-clock time of the first byte (received: when it arrived; sent: when it was written).
    pub first: SystemTime,
    /// Wall-clock time of the last byte (sent: its estimated end on the wire).
    pub last: SystemTime,
    /// The first byte on the line's monotonic clock (since the line started): for ordering.
    pub first_mono: Duration,
    /// The last byte on the line's monotonic clock.
    pub last_mono: Duration,
    /// The frame's bytes (data only: a faulty character is not in them, see `errors`).
    pub bytes: Vec<u8>,
    /// Parity, framing, overrun errors and BREAKs inside the frame.
    pub errors: Vec<FrameLineError>,
}

impl Frame {
    fn empty() -> Self {
        Self {
            seq: 0,
            direction: Direction::Rx,
            first: SystemTime::UNIX_EPOCH,
            last: SystemTime::UNIX_EPOCH,
            first_mono: Duration::ZERO,
            last_mono: Duration::ZERO,
            bytes: Vec::new(),
            errors: Vec::new(),
        }
    }
}

/// The ring and what a reader needs to continue it.
#[derive(Debug)]
struct Ring {
    frames: VecDeque<Frame>,
    next_seq: u64,
}

impl Ring {
    /// The frames with a sequence number above `since`, oldest first.
    fn above(&self, since: u64) -> Vec<Frame> {
        self.frames
            .iter()
            .filter(|f| f.seq > since)
            .cloned()
            .collect()
    }
}

/// A line's frame monitor: the ring of its last frames, shared by the line's task (which fills
/// it) and its readers (REST, zenoh, captures).
#[derive(Debug)]
pub struct FrameMonitor {
    line: String,
    kind: FrameKind,
    capacity: usize,
    ring: Mutex<Ring>,
    live: broadcast::Sender<Arc<Frame>>,
    overwritten: AtomicU64,
    lagged: AtomicU64,
    /// `gateway_monitor_dropped_total{line, reason}` (overwritten, lagged), when counted.
    counters: Option<(IntCounter, IntCounter)>,
    /// Cancelled when the line's task ends (no more frames come).
    ended: CancellationToken,
    /// The line's two directions: received and sent (`rx`, `tx`), or the two received sides of
    /// a line with two receive-only ports (`a`, `b`).
    directions: [Direction; 2],
}

// === impl FrameMonitor ===

impl FrameMonitor {
    /// A monitor of `capacity` frames (1 at least) for line `line` of `kind`, counting its drops
    /// in `metrics`.
    pub(crate) fn new(
        line: &str,
        kind: FrameKind,
        capacity: usize,
        metrics: Option<&LineFamilies>,
    ) -> Self {
        let capacity = capacity.clamp(1, MAX_MONITOR_FRAMES);
        let (live, _) = broadcast::channel(LIVE_DEPTH);
        Self {
            line: line.to_owned(),
            kind,
            capacity,
            ring: Mutex::new(Ring {
                frames: VecDeque::with_capacity(capacity),
                next_seq: 1,
            }),
            live,
            overwritten: AtomicU64::new(0),
            lagged: AtomicU64::new(0),
            counters: metrics.map(|m| {
                (
                    m.monitor_dropped(line, MonitorDrop::Overwritten),
                    m.monitor_dropped(line, MonitorDrop::Lagged),
                )
            }),
            ended: CancellationToken::new(),
            directions: [Direction::Rx, Direction::Tx],
        }
    }

    fn lock(&self) -> MutexGuard<'_, Ring> {
        self.ring.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The monitor of a line whose frames go the two `directions` (see [`Self::directions`]).
    #[must_use]
    pub fn with_directions(mut self, directions: [Direction; 2]) -> Self {
        self.directions = directions;
        self
    }

    /// The line's two directions: `[Rx, Tx]`, or `[A, B]` for a line with two receive-only
    /// ports (a capture has one interface for each).
    pub fn directions(&self) -> [Direction; 2] {
        self.directions
    }

    /// The line's name.
    pub fn line(&self) -> &str {
        &self.line
    }

    /// How the line's frames are described.
    pub fn kind(&self) -> FrameKind {
        self.kind
    }

    /// How many frames the ring keeps.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// A frame's verdict and summary, made now.
    pub fn describe(&self, frame: &Frame) -> Description {
        describe(self.kind, frame.direction, &frame.bytes, frame.errors.len())
    }

    /// The frames in the ring with a sequence number above `since` (every frame: `0`), oldest
    /// first, and the sequence number the next frame will have.
    pub fn frames_since(&self, since: u64) -> (Vec<Frame>, u64) {
        let ring = self.lock();
        (ring.above(since), ring.next_seq)
    }

    /// The frames above `since` and, from the same instant on, every new frame: nothing is
    /// missed or repeated between the two (unless the follower falls behind, see
    /// [`Self::count_lagged`]).
    pub fn follow(&self, since: u64) -> (Vec<Frame>, broadcast::Receiver<Arc<Frame>>) {
        let ring = self.lock();
        (ring.above(since), self.live.subscribe())
    }

    /// Every new frame from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<Arc<Frame>> {
        let _ring = self.lock();
        self.live.subscribe()
    }

    /// Resolves when the line's task has ended: no more frames come (a follower stops).
    pub fn ended(&self) -> WaitForCancellationFutureOwned {
        self.ended.clone().cancelled_owned()
    }

    /// A live follower fell behind and missed `n` frames.
    pub fn count_lagged(&self, n: u64) {
        self.lagged.fetch_add(n, Ordering::Relaxed);
        if let Some((_, lagged)) = &self.counters {
            lagged.inc_by(n);
        }
    }

    /// Frames pushed out of the full ring, and frames live followers missed, since the start.
    pub fn dropped(&self) -> (u64, u64) {
        (
            self.overwritten.load(Ordering::Relaxed),
            self.lagged.load(Ordering::Relaxed),
        )
    }

    /// Takes a closed frame into the ring; `bytes` and `errors` come back empty (with the
    /// buffers of the frame let go, when the ring was full).
    fn push(
        &self,
        direction: Direction,
        times: FrameTimes,
        bytes: &mut Vec<u8>,
        errors: &mut Vec<FrameLineError>,
    ) {
        let mut ring = self.lock();
        let mut frame = if ring.frames.len() >= self.capacity {
            self.overwritten.fetch_add(1, Ordering::Relaxed);
            if let Some((overwritten, _)) = &self.counters {
                overwritten.inc();
            }
            ring.frames.pop_front().unwrap_or_else(Frame::empty)
        } else {
            Frame::empty()
        };
        std::mem::swap(&mut frame.bytes, bytes);
        std::mem::swap(&mut frame.errors, errors);
        bytes.clear();
        errors.clear();
        frame.seq = ring.next_seq;
        ring.next_seq += 1;
        frame.direction = direction;
        frame.first = times.first;
        frame.last = times.last;
        frame.first_mono = times.first_mono;
        frame.last_mono = times.last_mono;
        if self.live.receiver_count() > 0 {
            // Only a follower costs a copy; a closed follower is nobody's loss.
            let _ = self.live.send(Arc::new(frame.clone()));
        }
        ring.frames.push_back(frame);
    }
}

/// A frame's times on both clocks.
#[derive(Clone, Copy, Debug)]
struct FrameTimes {
    first: SystemTime,
    last: SystemTime,
    first_mono: Duration,
    last_mono: Duration,
}

/// The received frame in progress.
#[derive(Clone, Copy, Debug)]
struct Open {
    first: Instant,
    last: Instant,
}

/// The port layer's side of the monitor: turns the line's bytes into frames (owned by the line's
/// task, fed where bytes pass: `PortTask::receive` and the transmit loop).
#[derive(Debug)]
pub(crate) struct Recorder {
    monitor: Arc<FrameMonitor>,
    clock: Clock,
    /// Where a received frame ends: end marks, and the silence of the framing's gap.
    cutter: FrameCutter,
    /// Silence that ends a received frame.
    gap: Duration,
    /// Time of one character on the line (to date the bytes of one read).
    char_time: Duration,
    open: Option<Open>,
    /// The estimated end of the last transmission: a received frame is not dated before it.
    tx_end: Option<Instant>,
    bytes: Vec<u8>,
    errors: Vec<FrameLineError>,
    /// The direction of the frames it receives (`Rx`, or `A`/`B` on a two-port line).
    rx: Direction,
    /// The byte of the last received frame, if it was one byte long and ended in the last
    /// [`Self::received`] (a control character for the other port, see [`Self::take_control`]).
    control: Option<u8>,
}

impl Drop for Recorder {
    fn drop(&mut self) {
        self.close();
        self.monitor.ended.cancel();
    }
}

// === impl Recorder ===

impl Recorder {
    /// Records into `monitor` with the engine's `framing`, on a line whose characters take
    /// `char_time` (the default gap: 3.5 of them).
    pub(crate) fn new(
        monitor: Arc<FrameMonitor>,
        clock: Clock,
        framing: Framing,
        char_time: Duration,
    ) -> Self {
        let gap = framing.silence(char_time);
        Self {
            monitor,
            clock,
            cutter: FrameCutter::new(framing.kind, gap),
            gap,
            char_time,
            open: None,
            tx_end: None,
            bytes: Vec::new(),
            errors: Vec::new(),
            rx: Direction::Rx,
            control: None,
        }
    }

    /// Records received frames as going `direction` (a port of a two-port line).
    #[must_use]
    pub(crate) fn receiving_as(mut self, direction: Direction) -> Self {
        self.rx = direction;
        self
    }

    /// The byte of a one-byte frame the last [`Self::received`] ended, once.
    pub(crate) fn take_control(&mut self) -> Option<u8> {
        self.control.take()
    }

    /// The partner on the line's other port sent `frame`: to this port's framing it is what the
    /// gateway's own transmission would be (3964(R): a DLE answers STX, a telegram follows).
    pub(crate) fn peer_sent(&mut self, frame: &[u8]) {
        self.cutter.sent(frame);
    }

    /// The port was (re)opened: a frame cut off by the loss of the port ends.
    pub(crate) fn opened(&mut self) {
        self.close();
        self.cutter = FrameCutter::new(self.monitor.kind, self.gap);
    }

    /// When the received frame in progress ends by silence.
    pub(crate) fn deadline(&self) -> Option<Instant> {
        self.cutter.deadline().map(|d| self.clock.to_tokio(d))
    }

    /// Ends the received frame in progress if its silence has passed at `now`.
    pub(crate) fn expire(&mut self, now: Instant) {
        if self.cutter.expire(self.clock.to_engine(now)) {
            self.close();
        }
    }

    /// Data bytes read at `now` (the last of them arrived at `now`, the ones before it a
    /// character time apart, but not before the end of the last transmission: a port that
    /// delivers faster than the wire, such as a pty, does not date an answer before its request).
    pub(crate) fn received(&mut self, now: Instant, data: &[u8]) {
        self.expire(now);
        self.control = None;
        let n = data.len();
        let floor = self.tx_end.map(|end| end.min(now));
        for (i, &byte) in data.iter().enumerate() {
            let back = self
                .char_time
                .saturating_mul(u32::try_from(n - 1 - i).unwrap_or(0));
            let at = now.checked_sub(back).unwrap_or(now);
            let at = floor.map_or(at, |floor| at.max(floor));
            let open = self.open.get_or_insert(Open {
                first: at,
                last: at,
            });
            open.last = at.max(open.first);
            self.bytes.push(byte);
            let ends = self.cutter.push(self.clock.to_engine(open.last), byte);
            if ends || self.bytes.len() >= MAX_FRAME_BYTES {
                self.close();
            }
        }
    }

    /// A line error at `now`, between the bytes before and after it.
    pub(crate) fn line_error(&mut self, now: Instant, error: LineError) {
        self.expire(now);
        let open = self.open.get_or_insert(Open {
            first: now,
            last: now,
        });
        open.last = now;
        self.cutter.line_error(self.clock.to_engine(now));
        self.errors.push(FrameLineError {
            offset: self.bytes.len(),
            error,
        });
    }

    /// `frame` was written at `written` and leaves the line at `end`: a received frame in
    /// progress ends, the transmission is a frame.
    pub(crate) fn sent(&mut self, written: Instant, end: Instant, frame: &[u8]) {
        self.close();
        self.tx_end = Some(end);
        self.cutter.sent(frame);
        self.bytes.extend_from_slice(frame);
        let times = self.times(written, end);
        self.monitor
            .push(Direction::Tx, times, &mut self.bytes, &mut self.errors);
    }

    /// Ends the received frame in progress, if any.
    fn close(&mut self) {
        let Some(open) = self.open.take() else { return };
        self.cutter.reset();
        self.control = match self.bytes[..] {
            [byte] => Some(byte),
            _ => None,
        };
        let times = self.times(open.first, open.last);
        self.monitor
            .push(self.rx, times, &mut self.bytes, &mut self.errors);
    }

    fn times(&self, first: Instant, last: Instant) -> FrameTimes {
        let now = Instant::now();
        let wall = SystemTime::now();
        let at = |t: Instant| {
            if t >= now {
                wall + (t - now)
            } else {
                wall.checked_sub(now - t).unwrap_or(wall)
            }
        };
        let base = self.clock.base();
        FrameTimes {
            first: at(first),
            last: at(last),
            first_mono: first.saturating_duration_since(base),
            last_mono: last.saturating_duration_since(base),
        }
    }
}

#[cfg(test)]
mod tests {
    use proto_core::monitor::{Role, Verdict};

    use super::*;

    fn recorder(capacity: usize, kind: FrameKind) -> (Arc<FrameMonitor>, Recorder) {
        let monitor = Arc::new(FrameMonitor::new("line", kind, capacity, None));
        let framing = Framing { kind, gap: None };
        let recorder = Recorder::new(
            Arc::clone(&monitor),
            Clock::start(),
            framing,
            Duration::from_micros(573),
        );
        (monitor, recorder)
    }

    #[tokio::test(start_paused = true)]
    async fn the_ring_is_bounded_and_counts_what_it_lets_go() {
        let (monitor, mut rec) = recorder(3, FrameKind::Raw);
        for n in 0..5u8 {
            let now = Instant::now();
            rec.sent(now, now, &[n, n]);
        }
        let (frames, next) = monitor.frames_since(0);
        assert_eq!(next, 6);
        assert_eq!(
            frames
                .iter()
                .map(|f| (f.seq, f.bytes[0]))
                .collect::<Vec<_>>(),
            [(3, 2), (4, 3), (5, 4)]
        );
        assert_eq!(monitor.dropped(), (2, 0));
        // The buffers of the frames let go are reused: the recorder's spare is empty.
        assert!(rec.bytes.is_empty() && rec.errors.is_empty());
    }

    #[tokio::test(start_paused = true)]
    async fn since_pages_through_the_ring() {
        let (monitor, mut rec) = recorder(10, FrameKind::Raw);
        for n in 0..4u8 {
            let now = Instant::now();
            rec.sent(now, now, &[n]);
        }
        let (page, next) = monitor.frames_since(2);
        assert_eq!(page.iter().map(|f| f.seq).collect::<Vec<_>>(), [3, 4]);
        assert_eq!(next, 5);
        assert!(monitor.frames_since(4).0.is_empty());
        assert!(monitor.frames_since(u64::MAX).0.is_empty());
    }

    #[tokio::test(start_paused = true)]
    async fn received_bytes_end_by_silence_by_a_transmission_or_by_the_protocol() {
        let (monitor, mut rec) = recorder(16, FrameKind::ModbusRtu(Role::Master));
        tokio::time::advance(Duration::from_millis(10)).await;
        // An answer in two reads 1 ms apart (less than t3.5 = 2 ms), then silence.
        rec.received(Instant::now(), &[0x01, 0x03, 0x02]);
        tokio::time::advance(Duration::from_millis(1)).await;
        rec.received(Instant::now(), &[0x00, 0x2A, 0x39, 0x9B]);
        assert!(monitor.frames_since(0).0.is_empty(), "still open");
        let deadline = rec.deadline().expect("open frame");
        tokio::time::advance(Duration::from_millis(3)).await;
        assert!(deadline <= Instant::now());
        rec.expire(Instant::now());
        // A BREAK and a byte, then our transmission ends that frame.
        rec.line_error(Instant::now(), LineError::Break);
        rec.received(Instant::now(), &[0x00]);
        let now = Instant::now();
        rec.sent(
            now,
            now + Duration::from_millis(4),
            &[0x01, 0x03, 0, 0, 0, 1, 0x84, 0x0A],
        );

        let (frames, _) = monitor.frames_since(0);
        assert_eq!(frames.len(), 3);
        assert_eq!(frames[0].bytes, [0x01, 0x03, 0x02, 0x00, 0x2A, 0x39, 0x9B]);
        assert_eq!(frames[0].direction, Direction::Rx);
        assert_eq!(
            frames[0].last_mono - frames[0].first_mono,
            Duration::from_micros(1000 + 2 * 573),
            "the first byte of a read is dated a character time per byte before its last"
        );
        let d = monitor.describe(&frames[0]);
        assert_eq!(d.verdict, Verdict::Ok, "{}", d.summary);
        assert_eq!(
            frames[1].errors,
            [FrameLineError {
                offset: 0,
                error: LineError::Break
            }]
        );
        assert_eq!(monitor.describe(&frames[1]).verdict, Verdict::LineError);
        assert_eq!(frames[2].direction, Direction::Tx);
        assert_eq!(
            frames[2].last.duration_since(frames[2].first).ok(),
            Some(Duration::from_millis(4))
        );
        assert_eq!(
            monitor.describe(&frames[2]).summary,
            "slave 1 read holding registers start 0 quantity 1, CRC ok"
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_follower_gets_every_frame_after_the_ring_and_a_lag_is_counted() {
        let (monitor, mut rec) = recorder(4, FrameKind::Proc3964 { bcc: true });
        rec.received(Instant::now(), &[0x02]); // STX ends at once
        let (before, mut live) = monitor.follow(0);
        assert_eq!(before.len(), 1);
        let now = Instant::now();
        rec.sent(now, now, &[0x10]);
        let next = live.recv().await.expect("live frame");
        assert_eq!((next.seq, next.direction), (2, Direction::Tx));
        monitor.count_lagged(3);
        assert_eq!(monitor.dropped(), (0, 3));
    }

    #[test]
    fn a_long_frame_without_silence_is_cut() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .expect("runtime");
        rt.block_on(async {
            let (monitor, mut rec) = recorder(8, FrameKind::Raw);
            rec.received(Instant::now(), &vec![0x55; MAX_FRAME_BYTES + 10]);
            let (frames, _) = monitor.frames_since(0);
            assert_eq!(frames.len(), 1);
            assert_eq!(frames[0].bytes.len(), MAX_FRAME_BYTES);
        });
    }
}
