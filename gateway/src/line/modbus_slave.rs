//! The Modbus slave RTU line (003 6.4.5 to 6.4.8, "CP 341 slave mode"): a serial master (a legacy
//! HMI, say) polls the gateway as if it were the CP at its slave address, reading and writing the
//! gateway's CP memory, which Modbus TCP, the image, zenoh and REST share.
//!
//! The task owns the port and a proto-core [`Slave`] engine that borrows the
//! [`SharedCpMemory`] for one request at a time. The driver loop is the master line's: write what
//! the engine transmits, hand its events to the status (diagnostic buffer, counters, STATUS word,
//! [`LineEvent`](super::LineEvent) broadcast) and the memory (image mirrors, persistence), then
//! wait for bytes, the engine's deadline or shutdown. On shutdown the port is no longer read, the
//! request already received is answered, and the task ends (STYLE habit 9). A port that fails is
//! reopened with back-off, as on the master line.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, SystemTime};

use proto_core::cpmem::{AddressMap, SlaveParams};
use proto_core::event::EventId;
use proto_core::modbus::rtu::CharTiming;
use proto_core::modbus::slave::{DiscardReason, Outcome, Slave, SlaveEvent};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::broadcast;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

use super::driver::Clock;
use super::line_metrics::{slave_result, LineMetrics, SLAVE_LINE_PARTNER};
use super::modbus_master::{EVENT_PORT_LOST, EVENT_PORT_SETUP};
use super::status::{LineEvent, LineStatus, Shared, DEFAULT_DIAG_DEPTH};
use super::{DEFAULT_REOPEN_MAX, DEFAULT_REOPEN_MIN};
use crate::cpmem::{CpMemoryUnit, SharedCpMemory};
use crate::metrics::Metrics;
use crate::serial::{self, Backoff, PortSettings};
use crate::timer::LineTimer;

/// Settings of one Modbus slave RTU line.
#[derive(Clone, Debug)]
pub struct SlaveLineSettings {
    /// The line's name (logs, status, keys).
    pub name: String,
    /// The serial port (003 6.4.5.1: 9600 Bd, 8 data bits, even parity, 1 stop bit by default).
    pub port: PortSettings,
    /// Own address, operating mode, delay multiplier and address conversion (003 6.4.5.1).
    pub params: SlaveParams,
    /// Depth of the diagnostic buffer (the CP keeps 9).
    pub diag_depth: usize,
    /// First delay before reopening a failed port.
    pub reopen_min: Duration,
    /// Longest delay between reopen attempts.
    pub reopen_max: Duration,
    /// Where the line counts its events, traffic and requests (`None`: nowhere).
    pub metrics: Option<Metrics>,
}

// === impl SlaveLineSettings ===

impl SlaveLineSettings {
    /// The `protocol` label of a slave line: the config's key.
    const PROTOCOL: &'static str = "modbus-slave-rtu";

    /// A slave line on `port` with `params` and the defaults of the master line for the rest.
    pub fn new(name: impl Into<String>, port: PortSettings, params: SlaveParams) -> Self {
        Self {
            name: name.into(),
            port,
            params,
            diag_depth: DEFAULT_DIAG_DEPTH,
            reopen_min: DEFAULT_REOPEN_MIN,
            reopen_max: DEFAULT_REOPEN_MAX,
            metrics: None,
        }
    }

    /// The character timing of the line: 3.5 character times end a frame (003 6.4.6 "CRC-CHECK"),
    /// fixed at 1.75 ms above 19200 Bd (Modbus over Serial Line V1.02, 2.5.1.1: the CP's own table
    /// stops at 76800 Bd and a pty or USB adapter delivers bytes in bursts anyway); the engine
    /// applies the multiplier of [`SlaveParams`].
    pub fn timing(&self) -> CharTiming {
        CharTiming::new(self.port.baud, self.port.bits_per_char())
    }
}

/// What the slave line has served since it started.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SlaveCounters {
    /// Requests answered with data or an echo.
    pub answered: u64,
    /// Requests answered with an exception (003 6.4.6 "Response of the slave").
    pub exceptions: u64,
    /// Broadcast writes applied (never answered).
    pub broadcasts_applied: u64,
    /// Broadcasts not applied (a read, or a refused write; never answered).
    pub broadcasts_refused: u64,
    /// Memory writes made from the serial line (broadcasts included).
    pub writes: u64,
    /// Good frames for other slave addresses (normal on a multi-drop bus).
    pub other_address: u64,
    /// Received bytes not served, by reason (`bad_crc`, `too_short`, `too_long`, `line_fault`).
    pub discarded: BTreeMap<&'static str, u64>,
    /// When the last request for this slave (or a broadcast) was handled.
    pub last_request: Option<SystemTime>,
}

