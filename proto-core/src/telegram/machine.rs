//! The ASCII driver's state machine: receive side, send side with data flow control, RS232
//! signals.

use core::time::Duration;
use std::collections::VecDeque;

use crate::event::{ids, EventId};
use crate::time::Instant;

use super::common::{
    LineError, ReceiveBuffer, SendError, Stored, TelegramEvent, TelegramId, TxQueue,
};
use super::config::{
    AsciiParams, AsciiSettings, EndCriterion, FlowControl, SendLength, MAX_TELEGRAM,
};
use super::receiver::{Outcome, Receiver};

/// What [`AsciiDriver::poll_event`] returns.
pub type AsciiEvent = TelegramEvent;

/// The RS232 inputs the driver watches (000 5.4 "RS232-Begleitsignale").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Signals {
    /// Clear to send: the partner can take data from us.
    pub cts: bool,
    /// Data set ready: the partner is ready.
    pub dsr: bool,
}

/// An RS232 output the runtime is asked to set (000 5.4).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Action {
    /// Set RTS (request to send) on or off.
    SetRts(bool),
    /// Set DTR (data terminal ready) on or off.
    SetDtr(bool),
}

/// One telegram to send.
#[derive(Clone, Debug)]
struct Job {
    /// As returned by `send`.
    id: TelegramId,
    /// The bytes, sent as given.
    data: Vec<u8>,
}

/// The send side.
#[derive(Clone, Debug)]
enum Tx {
    /// No telegram in progress.
    Idle,
    /// Automatic V24: RTS is on; at `deadline` (the data output wait time) CTS must be on.
    RtsSetup { job: Job, deadline: Instant },
    /// `sent` bytes handed out; `held_until` runs while the partner holds us back (XOFF, CTS off).
    Sending {
        job: Job,
        sent: usize,
        held_until: Option<Instant>,
    },
    /// Automatic V24: everything is out; RTS goes off at `deadline` (the RTS hold time).
    RtsHold { job: Job, deadline: Instant },
}

/// The ASCII driver of one line (003 6.2; 000 6.2 and 5.4 for RS232).
///
/// # Driving it
///
/// The runtime calls, as things happen:
///
/// - [`handle_rx`](Self::handle_rx) with every chunk of received bytes;
/// - [`handle_line_error`](Self::handle_line_error) for a character received with a parity,
///   framing or overrun error (instead of passing the character), or a BREAK;
/// - [`handle_signals`](Self::handle_signals) with the CTS and DSR inputs, once at start and on
///   every change (they count as off until then, as at the CP's power-on, 000 5.4);
/// - [`handle_tx_done`](Self::handle_tx_done) once for every buffer taken from
///   [`poll_transmit`](Self::poll_transmit), in order, with the instant its last byte left the
///   line (an estimate is fine);
/// - [`handle_timeout`](Self::handle_timeout) when [`poll_timeout`](Self::poll_timeout) has come;
/// - [`send`](Self::send) to queue a telegram.
///
/// After each call it drains, in this order:
///
/// 1. [`poll_action`](Self::poll_action) until `None`, setting RTS/DTR;
/// 2. [`poll_transmit`](Self::poll_transmit) until `None` (it holds bytes back while an action
///    is pending, so RTS is always on before data goes out);
/// 3. [`poll_event`](Self::poll_event) until `None`;
/// 4. [`poll_timeout`](Self::poll_timeout) for the next deadline.
///
/// Received telegrams stay in the receive buffer (003 6.2.1 "Receipt telegrams are buffered in
/// the CP at a ring buffer") until [`take_received`](Self::take_received); the
/// [`AsciiEvent::Received`] event is a copy for observers.
#[derive(Debug)]
pub struct AsciiDriver {
    /// The validated parameters.
    params: AsciiParams,
    /// `0x7F` with 7 data bits, `0xFF` with 8.
    mask: u8,
    /// Cuts the received bytes into telegrams.
    receiver: Receiver,
    /// Complete telegrams not yet taken.
    buffer: ReceiveBuffer,
    /// The latest CTS and DSR.
    signals: Signals,
    /// The partner sent XOFF and no XON since.
    held_by_xoff: bool,
    /// We sent XOFF because our receive buffer is full.
    xoff_sent: bool,
    /// RTS as last requested.
    rts: bool,
    /// Telegrams accepted by `send` and not yet started.
    queue: VecDeque<Job>,
    /// The send side's state.
    tx_state: Tx,
    /// Bytes to send and the ones on the wire.
    tx: TxQueue,
    /// When the line last went quiet (for the transmission pause).
    quiet_since: Option<Instant>,
    /// Signal changes for `poll_action`.
    actions: VecDeque<Action>,
    /// Events for `poll_event`.
    events: VecDeque<AsciiEvent>,
    /// The id of the last telegram accepted by `send`.
    last_id: u64,
}

