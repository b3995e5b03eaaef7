//! The line runtime: one port task for every line protocol.
//!
//! A line is a serial port, a protocol engine and the line's status. The runtime owns the first
//! and the last; the engine sits behind [`LineEngine`], a small adapter per protocol
//! (`master`, `modbus_slave`, `telegram::task`) over a sans-IO proto-core machine:
//!
//! ```text
//!   commands (queue) ──┐                    ┌──> status, events, metrics, image, mailbox
//!                      v                    │
//!   port ──bytes──> [ runtime ] ──bytes, time──> [ adapter: engine ] ──events──┘
//!        <──bytes──   │   ^  <──frames, RS232 actions, deadline──┘
//!                     │   └── open with back-off, 02 0Fh / 08 0Dh, shutdown
//!                     └──> one LineHandle (status, events, units, capabilities, join)
//! ```
//!
//! The task opens the port ([`PortOpener`]: a tokio-serial port, a pty, an in-process stream),
//! drives the engine until the port fails or the line stops, and reopens the port with back-off.
//! Each turn of the loop hands a deadline already passed to the engine without sleeping (quinn's
//! `drive_timer`), lets the adapter start work (a poll, a queued command), writes what the engine
//! transmits with the estimated end of each transmission, and hands the engine's events on; when
//! that made progress (a request completed) the loop turns again at once, so a completion starts
//! the next job without waiting. Then it waits for bytes, the line's one timer (a timerfd: the
//! deadlines of a Modbus line are fractions of a millisecond apart, tokio's timer would add
//! 1.2 ms to each; it wakes at the engine's deadline or at the silence that ends a frame the
//! monitor is receiving, whichever comes first), the adapter's own wake-up (the next poll, a signal poll), a command or
//! shutdown. On shutdown the adapter says how the line stops ([`Stop`]): whether the port is
//! still read, whether the command queue closes at once, how long the engine may finish what it
//! has started.

use std::any::Any;
use std::fmt;
use std::future::Future;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use proto_core::event::{ids, EventId};
use proto_core::monitor::{Direction, Framing};
use proto_core::serial_marks::{LineError, MarkDecoder, Piece};
use proto_core::telegram::Action;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{broadcast, mpsc};
use tokio::task::JoinHandle;
use tokio::time::Instant;
use tokio_serial::{SerialPort, SerialStream};
use tokio_util::sync::CancellationToken;

use super::driver::{estimated_tx_end, sleep_until_opt, Clock};
use super::line_metrics::{LineMetrics, LineTraffic};
use super::monitor::{FrameMonitor, Recorder};
use super::status::{DeviceStatus, LineEvent, LineStatus, Shared};
use crate::metrics::Metrics;
use crate::serial::{self, Backoff, PortSettings, UartCounters};
use crate::timer::LineTimer;
use crate::unit::UnitService;

/// The port could not be opened or set up: 003 7.2 event 02 0Fh "Interface could not be
/// parameterized" (also for RS485 mode refused by the driver).
pub const EVENT_PORT_SETUP: EventId = ids::INVALID_PARAMETERIZATION;
/// The open port failed (read or write error, end of file: the device node vanished): 003 7.2
/// event 08 0Dh "BREAK: receive line to partner is interrupted".
pub const EVENT_PORT_LOST: EventId = ids::LINE_BREAK;

/// Bytes read from the port at once.
const READ_BUF: usize = 1024;

/// A port a line runs on: a byte stream, with the RS232 modem lines where it has them.
pub trait LinePort: AsyncRead + AsyncWrite + Unpin + Send + 'static {
    /// The modem lines (DTR, RTS, CTS, DSR, DCD, RI), if the port offers them.
    fn modem(&mut self) -> Option<&mut dyn SerialPort> {
        None
    }
    /// The UART's error counters (`TIOCGICOUNT`), if the port is a UART; `Some(Err(..))` where the
    /// driver has none (a pty, most USB adapters).
    fn uart_counters(&self) -> Option<std::io::Result<UartCounters>> {
        None
    }
}

impl LinePort for SerialStream {
    fn modem(&mut self) -> Option<&mut dyn SerialPort> {
        Some(self)
    }
    fn uart_counters(&self) -> Option<std::io::Result<UartCounters>> {
        Some(serial::uart_counters(self))
    }
}

impl LinePort for tokio::io::DuplexStream {}

/// Opens a line's port with the line's settings.
pub trait PortOpener: Send + Sync + 'static {
    /// The port.
    type Port: LinePort;

    /// Opens the port; the error text goes into the status and event 02 0Fh.
    ///
    /// # Errors
    ///
    /// Why the port cannot be opened or set up.
    fn open(&self, settings: &PortSettings) -> Result<Self::Port, String>;
}

/// Opens serial ports (and pseudo-terminals) through tokio-serial: baud rate, character frame
/// and interface as [`serial::open`] sets them.
#[derive(Clone, Copy, Debug, Default)]
pub struct SerialOpener;

impl PortOpener for SerialOpener {
    type Port = SerialStream;

    fn open(&self, settings: &PortSettings) -> Result<SerialStream, String> {
        serial::open(settings).map_err(|err| err.to_string())
    }
}

/// How a line stops when its shutdown token is cancelled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Stop {
    /// The port is still read (a reply in flight can arrive); otherwise the frame being received
    /// ends by silence.
    pub(crate) read: bool,
    /// The command queue closes at once and what waits in it is refused; otherwise it stays
    /// open (unread) until the line has stopped.
    pub(crate) close_queue: bool,
    /// How long the engine may finish what it has started (`None`: until it is done).
    pub(crate) grace: Option<Duration>,
}

