//! The listen-only 3964(R) tap line (`protocol = "3964r-tap"`): both directions of a
//! point-to-point link, seen through a Y-cable on two receive ports, decoded by
//! [`proto_core::proc3964::tap::Tap3964`].
//!
//! ```text
//!   partner A ── TxD A ──┬──────────────────────────> partner B
//!                        └──> port   (side a) ─┐
//!   partner B ── TxD B ──┬──────────────────────────> partner A
//!                        └──> port_b (side b) ─┴─> [ runtime: both ports ] ─> Tap3964
//!                                                    │ monitor: frames a / b
//!                                                    └─> mailbox (read-only), events, counters
//! ```
//!
//! The line never writes to either port. The runtime reads both ([`LineBase::with_second_port`]),
//! so they open, fail and reopen together, and records each port's frames in the monitor as
//! side `a` or `b`. The decoder follows the procedure of 003 6.3.1 on both sides at once; each
//! telegram a partner sent and the other acknowledged goes to the line's mailbox with its side
//! (REST `telegrams`, zenoh `<line>/rx`, the Modbus TCP mailbox unit). The mailbox is
//! read-only: every send is refused ([`TelegramSendError::ListenOnly`]: REST 409, a zenoh error,
//! Modbus exception 01), and a full mailbox lets its oldest telegram go (a tap cannot refuse a
//! telegram: it is not a partner). Faults are events of 003 7.2 from the sender's view (a NAK to
//! the connection request is 07 02h, a bad BCC 08 08h) with the side in the detail, and are
//! counted in `gateway_frames_discarded_total{reason}`.

pub(crate) mod config;

use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};

use proto_core::event::{ids, EventId};
use proto_core::monitor::{FrameKind, Framing};
use proto_core::proc3964::frame::FrameError;
use proto_core::proc3964::tap::{Fault, Side, Tap3964, TapConfig3964, TapEvent3964};
use proto_core::proc3964::Variant;
use proto_core::serial_marks::LineError;
use tokio::sync::mpsc;
use tokio::time::Instant;
use tokio_serial::SerialPort;
use tokio_util::sync::CancellationToken;

use super::client::{Command, TelegramClient, TelegramSendError};
use super::LineShared;
use crate::line::metrics::LineFamilies;
use crate::line::runtime::{
    self, LineBase, LineEngine, LineHandle, PortOpener, SerialOpener, Stop,
};
use crate::line::runtime::{LineCommands, LineLifecycle, LineSignals, SecondPort};
use crate::line::{DEFAULT_DIAG_DEPTH, DEFAULT_REOPEN_MAX, DEFAULT_REOPEN_MIN};
use crate::mailbox::{Delivery, Mailbox, MailboxSettings, Overflow};
use crate::serial::PortSettings;
use crate::signals::SignalError;
pub use config::Proc3964TapConfig;

/// The config's `protocol` key of a 3964(R) tap line.
pub const TAP_3964_PROTOCOL: &str = "3964r-tap";
/// Telegrams the mailbox keeps by default (the 3964(R) line's default receive buffer).
pub const DEFAULT_TAP_MAILBOX: usize = crate::protocols::DEFAULT_3964_RECEIVE_BUFFER as usize;
/// Signal requests that may wait for the line (they are all refused).
const COMMAND_QUEUE: usize = 4;

/// Settings of one 3964(R) tap line.
#[derive(Clone, Debug)]
pub struct Tap3964LineSettings {
    /// The line's name (logs, status, keys).
    pub name: String,
    /// The first receive port: what partner A transmits (side `a`).
    pub port: PortSettings,
    /// The second receive port's path: what partner B transmits (side `b`), with the first
    /// port's serial settings.
    pub port_b: String,
    /// The partners' procedure: 3964 or 3964R, ZVZ, QVZ, the longest telegram.
    pub tap: TapConfig3964,
    /// Telegrams the mailbox keeps (the oldest goes when it is full).
    pub mailbox_depth: usize,
    /// Depth of the diagnostic buffer.
    pub diag_depth: usize,
    /// First delay before reopening the ports after a failure.
    pub reopen_min: Duration,
    /// Longest delay between reopen attempts.
    pub reopen_max: Duration,
    /// Prometheus families, if the gateway exports them.
    pub metrics: Option<LineFamilies>,
    /// The unit id under which Modbus TCP serves the (read-only) mailbox.
    pub unit_id: Option<u8>,
}

// === impl Tap3964LineSettings ===

impl Tap3964LineSettings {
    /// A tap on `port` (side a) and `port_b` (side b) of a link speaking `variant`, with the
    /// manual's times and the default mailbox.
    pub fn new(
        name: impl Into<String>,
        port: PortSettings,
        port_b: impl Into<String>,
        variant: Variant,
    ) -> Self {
        Self {
            name: name.into(),
            port,
            port_b: port_b.into(),
            tap: TapConfig3964::new(variant),
            mailbox_depth: DEFAULT_TAP_MAILBOX,
            diag_depth: DEFAULT_DIAG_DEPTH,
            reopen_min: DEFAULT_REOPEN_MIN,
            reopen_max: DEFAULT_REOPEN_MAX,
            metrics: None,
            unit_id: None,
        }
    }
}