// === impl AsciiDriver ===

impl AsciiDriver {
    /// A driver with nothing received or queued. With RTS/CTS flow control it first asks for
    /// RTS = ON (ready to receive); with the automatic V24 signal handling for RTS = OFF and
    /// DTR = ON (000 5.4: "setzt der CP die Leitungen RTS auf OFF und DTR auf ON").
    pub fn new(params: AsciiParams) -> Self {
        let s = params.settings();
        let mask = if s.data_bits == 7 { 0x7F } else { 0xFF };
        let receiver = Receiver::new(s.end, s.zvz);
        let buffer = ReceiveBuffer::new(s.receive_buffers.into(), !s.prevent_overwrite);
        let mut actions = VecDeque::new();
        let mut rts = false;
        match s.flow {
            FlowControl::RtsCts => {
                actions.push_back(Action::SetRts(true));
                rts = true;
            }
            FlowControl::AutoV24 { .. } => {
                actions.push_back(Action::SetRts(false));
                actions.push_back(Action::SetDtr(true));
            }
            FlowControl::None | FlowControl::XonXoff { .. } => {}
        }
        Self {
            params,
            mask,
            receiver,
            buffer,
            signals: Signals::default(),
            held_by_xoff: false,
            xoff_sent: false,
            rts,
            queue: VecDeque::new(),
            tx_state: Tx::Idle,
            tx: TxQueue::default(),
            quiet_since: None,
            actions,
            events: VecDeque::new(),
            last_id: 0,
        }
    }

    /// The parameters in use.
    pub fn params(&self) -> &AsciiParams {
        &self.params
    }

    fn settings(&self) -> &AsciiSettings {
        self.params.settings()
    }

    /// Queues `telegram` for sending, as given (with end characters, if the partner expects them).
    ///
    /// # Errors
    ///
    /// [`SendError::Empty`], [`SendError::TooLong`] beyond 1024 bytes, [`SendError::EighthBit`]
    /// with 7 data bits, [`SendError::QueueFull`].
    pub fn send(&mut self, now: Instant, mut telegram: Vec<u8>) -> Result<TelegramId, SendError> {
        let capacity = usize::from(self.settings().send_queue);
        if let Some(len) = self.end_chars_len(&telegram) {
            // 003 6.2.1 "Send with end character": the telegram ends with its end character(s).
            telegram.truncate(len);
        }
        if telegram.is_empty() {
            return Err(SendError::Empty);
        }
        if telegram.len() > MAX_TELEGRAM {
            return Err(SendError::TooLong {
                len: telegram.len(),
                max: MAX_TELEGRAM,
            });
        }
        if let Some(offset) = telegram.iter().position(|&b| b & !self.mask != 0) {
            let value = telegram.get(offset).copied().unwrap_or_default();
            return Err(SendError::EighthBit { offset, value });
        }
        if self.queue.len() >= capacity {
            return Err(SendError::QueueFull { capacity });
        }
        self.last_id += 1;
        let id = TelegramId::new(self.last_id);
        self.queue.push_back(Job { id, data: telegram });
        self.pump(now);
        Ok(id)
    }

    /// Takes received bytes.
    pub fn handle_rx(&mut self, now: Instant, bytes: &[u8]) {
        let flow = self.settings().flow;
        let mut dropped = false;
        for &raw in bytes {
            let byte = raw & self.mask;
            if let FlowControl::XonXoff { xon, xoff } = flow {
                if byte == xoff {
                    self.held_by_xoff = true;
                    continue;
                }
                if byte == xon {
                    self.held_by_xoff = false;
                    continue;
                }
            }
            if matches!(flow, FlowControl::AutoV24 { .. }) && !self.signals.dsr {
                // 000 5.4 "Empfangen": "Sobald die Leitung DSR auf ON gesetzt ist, ist Empfang
                // von Daten über die RS232-Schnittstelle möglich."
                dropped = true;
                continue;
            }
            if let Some(outcome) = self.receiver.push(now, byte) {
                self.deliver(outcome);
            }
        }
        if dropped {
            self.raise(ids::DSR_OR_CTS_OFF);
        }
        self.pump(now);
    }