/// What the runtime needs from a line protocol: the proto-core engine with what the protocol does
/// with its results. Inputs are bytes, time and commands; outputs are bytes, RS232 actions,
/// deadlines and the events the adapter hands on itself (status, image, mailbox).
pub(crate) trait LineEngine: Send + 'static {
    /// What clients queue for the line (`()` for a line without a queue).
    type Command: Send + 'static;

    /// The port opened: the adapter starts a fresh engine (nothing carries over a reopen) and
    /// sets the outputs as the protocol wants them.
    fn opened(&mut self, modem: Option<&mut dyn SerialPort>);
    /// Received bytes, at `now`.
    fn handle_rx(&mut self, now: proto_core::time::Instant, bytes: &[u8]);
    /// A character received with a parity or framing error, a BREAK, or characters lost to an
    /// overrun, at `now`, between the bytes handed to `handle_rx` before and after it.
    fn handle_line_error(&mut self, now: proto_core::time::Instant, error: LineError);
    /// Bytes received on the line's second, receive-only port at `now` (only a line started
    /// with one, see [`LineBase::with_second_port`]: a listen-only tap of both directions of a
    /// point-to-point link).
    fn handle_rx_second(&mut self, _now: proto_core::time::Instant, _bytes: &[u8]) {}
    /// A line error on the second port, as [`Self::handle_line_error`] on the first.
    fn handle_line_error_second(&mut self, _now: proto_core::time::Instant, _error: LineError) {}
    /// The engine's deadline has come.
    fn handle_timeout(&mut self, now: proto_core::time::Instant);
    /// The engine's next deadline.
    fn poll_timeout(&self) -> Option<proto_core::time::Instant>;
    /// Starts work while the line runs (the next poll or command); `now` on tokio's clock.
    fn start(&mut self, _now: Instant) {}
    /// The next RS232 output the engine sets (before its next transmission).
    fn poll_action(&mut self) -> Option<Action> {
        None
    }
    /// Sets an output the engine asks for.
    fn apply_action(&mut self, _action: Action, _modem: Option<&mut dyn SerialPort>) {}
    /// The next bytes to write.
    fn poll_transmit(&mut self) -> Option<Vec<u8>>;
    /// `len` bytes were written at `written`, estimated to leave the line at `end`.
    fn transmitted(&mut self, written: Instant, len: usize, end: proto_core::time::Instant);
    /// Hands the engine's events on; true when that made progress that needs another turn at
    /// once (a completed request starts the next job).
    fn handle_events(&mut self) -> bool;
    /// The adapter's own wake-up (the next poll, a signal poll, room in a mailbox).
    fn wake(&self) -> impl Future<Output = ()> + Send + '_ {
        std::future::pending()
    }
    /// The wake-up came.
    fn woken(&mut self, _modem: Option<&mut dyn SerialPort>) {}
    /// A command from the queue while the port is open.
    fn command(&mut self, command: Self::Command, modem: Option<&mut dyn SerialPort>);
    /// A command that cannot be carried: the port is closed, or the line is `shutting_down`.
    fn refuse(&mut self, command: Self::Command, shutting_down: bool);
    /// Shutdown began: refuses work not yet started, says how the line stops.
    fn stop(&mut self) -> Stop;
    /// Whether a stopping line is done (nothing in flight).
    fn done(&self) -> bool;
    /// The port closed: in-flight work is finished or failed (`shutting_down`: the line stops).
    fn closed(&mut self, shutting_down: bool);
    /// The port failed to open or was lost (after the status took the reason): the event and
    /// what the protocol does about it.
    fn port_failed(&mut self, id: EventId, reason: String);
    /// How the frame monitor cuts and describes the line's frames (asked once, at start): by
    /// default bytes cut by 3.5 character times of silence.
    fn monitor_framing(&self) -> Framing {
        Framing::RAW
    }
}

/// What every line is started with, whatever its protocol.
///
/// The protocol's settings carry these under the same names; [`LineBase::new`] takes them over.
#[derive(Clone, Debug)]
pub(crate) struct LineBase {
    /// The line's name (logs, status, keys).
    pub(crate) name: String,
    /// The config's `protocol` key (metrics label, REST).
    pub(crate) protocol: &'static str,
    /// The serial port.
    pub(crate) port: PortSettings,
    /// Depth of the diagnostic buffer.
    pub(crate) diag_depth: usize,
    /// First delay before reopening a failed port.
    pub(crate) reopen_min: Duration,
    /// Longest delay between reopen attempts.
    pub(crate) reopen_max: Duration,
    /// Where the line counts its events, traffic and requests (`None`: nowhere).
    pub(crate) metrics: Option<Metrics>,
    /// A second port the line only reads, with the first port's settings (`None`: one port).
    pub(crate) second_port: Option<String>,
}

// === impl LineBase ===

impl LineBase {
    /// The common settings of line `name` speaking `protocol` (the config's key).
    pub(crate) fn new(
        name: &str,
        protocol: &'static str,
        port: &PortSettings,
        diag_depth: usize,
        reopen: (Duration, Duration),
        metrics: Option<&Metrics>,
    ) -> Self {
        Self {
            name: name.to_owned(),
            protocol,
            port: port.clone(),
            diag_depth,
            reopen_min: reopen.0,
            reopen_max: reopen.1,
            metrics: metrics.cloned(),
            second_port: None,
        }
    }

    /// The line also reads the port at `path` (same settings as the first, never written): the
    /// two directions of a point-to-point link seen through a Y-cable. Both ports open and fail
    /// together; the monitor records the first port's frames as direction `a`, the second's as
    /// `b`; the engine gets the second port's bytes through [`LineEngine::handle_rx_second`].
    pub(crate) fn with_second_port(mut self, path: &str) -> Self {
        self.second_port = Some(path.to_owned());
        self
    }

    /// The line's shared state (status with `devices`, diagnostic buffer, events, metrics) on its
    /// clock.
    pub(crate) fn core(self, devices: Vec<DeviceStatus>) -> LineCore {
        let status = LineStatus::new(self.name.clone(), devices);
        let clock = Clock::start();
        let metrics = LineMetrics::new(
            self.metrics.as_ref().map(|m| m.line().clone()),
            &self.name,
            self.protocol,
        );
        LineCore {
            shared: Shared::with_metrics(status, self.diag_depth, clock, metrics),
            clock,
            base: self,
        }
    }
}

/// A line about to start: its settings, its shared state and its clock.
#[derive(Debug)]
pub(crate) struct LineCore {
    pub(crate) base: LineBase,
    pub(crate) shared: Arc<Shared>,
    pub(crate) clock: Clock,
}

/// What a line offers beyond what every line has. The protocol's module adds the accessors of
/// its own capabilities to [`LineHandle`] (an `impl LineHandle` block next to its adapter), which
/// find them with [`LineHandle::capability`].
pub(crate) trait LineCapabilities: Send + Sync + fmt::Debug + 'static {
    /// The Modbus TCP units the line answers, with their unit ids.
    fn units(&self) -> Vec<(u8, Arc<dyn UnitService>)> {
        Vec::new()
    }
    /// Frames, bytes and commands since the line started, where the protocol counts them itself.
    fn traffic(&self) -> Option<LineTraffic> {
        None
    }
    /// The capabilities as their own type.
    fn as_any(&self) -> &dyn Any;
}

