//! The telegram line, one adapter of the line runtime for both engines (3964(R) and ASCII): moves
//! received telegrams into the mailbox, carries sends and RS232 signal commands.
//!
//! After every input the engine's RS232 actions and transmissions go to the port (the runtime
//! writes them), its events to the status and the waiting senders, its received telegrams to the
//! mailbox (as long as the mailbox accepts them). Besides bytes and its deadline the line wakes
//! for a signal poll and for room in the mailbox. On shutdown new commands are refused and the
//! engine may finish what it has started (a telegram being sent or received) within the grace
//! period.

use std::collections::{HashMap, VecDeque};
use std::future::Future;
use std::sync::Arc;
use std::time::{Duration, SystemTime};

use proto_core::event::{ids, EventId};
use proto_core::serial_marks::LineError;
use proto_core::telegram::{Action, SendError, Signals, TelegramEvent, TelegramId};
use tokio::sync::oneshot;
use tokio::time::Instant;
use tokio_serial::SerialPort;

use super::client::{Command, SendResult, TelegramSendError};
use super::engine::{EngineFactory, TelegramEngine};
use super::{LineShared, TelegramLineSettings};
use crate::line::driver::{sleep_until_opt, Clock};
use crate::line::runtime::{LineCommands, LineLifecycle, LineSignals, SecondPort};
use crate::line::runtime::{LineEngine, Stop};
use crate::mailbox::Delivery;
use crate::serial::Interface;
use crate::signals::{self, Output, Signal, SignalError, SignalState};

/// How often CTS and DSR are read when the engine watches them (RTS/CTS flow control, automatic
/// V24 signal handling): the serial library offers no change notification. 10 ms is below every
/// time of 000 6.2.1 that depends on them (wait for CTS: at least 20 ms).
const SIGNAL_POLL: Duration = Duration::from_millis(10);

/// A send the engine accepted, waiting for its result.
#[derive(Debug)]
struct Waiting {
    bytes: usize,
    reply: oneshot::Sender<SendResult>,
}

/// The adapter of one telegram line; the engine and what goes with it live as long as one
/// opening of the port.
pub(crate) struct TelegramLine<F: EngineFactory> {
    settings: TelegramLineSettings,
    factory: F,
    shared: Arc<LineShared>,
    clock: Clock,
    engine: F::Engine,
    /// Sends accepted by the engine, by id.
    waiting: HashMap<TelegramId, Waiting>,
    /// Receive times of the telegrams in the engine's buffer, oldest first (one per `Received`).
    received_at: VecDeque<SystemTime>,
    /// DTR and RTS as last set.
    outputs: SignalState,
    /// CTS and DSR as last handed to the engine.
    inputs: Option<Signals>,
    /// When the signals are read next (`None`: not watched, or they cannot be read).
    signal_poll: Option<Instant>,
    /// The estimated end of the last transmission.
    tx_end: Option<proto_core::time::Instant>,
}

impl<F: EngineFactory> LineEngine for TelegramLine<F> {
    fn opened(&mut self, modem: Option<&mut dyn SerialPort>) {
        self.shared.mailbox.set_port_open(true);
        self.engine = self.factory.build();
        tracing::debug!(line = %self.name(), protocol = self.engine.protocol(), "driver started");
        self.waiting.clear();
        self.received_at.clear();
        self.outputs = SignalState::default();
        self.inputs = None;
        self.signal_poll = self.engine.watches_signals().then(Instant::now);
        self.tx_end = None;
        self.outputs_off(modem);
    }

    /// Hands received bytes to the engine one at a time and moves each completed telegram to
    /// the mailbox at once: a read can hold several short telegrams, and the engine's receive
    /// buffer is kept small (see the module doc of the line), so taking them only after the whole
    /// read would make the engine drop or refuse telegrams the mailbox has room for.
    ///
    /// The bytes are timestamped as the protocol counts them ([`TelegramEngine::rx_time`]: on
    /// arrival for the full-duplex ASCII driver, no earlier than the end of our own transmission
    /// for 3964(R)).
    fn handle_rx(&mut self, now: proto_core::time::Instant, bytes: &[u8]) {
        let at = self.engine.rx_time(now, self.tx_end);
        let journaled = self.settings.journal.is_some();
        for &byte in bytes {
            if journaled {
                // With a journal the driver holds no telegram beyond the mailbox: an STX that
                // finds it full is refused at once (3964(R): NAK).
                self.engine.set_receive_ready(self.shared.mailbox.accepts());
            }
            self.engine.handle_rx(at, &[byte]);
            if self.events() {
                self.move_received(false);
            }
        }
    }