/// Starts a 3964(R) tap line: opens both its ports (reopening them with back-off) and records
/// what the partners exchange until `shutdown` is cancelled. Must be called within a tokio
/// runtime.
pub fn spawn_3964_tap_line(
    settings: Tap3964LineSettings,
    shutdown: CancellationToken,
) -> LineHandle {
    spawn_on(settings, shutdown, SerialOpener)
}

/// [`spawn_3964_tap_line`] on the ports `opener` opens.
pub(crate) fn spawn_on<O: PortOpener>(
    settings: Tap3964LineSettings,
    shutdown: CancellationToken,
    opener: O,
) -> LineHandle {
    let name: Arc<str> = Arc::from(settings.name.as_str());
    let (tx, rx) = mpsc::channel(COMMAND_QUEUE);
    let base = LineBase::new(
        &settings.name,
        TAP_3964_PROTOCOL,
        &settings.port,
        settings.diag_depth,
        (settings.reopen_min, settings.reopen_max),
        settings.metrics.as_ref(),
    )
    .with_second_port(&settings.port_b);
    let core = base.core(Vec::new());
    core.shared.metrics().init_frames_discarded(&FAULT_KINDS);
    let mailbox = MailboxSettings {
        ack: crate::mailbox::AckMode::Explicit,
        queue_depth: settings.mailbox_depth,
        overflow: Overflow::DropOldest,
    };
    let shared = Arc::new(LineShared {
        metrics: core.shared.metrics().clone(),
        status: Arc::clone(&core.shared),
        mailbox: Mailbox::new(&settings.name, mailbox, 0),
        protocol: match settings.tap.variant {
            Variant::P3964 => "3964",
            Variant::P3964R => "3964R",
        },
        signals_error: Mutex::new(None),
        client: TelegramClient::new(Arc::clone(&name), tx, COMMAND_QUEUE).listen_only(),
        unit_id: settings.unit_id,
    });
    let engine = TapLine {
        tap: Tap3964::new(settings.tap),
        settings,
        shared: Arc::clone(&shared),
    };
    runtime::spawn(core, engine, Some(rx), shared, opener, shutdown)
}

/// The adapter of a 3964(R) tap line; the decoder lives as long as one opening of the ports.
struct TapLine {
    settings: Tap3964LineSettings,
    shared: Arc<LineShared>,
    tap: Tap3964,
}

impl LineEngine for TapLine {
    fn opened(&mut self, _modem: Option<&mut dyn SerialPort>) {
        self.shared.mailbox.set_port_open(true);
        self.tap = Tap3964::new(self.settings.tap);
    }

    fn handle_rx(&mut self, now: proto_core::time::Instant, bytes: &[u8]) {
        self.tap.handle_rx(Side::A, now, bytes);
    }

    fn handle_line_error(&mut self, now: proto_core::time::Instant, error: LineError) {
        self.tap.handle_line_error(Side::A, now, error);
    }

    crate::line::driver::engine_calls!(tap: timeout);

    /// A tap never transmits.
    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        None
    }

    fn transmitted(&mut self, _written: Instant, _len: usize, _end: proto_core::time::Instant) {}

    fn handle_events(&mut self) -> bool {
        while let Some(event) = self.tap.poll_event() {
            self.record(event);
        }
        false
    }
}

impl LineCommands for TapLine {
    type Command = Command;

    fn command(&mut self, command: Command, _modem: Option<&mut dyn SerialPort>) {
        self.refuse_listen_only(command);
    }

    fn refuse(&mut self, command: Command, shutting_down: bool) {
        if shutting_down {
            command.refuse(&self.settings.name, true);
        } else {
            self.refuse_listen_only(command);
        }
    }
}

impl LineLifecycle for TapLine {
    fn stop(&mut self) -> Stop {
        Stop::AT_ONCE
    }

    fn done(&self) -> bool {
        true
    }

    /// An exchange cut off by the loss of the ports is not reported: the decoder starts afresh.
    fn closed(&mut self, _shutting_down: bool) {
        self.handle_events();
        self.shared.mailbox.set_port_open(false);
    }

    fn port_failed(&mut self, id: EventId, reason: String) {
        self.shared.raise(id, Some(reason));
    }

    fn monitor_framing(&self) -> Framing {
        Framing {
            kind: FrameKind::Proc3964 {
                bcc: self.settings.tap.variant == Variant::P3964R,
            },
            // A frame of one side ends at its end mark or after the character delay time.
            gap: Some(self.settings.tap.zvz),
        }
    }
}

impl LineSignals for TapLine {}

impl SecondPort for TapLine {
    fn handle_rx_second(&mut self, now: proto_core::time::Instant, bytes: &[u8]) {
        self.tap.handle_rx(Side::B, now, bytes);
    }