/// A running line, whatever its protocol: name, protocol, status, events, Modbus TCP units, and
/// what its protocol adds (reached through accessors that answer `Option`, defined next to each
/// protocol's adapter: `client` and `device_units` of a Modbus master line, `slave_counters` and
/// `cp_memory` of a slave line, `telegram_client`, `signals`, `mailbox` and `telegram_status` of
/// a telegram line). Clones share the
/// line; [`Self::join`] waits for its task once.
#[derive(Clone, Debug)]
pub struct LineHandle {
    name: String,
    protocol: &'static str,
    shared: Arc<Shared>,
    caps: Arc<dyn LineCapabilities>,
    monitor: Option<Arc<FrameMonitor>>,
    task: Arc<Mutex<Option<JoinHandle<()>>>>,
}

// === impl LineHandle ===

impl LineHandle {
    /// The line's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The config's `protocol` key (`modbus-master-rtu`, `3964r`, ...).
    pub fn protocol(&self) -> &'static str {
        self.protocol
    }

    /// A snapshot of the line's state: port, diagnostic buffer (newest first), event counters,
    /// last STATUS word, devices. On a slave line `commands_answered` counts the requests served
    /// (answered with data or applied as a broadcast) and `commands_failed` those refused with an
    /// exception; the details are in `slave_counters`.
    pub fn status(&self) -> LineStatus {
        self.shared.snapshot()
    }

    /// Frames and bytes in each direction and commands since the line started.
    pub fn traffic(&self) -> LineTraffic {
        if let Some(traffic) = self.caps.traffic() {
            return traffic;
        }
        let mut traffic = self.shared.metrics().traffic();
        self.shared.update(|s| {
            traffic.commands_answered = s.commands_answered;
            traffic.commands_failed = s.commands_failed;
        });
        traffic
    }

    /// Empties the line's diagnostic buffer; the event counters and the STATUS word stay.
    pub fn clear_diagnostics(&self) {
        self.shared.clear_diagnostics();
    }

    /// The line's events as they happen (bounded; a lagging receiver is told how many it missed).
    pub fn subscribe_events(&self) -> broadcast::Receiver<LineEvent> {
        self.shared.subscribe()
    }

    /// The Modbus TCP units the line answers, with their unit ids.
    pub fn units(&self) -> Vec<(u8, Arc<dyn UnitService>)> {
        self.caps.units()
    }

    /// The line's frame monitor (`None` with `monitor_frames = 0`).
    pub fn monitor(&self) -> Option<&Arc<FrameMonitor>> {
        self.monitor.as_ref()
    }

    /// The capabilities of the line's protocol, if they are a `T`.
    pub(crate) fn capability<T: 'static>(&self) -> Option<&T> {
        self.caps.as_any().downcast_ref()
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
            tracing::error!(line = %self.name, %err, "line task failed");
        }
    }
}

/// Starts the task of a line: `engine` on the port `opener` opens with the line's settings, fed
/// by `commands`, until `shutdown` is cancelled. Must be called within a tokio runtime.
pub(crate) fn spawn<E: LineEngine, O: PortOpener>(
    core: LineCore,
    engine: E,
    commands: Option<mpsc::Receiver<E::Command>>,
    caps: Arc<dyn LineCapabilities>,
    opener: O,
    shutdown: CancellationToken,
) -> LineHandle {
    let LineCore {
        base,
        shared,
        clock,
    } = core;
    let name = base.name.clone();
    let protocol = base.protocol;
    let framing = engine.monitor_framing();
    let two_ports = base.second_port.is_some();
    let directions = if two_ports {
        [Direction::A, Direction::B]
    } else {
        [Direction::Rx, Direction::Tx]
    };
    let monitor = (base.port.monitor_frames > 0).then(|| {
        Arc::new(
            FrameMonitor::new(
                &name,
                framing.kind,
                base.port.monitor_frames,
                base.metrics.as_ref(),
            )
            .with_directions(directions),
        )
    });
    let reader = |direction| Reader {
        marks: MarkDecoder::new(),
        uart: None,
        no_uart_counters: false,
        recorder: monitor.as_ref().map(|m| {
            Recorder::new(Arc::clone(m), clock, framing, base.port.char_time())
                .receiving_as(direction)
        }),
    };
    let first = reader(directions[0]);
    let second = two_ports.then(|| reader(Direction::B));
    let task = PortTask {
        base,
        shared: Arc::clone(&shared),
        clock,
        engine,
        commands,
        opener,
        shutdown,
        first,
        second,
    };
    let task = tokio::spawn(task.run());
    LineHandle {
        name,
        protocol,
        shared,
        caps,
        monitor,
        task: Arc::new(Mutex::new(Some(task))),
    }
}

/// Why the driver loop ended.
#[derive(Debug)]
enum PortExit {
    Shutdown,
    Lost(String),
}

/// The task of one line.
struct PortTask<E: LineEngine, O> {
    base: LineBase,
    shared: Arc<Shared>,
    clock: Clock,
    engine: E,
    /// The line's queue; `None` once closed and drained (or for a line without one).
    commands: Option<mpsc::Receiver<E::Command>>,
    opener: O,
    shutdown: CancellationToken,
    /// What the line keeps of the port it reads (and writes).
    first: Reader,
    /// The same of its second, receive-only port, if it has one.
    second: Option<Reader>,
}

/// Which of a line's ports bytes came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Which {
    First,
    Second,
}

/// The receive side of one port of a line.
#[derive(Debug)]
struct Reader {
    /// Undoes the tty layer's line error marks of the open port (reset on every opening).
    marks: MarkDecoder,
    /// The UART's counters at the last look; `None` before the first look on this opening.
    uart: Option<UartCounters>,
    /// The port has no UART counters (a pty): not asked again until it is reopened.
    no_uart_counters: bool,
    /// Records the port's frames into the line's monitor (`None`: the monitor is off).
    recorder: Option<Recorder>,
}

// === impl Reader ===

impl Reader {
    /// The port was (re)opened: nothing carries over.
    fn opened(&mut self) {
        self.marks.reset();
        self.no_uart_counters = false;
        self.uart = None;
        if let Some(recorder) = &mut self.recorder {
            recorder.opened();
        }
    }

    /// Ends the received frame in progress if its silence has passed at `now`.
    fn expire(&mut self, now: Instant) {
        if let Some(recorder) = &mut self.recorder {
            recorder.expire(now);
        }
    }

    /// When the received frame in progress ends by silence.
    fn frame_end(&self) -> Option<Instant> {
        self.recorder.as_ref().and_then(Recorder::deadline)
    }