    /// Takes a character received with an error, or a BREAK.
    pub fn handle_line_error(&mut self, now: Instant, error: LineError) {
        match error {
            LineError::Break => {
                // 7.2, 08 0Dh "BREAK: Receive line to partner is interrupted"; the telegram in
                // progress cannot be complete.
                self.receiver.abort();
                self.raise(error.event());
            }
            LineError::Parity
            | LineError::Framing
            | LineError::ParityOrFraming
            | LineError::Overrun => {
                if let Some(outcome) = self.receiver.push_faulty(now, error.event()) {
                    self.deliver(outcome);
                }
            }
        }
        self.pump(now);
    }

    /// Takes the current CTS and DSR inputs.
    pub fn handle_signals(&mut self, now: Instant, signals: Signals) {
        let before = core::mem::replace(&mut self.signals, signals);
        if matches!(self.settings().flow, FlowControl::AutoV24 { .. }) {
            let dsr_dropped = before.dsr && !signals.dsr;
            let cts_dropped =
                before.cts && !signals.cts && matches!(self.tx_state, Tx::Sending { .. });
            if dsr_dropped || cts_dropped {
                // 000 5.4: "Bei einem Wechsel von DSR von ON nach OFF wird sowohl ein laufender
                // Sendeauftrag als auch das Empfangen von Daten mit einer Fehlermeldung
                // abgebrochen"; a change of CTS to OFF while sending aborts the send job. 7.2,
                // 08 18h "DSR = OFF or CTS = OFF".
                let aborted_send = self.abort_send(now, ids::DSR_OR_CTS_OFF);
                let aborted_receive = dsr_dropped && self.receiver.abort();
                if !aborted_send && (dsr_dropped || aborted_receive) {
                    self.raise(ids::DSR_OR_CTS_OFF);
                }
            }
        }
        self.pump(now);
    }

    /// Confirms that the oldest buffer from `poll_transmit` has left the line at `now`.
    pub fn handle_tx_done(&mut self, now: Instant) {
        if self.tx.done() {
            self.quiet_since = Some(now);
        }
        self.pump(now);
    }

    /// Acts on the deadlines of [`poll_timeout`](Self::poll_timeout) that have come.
    pub fn handle_timeout(&mut self, now: Instant) {
        if let Some(outcome) = self.receiver.handle_timeout(now) {
            self.deliver(outcome);
        }
        match core::mem::replace(&mut self.tx_state, Tx::Idle) {
            Tx::RtsSetup { job, deadline } if now >= deadline => {
                if self.signals.cts {
                    // 000 5.4 "Senden": "Nach Ablauf der Datenausgabewartezeit und CTS = ON werden
                    // die Daten ... gesendet."
                    self.tx_state = Tx::Sending {
                        job,
                        sent: 0,
                        held_until: None,
                    };
                } else {
                    // "Wird ... innerhalb der Datenausgabewartezeit die Leitung CTS nicht auf ON
                    // gesetzt ... wird der Sendeauftrag abgebrochen"; 7.2, 07 08h.
                    self.tx_state = Tx::RtsSetup { job, deadline };
                    self.abort_send(now, ids::SEND_FLOW_CONTROL_TIMEOUT);
                }
            }
            // 003 6.2.1 "Wait for XON after XOFF (Wait time for CTS=ON)"; 7.2, 07 08h "The waiting
            // time for XON respectively CTS = ON has elapsed."
            Tx::Sending {
                job,
                sent,
                held_until: Some(until),
            } if now >= until => {
                self.tx_state = Tx::Sending {
                    job,
                    sent,
                    held_until: Some(until),
                };
                self.abort_send(now, ids::SEND_FLOW_CONTROL_TIMEOUT);
            }
            // 000 5.4: "Nach dem Senden der Daten wird nach Ablauf der parametrierten RTS
            // Wegnahmezeit die Leitung RTS auf OFF gesetzt."
            Tx::RtsHold { job, deadline } if now >= deadline => {
                self.set_rts(false);
                self.events.push_back(TelegramEvent::Sent { id: job.id });
            }
            other => self.tx_state = other,
        }
        self.pump(now);
    }

