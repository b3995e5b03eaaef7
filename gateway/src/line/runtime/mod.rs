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
use super::metrics::{LineFamilies, LineMetrics, LineTraffic};
use super::monitor::{FrameMonitor, Recorder};
use super::status::{DeviceStatus, LineEvent, LineStatus, Shared};
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
    /// Whether the tty layer marks line errors in the received bytes (`INPCK | PARMRK`, as
    /// [`serial::open`] sets them): the runtime then undoes the marks. A port opened without
    /// them says false, and its bytes reach the engine as they are.
    fn marks_line_errors(&self) -> bool {
        true
    }
}

/// A byte stream whose bytes carry no line error marks (a serial port opened without
/// `PARMRK`, one end of `SerialStream::pair()`, an in-process stream): the simulators' ports.
#[derive(Debug)]
pub struct Unmarked<S>(pub S);

impl<S: AsyncRead + Unpin> AsyncRead for Unmarked<S> {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.0).poll_read(cx, buf)
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Unmarked<S> {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.0).poll_write(cx, buf)
    }
    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.0).poll_flush(cx)
    }
    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.0).poll_shutdown(cx)
    }
}

impl<S: AsyncRead + AsyncWrite + Unpin + Send + 'static> LinePort for Unmarked<S> {
    fn marks_line_errors(&self) -> bool {
        false
    }
}

/// Hands out one port already open, then refuses: a line on a stream its caller made (the
/// simulators on one end of a pty pair).
#[derive(Debug)]
pub(crate) struct GivenPort<P>(Mutex<Option<P>>);

impl<P> GivenPort<P> {
    /// The opener of `port`.
    pub(crate) fn new(port: P) -> Self {
        Self(Mutex::new(Some(port)))
    }
}

impl<P: LinePort> PortOpener for GivenPort<P> {
    type Port = P;

    fn open(&self, _settings: &PortSettings) -> Result<P, String> {
        self.0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .take()
            .ok_or_else(|| "the port was closed".to_owned())
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

impl Stop {
    /// Stops at once, as a device switched off: the port no longer read, the queue closed, no
    /// grace (the simulators and the listen-only taps, which have nothing in flight of their own).
    pub(crate) const AT_ONCE: Self = Self {
        read: false,
        close_queue: true,
        grace: Some(Duration::ZERO),
    };
}

/// What the runtime needs from a line protocol: the proto-core engine with what the protocol does
/// with its results. Inputs are bytes, time and commands; outputs are bytes, RS232 actions,
/// deadlines and the events the adapter hands on itself (status, image, mailbox).
///
/// The engine proper is this trait: bytes and time in, frames and the next deadline out. What a
/// line does besides is grouped by capability, each with its own small trait: the queue of
/// commands ([`LineCommands`]), how it starts being watched, stops, closes and fails
/// ([`LineLifecycle`]), the RS232 outputs and the adapter's own wake-up ([`LineSignals`], nothing
/// by default) and a second, receive-only port ([`SecondPort`], nothing by default).
pub(crate) trait LineEngine:
    LineCommands + LineLifecycle + LineSignals + SecondPort + Send + 'static
{
    /// The port opened: the adapter starts a fresh engine (nothing carries over a reopen) and
    /// sets the outputs as the protocol wants them.
    fn opened(&mut self, modem: Option<&mut dyn SerialPort>);
    /// Received bytes, at `now`.
    fn handle_rx(&mut self, now: proto_core::time::Instant, bytes: &[u8]);
    /// A character received with a parity or framing error, a BREAK, or characters lost to an
    /// overrun, at `now`, between the bytes handed to `handle_rx` before and after it.
    fn handle_line_error(&mut self, now: proto_core::time::Instant, error: LineError);
    /// The engine's deadline has come.
    fn handle_timeout(&mut self, now: proto_core::time::Instant);
    /// The engine's next deadline.
    fn poll_timeout(&self) -> Option<proto_core::time::Instant>;
    /// The next bytes to write.
    fn poll_transmit(&mut self) -> Option<Vec<u8>>;
    /// `len` bytes were written at `written`, estimated to leave the line at `end`.
    fn transmitted(&mut self, written: Instant, len: usize, end: proto_core::time::Instant);
    /// Hands the engine's events on; true when that made progress that needs another turn at
    /// once (a completed request starts the next job).
    fn handle_events(&mut self) -> bool;
}

/// The line's queue: what clients ask of it, and the work it starts by itself.
pub(crate) trait LineCommands {
    /// What clients queue for the line (`()` for a line without a queue).
    type Command: Send + 'static;

    /// Starts work while the line runs (the next poll or command); `now` on tokio's clock.
    fn start(&mut self, _now: Instant) {}
    /// A command from the queue while the port is open.
    fn command(&mut self, command: Self::Command, modem: Option<&mut dyn SerialPort>);
    /// A command that cannot be carried: the port is closed, or the line is `shutting_down`.
    fn refuse(&mut self, command: Self::Command, shutting_down: bool);
}

/// How a line is watched, stops, closes and fails.
pub(crate) trait LineLifecycle {
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

/// The RS232 outputs the engine sets and the adapter's own wake-up (the next poll, a signal
/// poll, room in a mailbox); a line without either keeps the defaults.
pub(crate) trait LineSignals {
    /// The next RS232 output the engine sets (before its next transmission).
    fn poll_action(&mut self) -> Option<Action> {
        None
    }
    /// Sets an output the engine asks for.
    fn apply_action(&mut self, _action: Action, _modem: Option<&mut dyn SerialPort>) {}
    /// The adapter's own wake-up.
    fn wake(&self) -> impl Future<Output = ()> + Send + '_ {
        std::future::pending()
    }
    /// The wake-up came.
    fn woken(&mut self, _modem: Option<&mut dyn SerialPort>) {}
}

/// The line's second, receive-only port (only a line started with one, see
/// [`LineBase::with_second_port`]: a listen-only tap of both directions of a point-to-point
/// link); a line without one keeps the defaults.
pub(crate) trait SecondPort {
    /// Bytes received on the second port at `now`.
    fn handle_rx_second(&mut self, _now: proto_core::time::Instant, _bytes: &[u8]) {}
    /// A line error on the second port, as [`LineEngine::handle_line_error`] on the first.
    fn handle_line_error_second(&mut self, _now: proto_core::time::Instant, _error: LineError) {}
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
    pub(crate) metrics: Option<LineFamilies>,
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
        metrics: Option<&LineFamilies>,
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
        let metrics = LineMetrics::new(self.metrics.clone(), &self.name, self.protocol);
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
        unmarked: false,
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
    let task = crate::task::spawn("line port task", task.run());
    LineHandle {
        name,
        protocol,
        shared,
        caps,
        monitor,
        task: Arc::new(Mutex::new(Some(task))),
    }
}

mod task;
use task::{PortTask, Reader};

#[cfg(test)]
mod tests;