    /// Characters lost to an overrun since the last look at the UART's counters (0 without
    /// counters; a port without them is not asked again).
    fn overruns<P: LinePort>(&mut self, port: &P, line: &str) -> u32 {
        if self.no_uart_counters {
            return 0;
        }
        match port.uart_counters() {
            Some(Ok(counters)) => self
                .uart
                .replace(counters)
                .map_or(0, |earlier| counters.lost_since(&earlier)),
            Some(Err(err)) => {
                tracing::debug!(line, %err, "no UART counters on this port");
                self.no_uart_counters = true;
                0
            }
            None => {
                self.no_uart_counters = true;
                0
            }
        }
    }
}

// === impl PortTask ===

impl<E: LineEngine, O: PortOpener> PortTask<E, O> {
    /// Opens the port, drives it until it fails, reopens with back-off; until shutdown.
    async fn run(mut self) {
        let name = self.base.name.clone();
        let mut reopen = Backoff::clamped(self.base.reopen_min, self.base.reopen_max);
        loop {
            match self.open() {
                Ok((port, second)) => {
                    reopen.reset();
                    tracing::info!(line = %name, path = %self.base.port.path, second = self.base.second_port.as_deref(), protocol = self.base.protocol, "port open");
                    // 00 03h "parameter accepted": status, diag buffer, log, metrics.
                    self.shared.started();
                    let exit = self.drive(port, second).await;
                    self.shared.port_closed();
                    let shutting_down = matches!(exit, PortExit::Shutdown);
                    self.engine.closed(shutting_down);
                    match exit {
                        PortExit::Shutdown => break,
                        PortExit::Lost(reason) => self.port_failed(EVENT_PORT_LOST, reason),
                    }
                }
                Err(err) => self.port_failed(EVENT_PORT_SETUP, err),
            }
            let delay = reopen.next_delay();
            tracing::info!(line = %name, ?delay, "reopening the port after back-off");
            if !self.wait_closed(delay).await {
                break;
            }
        }
        if let Some(mut commands) = self.commands.take() {
            commands.close();
            while let Some(command) = commands.recv().await {
                self.engine.refuse(command, true);
            }
        }
        tracing::info!(line = %name, "line stopped");
    }

    /// Opens the line's port and its second port, if it has one: both or neither.
    fn open(&self) -> Result<(O::Port, Option<O::Port>), String> {
        let first = self.opener.open(&self.base.port)?;
        let Some(path) = &self.base.second_port else {
            return Ok((first, None));
        };
        let settings = PortSettings {
            path: path.clone(),
            ..self.base.port.clone()
        };
        let second = self
            .opener
            .open(&settings)
            .map_err(|err| format!("second port {path}: {err}"))?;
        Ok((first, Some(second)))
    }

    fn port_failed(&mut self, id: EventId, reason: String) {
        self.shared.update(|s| s.port_error = Some(reason.clone()));
        self.engine.port_failed(id, reason);
    }

    /// Waits `delay` with the port closed, refusing commands at once. False on shutdown.
    async fn wait_closed(&mut self, delay: Duration) -> bool {
        let until = Instant::now() + delay;
        loop {
            tokio::select! {
                biased;
                () = self.shutdown.cancelled() => return false,
                () = tokio::time::sleep_until(until) => return true,
                command = recv(&mut self.commands) => match command {
                    Some(command) => self.engine.refuse(command, false),
                    None => self.commands = None,
                },
            }
        }
    }

    /// Hands bytes read from a port to the engine: the one place where received bytes pass
    /// from the port to the protocol. The tty layer's marks are undone here: data to the engine's
    /// `handle_rx`, a faulty character or a BREAK to its `handle_line_error`, in stream order (a
    /// read without an `FF` byte goes to the engine as it is, without a copy). Bytes of the
    /// second port go to the engine's `*_second` hooks.
    fn receive(&mut self, which: Which, bytes: &[u8]) {
        let (at, now) = self.clock.now();
        let mut data = 0;
        let reader = match which {
            Which::First => &mut self.first,
            Which::Second => match &mut self.second {
                Some(second) => second,
                None => return,
            },
        };
        for piece in reader.marks.decode(bytes) {
            match piece {
                Piece::Data(bytes) => {
                    data += bytes.len();
                    if let Some(recorder) = &mut reader.recorder {
                        recorder.received(at, bytes);
                    }
                    match which {
                        Which::First => self.engine.handle_rx(now, bytes),
                        Which::Second => self.engine.handle_rx_second(now, bytes),
                    }
                }
                Piece::Error { error, .. } => {
                    if let Some(recorder) = &mut reader.recorder {
                        recorder.line_error(at, error);
                    }
                    match which {
                        Which::First => self.engine.handle_line_error(now, error),
                        Which::Second => self.engine.handle_line_error_second(now, error),
                    }
                }
            }
        }
        // A control character one port received tells the other port's framing what comes
        // next, as the gateway's own transmission would (3964(R): a DLE answers STX, so the
        // partner's telegram follows).
        let control = reader.recorder.as_mut().and_then(Recorder::take_control);
        let other = match which {
            Which::First => self.second.as_mut(),
            Which::Second => Some(&mut self.first),
        };
        if let (Some(byte), Some(other)) = (control, other) {
            if let Some(recorder) = &mut other.recorder {
                recorder.peer_sent(&[byte]);
            }
        }
        self.shared.metrics().received_bytes(data);
    }

    /// Looks at the UART's counters of a port (after a read): characters lost to an overrun
    /// since the last look go to the engine as [`LineError::Overrun`] (003 7.2, 08 0Ch), the one
    /// line error the stream's marks cannot show. A port without counters is not asked again.
    fn check_uart(&mut self, which: Which, port: &O::Port) {
        let line = self.base.name.as_str();
        let reader = match which {
            Which::First => &mut self.first,
            Which::Second => match &mut self.second {
                Some(second) => second,
                None => return,
            },
        };
        let lost = reader.overruns(port, line);
        if lost == 0 {
            return;
        }
        tracing::debug!(line, lost, "receive overrun");
        let (at, now) = self.clock.now();
        if let Some(recorder) = &mut reader.recorder {
            recorder.line_error(at, LineError::Overrun);
        }
        match which {
            Which::First => self.engine.handle_line_error(now, LineError::Overrun),
            Which::Second => self
                .engine
                .handle_line_error_second(now, LineError::Overrun),
        }
    }