    /// The next RS232 output to set. Drain before [`poll_transmit`](Self::poll_transmit).
    pub fn poll_action(&mut self) -> Option<Action> {
        self.actions.pop_front()
    }

    /// The next bytes to write to the port; `None` while an action is pending.
    pub fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        if self.actions.is_empty() {
            self.tx.pop()
        } else {
            None
        }
    }

    /// When [`handle_timeout`](Self::handle_timeout) is due next.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let tx = match &self.tx_state {
            Tx::Idle if !self.queue.is_empty() && self.tx.is_quiet() => Some(self.next_start()),
            Tx::Idle => None,
            Tx::RtsSetup { deadline, .. } | Tx::RtsHold { deadline, .. } => Some(*deadline),
            Tx::Sending { held_until, .. } => *held_until,
        };
        [tx, self.receiver.deadline()].into_iter().flatten().min()
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<AsciiEvent> {
        self.events.pop_front()
    }

    /// How many received telegrams wait in the receive buffer.
    pub fn received_len(&self) -> usize {
        self.buffer.len()
    }

    /// The oldest received telegram, left in the buffer.
    pub fn peek_received(&self) -> Option<&[u8]> {
        self.buffer.peek()
    }

    /// Removes and returns the oldest received telegram. Under flow control this lets the partner
    /// go on again (XON, RTS = ON) once the buffer has room.
    pub fn take_received(&mut self) -> Option<Vec<u8>> {
        let telegram = self.buffer.take()?;
        if !self.buffer.is_full() {
            match self.settings().flow {
                FlowControl::XonXoff { xon, .. } if self.xoff_sent => {
                    self.xoff_sent = false;
                    self.tx.push(vec![xon]);
                }
                FlowControl::RtsCts if !self.rts => self.set_rts(true),
                _ => {}
            }
        }
        Some(telegram)
    }

    /// Whether nothing is being sent or queued and no bytes wait for the line.
    pub fn is_idle(&self) -> bool {
        matches!(self.tx_state, Tx::Idle) && self.queue.is_empty() && self.tx.is_quiet()
    }

    // --- receive side ---

    fn deliver(&mut self, outcome: Outcome) {
        let data = match outcome {
            Outcome::Telegram(data) => data,
            Outcome::Discarded(cause) => return self.raise(cause),
        };
        match self.buffer.store(data.clone()) {
            Stored::Kept | Stored::Replaced => {
                self.events.push_back(TelegramEvent::Received { data })
            }
            // 003 6.2.1 "Prevent overwriting"; 7.2, 08 0Ah "There is no free input buffer available."
            Stored::Dropped => self.raise(ids::NO_FREE_RECEIVE_BUFFER),
        }
        if self.buffer.is_full() && self.settings().prevent_overwrite {
            // The receiving half of data flow control ("synchronizes data transmission when one
            // communication partner works faster than the other", 003 6.2.1): hold the partner.
            match self.settings().flow {
                FlowControl::XonXoff { xoff, .. } if !self.xoff_sent => {
                    self.xoff_sent = true;
                    self.tx.push(vec![xoff]);
                }
                FlowControl::RtsCts if self.rts => self.set_rts(false),
                _ => {}
            }
        }
    }

    // --- send side ---

    /// When the next telegram may start: 003 6.2.1 "Transmission pause" keeps the line quiet for
    /// the character delay time between telegrams.
    fn next_start(&self) -> Instant {
        let pause = if self.settings().send_pause {
            self.settings().zvz
        } else {
            Duration::ZERO
        };
        self.quiet_since.map_or(Instant::ZERO, |t| t + pause)
    }

    /// Whether the partner lets us send now.
    fn may_send(&self) -> bool {
        match self.settings().flow {
            FlowControl::None | FlowControl::AutoV24 { .. } => true,
            FlowControl::XonXoff { .. } => !self.held_by_xoff,
            FlowControl::RtsCts => self.signals.cts,
        }
    }

    /// Moves the send side on as far as it can go at `now`.
    fn pump(&mut self, now: Instant) {
        loop {
            match core::mem::replace(&mut self.tx_state, Tx::Idle) {
                Tx::Idle => {
                    let ready = self.tx.is_quiet() && now >= self.next_start();
                    let Some(job) = ready.then(|| self.queue.pop_front()).flatten() else {
                        return;
                    };
                    if let FlowControl::AutoV24 { output_wait, .. } = self.settings().flow {
                        if !self.signals.dsr {
                            // 000 7.2 08 18h: "Vor oder während eines Sendevorgangs sind die
                            // Signale DSR bzw. CTS vom Partner auf OFF geschaltet worden": a send
                            // does not start while the partner is not ready (DSR, 000 5.4).
                            self.refuse_send(job, ids::DSR_OR_CTS_OFF);
                            continue;
                        }
                        // 000 5.4 "Senden": "Steht ein Sendeauftrag an, wird RTS auf ON gesetzt und
                        // die parametrierte Datenausgabewartezeit gestartet."
                        let deadline = now + output_wait;
                        self.set_rts(true);
                        self.tx_state = Tx::RtsSetup { job, deadline };
                        return;
                    }
                    self.tx_state = Tx::Sending {
                        job,
                        sent: 0,
                        held_until: None,
                    };
                }
                Tx::Sending {
                    job,
                    sent,
                    held_until,
                } => {
                    if !self.tx.is_quiet() {
                        self.tx_state = Tx::Sending {
                            job,
                            sent,
                            held_until,
                        };
                        return;
                    }
                    if sent >= job.data.len() {
                        self.finish_send(now, job);
                        continue;
                    }
                    if !self.may_send() {
                        let until = held_until.unwrap_or(now + self.settings().flow_wait);
                        self.tx_state = Tx::Sending {
                            job,
                            sent,
                            held_until: Some(until),
                        };
                        return;
                    }
                    let chunk = if self.settings().flow.can_pause() {
                        usize::from(self.settings().tx_chunk)
                    } else {
                        MAX_TELEGRAM
                    };
                    let end = sent.saturating_add(chunk).min(job.data.len());
                    self.tx
                        .push(job.data.get(sent..end).unwrap_or_default().to_vec());
                    self.tx_state = Tx::Sending {
                        job,
                        sent: end,
                        held_until: None,
                    };
                    return;
                }
                other => {
                    self.tx_state = other;
                    return;
                }
            }
        }
    }

    fn finish_send(&mut self, now: Instant, job: Job) {
        if let FlowControl::AutoV24 { rts_hold, .. } = self.settings().flow {
            self.tx_state = Tx::RtsHold {
                job,
                deadline: now + rts_hold,
            };
        } else {
            self.events.push_back(TelegramEvent::Sent { id: job.id });
        }
    }

    /// Gives up the job in progress with `cause`; returns whether there was one. RTS goes off
    /// at once under the automatic V24 signal handling.
    fn abort_send(&mut self, now: Instant, cause: EventId) -> bool {
        let job = match core::mem::replace(&mut self.tx_state, Tx::Idle) {
            Tx::Idle => return false,
            Tx::RtsSetup { job, .. } | Tx::Sending { job, .. } => job,
            // The data are out: only RTS is still on. The job is complete.
            Tx::RtsHold { job, deadline } => {
                self.tx_state = Tx::RtsHold { job, deadline };
                return false;
            }
        };
        if matches!(self.settings().flow, FlowControl::AutoV24 { .. }) {
            self.set_rts(false);
        }
        self.raise(cause);
        self.events.push_back(TelegramEvent::SendFailed {
            id: job.id,
            event: cause,
            first: cause,
        });
        if self.tx.is_quiet() {
            self.quiet_since = Some(now);
        }
        true
    }

    /// With [`SendLength::UpToEndChars`]: the length of `telegram` up to and including the first
    /// occurrence of the end character(s), if it has them.
    fn end_chars_len(&self, telegram: &[u8]) -> Option<usize> {
        if self.params.send_length() != SendLength::UpToEndChars {
            return None;
        }
        let EndCriterion::EndChars { first, second } = self.settings().end else {
            return None;
        };
        match second {
            None => telegram.iter().position(|&b| b == first).map(|at| at + 1),
            Some(second) => telegram
                .windows(2)
                .position(|w| w == [first, second])
                .map(|at| at + 2),
        }
    }

    /// Gives up `job` before any of it went out (the line stays as quiet as it was).
    fn refuse_send(&mut self, job: Job, cause: EventId) {
        self.raise(cause);
        self.events.push_back(TelegramEvent::SendFailed {
            id: job.id,
            event: cause,
            first: cause,
        });
    }

    fn set_rts(&mut self, on: bool) {
        self.rts = on;
        self.actions.push_back(Action::SetRts(on));
    }

    fn raise(&mut self, id: EventId) {
        self.events.push_back(TelegramEvent::Raised { id });
    }
}