    fn handle_line_error(&mut self, now: proto_core::time::Instant, error: LineError) {
        let at = self.engine.rx_time(now, self.tx_end);
        self.engine.handle_line_error(at, error);
        if self.events() {
            self.move_received(false);
        }
    }

    crate::line::driver::engine_calls!(engine: timeout, tx);

    fn transmitted(&mut self, _written: Instant, _len: usize, end: proto_core::time::Instant) {
        self.tx_end = Some(end);
        self.engine.handle_tx_done(end);
    }

    fn handle_events(&mut self) -> bool {
        let events = self.events();
        let moved = self.move_received(false);
        events || moved
    }
}

impl<F: EngineFactory> LineCommands for TelegramLine<F> {
    type Command = Command;

    fn command(&mut self, command: Command, modem: Option<&mut dyn SerialPort>) {
        self.handle_command(modem, command);
    }

    fn refuse(&mut self, command: Command, shutting_down: bool) {
        command.refuse(&self.settings.name, shutting_down);
    }
}

impl<F: EngineFactory> LineLifecycle for TelegramLine<F> {
    fn stop(&mut self) -> Stop {
        Stop {
            read: true,
            close_queue: true,
            grace: Some(self.settings.shutdown_grace),
        }
    }

    fn done(&self) -> bool {
        self.engine.is_idle()
    }

    /// Telegrams the driver still holds are delivered (or counted as overflow), never lost with
    /// the engine; the sends waiting for their result fail.
    fn closed(&mut self, shutting_down: bool) {
        self.move_received(true);
        let waiting = self.shared.mailbox.len();
        if shutting_down && waiting > 0 && !self.shared.mailbox.journaled() {
            tracing::warn!(
                line = %self.name(),
                waiting,
                "{waiting} telegrams waiting were not journaled: they are lost with this stop (set `journal` to keep them)"
            );
        }
        for (_, waiting) in self.waiting.drain() {
            let error = if shutting_down {
                TelegramSendError::ShuttingDown
            } else {
                TelegramSendError::PortClosed
            };
            self.shared.mailbox.count_send(false, waiting.bytes);
            let _ = waiting.reply.send(Err(error));
        }
        self.shared.mailbox.set_port_open(false);
    }

    fn port_failed(&mut self, id: EventId, reason: String) {
        self.shared.raise(id, Some(reason));
    }

    fn monitor_framing(&self) -> proto_core::monitor::Framing {
        self.factory.framing()
    }
}

impl<F: EngineFactory> LineSignals for TelegramLine<F> {
    fn poll_action(&mut self) -> Option<Action> {
        self.engine.poll_action()
    }

    /// Sets the output the engine asks for; a port that refuses is reported once in the status.
    fn apply_action(&mut self, action: Action, modem: Option<&mut dyn SerialPort>) {
        let (output, on) = match action {
            Action::SetRts(on) => (Output::Rts, on),
            Action::SetDtr(on) => (Output::Dtr, on),
        };
        let path = &self.settings.port.path;
        let result = match modem {
            Some(port) => signals::set(port, path, &mut self.outputs, output, on),
            None => Err(signals::no_modem(path, output.signal(), "set")),
        };
        if let Err(err) = result {
            if self.shared.set_signals_error(err.to_string()) {
                tracing::warn!(line = %self.name(), %err, "the data flow control cannot set its output");
            }
        }
    }

    fn wake(&self) -> impl Future<Output = ()> + Send + '_ {
        // The notification is created before the check, so that no wake-up is missed.
        let room = self.shared.mailbox.room_freed();
        let wants_room = !self.received_at.is_empty() && !self.shared.mailbox.accepts();
        let signal_poll = self.signal_poll;
        async move {
            tokio::select! {
                () = sleep_until_opt(signal_poll) => {}
                () = room, if wants_room => {}
            }
        }
    }

    fn woken(&mut self, modem: Option<&mut dyn SerialPort>) {
        if self.signal_poll.is_some_and(|at| at <= Instant::now()) {
            self.poll_signals(modem);
        }
    }
}

impl<F: EngineFactory> SecondPort for TelegramLine<F> {}

// === impl TelegramLine ===

impl<F: EngineFactory> TelegramLine<F> {
    pub(crate) fn new(
        settings: TelegramLineSettings,
        factory: F,
        shared: Arc<LineShared>,
        clock: Clock,
    ) -> Self {
        let engine = factory.build();
        Self {
            settings,
            factory,
            shared,
            clock,
            engine,
            waiting: HashMap::new(),
            received_at: VecDeque::new(),
            outputs: SignalState::default(),
            inputs: None,
            signal_poll: None,
            tx_end: None,
        }
    }

    fn name(&self) -> &str {
        &self.settings.name
    }

