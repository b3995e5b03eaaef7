//! The telegram line task, one loop for both engines: owns the port and an engine, moves received
//! telegrams into the mailbox, carries sends and RS232 signal commands, and reopens the port with
//! back-off when it fails.
//!
//! The driver loop (STYLE "serial/driver.rs"): hand a due deadline to the engine; drain its RS232
//! actions and transmissions to the port, its events to the status and the waiting senders, its
//! received telegrams to the mailbox (as long as the mailbox accepts them); then wait for bytes,
//! the engine's deadline, a signal poll, room in the mailbox, a command or shutdown. On shutdown
//! new commands are refused and the engine may finish what it has started (a telegram being sent
//! or received) within the grace period.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;
use std::time::{Duration, SystemTime};

use proto_core::event::{ids, EventId};
use proto_core::telegram::{Action, SendError, Signals, TelegramEvent, TelegramId};
use tokio::io::AsyncReadExt;
use tokio::sync::{mpsc, oneshot};
use tokio::time::Instant;
use tokio_serial::SerialStream;
use tokio_util::sync::CancellationToken;

use super::client::{Command, SendResult, TelegramSendError};
use super::engine::{EngineFactory, TelegramEngine};
use super::pump::Pump;
use super::{LineShared, TelegramLineSettings};
use crate::line::driver::sleep_until_opt;
use crate::line::{EVENT_PORT_LOST, EVENT_PORT_SETUP};
use crate::mailbox::Delivery;
use crate::serial::{self, Backoff, Interface};
use crate::signals::{self, Output, SignalError, SignalState};

/// How often CTS and DSR are read when the engine watches them (RTS/CTS flow control, automatic
/// V24 signal handling): the serial library offers no change notification. 10 ms is below every
/// time of 000 6.2.1 that depends on them (wait for CTS: at least 20 ms).
const SIGNAL_POLL: Duration = Duration::from_millis(10);

/// Why the driver loop ended.
#[derive(Debug)]
enum PortExit {
    Shutdown,
    Lost(String),
}

/// A send the engine accepted, waiting for its result.
#[derive(Debug)]
struct Waiting {
    bytes: usize,
    reply: oneshot::Sender<SendResult>,
}

/// What lives as long as one opening of the port.
#[derive(Debug)]
struct Session<E> {
    pump: Pump<E>,
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
}

/// The task of one telegram line.
pub(crate) struct TelegramTask<F> {
    settings: TelegramLineSettings,
    factory: F,
    shared: Arc<LineShared>,
    commands: mpsc::Receiver<Command>,
    commands_open: bool,
    shutdown: CancellationToken,
}

// === impl TelegramTask ===

impl<F: EngineFactory> TelegramTask<F> {
    pub(crate) fn new(
        settings: TelegramLineSettings,
        factory: F,
        shared: Arc<LineShared>,
        commands: mpsc::Receiver<Command>,
        shutdown: CancellationToken,
    ) -> Self {
        Self {
            settings,
            factory,
            shared,
            commands,
            commands_open: true,
            shutdown,
        }
    }

    fn name(&self) -> &str {
        &self.settings.name
    }

    /// Opens the port, drives it until it fails, reopens with back-off; until shutdown.
    pub(crate) async fn run(mut self) {
        let mut reopen = Backoff::clamped(self.settings.reopen_min, self.settings.reopen_max);
        loop {
            match serial::open(&self.settings.port) {
                Ok(port) => {
                    reopen.reset();
                    self.shared.status.update(|s| {
                        s.port_open = true;
                        s.port_error = None;
                        s.port_opens += 1;
                    });
                    self.shared.mailbox.set_port_open(true);
                    tracing::info!(line = %self.name(), path = %self.settings.port.path, "port open");
                    let exit = self.drive(port).await;
                    self.shared.status.update(|s| s.port_open = false);
                    self.shared.mailbox.set_port_open(false);
                    match exit {
                        PortExit::Shutdown => break,
                        PortExit::Lost(reason) => self.port_failed(EVENT_PORT_LOST, reason),
                    }
                }
                Err(err) => self.port_failed(EVENT_PORT_SETUP, err.to_string()),
            }
            let delay = reopen.next_delay();
            tracing::info!(line = %self.name(), ?delay, "reopening the port after back-off");
            if !self.wait_closed(delay).await {
                break;
            }
        }
        self.commands.close();
        while let Some(command) = self.commands.recv().await {
            command.refuse(&self.settings.name, true);
        }
        tracing::info!(line = %self.name(), "line stopped");
    }

    fn port_failed(&self, id: EventId, reason: String) {
        self.shared
            .status
            .update(|s| s.port_error = Some(reason.clone()));
        self.shared.raise(id, Some(reason));
    }

