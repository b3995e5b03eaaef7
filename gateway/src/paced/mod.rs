//! A paced link: a virtual serial cable with the timing of a real one.
//!
//! A pty pair carries bytes as fast as they are written and ignores the baud rate (see the machine
//! notes: parity and data bits read back as none and 8). The paced link puts a relay between two
//! pty pairs that holds every byte until a UART at the configured baud rate and character frame
//! would have received it completely, in both directions independently:
//!
//! ```text
//!  gateway ── opens `a` ═ pty 1 ═ master 1 ─┐         ┌─ master 2 ═ pty 2 ═ `b` opened by ── device
//!                                          └─ relay ─┘                                        simulator
//!                                 each byte delivered at max(arrival, end of previous) + char time
//! ```
//!
//! The character time is `bits_per_char / baud` with `bits_per_char = 1 start + data bits + parity
//! bit + stop bits` (003 6.4.2.1 counts 11 bits for 8E1). The relay keeps the pty slave ends open
//! for as long as it runs, so the paths stay valid when a side closes and reopens them.
//!
//! [`paced_duplex`] paces an in-process stream pair the same way, for benchmarks without ptys.
//!
//! A [`FaultHook`] sees every byte when it is due and may drop it or replace it (a character lost
//! or corrupted on the line); the byte's time on the wire passes either way.

mod relay;
mod schedule;

use std::io;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

use tokio::task::JoinHandle;
use tokio_serial::{SerialPort, SerialStream};
use tokio_util::sync::CancellationToken;

use relay::{pace, RelayParts};

/// The character timing of a paced line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PacedSettings {
    /// Bits per second, at least 1.
    pub baud: u32,
    /// Bits a character takes on the wire: 1 start + data + parity + stop bits, at least 1.
    pub bits_per_char: u8,
}

// === impl PacedSettings ===

impl PacedSettings {
    /// Settings for `baud` and the character frame: `data_bits` (5..8), a parity bit or none,
    /// `stop_bits` (1 or 2).
    pub fn from_frame(baud: u32, data_bits: u8, parity: bool, stop_bits: u8) -> Self {
        Self {
            baud,
            bits_per_char: 1 + data_bits + u8::from(parity) + stop_bits,
        }
    }

    /// The time one character takes on the wire (rounded down to the nanosecond; the relay
    /// itself computes bursts exactly).
    pub fn char_time(&self) -> Duration {
        let nanos =
            u64::from(self.bits_per_char.max(1)) * 1_000_000_000 / u64::from(self.baud.max(1));
        Duration::from_nanos(nanos)
    }

    /// The time `bytes` characters take back to back.
    pub fn transmit_time(&self, bytes: u64) -> Duration {
        let nanos = u128::from(bytes) * u128::from(self.bits_per_char.max(1)) * 1_000_000_000
            / u128::from(self.baud.max(1));
        Duration::from_nanos(u64::try_from(nanos).unwrap_or(u64::MAX))
    }

    fn check(self) -> io::Result<Self> {
        if self.baud == 0 || self.bits_per_char == 0 {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "paced link: baud rate and bits per character must be at least 1",
            ));
        }
        Ok(self)
    }
}

/// The two directions of a link.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Direction {
    /// From side `a` (the gateway) to side `b` (the device).
    AToB,
    /// From side `b` to side `a`.
    BToA,
}

/// What becomes of a byte when it is due (see [`FaultHook`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultAction {
    /// Deliver it unchanged.
    Deliver,
    /// Lose it (its time on the wire passes all the same).
    Drop,
    /// Deliver this byte instead (a corrupted character).
    Replace(u8),
}

/// Decides the fate of every byte when it is due: `index` counts the bytes of `direction` from 0.
/// Called on the relay's task: must not block.
pub trait FaultHook: Send + Sync + 'static {
    /// The fate of byte number `index` of `direction`.
    fn on_byte(&self, direction: Direction, index: u64, byte: u8) -> FaultAction;
}

