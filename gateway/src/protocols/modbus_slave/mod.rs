//! The Modbus slave RTU line (003 6.4.5 to 6.4.8, "CP 341 slave mode"): a serial master (a legacy
//! HMI, say) polls the gateway as if it were the CP at its slave address, reading and writing the
//! gateway's CP memory, which Modbus TCP, the image, zenoh and REST share.
//!
//! An adapter of the line runtime over a proto-core [`Slave`] engine that borrows the
//! [`SharedCpMemory`] for one request at a time: the engine's events go to the status (diagnostic
//! buffer, counters, STATUS word, [`LineEvent`](crate::line::LineEvent) broadcast) and the memory
//! (image mirrors, persistence). On shutdown the port is no longer read, the request already
//! received is answered, and the line stops.

mod build;
pub(crate) mod config;
pub mod cpmem;
pub mod partner;

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, SystemTime};

use proto_core::cpmem::SlaveParams;
use proto_core::event::EventId;
use proto_core::modbus::rtu::CharTiming;
use proto_core::modbus::slave::{self, DiscardReason, Outcome, Slave, SlaveEvent};
use tokio::time::Instant;
use tokio_serial::SerialPort;
use tokio_util::sync::CancellationToken;

use crate::cpmem::{CpMemoryUnit, SharedCpMemory};
use crate::line::metrics::{slave_result, LineFamilies, SLAVE_LINE_PARTNER};
use crate::line::runtime::{
    self, LineBase, LineCapabilities, LineEngine, LineHandle, PortOpener, SerialOpener, Stop,
};
use crate::line::runtime::{LineCommands, LineLifecycle, LineSignals, SecondPort};
use crate::line::status::{Shared, DEFAULT_DIAG_DEPTH};
use crate::line::{DEFAULT_REOPEN_MAX, DEFAULT_REOPEN_MIN};
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
    pub metrics: Option<LineFamilies>,
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
    /// at every baud rate as the CP's table has it ([`crate::line::rtu_timing`]); the engine applies the
    /// multiplier of [`SlaveParams`].
    pub fn timing(&self) -> CharTiming {
        crate::line::rtu_timing(&self.port)
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
    /// Received bytes not served, by reason (`bad_crc`, `too_short`, `too_long`, `line_error`,
    /// `trailing_data`); also in the metrics as `gateway_frames_discarded_total`.
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
    spawn_on(settings, memory, shutdown, SerialOpener)
}

/// [`spawn_modbus_slave_line`] on the ports `opener` opens.
fn spawn_on<O: PortOpener>(
    settings: SlaveLineSettings,
    memory: SharedCpMemory,
    shutdown: CancellationToken,
    opener: O,
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
    core.shared.metrics().init_frames_discarded(&slave::LOST);
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
    runtime::spawn(core, engine, None, Arc::new(caps), opener, shutdown)
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
    fn opened(&mut self, _modem: Option<&mut dyn SerialPort>) {
        tracing::debug!(line = %self.settings.name, address = self.settings.params.address(), "slave address");
        self.slave = Slave::new(
            self.settings.params.clone(),
            self.settings.timing(),
            self.memory.clone(),
        );
    }

    crate::line::driver::engine_calls!(slave: rx, timeout, tx);

    fn transmitted(&mut self, _written: Instant, _len: usize, _end: proto_core::time::Instant) {
        self.shared.metrics().sent_telegram();
    }

    fn handle_events(&mut self) -> bool {
        while let Some(event) = self.slave.poll_event() {
            self.on_event(event);
        }
        false
    }
}

impl LineCommands for SlaveLine {
    type Command = ();

    fn command(&mut self, (): (), _modem: Option<&mut dyn SerialPort>) {}

    fn refuse(&mut self, (): (), _shutting_down: bool) {}
}

impl LineLifecycle for SlaveLine {
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

    /// RTU frames end by t3.5 of silence (003 6.4.3): the default gap of 3.5 characters.
    fn monitor_framing(&self) -> proto_core::monitor::Framing {
        proto_core::monitor::Framing {
            kind: proto_core::monitor::FrameKind::ModbusRtu(proto_core::monitor::Role::Slave),
            gap: None,
        }
    }
}

impl LineSignals for SlaveLine {}