    /// Waits `delay` with the port closed, refusing commands at once. False on shutdown.
    async fn wait_closed(&mut self, delay: Duration) -> bool {
        let until = Instant::now() + delay;
        loop {
            tokio::select! {
                biased;
                () = self.shutdown.cancelled() => return false,
                () = tokio::time::sleep_until(until) => return true,
                command = self.commands.recv(), if self.commands_open => match command {
                    Some(command) => command.refuse(&self.settings.name, false),
                    None => self.commands_open = false,
                },
            }
        }
    }

    /// The driver loop on an open port.
    async fn drive(&mut self, mut port: SerialStream) -> PortExit {
        let engine = self.factory.build();
        tracing::debug!(line = %self.name(), protocol = engine.protocol(), "driver started");
        let watch = engine.watches_signals();
        let mut session = Session {
            pump: Pump::new(engine, self.settings.port.char_time()),
            waiting: HashMap::new(),
            received_at: VecDeque::new(),
            outputs: SignalState::default(),
            inputs: None,
            signal_poll: watch.then(Instant::now),
        };
        self.outputs_off(&mut port, &mut session.outputs);
        let exit = self.drive_session(&mut port, &mut session).await;
        // Telegrams the driver still holds are delivered (or counted as overflow), never lost
        // with the engine.
        self.move_received(&mut session, true);
        let shutting_down = matches!(exit, PortExit::Shutdown);
        for (_, waiting) in session.waiting.drain() {
            let error = if shutting_down {
                TelegramSendError::ShuttingDown
            } else {
                TelegramSendError::PortClosed
            };
            self.shared.mailbox.count_send(false, waiting.bytes);
            let _ = waiting.reply.send(Err(error));
        }
        exit
    }

    async fn drive_session(
        &mut self,
        port: &mut SerialStream,
        session: &mut Session<F::Engine>,
    ) -> PortExit {
        let path = self.settings.port.path.clone();
        let mut stop_at: Option<Instant> = None;
        let mut buf = [0u8; 1024];
        loop {
            session.pump.handle_due();
            loop {
                let outputs = &mut session.outputs;
                let shared = &self.shared;
                let wrote = session
                    .pump
                    .flush(port, |port, action| {
                        apply_action(shared, port, &path, outputs, action);
                    })
                    .await;
                let wrote = match wrote {
                    Ok(wrote) => wrote,
                    Err(err) => return PortExit::Lost(format!("write to {path} failed: {err}")),
                };
                let events = self.handle_events(session);
                let moved = self.move_received(session, false);
                if !(wrote || events || moved) {
                    break;
                }
            }
            if stop_at.is_some() && session.pump.engine.is_idle() {
                return PortExit::Shutdown;
            }
            let room = self.shared.mailbox.room_freed();
            let wants_room = !session.received_at.is_empty() && !self.shared.mailbox.accepts();
            tokio::select! {
                biased;
                () = self.shutdown.cancelled(), if stop_at.is_none() => {
                    stop_at = Some(Instant::now() + self.settings.shutdown_grace);
                    self.commands.close();
                    while let Ok(command) = self.commands.try_recv() {
                        command.refuse(&self.settings.name, true);
                    }
                    self.commands_open = false;
                }
                () = sleep_until_opt(stop_at) => return PortExit::Shutdown,
                read = port.read(&mut buf) => match read {
                    Ok(0) => return PortExit::Lost(format!("{path} reached end of file")),
                    Ok(n) => self.receive(session, buf.get(..n).unwrap_or_default()),
                    Err(err) => return PortExit::Lost(format!("read from {path} failed: {err}")),
                },
                () = sleep_until_opt(session.pump.deadline()) => session.pump.handle_timeout(),
                () = sleep_until_opt(session.signal_poll) => self.poll_signals(port, session),
                () = room, if wants_room => {}
                command = self.commands.recv(), if self.commands_open => match command {
                    Some(command) => self.handle_command(port, session, command),
                    None => self.commands_open = false,
                },
            }
        }
    }

    /// Hands received bytes to the engine one at a time and moves each completed telegram to
    /// the mailbox at once: a read can hold several short telegrams, and the engine's receive
    /// buffer is kept small (see the module doc of the line), so taking them only after the whole
    /// read would make the engine drop or refuse telegrams the mailbox has room for.
    fn receive(&self, session: &mut Session<F::Engine>, bytes: &[u8]) {
        for &byte in bytes {
            session.pump.handle_rx(&[byte]);
            if self.handle_events(session) {
                self.move_received(session, false);
            }
        }
    }

    /// 000 5.4 "Nach dem Einschalten des CP sind alle Ausgangssignale inaktiv": DTR and RTS off
    /// on every opening, where the port has them (a pseudo-terminal has not: logged at debug).
    fn outputs_off(&self, port: &mut SerialStream, outputs: &mut SignalState) {
        if self.settings.port.interface != Interface::Rs232 {
            return;
        }
        for output in [Output::Dtr, Output::Rts] {
            if let Err(err) = signals::set(port, &self.settings.port.path, outputs, output, false) {
                tracing::debug!(line = %self.name(), %err, "modem outputs left as they are");
                return;
            }
        }
    }