impl<F> FaultHook for F
where
    F: Fn(Direction, u64, u8) -> FaultAction + Send + Sync + 'static,
{
    fn on_byte(&self, direction: Direction, index: u64, byte: u8) -> FaultAction {
        self(direction, index, byte)
    }
}

/// The counters of one direction, updated by the relay while it runs.
#[derive(Debug, Default)]
pub struct DirectionCounters {
    /// Bytes read from the sending side.
    received: AtomicU64,
    /// Bytes written to the receiving side (replaced ones included).
    delivered: AtomicU64,
    /// Bytes the fault hook dropped.
    dropped: AtomicU64,
    /// Bytes the fault hook replaced.
    corrupted: AtomicU64,
    /// Writes to the receiving side (each carries every byte due at that moment).
    batches: AtomicU64,
    /// The latest a batch's first byte was written after its delivery time, in nanoseconds.
    max_lateness_nanos: AtomicU64,
}

/// A snapshot of [`DirectionCounters`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DirectionStats {
    /// Bytes read from the sending side.
    pub received: u64,
    /// Bytes written to the receiving side (replaced ones included).
    pub delivered: u64,
    /// Bytes the fault hook dropped.
    pub dropped: u64,
    /// Bytes the fault hook replaced.
    pub corrupted: u64,
    /// Writes to the receiving side.
    pub batches: u64,
    /// The latest a byte was written after its delivery time (never early: see the module doc).
    pub max_lateness: Duration,
}

// === impl DirectionCounters ===

impl DirectionCounters {
    /// The current values.
    pub fn snapshot(&self) -> DirectionStats {
        DirectionStats {
            received: self.received.load(Ordering::Relaxed),
            delivered: self.delivered.load(Ordering::Relaxed),
            dropped: self.dropped.load(Ordering::Relaxed),
            corrupted: self.corrupted.load(Ordering::Relaxed),
            batches: self.batches.load(Ordering::Relaxed),
            max_lateness: Duration::from_nanos(self.max_lateness_nanos.load(Ordering::Relaxed)),
        }
    }

    fn add_received(&self, n: usize) {
        self.received.fetch_add(as_u64(n), Ordering::Relaxed);
    }

    fn add_delivered(&self, n: usize) {
        self.delivered.fetch_add(as_u64(n), Ordering::Relaxed);
    }

    fn add_dropped(&self) {
        self.dropped.fetch_add(1, Ordering::Relaxed);
    }

    fn add_corrupted(&self) {
        self.corrupted.fetch_add(1, Ordering::Relaxed);
    }

    fn record_batch(&self, lateness: Duration) {
        self.batches.fetch_add(1, Ordering::Relaxed);
        let nanos = u64::try_from(lateness.as_nanos()).unwrap_or(u64::MAX);
        self.max_lateness_nanos.fetch_max(nanos, Ordering::Relaxed);
    }
}

fn as_u64(n: usize) -> u64 {
    u64::try_from(n).unwrap_or(u64::MAX)
}

/// The counters of both directions of a link.
#[derive(Debug, Default)]
pub struct LinkCounters {
    /// From `a` to `b`.
    pub a_to_b: Arc<DirectionCounters>,
    /// From `b` to `a`.
    pub b_to_a: Arc<DirectionCounters>,
}

// === impl LinkCounters ===

impl LinkCounters {
    /// The counters of one direction.
    pub fn direction(&self, direction: Direction) -> DirectionStats {
        match direction {
            Direction::AToB => self.a_to_b.snapshot(),
            Direction::BToA => self.b_to_a.snapshot(),
        }
    }
}

/// A running paced link between two pty paths.
#[derive(Debug, Clone)]
pub struct PacedLink {
    /// The path of the pty end the gateway opens.
    pub a: String,
    /// The path of the pty end the device or simulator opens.
    pub b: String,
    /// The timing in force.
    pub settings: PacedSettings,
    /// Bytes relayed each way, lateness.
    pub counters: Arc<LinkCounters>,
}