    /// The driver loop on an open port.
    async fn drive(&mut self, mut port: O::Port, mut second: Option<O::Port>) -> PortExit {
        let path = self.base.port.path.clone();
        let second_path = self.base.second_port.clone().unwrap_or_default();
        let char_time = self.base.port.char_time();
        self.first.opened();
        self.check_uart(Which::First, &port); // the counters' start on this opening
        if let (Some(reader), Some(port)) = (&mut self.second, &second) {
            reader.opened();
            let _ = reader.overruns(port, &self.base.name);
        }
        self.engine.opened(port.modem());
        // The engine's deadlines can be fractions of a millisecond apart (t1.5/t3.5, 003 6.4.3;
        // the turnaround after a broadcast, 003 6.4.2.2): tokio's millisecond timer would add
        // 1.2 ms to each.
        let mut timer = LineTimer::new();
        let mut stopping: Option<Stop> = None;
        let mut stop_at: Option<Instant> = None;
        let mut buf = [0u8; READ_BUF];
        let mut buf_second = [0u8; READ_BUF];
        loop {
            let (now, engine_now) = self.clock.now();
            // A deadline already passed is handled without sleeping (quinn drive_timer).
            if self
                .engine
                .poll_timeout()
                .is_some_and(|t| self.clock.to_tokio(t) <= now)
            {
                self.engine.handle_timeout(engine_now);
            }
            self.first.expire(now);
            if let Some(reader) = &mut self.second {
                reader.expire(now);
            }
            if stopping.is_none() {
                self.engine.start(now);
            }
            loop {
                while let Some(action) = self.engine.poll_action() {
                    self.engine.apply_action(action, port.modem());
                }
                let Some(frame) = self.engine.poll_transmit() else {
                    break;
                };
                if let Err(err) = port.write_all(&frame).await {
                    return PortExit::Lost(format!("write to {path} failed: {err}"));
                }
                let written = Instant::now();
                let end = estimated_tx_end(written, frame.len(), char_time);
                if let Some(recorder) = &mut self.first.recorder {
                    recorder.sent(written, end, &frame);
                }
                self.shared.metrics().sent_bytes(frame.len());
                self.engine
                    .transmitted(written, frame.len(), self.clock.to_engine(end));
            }
            if self.engine.handle_events() {
                continue; // start the next job at once
            }
            if stopping.is_some() && self.engine.done() {
                return PortExit::Shutdown;
            }
            // One timer for every deadline of the line: the engine's, and the end by silence of a
            // frame the monitor is receiving (the turn of the loop closes it).
            let deadline = self.engine.poll_timeout().map(|t| self.clock.to_tokio(t));
            let wake_at = [
                deadline,
                self.first.frame_end(),
                self.second.as_ref().and_then(Reader::frame_end),
            ]
            .into_iter()
            .flatten()
            .min();
            let reading = stopping.is_none_or(|s| s.read);
            let taking = stopping.is_none();
            tokio::select! {
                biased;
                () = self.shutdown.cancelled(), if stopping.is_none() => {
                    let stop = self.engine.stop();
                    stop_at = stop.grace.map(|grace| Instant::now() + grace);
                    if stop.close_queue {
                        if let Some(mut commands) = self.commands.take() {
                            commands.close();
                            while let Ok(command) = commands.try_recv() {
                                self.engine.refuse(command, true);
                            }
                        }
                    }
                    stopping = Some(stop);
                }
                () = sleep_until_opt(stop_at) => return PortExit::Shutdown,
                read = port.read(&mut buf), if reading => match read {
                    Ok(0) => return PortExit::Lost(format!("{path} reached end of file")),
                    Ok(n) => {
                        self.receive(Which::First, buf.get(..n).unwrap_or_default());
                        self.check_uart(Which::First, &port);
                    }
                    Err(err) => return PortExit::Lost(format!("read from {path} failed: {err}")),
                },
                read = read_opt(&mut second, &mut buf_second), if reading => match read {
                    Ok(0) => return PortExit::Lost(format!("{second_path} reached end of file")),
                    Ok(n) => {
                        self.receive(Which::Second, buf_second.get(..n).unwrap_or_default());
                        if let Some(port) = &second {
                            self.check_uart(Which::Second, port);
                        }
                    }
                    Err(err) => return PortExit::Lost(format!("read from {second_path} failed: {err}")),
                },
                () = timer.sleep_until_opt(wake_at) => {
                    if deadline.is_some() && deadline == wake_at {
                        let (_, engine_now) = self.clock.now();
                        self.engine.handle_timeout(engine_now);
                    }
                }
                () = self.engine.wake() => self.engine.woken(port.modem()),
                command = recv(&mut self.commands), if taking => match command {
                    Some(command) => self.engine.command(command, port.modem()),
                    None => self.commands = None,
                },
            }
        }
    }
}

/// Reads the port if there is one; never completes without one.
async fn read_opt<P: LinePort>(port: &mut Option<P>, buf: &mut [u8]) -> std::io::Result<usize> {
    match port {
        Some(port) => port.read(buf).await,
        None => std::future::pending().await,
    }
}

/// The next command of an open queue; never for a closed one.
async fn recv<C>(commands: &mut Option<mpsc::Receiver<C>>) -> Option<C> {
    match commands {
        Some(commands) => commands.recv().await,
        None => std::future::pending().await,
    }
}

#[cfg(test)]
mod tests {
    use std::collections::VecDeque;

    use tokio::io::DuplexStream;

    use super::*;
    use crate::line::testing::{events, eventually, Ports};

    /// Echoes what it receives and writes what it is sent as a command.
    struct Echo {
        shared: Arc<Shared>,
        out: VecDeque<Vec<u8>>,
        refused: Arc<Mutex<Vec<Vec<u8>>>>,
    }

    impl LineEngine for Echo {
        type Command = Vec<u8>;

        fn opened(&mut self, modem: Option<&mut dyn SerialPort>) {
            assert!(modem.is_none(), "an in-process stream has no modem lines");
            self.out.clear();
        }
        fn handle_rx(&mut self, _now: proto_core::time::Instant, bytes: &[u8]) {
            self.out.push_back(bytes.to_vec());
        }
        fn handle_line_error(&mut self, _now: proto_core::time::Instant, error: LineError) {
            self.out.push_back(format!("<{error:?}>").into_bytes());
        }
        fn handle_timeout(&mut self, _now: proto_core::time::Instant) {}
        fn poll_timeout(&self) -> Option<proto_core::time::Instant> {
            None
        }
        fn poll_transmit(&mut self) -> Option<Vec<u8>> {
            self.out.pop_front()
        }
        fn transmitted(&mut self, _at: Instant, _len: usize, _end: proto_core::time::Instant) {
            self.shared.metrics().sent_telegram();
        }
        fn handle_events(&mut self) -> bool {
            false
        }
        fn command(&mut self, command: Vec<u8>, _modem: Option<&mut dyn SerialPort>) {
            self.out.push_back(command);
        }
        fn refuse(&mut self, command: Vec<u8>, _shutting_down: bool) {
            self.refused
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .push(command);
        }
        fn stop(&mut self) -> Stop {
            Stop {
                read: true,
                close_queue: true,
                grace: None,
            }
        }
        fn done(&self) -> bool {
            self.out.is_empty()
        }
        fn closed(&mut self, _shutting_down: bool) {}
        fn port_failed(&mut self, id: EventId, reason: String) {
            self.shared.raise(id, None, Some(reason));
        }
    }