    fn handle_line_error_second(&mut self, now: proto_core::time::Instant, error: LineError) {
        self.tap.handle_line_error(Side::B, now, error);
    }
}

// === impl TapLine ===

impl TapLine {
    /// Answers a command: a tap neither sends nor uses modem signals.
    fn refuse_listen_only(&self, command: Command) {
        let line = self.settings.name.clone();
        match command {
            Command::Send { reply, .. } => {
                let _ = reply.send(Err(TelegramSendError::ListenOnly { line }));
            }
            Command::ReadSignals { reply } => {
                let _ = reply.send(Err(SignalError::ListenOnly { line }));
            }
            Command::SetSignal { reply, .. } => {
                let _ = reply.send(Err(SignalError::ListenOnly { line }));
            }
        }
    }

    /// Hands one event of the decoder on: a telegram to the mailbox, a fault to the status
    /// (the event of 003 7.2 from the sender's view) and the discard counter.
    fn record(&mut self, event: TapEvent3964) {
        match event {
            TapEvent3964::Telegram { side, data, .. } => {
                self.shared.metrics.received_telegram();
                let mailbox = &self.shared.mailbox;
                let depth = mailbox.settings().queue_depth;
                match mailbox.deliver_from(data, SystemTime::now(), Some(side)) {
                    Delivery::DroppedOldest { seq, dropped } => self.shared.raise(
                        ids::NO_FREE_RECEIVE_BUFFER,
                        Some(format!(
                            "mailbox full ({depth} telegrams): oldest telegram {dropped} dropped for {seq}"
                        )),
                    ),
                    other => {
                        tracing::debug!(line = %self.settings.name, side = side.as_str(), ?other, "telegram seen");
                    }
                }
            }
            TapEvent3964::Repetition { side } => {
                self.shared.raise(
                    ids::SEND_REPETITION,
                    Some(format!("partner {} repeats its request", side.as_str())),
                );
            }
            TapEvent3964::Fault { side, fault } => {
                self.shared.metrics.frame_discarded(fault);
                let detail = format!("partner {}: {}", side.as_str(), describe(fault));
                match fault_event(fault) {
                    Some(id) => self.shared.raise(id, Some(detail)),
                    None => tracing::debug!(line = %self.settings.name, %detail, "tap fault"),
                }
            }
        }
    }
}

/// One fault of each kind, in the order of [`Fault::REASONS`]: the discard series a 3964(R) tap
/// line creates at 0.
const FAULT_KINDS: [Fault; 7] = [
    Fault::Nak {
        after_telegram: false,
    },
    Fault::MissingDle {
        after_telegram: false,
    },
    Fault::Frame(FrameError::BadBcc {
        expected: 0,
        actual: 0,
    }),
    Fault::Frame(FrameError::Incomplete),
    Fault::Conflict,
    Fault::Stray { len: 0 },
    Fault::LineError {
        error: LineError::Break,
    },
];

/// The event of 003 7.2 that the sender of the exchange would raise for `fault` (a CP 341 in
/// its place); `None` for what the catalog has no event for (both partners sending STX: each
/// resolves it by its priority, 003 6.3.3).
fn fault_event(fault: Fault) -> Option<EventId> {
    match fault {
        Fault::Nak {
            after_telegram: false,
        } => Some(ids::SEND_SETUP_REJECTED),
        Fault::Nak {
            after_telegram: true,
        } => Some(ids::SEND_END_REJECTED),
        Fault::MissingDle {
            after_telegram: false,
        } => Some(ids::SEND_SETUP_TIMEOUT),
        Fault::MissingDle {
            after_telegram: true,
        } => Some(ids::SEND_END_TIMEOUT),
        Fault::Frame(error) => Some(error.event()),
        // 7.2 08 02h: a character other than STX where a connection request was expected.
        Fault::Stray { .. } => Some(ids::RECEIVE_SETUP_ERROR),
        Fault::LineError { error } => Some(error.event()),
        Fault::Conflict => None,
    }
}

/// The fault in words for the diagnostic buffer.
fn describe(fault: Fault) -> String {
    match fault {
        Fault::Nak {
            after_telegram: false,
        } => "NAK to its connection request".to_owned(),
        Fault::Nak {
            after_telegram: true,
        } => "NAK to its telegram".to_owned(),
        Fault::MissingDle {
            after_telegram: false,
        } => "no DLE to its connection request within the acknowledgement delay time".to_owned(),
        Fault::MissingDle {
            after_telegram: true,
        } => "no DLE to its telegram within the acknowledgement delay time".to_owned(),
        Fault::Frame(error) => format!("telegram received damaged: {error}"),
        Fault::Conflict => "both partners sent STX (initialization conflict)".to_owned(),
        Fault::Stray { len } => format!("{len} byte(s) outside any exchange"),
        Fault::LineError { error } => format!("line error on its port: {error:?}"),
    }
}

#[cfg(test)]
mod tests;