/// A running slave line: its status, counters and the memory it serves.
/// Clones share the line; [`Self::join`] waits for its task once.
#[derive(Clone, Debug)]
pub struct SlaveLineHandle {
    name: String,
    params: SlaveParams,
    shared: Arc<Shared>,
    counters: Arc<Mutex<SlaveCounters>>,
    memory: SharedCpMemory,
    task: Arc<Mutex<Option<JoinHandle<()>>>>,
}

// === impl SlaveLineHandle ===

impl SlaveLineHandle {
    /// The line's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The parameters the line runs with.
    pub fn params(&self) -> &SlaveParams {
        &self.params
    }

    /// A snapshot of the line's state in the master line's shape: port, diagnostic buffer (newest
    /// first), event counters, last STATUS word. A slave line has no devices; `commands_answered`
    /// counts the requests served (answered with data or applied as a broadcast) and
    /// `commands_failed` those refused with an exception (answered or broadcast). The details are
    /// in [`SlaveLineHandle::counters`].
    pub fn status(&self) -> LineStatus {
        self.shared.snapshot()
    }

    /// What the line has served.
    pub fn counters(&self) -> SlaveCounters {
        self.counters
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }

    /// Empties the line's diagnostic buffer; the event counters and the STATUS word stay.
    pub fn clear_diagnostics(&self) {
        self.shared.clear_diagnostics();
    }

    /// The line's events as they happen (bounded; a lagging receiver is told how many it missed).
    pub fn subscribe_events(&self) -> broadcast::Receiver<LineEvent> {
        self.shared.subscribe()
    }

    /// The memory the line serves.
    pub fn memory(&self) -> &SharedCpMemory {
        &self.memory
    }

    /// The same memory with the same address conversion, for the Modbus TCP unit map.
    pub fn unit(&self) -> CpMemoryUnit {
        CpMemoryUnit::new(self.memory.clone(), self.params.map().clone())
    }

    /// The address map of the line (for [`SharedCpMemory::mirror_to`]).
    pub fn map(&self) -> &AddressMap {
        self.params.map()
    }

    /// Waits for the line task to end (after the shutdown token was cancelled).
    pub async fn join(self) {
        let task = self
            .task
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .take();
        let Some(task) = task else { return };
        if let Err(err) = task.await {
            tracing::error!(line = %self.name, %err, "slave line task failed");
        }
    }
}

/// Starts a Modbus slave RTU line: opens its port (reopening with back-off) and serves `memory` to
/// the serial master until `shutdown` is cancelled. Must be called within a tokio runtime.
pub fn spawn_modbus_slave_line(
    settings: SlaveLineSettings,
    memory: SharedCpMemory,
    shutdown: CancellationToken,
) -> SlaveLineHandle {
    let status = LineStatus {
        name: settings.name.clone(),
        port_open: false,
        port_error: None,
        port_opens: 0,
        status_word: 0,
        diagnostics: Vec::new(),
        last_event: None,
        started: SystemTime::now(),
        event_counts: BTreeMap::new(),
        devices: Vec::new(),
        commands_answered: 0,
        commands_failed: 0,
    };
    let clock = Clock::start();
    let metrics = LineMetrics::new(
        settings.metrics.clone(),
        &settings.name,
        SlaveLineSettings::PROTOCOL,
    );
    let shared = Shared::with_metrics(status, settings.diag_depth, clock, metrics);
    let counters = Arc::new(Mutex::new(SlaveCounters::default()));
    let task = SlaveTask {
        settings: settings.clone(),
        memory: memory.clone(),
        shared: Arc::clone(&shared),
        counters: Arc::clone(&counters),
        shutdown,
        clock,
    };
    let task = tokio::spawn(task.run());
    SlaveLineHandle {
        name: settings.name,
        params: settings.params,
        shared,
        counters,
        memory,
        task: Arc::new(Mutex::new(Some(task))),
    }
}

/// Why the driver loop ended.
#[derive(Debug)]
enum PortExit {
    Shutdown,
    Lost(String),
}

/// The task of one slave line.
struct SlaveTask {
    settings: SlaveLineSettings,
    memory: SharedCpMemory,
    shared: Arc<Shared>,
    counters: Arc<Mutex<SlaveCounters>>,
    shutdown: CancellationToken,
    clock: Clock,
}

// === impl SlaveTask ===

impl SlaveTask {
    /// Opens the port, serves it until it fails, reopens with back-off; until shutdown.
    async fn run(self) {
        let name = &self.settings.name;
        let mut reopen = Backoff::clamped(self.settings.reopen_min, self.settings.reopen_max);
        loop {
            match serial::open(&self.settings.port) {
                Ok(port) => {
                    reopen.reset();
                    tracing::info!(line = %name, path = %self.settings.port.path, address = self.settings.params.address(), "slave port open");
                    self.shared.started();
                    let exit = self.drive(port).await;
                    self.shared.port_closed();
                    match exit {
                        PortExit::Shutdown => break,
                        PortExit::Lost(reason) => self.port_failed(EVENT_PORT_LOST, reason),
                    }
                }
                Err(err) => self.port_failed(EVENT_PORT_SETUP, err.to_string()),
            }
            let delay = reopen.next_delay();
            tracing::info!(line = %name, ?delay, "reopening the port after back-off");
            tokio::select! {
                biased;
                () = self.shutdown.cancelled() => break,
                () = tokio::time::sleep(delay) => {}
            }
        }
        tracing::info!(line = %name, "slave line stopped");
    }