impl SecondPort for SlaveLine {}

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
                    self.shared.metrics().frame_discarded(reason);
                }
            },
            SlaveEvent::Diagnostic(id) => self.shared.raise(id, None, None),
            other => tracing::debug!(line = %line, kind = other.kind(), "slave event"),
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Mutex;

    use proto_core::cpmem::{AddressMap, MemoryLayout, OperatingMode};
    use proto_core::event::ids;
    use proto_core::modbus::rtu::encode_frame;
    use proto_core::serial_marks::{encode, Received};
    use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

    use super::*;
    use crate::line::testing::{events, eventually, OnePort};

    const ADDRESS: u8 = 222;

    fn request() -> Vec<u8> {
        let mut frame = Vec::new();
        encode_frame(ADDRESS, &[0x03, 0x00, 0x00, 0x00, 0x01], &mut frame);
        frame
    }

    /// The answer to a request: what arrives until the line is silent for 50 ms.
    async fn answer(partner: &mut DuplexStream) -> Vec<u8> {
        let mut answer = vec![0u8; 1];
        partner.read_exact(&mut answer).await.expect("answer");
        let mut more = [0u8; 64];
        while let Ok(Ok(n)) =
            tokio::time::timeout(Duration::from_millis(50), partner.read(&mut more)).await
        {
            answer.extend_from_slice(more.get(..n).unwrap_or_default());
            if n == 0 {
                break;
            }
        }
        answer
    }

    /// Nothing arrives within 100 ms.
    async fn silent(partner: &mut DuplexStream) {
        let mut byte = [0u8; 1];
        let read = tokio::time::timeout(Duration::from_millis(100), partner.read(&mut byte)).await;
        assert!(read.is_err(), "unexpected answer {read:?}");
    }

    async fn start(
        mode: OperatingMode,
    ) -> (
        LineHandle,
        DuplexStream,
        prometheus::Registry,
        CancellationToken,
    ) {
        let (port, partner) = tokio::io::duplex(256);
        let registry = prometheus::Registry::new();
        let params =
            SlaveParams::new(ADDRESS, mode, 1, AddressMap::manual_example()).expect("params");
        let mut settings =
            SlaveLineSettings::new("hmi", PortSettings::new("/dev/in-process", 19200), params);
        settings.metrics = Some(LineFamilies::register(&registry).expect("metrics"));
        let shutdown = CancellationToken::new();
        let memory = SharedCpMemory::new(MemoryLayout::default());
        let line = spawn_on(
            settings,
            memory,
            shutdown.clone(),
            OnePort(Mutex::new(Some(port))),
        );
        eventually("the port open", || line.status().port_open).await;
        (line, partner, registry, shutdown)
    }

    #[tokio::test]
    async fn parity_errors_and_breaks_from_the_uart_are_events_and_drop_the_request() {
        let (line, mut partner, registry, shutdown) = start(OperatingMode::Normal).await;
        let good = request();

        // A request with one character received with a parity error in its middle (FF 00 x):
        // 08 0Ch, the request dropped, no answer.
        let (head, tail) = good.split_at(3);
        let mut marked = head.to_vec();
        encode([Received::Faulty(0x5A)], &mut marked);
        marked.extend_from_slice(tail.get(1..).unwrap_or_default());
        partner.write_all(&marked).await.expect("write");
        silent(&mut partner).await;
        assert_eq!(events(&line, ids::CHARACTER_ERROR), 1);
        let counters = line.slave_counters().expect("slave counters");
        assert_eq!(counters.answered, 0);
        assert!(
            counters.discarded.get("line_error").copied().unwrap_or(0) >= 1,
            "{counters:?}"
        );

        // A BREAK while idle (FF 00 00): in normal operation reported at once (08 0Dh).
        let mut brk = Vec::new();
        encode([Received::Break], &mut brk);
        partner.write_all(&brk).await.expect("write");
        eventually("08 0Dh", || events(&line, ids::LINE_BREAK) == 1).await;

        // The line keeps running: the next good request is answered.
        partner.write_all(&good).await.expect("write");
        assert_eq!(answer(&mut partner).await.first(), Some(&ADDRESS));

        let text = crate::metrics::encode_text(&registry);
        for event in ["080C", "080D"] {
            let series = text
                .lines()
                .find(|l| l.starts_with("gateway_events_total") && l.contains(event))
                .unwrap_or_else(|| panic!("no {event} series in\n{text}"));
            assert!(series.ends_with(" 1"), "{series}");
        }
        shutdown.cancel();
        line.join().await;
    }

    #[tokio::test]
    async fn a_request_with_trailing_bytes_is_discarded_and_counted_not_answered() {
        let (line, mut partner, registry, shutdown) = start(OperatingMode::Normal).await;
        let good = request();
        // 003 6.4.6: the frame is what came before the silence; a request followed by more bytes
        // within it is not a valid request.
        let mut long = good.clone();
        long.extend_from_slice(&[0x12, 0x34]);
        partner.write_all(&long).await.expect("write");
        silent(&mut partner).await;
        let counters = line.slave_counters().expect("slave counters");
        assert_eq!(
            counters.discarded.get("trailing_data"),
            Some(&1),
            "{counters:?}"
        );
        assert_eq!(counters.answered + counters.exceptions, 0);
        let text = crate::metrics::encode_text(&registry);
        let series = r#"gateway_frames_discarded_total{line="hmi",reason="trailing_data"} 1"#;
        assert!(text.contains(series), "{series} missing in\n{text}");

        partner.write_all(&good).await.expect("write");
        assert_eq!(answer(&mut partner).await.first(), Some(&ADDRESS));
        shutdown.cancel();
        line.join().await;
    }

    #[tokio::test]
    async fn interference_suppression_ignores_a_break_while_idle_but_not_inside_a_request() {
        let (line, mut partner, _registry, shutdown) =
            start(OperatingMode::InterferenceSuppression).await;
        let mut brk = Vec::new();
        encode([Received::Break, Received::Faulty(0x31)], &mut brk);
        partner.write_all(&brk).await.expect("write");
        let good = request();
        tokio::time::sleep(Duration::from_millis(20)).await;
        partner.write_all(&good).await.expect("write");
        assert_eq!(answer(&mut partner).await.first(), Some(&ADDRESS));
        assert_eq!(events(&line, ids::LINE_BREAK), 0);
        assert_eq!(events(&line, ids::CHARACTER_ERROR), 0);

        // Inside a request the fault counts and drops it (003 6.4.5.1).
        let mut marked = good.get(..4).unwrap_or_default().to_vec();
        encode([Received::Break], &mut marked);
        partner.write_all(&marked).await.expect("write");
        eventually("08 0Dh inside the request", || {
            events(&line, ids::LINE_BREAK) == 1
        })
        .await;
        silent(&mut partner).await;
        shutdown.cancel();
        line.join().await;
    }
}
