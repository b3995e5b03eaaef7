//! The Modbus slave RTU line (003 6.4.5 to 6.4.8, "CP 341 slave mode"): a serial master (a legacy
//! HMI, say) polls the gateway as if it were the CP at its slave address, reading and writing the
//! gateway's CP memory, which Modbus TCP, the image, zenoh and REST share.
//!
//! An adapter of the line runtime over a proto-core [`Slave`] engine that borrows the
//! [`SharedCpMemory`] for one request at a time: the engine's events go to the status (diagnostic
//! buffer, counters, STATUS word, [`LineEvent`](super::LineEvent) broadcast) and the memory
//! (image mirrors, persistence). On shutdown the port is no longer read, the request already
//! received is answered, and the line stops.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, SystemTime};

use proto_core::cpmem::SlaveParams;
use proto_core::event::EventId;
use proto_core::modbus::rtu::CharTiming;
use proto_core::modbus::slave::{DiscardReason, Outcome, Slave, SlaveEvent};
use tokio::time::Instant;
use tokio_serial::SerialPort;
use tokio_util::sync::CancellationToken;

use super::line_metrics::{slave_result, SLAVE_LINE_PARTNER};
use super::runtime::{
    self, LineBase, LineCapabilities, LineEngine, LineHandle, SerialOpener, Stop,
};
use super::status::{Shared, DEFAULT_DIAG_DEPTH};
use super::{DEFAULT_REOPEN_MAX, DEFAULT_REOPEN_MIN};
use crate::cpmem::{CpMemoryUnit, SharedCpMemory};
use crate::metrics::Metrics;
use crate::serial::PortSettings;
use crate::unit::UnitService;

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
    /// The unit id under which Modbus TCP serves the memory with the line's address conversion
    /// (`None`: not served there).
    pub unit_id: Option<u8>,
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
            unit_id: None,
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

/// Starts a Modbus slave RTU line: opens its port (reopening with back-off) and serves `memory` to
/// the serial master until `shutdown` is cancelled. Must be called within a tokio runtime.
pub fn spawn_modbus_slave_line(
    settings: SlaveLineSettings,
    memory: SharedCpMemory,
    shutdown: CancellationToken,
) -> LineHandle {
    let base = LineBase::new(
        &settings.name,
        SlaveLineSettings::PROTOCOL,
        &settings.port,
        settings.diag_depth,
        (settings.reopen_min, settings.reopen_max),
        settings.metrics.as_ref(),
    );
    let core = base.core(Vec::new());
    let counters = Arc::new(Mutex::new(SlaveCounters::default()));
    let caps = SlaveCapabilities {
        params: settings.params.clone(),
        unit_id: settings.unit_id,
        counters: Arc::clone(&counters),
        memory: memory.clone(),
    };
    let slave = Slave::new(settings.params.clone(), settings.timing(), memory.clone());
    let engine = SlaveLine {
        settings,
        memory,
        shared: Arc::clone(&core.shared),
        counters,
        slave,
    };
    runtime::spawn(core, engine, None, Arc::new(caps), SerialOpener, shutdown)
}

/// What a slave line offers: its counters, the memory it serves and that memory as a unit.
#[derive(Debug)]
struct SlaveCapabilities {
    params: SlaveParams,
    unit_id: Option<u8>,
    counters: Arc<Mutex<SlaveCounters>>,
    memory: SharedCpMemory,
}

impl LineCapabilities for SlaveCapabilities {
    fn units(&self) -> Vec<(u8, Arc<dyn UnitService>)> {
        let unit = self.memory().unit();
        self.unit_id
            .map(|id| (id, Arc::new(unit) as Arc<dyn UnitService>))
            .into_iter()
            .collect()
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

// === impl SlaveCapabilities ===

impl SlaveCapabilities {
    fn counters(&self) -> SlaveCounters {
        self.counters
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }

    fn memory(&self) -> CpMemoryView {
        CpMemoryView {
            memory: self.memory.clone(),
            map: self.params.map().clone(),
            unit_id: self.unit_id,
        }
    }
}

/// The CP memory a slave line serves, with its address conversion and unit id.
#[derive(Clone, Debug)]
pub struct CpMemoryView {
    /// The memory.
    pub memory: SharedCpMemory,
    /// The line's address conversion (for [`SharedCpMemory::mirror_to`]).
    pub map: proto_core::cpmem::AddressMap,
    /// The unit id under which Modbus TCP and the image show it, if any.
    pub unit_id: Option<u8>,
}

// === impl CpMemoryView ===

impl CpMemoryView {
    /// The memory with the line's address conversion as a Modbus TCP unit.
    pub fn unit(&self) -> CpMemoryUnit {
        CpMemoryUnit::new(self.memory.clone(), self.map.clone())
    }
}

/// What a Modbus slave line adds to every line.
impl LineHandle {
    /// What a Modbus slave line has served.
    pub fn slave_counters(&self) -> Option<SlaveCounters> {
        self.capability::<SlaveCapabilities>()
            .map(SlaveCapabilities::counters)
    }

    /// The CP memory a Modbus slave line serves.
    pub fn cp_memory(&self) -> Option<CpMemoryView> {
        self.capability::<SlaveCapabilities>()
            .map(SlaveCapabilities::memory)
    }
}

/// The adapter of one slave line.
struct SlaveLine {
    settings: SlaveLineSettings,
    memory: SharedCpMemory,
    shared: Arc<Shared>,
    counters: Arc<Mutex<SlaveCounters>>,
    slave: Slave<SharedCpMemory>,
}

impl LineEngine for SlaveLine {
    type Command = ();

    fn opened(&mut self, _modem: Option<&mut dyn SerialPort>) {
        tracing::debug!(line = %self.settings.name, address = self.settings.params.address(), "slave address");
        self.slave = Slave::new(
            self.settings.params.clone(),
            self.settings.timing(),
            self.memory.clone(),
        );
    }

    fn handle_rx(&mut self, now: proto_core::time::Instant, bytes: &[u8]) {
        self.slave.handle_rx(now, bytes);
    }

    fn handle_timeout(&mut self, now: proto_core::time::Instant) {
        self.slave.handle_timeout(now);
    }

    fn poll_timeout(&self) -> Option<proto_core::time::Instant> {
        self.slave.poll_timeout()
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.slave.poll_transmit()
    }

    fn transmitted(&mut self, _written: Instant, _len: usize, _end: proto_core::time::Instant) {
        self.shared.metrics().sent_telegram();
    }

    fn handle_events(&mut self) -> bool {
        while let Some(event) = self.slave.poll_event() {
            self.on_event(event);
        }
        false
    }

    fn command(&mut self, (): (), _modem: Option<&mut dyn SerialPort>) {}

    fn refuse(&mut self, (): (), _shutting_down: bool) {}

    /// Nothing is read any more, so the frame being received ends by silence and the last
    /// request is answered; then the line stops.
    fn stop(&mut self) -> Stop {
        Stop {
            read: false,
            close_queue: true,
            grace: None,
        }
    }

    fn done(&self) -> bool {
        self.slave.poll_timeout().is_none()
    }

    fn closed(&mut self, _shutting_down: bool) {}

    fn port_failed(&mut self, id: EventId, reason: String) {
        self.shared.raise(id, None, Some(reason));
    }
}

// === impl SlaveLine ===

impl SlaveLine {
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