    /// 000 5.4 "Nach dem Einschalten des CP sind alle Ausgangssignale inaktiv": DTR and RTS off
    /// on every opening, where the port has them (a pseudo-terminal has not: logged at debug).
    fn outputs_off(&mut self, mut modem: Option<&mut dyn SerialPort>) {
        if self.settings.port.interface != Interface::Rs232 {
            return;
        }
        for output in [Output::Dtr, Output::Rts] {
            let path = &self.settings.port.path;
            let result = match modem.as_deref_mut() {
                Some(port) => signals::set(port, path, &mut self.outputs, output, false),
                None => Err(signals::no_modem(path, output.signal(), "set")),
            };
            if let Err(err) = result {
                tracing::debug!(line = %self.name(), %err, "modem outputs left as they are");
                return;
            }
        }
    }

    /// Hands the engine's events on; returns whether there were any.
    fn events(&mut self) -> bool {
        let mut any = false;
        while let Some(event) = self.engine.poll_event() {
            any = true;
            match event {
                // The copy for observers; the telegram itself is taken from the engine's buffer.
                TelegramEvent::Received { .. } => {
                    self.shared.metrics.received_telegram();
                    self.received_at.push_back(SystemTime::now());
                }
                TelegramEvent::Sent { id } => {
                    self.shared.metrics.sent_telegram();
                    if let Some(waiting) = self.waiting.remove(&id) {
                        self.shared.mailbox.count_send(true, waiting.bytes);
                        let _ = waiting.reply.send(Ok(()));
                    }
                }
                TelegramEvent::SendFailed { id, event, first } => {
                    if let Some(waiting) = self.waiting.remove(&id) {
                        self.shared.mailbox.count_send(false, waiting.bytes);
                        let _ = waiting
                            .reply
                            .send(Err(TelegramSendError::Failed { event, first }));
                    }
                }
                TelegramEvent::Raised { id } => self.shared.raise(id, None),
            }
        }
        any
    }

    /// Moves received telegrams from the engine to the mailbox while it accepts them (`all`:
    /// every one, the port is closing). Returns whether any moved.
    ///
    /// With a journal each telegram is written (and synced) first; a 3964(R) telegram waiting
    /// for its acknowledgement is then confirmed (final DLE), or refused with NAK when the write
    /// failed (04 07h: the partner repeats it) or the mailbox has no room (08 0Ah). An ASCII
    /// telegram whose write failed is kept in memory (04 07h says it is not journaled): the
    /// ASCII driver has no way to make the partner repeat it.
    fn move_received(&mut self, all: bool) -> bool {
        let mut any = false;
        while all || self.shared.mailbox.accepts() {
            let Some(data) = self.engine.take_received() else {
                break;
            };
            any = true;
            let at = self.received_at.pop_front().unwrap_or_else(SystemTime::now);
            let delivered = self.shared.mailbox.try_deliver(data, at);
            let delivery = match delivered {
                Ok(delivery) => {
                    self.confirm(Ok(()));
                    delivery
                }
                Err((error, data)) if self.engine.awaiting_confirm() => {
                    crate::warn_limited!(
                        format!("journal {}", self.name()),
                        line = %self.name(),
                        %error,
                        "telegram refused (NAK): the journal did not take it; the partner repeats"
                    );
                    drop(data);
                    self.shared.raise(
                        ids::CPU_TRANSFER_ERROR,
                        Some(format!("{error}: refused with NAK")),
                    );
                    self.confirm(Err(ids::CPU_TRANSFER_ERROR));
                    continue;
                }
                Err((error, data)) => {
                    crate::warn_limited!(
                        format!("journal {}", self.name()),
                        line = %self.name(),
                        %error,
                        "telegram kept without the journal: lost at a restart"
                    );
                    self.shared.raise(
                        ids::CPU_TRANSFER_ERROR,
                        Some(format!("{error}: telegram kept in memory only")),
                    );
                    self.shared.mailbox.deliver_unjournaled(data, at)
                }
            };
            self.report(delivery);
        }
        if self.engine.awaiting_confirm() {
            // No room (the STX came before the mailbox filled): refused, the partner repeats.
            if self.engine.take_received().is_some() {
                self.received_at.pop_front();
            }
            let depth = self.shared.mailbox.settings().queue_depth;
            self.shared.raise(
                ids::NO_FREE_RECEIVE_BUFFER,
                Some(format!(
                    "mailbox full ({depth} telegrams): telegram refused with NAK"
                )),
            );
            self.confirm(Err(ids::NO_FREE_RECEIVE_BUFFER));
            any = true;
        }
        any
    }