    fn port_failed(&self, id: EventId, reason: String) {
        self.shared.update(|s| s.port_error = Some(reason.clone()));
        self.shared.raise(id, None, Some(reason));
    }

    /// The driver loop on an open port.
    async fn drive<P: AsyncRead + AsyncWrite + Unpin>(&self, mut port: P) -> PortExit {
        let path = &self.settings.port.path;
        let mut slave = Slave::new(
            self.settings.params.clone(),
            self.settings.timing(),
            self.memory.clone(),
        );
        // The slave's deadlines are fractions of a millisecond: the end of a request by t3.5 of
        // silence (003 6.4.3) and the t3.5 before its answer; tokio's timer would add 1.2 ms.
        let mut timer = LineTimer::new();
        let mut stopping = false;
        let mut buf = [0u8; 512];
        loop {
            let (now, engine_now) = self.clock.now();
            // A deadline already passed is handled without sleeping (quinn drive_timer).
            if slave
                .poll_timeout()
                .is_some_and(|t| self.clock.to_tokio(t) <= now)
            {
                slave.handle_timeout(engine_now);
            }
            while let Some(frame) = slave.poll_transmit() {
                if let Err(err) = port.write_all(&frame).await {
                    return PortExit::Lost(format!("write to {path} failed: {err}"));
                }
                self.shared.metrics().sent(frame.len());
            }
            while let Some(event) = slave.poll_event() {
                self.on_event(event);
            }
            let deadline = slave.poll_timeout().map(|t| self.clock.to_tokio(t));
            // Stopping: nothing is read any more, so the frame being received ends by silence
            // and the last request is answered; then the line stops.
            if stopping && deadline.is_none() {
                return PortExit::Shutdown;
            }
            tokio::select! {
                biased;
                () = self.shutdown.cancelled(), if !stopping => stopping = true,
                () = timer.sleep_until_opt(deadline) => {
                    let (_, engine_now) = self.clock.now();
                    slave.handle_timeout(engine_now);
                }
                read = port.read(&mut buf), if !stopping => match read {
                    Ok(0) => return PortExit::Lost(format!("{path} reached end of file")),
                    Ok(n) => {
                        let (_, engine_now) = self.clock.now();
                        self.shared.metrics().received_bytes(n);
                        slave.handle_rx(engine_now, buf.get(..n).unwrap_or_default());
                    }
                    Err(err) => return PortExit::Lost(format!("read from {path} failed: {err}")),
                },
            }
        }
    }

    fn count(&self, f: impl FnOnce(&mut SlaveCounters)) {
        f(&mut self.counters.lock().unwrap_or_else(PoisonError::into_inner));
    }

    /// One event of the engine: counters, status, memory notifications, log.
    fn on_event(&self, event: SlaveEvent) {
        let line = &self.settings.name;
        match event {
            SlaveEvent::Request {
                address,
                function,
                outcome,
            } => {
                tracing::debug!(line = %line, address, function = function.0, ?outcome, "request");
                let metrics = self.shared.metrics();
                metrics.received_telegram();
                metrics.request(SLAVE_LINE_PARTNER, function.0, slave_result(outcome));
                let served = matches!(outcome, Outcome::Answered | Outcome::BroadcastApplied);
                self.shared.update(|s| {
                    if served {
                        s.commands_answered += 1;
                    } else {
                        s.commands_failed += 1;
                    }
                });
                self.count(|c| {
                    match outcome {
                        Outcome::Answered => c.answered += 1,
                        Outcome::Exception(_) => c.exceptions += 1,
                        Outcome::BroadcastApplied => c.broadcasts_applied += 1,
                        Outcome::BroadcastRefused(_) => c.broadcasts_refused += 1,
                    }
                    c.last_request = Some(SystemTime::now());
                });
            }
            SlaveEvent::Written(written) => {
                self.memory.note_written(written);
                self.count(|c| c.writes += 1);
            }
            SlaveEvent::Discarded { reason, len } => match reason {
                DiscardReason::OtherAddress(address) => {
                    tracing::trace!(line = %line, address, len, "frame for another slave");
                    self.count(|c| c.other_address += 1);
                }
                reason => {
                    tracing::debug!(line = %line, reason = reason.as_str(), len, "received bytes discarded");
                    self.count(|c| *c.discarded.entry(reason.as_str()).or_default() += 1);
                }
            },
            SlaveEvent::Diagnostic(id) => self.shared.raise(id, None, None),
            other => tracing::debug!(line = %line, kind = other.kind(), "slave event"),
        }
    }
}