    #[derive(Debug)]
    struct Nothing;

    impl LineCapabilities for Nothing {
        fn as_any(&self) -> &dyn Any {
            self
        }
    }

    /// The core of a test line named `name` on `path` (diag depth 8, reopen after 10 to 20 ms,
    /// no metrics) and its `Echo` engine.
    fn echo_line(name: &str, path: &str) -> (LineCore, Echo) {
        let base = LineBase::new(
            name,
            "echo",
            &PortSettings::new(path, 9600),
            8,
            (Duration::from_millis(10), Duration::from_millis(20)),
            None,
        );
        let core = base.core(Vec::new());
        let engine = Echo {
            shared: Arc::clone(&core.shared),
            out: VecDeque::new(),
            refused: Arc::new(Mutex::new(Vec::new())),
        };
        (core, engine)
    }

    #[tokio::test]
    async fn a_line_on_an_in_process_stream_opens_echoes_reopens_and_stops() {
        let (port, mut partner) = tokio::io::duplex(64);
        let opener = Ports(Mutex::new(VecDeque::from([
            Err("busy".to_owned()),
            Ok(port),
        ])));
        let (core, engine) = echo_line("echo", "/dev/in-process");
        let refused = Arc::clone(&engine.refused);
        let (tx, rx) = mpsc::channel(4);
        let shutdown = CancellationToken::new();
        let line = spawn(
            core,
            engine,
            Some(rx),
            Arc::new(Nothing),
            opener,
            shutdown.clone(),
        );
        assert_eq!((line.name(), line.protocol()), ("echo", "echo"));

        // The first opening fails (02 0Fh), the second after the back-off succeeds.
        eventually("the port open", || line.status().port_open).await;
        assert_eq!(events(&line, EVENT_PORT_SETUP), 1);
        assert_eq!(events(&line, ids::PTP_PARAMS_ACCEPTED), 1);

        // Bytes in, the engine's answer out; a command out.
        partner.write_all(b"hello").await.expect("write");
        let mut echo = [0u8; 5];
        partner.read_exact(&mut echo).await.expect("echo");
        assert_eq!(&echo, b"hello");
        tx.send(b"cmd".to_vec()).await.expect("queue");
        let mut cmd = [0u8; 3];
        partner.read_exact(&mut cmd).await.expect("command");
        assert_eq!(&cmd, b"cmd");
        let traffic = line.traffic();
        assert_eq!(
            (
                traffic.bytes_received,
                traffic.bytes_sent,
                traffic.frames_sent
            ),
            (5, 8, 2)
        );

        // The partner goes: 08 0Dh, then every reopening fails while commands are refused.
        drop(partner);
        eventually("the port lost", || events(&line, EVENT_PORT_LOST) == 1).await;
        eventually("a failed reopening", || {
            events(&line, EVENT_PORT_SETUP) >= 2
        })
        .await;
        let status = line.status();
        assert!(!status.port_open);
        assert_eq!(status.port_error.as_deref(), Some("no such port"));
        tx.send(b"late".to_vec()).await.expect("queue");
        eventually("the late command refused", || {
            refused.lock().unwrap_or_else(PoisonError::into_inner).len() == 1
        })
        .await;

        shutdown.cancel();
        tokio::time::timeout(Duration::from_secs(2), line.join())
            .await
            .expect("the line stops");
        assert!(tx.send(b"after".to_vec()).await.is_err(), "queue closed");
    }

    #[tokio::test]
    async fn the_port_layer_records_every_frame_into_the_monitor() {
        let (port, mut partner) = tokio::io::duplex(64);
        let opener = Ports(Mutex::new(VecDeque::from([Ok(port)])));
        let (core, engine) = echo_line("monitored", "/dev/in-process");
        let shutdown = CancellationToken::new();
        let line = spawn(
            core,
            engine,
            None,
            Arc::new(Nothing),
            opener,
            shutdown.clone(),
        );
        eventually("the port open", || line.status().port_open).await;
        let monitor = Arc::clone(line.monitor().expect("a monitor by default"));

        // Bytes in with a parity mark inside (one read), the echo out piece by piece: the first
        // transmission ends the received frame, which carries the line error at its place.
        partner
            .write_all(&[b'h', b'i', 0xFF, 0x00, b'x', b'!'])
            .await
            .expect("write");
        let expected: &[u8] = b"hi<ParityOrFraming>!";
        let mut echo = vec![0u8; expected.len()];
        partner.read_exact(&mut echo).await.expect("echo");
        eventually("four frames", || monitor.frames_since(0).0.len() == 4).await;
        let (frames, next) = monitor.frames_since(0);
        assert_eq!(next, 5);
        assert_eq!(
            frames
                .iter()
                .map(|f| (f.direction, f.bytes.clone()))
                .collect::<Vec<_>>(),
            [
                (Direction::Rx, b"hi!".to_vec()),
                (Direction::Tx, b"hi".to_vec()),
                (Direction::Tx, b"<ParityOrFraming>".to_vec()),
                (Direction::Tx, b"!".to_vec()),
            ]
        );
        assert_eq!(frames[0].errors.len(), 1);
        assert_eq!(frames[0].errors[0].offset, 2);
        assert!(frames[0].first_mono <= frames[0].last_mono);
        assert!(
            frames[0].last_mono <= frames[1].first_mono,
            "ordered by time"
        );

        shutdown.cancel();
        tokio::time::timeout(Duration::from_secs(2), line.join())
            .await
            .expect("the line stops");
    }