    /// Ends a reception that waits for its acknowledgement (3964(R) with a journal).
    fn confirm(&mut self, result: Result<(), EventId>) {
        if self.engine.awaiting_confirm() {
            let (_, now) = self.clock.now();
            self.engine.confirm_received(now, result);
            // The refusal's events (the cause, 08 01h) go out with the next drain.
            self.events();
        }
    }

    /// Logs and raises what became of a telegram handed to the mailbox.
    fn report(&self, delivery: Delivery) {
        let depth = self.shared.mailbox.settings().queue_depth;
        match delivery {
            Delivery::Kept { seq } => {
                tracing::debug!(line = %self.name(), seq, "telegram received");
            }
            Delivery::DroppedNew { seq } => self.shared.raise(
                ids::NO_FREE_RECEIVE_BUFFER,
                Some(format!(
                    "mailbox full ({depth} telegrams): telegram {seq} dropped"
                )),
            ),
            // Overwriting allowed (003 6.2.1): the configured behaviour, not an overflow.
            Delivery::Overwritten { seq, replaced } => {
                tracing::debug!(line = %self.name(), seq, replaced, "telegram overwrote the held one");
            }
            Delivery::DroppedOldest { seq, dropped } => self.shared.raise(
                ids::NO_FREE_RECEIVE_BUFFER,
                Some(format!(
                    "mailbox full ({depth} telegrams): oldest telegram {dropped} dropped for {seq}"
                )),
            ),
        }
    }

    /// Reads CTS and DSR and hands a change to the engine.
    fn poll_signals(&mut self, modem: Option<&mut dyn SerialPort>) {
        let path = &self.settings.port.path;
        let outputs = self.outputs;
        let inputs = match modem {
            Some(port) => signals::read(port, path, outputs, Signal::Cts).and_then(|cts| {
                signals::read(port, path, outputs, Signal::Dsr).map(|dsr| Signals { cts, dsr })
            }),
            None => Err(signals::no_modem(path, Signal::Cts, "read")),
        };
        match inputs {
            Ok(inputs) => {
                if self.inputs != Some(inputs) {
                    self.inputs = Some(inputs);
                    let (_, now) = self.clock.now();
                    self.engine.handle_signals(now, inputs);
                }
                self.signal_poll = Some(Instant::now() + SIGNAL_POLL);
            }
            Err(err) => {
                // The engine keeps CTS and DSR off: its sends end with 07 08h (no CTS) and,
                // under the automatic V24 handling, nothing is received (DSR off).
                tracing::warn!(line = %self.name(), %err, "cannot watch CTS/DSR for the data flow control");
                self.shared.set_signals_error(err.to_string());
                self.signal_poll = None;
            }
        }
    }

    fn handle_command(&mut self, modem: Option<&mut dyn SerialPort>, command: Command) {
        let path = &self.settings.port.path;
        let not_rs232 = || SignalError::NotRs232 {
            line: self.settings.name.clone(),
        };
        match command {
            Command::Send { data, reply } => {
                let bytes = data.len();
                let max = self.settings.max_len;
                let accepted = if bytes > max {
                    Err(SendError::TooLong { len: bytes, max })
                } else {
                    let (_, now) = self.clock.now();
                    self.engine.send(now, data)
                };
                match accepted {
                    Ok(id) => {
                        self.waiting.insert(id, Waiting { bytes, reply });
                    }
                    // Back-pressure, not a failure: the client may try again.
                    Err(SendError::QueueFull { capacity }) => {
                        let _ = reply.send(Err(TelegramSendError::QueueFull { capacity }));
                    }
                    Err(err) => {
                        self.shared.mailbox.count_send(false, bytes);
                        let _ = reply.send(Err(TelegramSendError::Refused(err)));
                    }
                }
            }
            Command::ReadSignals { reply } => {
                let result = match modem {
                    _ if self.settings.port.interface != Interface::Rs232 => Err(not_rs232()),
                    Some(port) => signals::read_all(port, path, self.outputs),
                    None => Err(signals::no_modem(path, Signal::Dsr, "read")),
                };
                let _ = reply.send(result);
            }
            Command::SetSignal { output, on, reply } => {
                let owner = self.engine.output_owner();
                let result = if self.settings.port.interface != Interface::Rs232 {
                    Err(not_rs232())
                } else if let Err(flow) = signals::may_set(owner, output) {
                    Err(SignalError::DrivenByDriver {
                        line: self.settings.name.clone(),
                        signal: output.signal(),
                        flow,
                    })
                } else if let Some(port) = modem {
                    signals::set(port, path, &mut self.outputs, output, on)
                } else {
                    Err(signals::no_modem(path, output.signal(), "set"))
                };
                let _ = reply.send(result);
            }
        }
    }
}