/// Starts a paced link between two new pty pairs; it runs until `shutdown` is cancelled or a pty
/// fails. The handle's result is the first error of either direction.
pub async fn spawn(
    settings: PacedSettings,
    shutdown: CancellationToken,
) -> io::Result<(PacedLink, JoinHandle<io::Result<()>>)> {
    spawn_with(settings, None, shutdown).await
}

/// [`spawn`] with a fault hook that sees every byte of both directions when it is due.
pub async fn spawn_with(
    settings: PacedSettings,
    faults: Option<Arc<dyn FaultHook>>,
    shutdown: CancellationToken,
) -> io::Result<(PacedLink, JoinHandle<io::Result<()>>)> {
    let settings = settings.check()?;
    let (master_a, slave_a) = SerialStream::pair().map_err(io::Error::from)?;
    let (master_b, slave_b) = SerialStream::pair().map_err(io::Error::from)?;
    let a = pty_name(&slave_a)?;
    let b = pty_name(&slave_b)?;
    let counters = Arc::new(LinkCounters::default());
    let parts = |direction, counters: &Arc<DirectionCounters>| RelayParts {
        settings,
        direction,
        faults: faults.clone(),
        counters: Arc::clone(counters),
        shutdown: shutdown.clone(),
    };
    let to_b = parts(Direction::AToB, &counters.a_to_b);
    let to_a = parts(Direction::BToA, &counters.b_to_a);
    let handle = crate::task::spawn("paced pty relay", async move {
        // The slave ends stay open while the relay runs: the paths remain valid, and a side that
        // closes its end does not hang up the master.
        let _keep = (slave_a, slave_b);
        let (read_a, write_a) = tokio::io::split(master_a);
        let (read_b, write_b) = tokio::io::split(master_b);
        tokio::try_join!(pace(read_a, write_b, to_b), pace(read_b, write_a, to_a)).map(|_| ())
    });
    let link = PacedLink {
        a,
        b,
        settings,
        counters,
    };
    Ok((link, handle))
}

fn pty_name(slave: &SerialStream) -> io::Result<String> {
    slave
        .name()
        .ok_or_else(|| io::Error::other("paced link: the pty has no path"))
}

/// An in-process stream pair paced like a [`PacedLink`]: what is written to `a` is read from `b`
/// on the schedule, and back.
#[derive(Debug)]
pub struct PacedDuplex {
    /// The gateway's end.
    pub a: tokio::io::DuplexStream,
    /// The device's end.
    pub b: tokio::io::DuplexStream,
    /// Bytes relayed each way, lateness.
    pub counters: Arc<LinkCounters>,
}

/// Starts a paced in-process link (see [`PacedDuplex`]); it runs until `shutdown`, or until both
/// ends are closed (a closed end's queued bytes are still delivered on time first).
pub fn paced_duplex(
    settings: PacedSettings,
    faults: Option<Arc<dyn FaultHook>>,
    shutdown: CancellationToken,
) -> io::Result<(PacedDuplex, JoinHandle<io::Result<()>>)> {
    let settings = settings.check()?;
    let (a, relay_a) = tokio::io::duplex(relay::DUPLEX_BUFFER);
    let (b, relay_b) = tokio::io::duplex(relay::DUPLEX_BUFFER);
    let counters = Arc::new(LinkCounters::default());
    let parts = |direction, counters: &Arc<DirectionCounters>| RelayParts {
        settings,
        direction,
        faults: faults.clone(),
        counters: Arc::clone(counters),
        shutdown: shutdown.clone(),
    };
    let to_b = parts(Direction::AToB, &counters.a_to_b);
    let to_a = parts(Direction::BToA, &counters.b_to_a);
    let handle = crate::task::spawn("paced duplex relay", async move {
        let (read_a, write_a) = tokio::io::split(relay_a);
        let (read_b, write_b) = tokio::io::split(relay_b);
        tokio::try_join!(pace(read_a, write_b, to_b), pace(read_b, write_a, to_a)).map(|_| ())
    });
    Ok((PacedDuplex { a, b, counters }, handle))
}

#[cfg(test)]
mod tests;