    /// Hands the engine's events on; returns whether there were any.
    fn handle_events(&self, session: &mut Session<F::Engine>) -> bool {
        let mut any = false;
        while let Some(event) = session.pump.engine.poll_event() {
            any = true;
            match event {
                // The copy for observers; the telegram itself is taken from the engine's buffer.
                TelegramEvent::Received { .. } => session.received_at.push_back(SystemTime::now()),
                TelegramEvent::Sent { id } => {
                    if let Some(waiting) = session.waiting.remove(&id) {
                        self.shared.mailbox.count_send(true, waiting.bytes);
                        let _ = waiting.reply.send(Ok(()));
                    }
                }
                TelegramEvent::SendFailed { id, event, first } => {
                    if let Some(waiting) = session.waiting.remove(&id) {
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
    fn move_received(&self, session: &mut Session<F::Engine>, all: bool) -> bool {
        let mailbox = &self.shared.mailbox;
        let mut any = false;
        while all || mailbox.accepts() {
            let Some(data) = session.pump.engine.take_received() else {
                break;
            };
            any = true;
            let at = session
                .received_at
                .pop_front()
                .unwrap_or_else(SystemTime::now);
            let depth = mailbox.settings().queue_depth;
            match mailbox.deliver(data, at) {
                Delivery::Kept { seq } => {
                    tracing::debug!(line = %self.name(), seq, "telegram received");
                }
                Delivery::DroppedNew { seq } => self.shared.raise(
                    ids::NO_FREE_RECEIVE_BUFFER,
                    Some(format!(
                        "mailbox full ({depth} telegrams): telegram {seq} dropped"
                    )),
                ),
                Delivery::DroppedOldest { seq, dropped } => self.shared.raise(
                    ids::NO_FREE_RECEIVE_BUFFER,
                    Some(format!(
                        "mailbox full ({depth} telegrams): oldest telegram {dropped} dropped for {seq}"
                    )),
                ),
            }
        }
        any
    }

    /// Reads CTS and DSR and hands a change to the engine.
    fn poll_signals(&self, port: &mut SerialStream, session: &mut Session<F::Engine>) {
        let path = &self.settings.port.path;
        let read =
            |port: &mut SerialStream, signal| signals::read(port, path, session.outputs, signal);
        let inputs = read(port, signals::Signal::Cts)
            .and_then(|cts| read(port, signals::Signal::Dsr).map(|dsr| Signals { cts, dsr }));
        match inputs {
            Ok(inputs) => {
                if session.inputs != Some(inputs) {
                    session.inputs = Some(inputs);
                    let now = session.pump.now();
                    session.pump.engine.handle_signals(now, inputs);
                }
                session.signal_poll = Some(Instant::now() + SIGNAL_POLL);
            }
            Err(err) => {
                // The engine keeps CTS and DSR off: its sends end with 07 08h (no CTS) and,
                // under the automatic V24 handling, nothing is received (DSR off).
                tracing::warn!(line = %self.name(), %err, "cannot watch CTS/DSR for the data flow control");
                self.shared.set_signals_error(err.to_string());
                session.signal_poll = None;
            }
        }
    }

    fn handle_command(
        &self,
        port: &mut SerialStream,
        session: &mut Session<F::Engine>,
        command: Command,
    ) {
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
                    let now = session.pump.now();
                    session.pump.engine.send(now, data)
                };
                match accepted {
                    Ok(id) => {
                        session.waiting.insert(id, Waiting { bytes, reply });
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
                let result = if self.settings.port.interface == Interface::Rs232 {
                    signals::read_all(port, path, session.outputs)
                } else {
                    Err(not_rs232())
                };
                let _ = reply.send(result);
            }
            Command::SetSignal { output, on, reply } => {
                let owner = session.pump.engine.output_owner();
                let result = if self.settings.port.interface != Interface::Rs232 {
                    Err(not_rs232())
                } else if let Err(flow) = signals::may_set(owner, output) {
                    Err(SignalError::DrivenByDriver {
                        line: self.settings.name.clone(),
                        signal: output.signal(),
                        flow,
                    })
                } else {
                    signals::set(port, path, &mut session.outputs, output, on)
                };
                let _ = reply.send(result);
            }
        }
    }
}

/// Sets the output the engine asks for; a port that refuses is reported once in the status.
fn apply_action(
    shared: &LineShared,
    port: &mut SerialStream,
    path: &str,
    outputs: &mut SignalState,
    action: Action,
) {
    let (output, on) = match action {
        Action::SetRts(on) => (Output::Rts, on),
        Action::SetDtr(on) => (Output::Dtr, on),
    };
    if let Err(err) = signals::set(port, path, outputs, output, on) {
        if shared.set_signals_error(err.to_string()) {
            tracing::warn!(line = %shared.mailbox.line(), %err, "the data flow control cannot set its output");
        }
    }
}