    #[tokio::test]
    async fn marks_are_decoded_in_stream_order_and_forgotten_on_reopening() {
        let (first, mut partner) = tokio::io::duplex(64);
        let (second, mut partner2) = tokio::io::duplex(64);
        let opener = Ports(Mutex::new(VecDeque::from([Ok(first), Ok(second)])));
        let (core, engine) = echo_line("marks", "/dev/in-process");
        let shutdown = CancellationToken::new();
        let line = spawn(
            core,
            engine,
            None,
            Arc::new(Nothing),
            opener,
            shutdown.clone(),
        );
        eventually("the port open", || line.status().port_open).await;

        // What the tty layer delivers with INPCK | PARMRK: 01, FF (doubled), 02, 'A' with a
        // parity or framing error, 03, a BREAK, 04; the BREAK's mark split across two reads.
        partner
            .write_all(&[0x01, 0xFF, 0xFF, 0x02, 0xFF, 0x00, b'A', 0x03, 0xFF])
            .await
            .expect("write");
        partner.write_all(&[0x00, 0x00, 0x04]).await.expect("write");
        let expected: &[u8] = b"\x01\xFF\x02<ParityOrFraming>\x03<Break>\x04";
        let mut echo = vec![0u8; expected.len()];
        partner.read_exact(&mut echo).await.expect("echo");
        assert_eq!(echo, expected);
        assert_eq!(
            line.traffic().bytes_received,
            5,
            "data bytes, marks removed"
        );

        // A mark cut off by the port's loss is not completed by the next opening's bytes.
        partner.write_all(&[0x05, 0xFF]).await.expect("write");
        let mut five = [0u8; 1];
        partner.read_exact(&mut five).await.expect("echo");
        assert_eq!(five, [0x05]);
        drop(partner);
        eventually("the port reopened", || {
            line.status().port_opens == 2 && line.status().port_open
        })
        .await;
        partner2.write_all(&[0x00, 0x00]).await.expect("write");
        let mut zeros = [0xAAu8; 2];
        partner2.read_exact(&mut zeros).await.expect("echo");
        assert_eq!(zeros, [0x00, 0x00]);

        shutdown.cancel();
        tokio::time::timeout(Duration::from_secs(2), line.join())
            .await
            .expect("the line stops");
    }

    /// What each port of a two-port line handed the engine, in order.
    type Got = Arc<Mutex<Vec<(Which, Vec<u8>)>>>;

    /// Keeps what each port of a two-port line hands it; never transmits.
    struct Listener {
        shared: Arc<Shared>,
        got: Got,
    }

    impl LineEngine for Listener {
        type Command = ();

        fn opened(&mut self, _modem: Option<&mut dyn SerialPort>) {}
        fn handle_rx(&mut self, _now: proto_core::time::Instant, bytes: &[u8]) {
            let mut got = self.got.lock().unwrap_or_else(PoisonError::into_inner);
            got.push((Which::First, bytes.to_vec()));
        }
        fn handle_rx_second(&mut self, _now: proto_core::time::Instant, bytes: &[u8]) {
            let mut got = self.got.lock().unwrap_or_else(PoisonError::into_inner);
            got.push((Which::Second, bytes.to_vec()));
        }
        fn handle_line_error(&mut self, _now: proto_core::time::Instant, _error: LineError) {}
        fn handle_line_error_second(&mut self, _now: proto_core::time::Instant, error: LineError) {
            let mut got = self.got.lock().unwrap_or_else(PoisonError::into_inner);
            got.push((Which::Second, format!("<{error:?}>").into_bytes()));
        }
        fn handle_timeout(&mut self, _now: proto_core::time::Instant) {}
        fn poll_timeout(&self) -> Option<proto_core::time::Instant> {
            None
        }
        fn poll_transmit(&mut self) -> Option<Vec<u8>> {
            None
        }
        fn transmitted(&mut self, _at: Instant, _len: usize, _end: proto_core::time::Instant) {}
        fn handle_events(&mut self) -> bool {
            false
        }
        fn command(&mut self, (): (), _modem: Option<&mut dyn SerialPort>) {}
        fn refuse(&mut self, (): (), _shutting_down: bool) {}
        fn stop(&mut self) -> Stop {
            Stop {
                read: false,
                close_queue: true,
                grace: None,
            }
        }
        fn done(&self) -> bool {
            true
        }
        fn closed(&mut self, _shutting_down: bool) {}
        fn port_failed(&mut self, id: EventId, reason: String) {
            self.shared.raise(id, None, Some(reason));
        }
        fn monitor_framing(&self) -> Framing {
            Framing {
                kind: proto_core::monitor::FrameKind::Proc3964 { bcc: true },
                gap: Some(Duration::from_millis(50)),
            }
        }
    }

    #[tokio::test]
    async fn a_line_with_a_second_port_reads_both_and_records_each_as_its_side() {
        use proto_core::monitor::Direction;
        use proto_core::proc3964::{DLE, STX};

        // First opening: the second port is missing, so neither stays open (02 0Fh names it).
        let (a, mut partner_a) = tokio::io::duplex(64);
        let (b, mut partner_b) = tokio::io::duplex(64);
        let (unused, _unused_partner) = tokio::io::duplex(64);
        let opener = Ports(Mutex::new(VecDeque::from([
            Ok(unused),
            Err("busy".to_owned()),
            Ok(a),
            Ok(b),
        ])));
        let base = LineBase::new(
            "y",
            "listener",
            &PortSettings::new("/dev/in-process-a", 9600),
            8,
            (Duration::from_millis(10), Duration::from_millis(20)),
            None,
        )
        .with_second_port("/dev/in-process-b");
        let core = base.core(Vec::new());
        let got = Arc::new(Mutex::new(Vec::new()));
        let engine = Listener {
            shared: Arc::clone(&core.shared),
            got: Arc::clone(&got),
        };
        let shutdown = CancellationToken::new();
        let line = spawn(
            core,
            engine,
            None,
            Arc::new(Nothing),
            opener,
            shutdown.clone(),
        );
        eventually("the ports open", || line.status().port_open).await;
        assert_eq!(events(&line, EVENT_PORT_SETUP), 1);
        assert_eq!(line.status().port_opens, 1);
        let monitor = Arc::clone(line.monitor().expect("a monitor"));
        assert_eq!(monitor.directions(), [Direction::A, Direction::B]);

        // A asks, B acknowledges, A's telegram begins with a doubled DLE (data 10 20): B's DLE
        // tells A's framing that a telegram follows, so it is one frame, not a DLE and the rest.
        let telegram = [DLE, DLE, 0x20, DLE, 0x03, 0x20 ^ 0x03];
        partner_a.write_all(&[STX]).await.expect("write");
        eventually("A's STX", || monitor.frames_since(0).0.len() == 1).await;
        partner_b.write_all(&[DLE]).await.expect("write");
        eventually("B's DLE", || monitor.frames_since(0).0.len() == 2).await;
        partner_a.write_all(&telegram).await.expect("write");
        eventually("A's telegram", || monitor.frames_since(0).0.len() == 3).await;
        // A parity mark on B's port reaches the engine's second-port hook.
        partner_b
            .write_all(&[0xFF, 0x00, b'x', DLE])
            .await
            .expect("write");
        eventually("B's answer", || monitor.frames_since(0).0.len() == 4).await;
        let (frames, _) = monitor.frames_since(0);
        assert_eq!(
            frames
                .iter()
                .map(|f| (f.direction, f.bytes.clone()))
                .collect::<Vec<_>>(),
            [
                (Direction::A, vec![STX]),
                (Direction::B, vec![DLE]),
                (Direction::A, telegram.to_vec()),
                (Direction::B, vec![DLE]),
            ]
        );
        assert_eq!(
            frames[3].errors.len(),
            1,
            "the parity error inside B's frame"
        );
        let got = got.lock().unwrap_or_else(PoisonError::into_inner).clone();
        let first: Vec<u8> = got
            .iter()
            .filter(|(w, _)| *w == Which::First)
            .flat_map(|(_, b)| b.clone())
            .collect();
        let second: Vec<u8> = got
            .iter()
            .filter(|(w, _)| *w == Which::Second)
            .flat_map(|(_, b)| b.clone())
            .collect();
        assert_eq!(first, [&[STX][..], &telegram].concat());
        assert_eq!(second, b"\x10<ParityOrFraming>\x10");
        assert_eq!(line.traffic().bytes_received, 1 + 6 + 1 + 1);

        // Losing the second port loses the line: 08 0Dh naming it.
        drop(partner_b);
        eventually("the port lost", || events(&line, EVENT_PORT_LOST) == 1).await;
        let error = line.status().port_error.unwrap_or_default();
        assert!(error.contains("/dev/in-process-b"), "{error}");

        shutdown.cancel();
        tokio::time::timeout(Duration::from_secs(2), line.join())
            .await
            .expect("the line stops");
    }

    /// An in-process port with UART counters the test sets (`None`: the driver has none).
    struct Uart {
        inner: DuplexStream,
        counters: Arc<Mutex<Option<UartCounters>>>,
        asked: Arc<std::sync::atomic::AtomicUsize>,
    }

    impl AsyncRead for Uart {
        fn poll_read(
            mut self: std::pin::Pin<&mut Self>,
            cx: &mut std::task::Context<'_>,
            buf: &mut tokio::io::ReadBuf<'_>,
        ) -> std::task::Poll<std::io::Result<()>> {
            std::pin::Pin::new(&mut self.inner).poll_read(cx, buf)
        }
    }

    impl AsyncWrite for Uart {
        fn poll_write(
            mut self: std::pin::Pin<&mut Self>,
            cx: &mut std::task::Context<'_>,
            buf: &[u8],
        ) -> std::task::Poll<std::io::Result<usize>> {
            std::pin::Pin::new(&mut self.inner).poll_write(cx, buf)
        }
        fn poll_flush(
            mut self: std::pin::Pin<&mut Self>,
            cx: &mut std::task::Context<'_>,
        ) -> std::task::Poll<std::io::Result<()>> {
            std::pin::Pin::new(&mut self.inner).poll_flush(cx)
        }
        fn poll_shutdown(
            mut self: std::pin::Pin<&mut Self>,
            cx: &mut std::task::Context<'_>,
        ) -> std::task::Poll<std::io::Result<()>> {
            std::pin::Pin::new(&mut self.inner).poll_shutdown(cx)
        }
    }

    impl LinePort for Uart {
        fn uart_counters(&self) -> Option<std::io::Result<UartCounters>> {
            self.asked.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
            let counters = *self.counters.lock().unwrap_or_else(PoisonError::into_inner);
            Some(counters.ok_or_else(|| std::io::Error::from_raw_os_error(libc::ENOTTY)))
        }
    }

    struct OneUart(Mutex<Option<Uart>>);

    impl PortOpener for OneUart {
        type Port = Uart;

        fn open(&self, _settings: &PortSettings) -> Result<Uart, String> {
            self.0
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .take()
                .ok_or_else(|| "no second port".to_owned())
        }
    }

    #[tokio::test]
    async fn a_grown_overrun_count_is_a_line_error_and_a_port_without_counters_is_not_asked_again()
    {
        let (inner, mut partner) = tokio::io::duplex(64);
        let counters = Arc::new(Mutex::new(Some(UartCounters {
            overrun: 5,
            frame: 2,
            ..UartCounters::default()
        })));
        let asked = Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let port = Uart {
            inner,
            counters: Arc::clone(&counters),
            asked: Arc::clone(&asked),
        };
        let (core, engine) = echo_line("uart", "/dev/ttyS0");
        let shutdown = CancellationToken::new();
        let opener = OneUart(Mutex::new(Some(port)));
        let line = spawn(
            core,
            engine,
            None,
            Arc::new(Nothing),
            opener,
            shutdown.clone(),
        );
        eventually("the port open", || line.status().port_open).await;
        let set = |c: Option<UartCounters>| {
            *counters.lock().unwrap_or_else(PoisonError::into_inner) = c;
        };

        // The counts at opening are the start: nothing lost yet.
        partner.write_all(b"a").await.expect("write");
        let mut a = [0u8; 1];
        partner.read_exact(&mut a).await.expect("echo");
        assert_eq!(&a, b"a");

        // Two characters lost (and a framing error, which the marks report, not the counters).
        set(Some(UartCounters {
            overrun: 7,
            frame: 3,
            ..UartCounters::default()
        }));
        partner.write_all(b"b").await.expect("write");
        let expected: &[u8] = b"b<Overrun>";
        let mut got = vec![0u8; expected.len()];
        partner.read_exact(&mut got).await.expect("echo");
        assert_eq!(got, expected);

        // The driver refuses the ioctl: asked once more, then never again on this opening.
        set(None);
        partner.write_all(b"c").await.expect("write");
        let mut c = [0u8; 1];
        partner.read_exact(&mut c).await.expect("echo");
        let after_refusal = asked.load(std::sync::atomic::Ordering::SeqCst);
        partner.write_all(b"d").await.expect("write");
        partner.read_exact(&mut c).await.expect("echo");
        assert_eq!(&c, b"d");
        assert_eq!(
            asked.load(std::sync::atomic::Ordering::SeqCst),
            after_refusal
        );
        assert_eq!(
            after_refusal, 4,
            "at opening and after the reads of a, b and c"
        );

        shutdown.cancel();
        tokio::time::timeout(Duration::from_secs(2), line.join())
            .await
            .expect("the line stops");
    }
}
