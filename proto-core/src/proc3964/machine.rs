//! The 3964(R) state machine: one station, both roles.

use std::collections::VecDeque;

use crate::event::{ids, EventId};
use crate::telegram::common::{ReceiveBuffer, Stored, TxQueue};
use crate::time::Instant;

use super::frame::{self, Deframer, Progress};
use super::{
    Event3964, LineError, Params3964, Priority, SendError, Settings3964, TelegramEvent, TelegramId,
    DLE, NAK, STX,
};

/// One station of a 3964(R) link.
///
/// # Driving it
///
/// The runtime owns the serial port and the clock and calls, in any order as things happen:
///
/// - [`handle_rx`](Self::handle_rx) with every chunk of received bytes, in order;
/// - [`handle_line_error`](Self::handle_line_error) for a character the UART received with a
///   parity, framing or overrun error (instead of passing the character), or a BREAK;
/// - [`handle_tx_done`](Self::handle_tx_done) once for every buffer taken from
///   [`poll_transmit`](Self::poll_transmit), in order, with the instant its last byte left the
///   line (an estimate such as write time + length x character time is fine): the
///   acknowledgement delay time after STX and after the telegram, and the character delay time
///   after our DLE, start then;
/// - [`handle_timeout`](Self::handle_timeout) when the instant of
///   [`poll_timeout`](Self::poll_timeout) has come (calling it early does nothing);
/// - [`send`](Self::send) to queue a telegram.
///
/// After each of these calls it drains, in this order:
///
/// 1. [`poll_transmit`](Self::poll_transmit) until `None`, writing each buffer to the port;
/// 2. [`poll_event`](Self::poll_event) until `None` (received telegrams, send results, events);
/// 3. [`poll_timeout`](Self::poll_timeout) for the next deadline, which any call above can move.
///
/// Received telegrams stay in the receive buffer (the CP's, 003 6.2.1) until
/// [`take_received`](Self::take_received); while it is full, the station answers STX with NAK
/// (003 6.3.1 "Passive operation": "When the driver is not ready yet at reception of the STX, it
/// sends a NAK") and raises 08 0Ah.
#[derive(Debug)]
pub struct Proc3964 {
    /// The validated parameters.
    params: Params3964,
    /// What the station is doing.
    state: State,
    /// Telegrams accepted by `send` and not yet started, oldest first.
    queue: VecDeque<Job>,
    /// Received telegrams not yet taken.
    buffer: ReceiveBuffer,
    /// Bytes to send and the ones on the wire.
    tx: TxQueue,
    /// Events for `poll_event`.
    events: VecDeque<Event3964>,
    /// The id of the last telegram accepted by `send`.
    last_id: u64,
    /// The receiving side's account of failed receptions, for 08 01h and 08 15h.
    repeats: Repeats,
    /// Whether the runtime can take a telegram now ([`Proc3964::set_receive_ready`]); when not,
    /// STX is answered with NAK as with a full receive buffer.
    ready: bool,
}

/// One telegram to send, with its attempt counters.
#[derive(Debug)]
struct Job {
    /// As returned by `send`.
    id: TelegramId,
    /// The bytes sent after the partner's DLE ([`frame::encode`]).
    frame: Vec<u8>,
    /// STX sent in the current transmission attempt.
    setups: u8,
    /// Transmission attempts started.
    transmissions: u8,
    /// The first error of the job (7.2, 07 01h).
    first: Option<EventId>,
    /// Whether 07 01h was raised for this job.
    repeated: bool,
}

/// The states of the station; the ones of a send job own the job.
#[derive(Debug)]
enum State {
    /// Waiting for a partner's STX or a job.
    Idle,
    /// STX sent, waiting for the partner's DLE; the QVZ starts when the STX is out.
    Connecting { job: Job, deadline: Option<Instant> },
    /// The telegram is being sent; a character received now is a fault (07 04h, 07 06h).
    Sending { job: Job, fault: Option<EventId> },
    /// The telegram is out, waiting for the partner's DLE within the QVZ.
    AwaitAck { job: Job, deadline: Instant },
    /// We answered the partner's STX with DLE and collect its telegram.
    Receiving(Reception),
    /// A telegram was received complete and correct; its final DLE waits for
    /// [`Proc3964::confirm_received`] (`Settings3964::hold_ack`).
    AwaitConfirm,
}

/// A telegram being received.
#[derive(Debug)]
struct Reception {
    /// Turns the bytes into user data.
    deframer: Deframer,
    /// When the character delay time expires; set once our DLE is out, moved by every byte.
    deadline: Option<Instant>,
    /// When our DLE left the line; a byte before it did not wait for our answer.
    dle_end: Option<Instant>,
    /// The first error, answered with NAK at the end of the telegram.
    fault: Option<EventId>,
}

/// Failed receptions in a row, to tell the partner's repetitions (08 01h, 08 15h).
#[derive(Debug, Default)]
struct Repeats {
    /// Receptions answered with NAK since the last good one.
    failures: u16,
    /// An STX up to this instant repeats the failed telegram.
    until: Option<Instant>,
    /// Whether 08 15h was raised for this series.
    mismatch_reported: bool,
}

// === impl Proc3964 ===

impl Proc3964 {
    /// An idle station.
    pub fn new(params: Params3964) -> Self {
        let buffer = ReceiveBuffer::new(params.settings.receive_buffers.into(), false);
        Self {
            params,
            state: State::Idle,
            queue: VecDeque::new(),
            buffer,
            tx: TxQueue::default(),
            events: VecDeque::new(),
            last_id: 0,
            repeats: Repeats::default(),
            ready: true,
        }
    }

    /// Whether the runtime can take a telegram now. While not, the partner's STX is answered
    /// with NAK and 08 0Ah is raised, as with a full receive buffer (003 6.3.1 "When the driver
    /// is not ready yet at reception of the STX, it sends a NAK"). Ready from the start.
    pub fn set_receive_ready(&mut self, ready: bool) {
        self.ready = ready;
    }

    /// Whether a received telegram waits for [`confirm_received`](Self::confirm_received)
    /// (only with `hold_ack`).
    pub fn awaiting_confirm(&self) -> bool {
        matches!(self.state, State::AwaitConfirm)
    }

    /// Ends the reception that waits for confirmation (`hold_ack`): `Ok` sends the final DLE
    /// (the partner's send is done), `Err(cause)` answers NAK and raises `cause`, and the
    /// partner repeats the telegram (003 6.3.1, "In the event of an error, the NAK code is
    /// sent"). The caller takes the telegram from the receive buffer before it refuses it.
    /// Does nothing when no telegram waits.
    pub fn confirm_received(&mut self, now: Instant, result: Result<(), EventId>) {
        if !self.awaiting_confirm() {
            return;
        }
        self.state = match result {
            Ok(()) => {
                self.tx.push(vec![DLE]);
                self.repeats = Repeats::default();
                State::Idle
            }
            Err(cause) => self.fail_reception(now, cause),
        };
        self.kick();
    }

    /// Whether the partner's STX can be answered with DLE now.
    fn can_receive(&self) -> bool {
        self.ready && !self.buffer.is_full()
    }

    /// The parameters in use.
    pub fn params(&self) -> &Params3964 {
        &self.params
    }

    fn settings(&self) -> &Settings3964 {
        &self.params.settings
    }

    /// Queues `telegram` (user data, without control codes) for sending.
    ///
    /// # Errors
    ///
    /// [`SendError::Empty`], [`SendError::TooLong`] beyond the configured maximum (003 6.3.1: 250
    /// bytes unless configured up to 1024), [`SendError::QueueFull`].
    pub fn send(&mut self, now: Instant, telegram: Vec<u8>) -> Result<TelegramId, SendError> {
        let _ = now; // no timer starts here: the STX goes out first (handle_tx_done)
        let max = usize::from(self.settings().max_len);
        let capacity = usize::from(self.settings().send_queue);
        if telegram.is_empty() {
            return Err(SendError::Empty);
        }
        if telegram.len() > max {
            return Err(SendError::TooLong {
                len: telegram.len(),
                max,
            });
        }
        if self.queue.len() >= capacity {
            return Err(SendError::QueueFull { capacity });
        }
        self.last_id += 1;
        let id = TelegramId::new(self.last_id);
        let frame = frame::encode(&telegram, self.settings().variant);
        self.queue.push_back(Job {
            id,
            frame,
            setups: 0,
            transmissions: 0,
            first: None,
            repeated: false,
        });
        self.kick();
        Ok(id)
    }

    /// Takes received bytes.
    pub fn handle_rx(&mut self, now: Instant, bytes: &[u8]) {
        for &byte in bytes {
            self.state = match core::mem::replace(&mut self.state, State::Idle) {
                State::Idle => self.idle_byte(now, byte),
                State::Connecting { job, deadline } => self.connecting_byte(job, deadline, byte),
                State::Sending { job, fault } => {
                    self.sending_fault(job, fault, sending_fault_of(byte))
                }
                State::AwaitAck { job, .. } if byte == DLE => {
                    self.events.push_back(TelegramEvent::Sent { id: job.id });
                    State::Idle
                }
                // 003 6.3.1 "Timeout times": "when a character other than DLE is received the
                // attempt to establish the connection and the telegram are repeated"; 7.2, 07 06h.
                State::AwaitAck { job, .. } => self.fail_transmission(job, ids::SEND_END_REJECTED),
                State::Receiving(reception) => self.receiving_byte(now, reception, byte),
                // The partner must wait for our DLE or NAK: a character now is its fault
                // (7.2, 08 02h "partner sent more codes without waiting for response DLE").
                State::AwaitConfirm => {
                    self.raise(ids::RECEIVE_SETUP_ERROR);
                    State::AwaitConfirm
                }
            };
            self.kick();
        }
    }

    /// Takes a character the UART received with an error, or a BREAK.
    ///
    /// 7.2, 08 0Ch: "If faulty character is received in idle mode, the error is reported
    /// immediately ... If this occurs during send or receive operation, repetitions are initiated."
    pub fn handle_line_error(&mut self, now: Instant, error: LineError) {
        let cause = error.event();
        self.state = match core::mem::replace(&mut self.state, State::Idle) {
            State::Idle => {
                self.raise(cause);
                if error != LineError::Break {
                    // A character other than STX in idle (6.3.1 "Passive operation").
                    self.tx.push(vec![NAK]);
                }
                State::Idle
            }
            State::Connecting { job, .. } => self.retry_setup(job, cause),
            State::Sending { job, fault } => self.sending_fault(job, fault, cause),
            State::AwaitAck { job, .. } => self.fail_transmission(job, cause),
            State::Receiving(mut reception) => {
                reception.fault.get_or_insert(cause);
                reception.deadline = Some(now + self.settings().zvz);
                State::Receiving(reception)
            }
            State::AwaitConfirm => {
                self.raise(cause);
                State::AwaitConfirm
            }
        };
        self.kick();
    }

    /// Confirms that the oldest buffer from `poll_transmit` has left the line at `now`.
    pub fn handle_tx_done(&mut self, now: Instant) {
        if !self.tx.done() {
            return;
        }
        let (qvz, zvz) = (self.settings().qvz, self.settings().zvz);
        self.state = match core::mem::replace(&mut self.state, State::Idle) {
            // 003 6.3.1 "Timeout times": "The QVZ is monitored between STX and DLE and between
            // BCC and DLE."
            State::Connecting {
                job,
                deadline: None,
            } => State::Connecting {
                job,
                deadline: Some(now + qvz),
            },
            State::Sending { job, fault: None } => State::AwaitAck {
                job,
                deadline: now + qvz,
            },
            State::Sending {
                job,
                fault: Some(_),
            } => self.retry_transmission(job),
            // 7.2, 08 06h: "1. character after sending of DLE during connection setup was not
            // received within character delay time".
            State::Receiving(mut reception) if reception.dle_end.is_none() => {
                reception.dle_end = Some(now);
                reception.deadline =
                    Some(reception.deadline.map_or(now + zvz, |d| d.max(now + zvz)));
                State::Receiving(reception)
            }
            other => other,
        };
        self.kick();
    }

    /// Acts on the deadline of [`poll_timeout`](Self::poll_timeout) if it has come.
    pub fn handle_timeout(&mut self, now: Instant) {
        self.state = match core::mem::replace(&mut self.state, State::Idle) {
            // 003 6.3.1 "Timeout times": "When the QVZ expires after an STX, the STX is repeated."
            State::Connecting {
                job,
                deadline: Some(deadline),
            } if now >= deadline => self.retry_setup(job, ids::SEND_SETUP_TIMEOUT),
            // "When the QVZ expires after a telegram (following the BCC-byte) ... the attempt to
            // establish the connection and the telegram are repeated"; 7.2, 07 07h.
            State::AwaitAck { job, deadline } if now >= deadline => {
                self.fail_transmission(job, ids::SEND_END_TIMEOUT)
            }
            // 6.3.1 "Passive operation": "When the ZVZ is exceeded at reception, a NAK is sent
            // and it is waited for a new connection"; 7.2, 08 06h.
            State::Receiving(reception) if reception.deadline.is_some_and(|d| now >= d) => {
                let cause = reception.fault.unwrap_or(ids::CHARACTER_DELAY_EXCEEDED);
                self.fail_reception(now, cause)
            }
            other => other,
        };
        self.kick();
    }

    /// The next bytes to write to the port.
    pub fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.tx.pop()
    }

    /// When [`handle_timeout`](Self::handle_timeout) is due next, if anything is timed.
    pub fn poll_timeout(&self) -> Option<Instant> {
        match &self.state {
            State::Connecting { deadline, .. } => *deadline,
            State::AwaitAck { deadline, .. } => Some(*deadline),
            State::Receiving(reception) => reception.deadline,
            State::Idle | State::Sending { .. } | State::AwaitConfirm => None,
        }
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<Event3964> {
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

    /// Removes and returns the oldest received telegram.
    pub fn take_received(&mut self) -> Option<Vec<u8>> {
        self.buffer.take()
    }

    /// Whether nothing is in progress: no telegram being sent, received or queued, no bytes
    /// waiting for the line.
    pub fn is_idle(&self) -> bool {
        matches!(self.state, State::Idle) && self.queue.is_empty() && self.tx.is_quiet()
    }

    // --- the passive role ---

    fn idle_byte(&mut self, now: Instant, byte: u8) -> State {
        match byte {
            STX => self.accept_stx(now),
            // 6.3.1 "Passive operation": "The driver does not respond with an answer to the
            // reception of a NAK."
            NAK => State::Idle,
            // "When the procedure driver is expecting a connection request and it receives a
            // character that is not equal to STX it will transmit a NAK"; 7.2, 08 02h.
            _ => {
                self.tx.push(vec![NAK]);
                self.raise(ids::RECEIVE_SETUP_ERROR);
                State::Idle
            }
        }
    }

    fn accept_stx(&mut self, now: Instant) -> State {
        if !self.can_receive() {
            // 6.3.1: "When the driver is not ready yet at reception of the STX, it sends a NAK";
            // 7.2, 08 0Ah "There is no free input buffer available."
            self.tx.push(vec![NAK]);
            self.raise(ids::NO_FREE_RECEIVE_BUFFER);
            return State::Idle;
        }
        self.note_incoming_repetition(now);
        self.tx.push(vec![DLE]);
        State::Receiving(self.new_reception())
    }

    fn new_reception(&self) -> Reception {
        let settings = self.settings();
        Reception {
            deframer: Deframer::new(settings.variant, settings.max_len.into()),
            deadline: None,
            dle_end: None,
            fault: None,
        }
    }

    /// 7.2, 08 15h "Discrepancy between settings for transfer attempts at CP and communication
    /// partner": the manual does not say how the CP sees it. Our reading: a repetition (an STX
    /// within the QVZ after our NAK) that arrives when our own transmission attempts are used up
    /// means that the partner makes more attempts than we do.
    fn note_incoming_repetition(&mut self, now: Instant) {
        if self.repeats.failures == 0 {
            return;
        }
        if self.repeats.until.is_some_and(|until| now <= until) {
            let attempts = u16::from(self.settings().transmission_attempts);
            if self.repeats.failures >= attempts && !self.repeats.mismatch_reported {
                self.repeats.mismatch_reported = true;
                self.raise(ids::ATTEMPTS_MISMATCH);
            }
        } else {
            self.repeats = Repeats::default();
        }
    }

    fn receiving_byte(&mut self, now: Instant, mut reception: Reception, byte: u8) -> State {
        if reception.dle_end.is_none_or(|end| now < end) {
            // 7.2, 08 02h: "After a STX was received, partner sent more codes without waiting for
            // response DLE."
            reception.fault.get_or_insert(ids::RECEIVE_SETUP_ERROR);
        }
        let progress = reception.deframer.push(byte);
        if reception.fault.is_none() {
            reception.fault = reception.deframer.error().map(frame::FrameError::event);
        }
        // 003 6.3.1 "Timeout times": "ZVZ is monitored for the entire period of receiving".
        reception.deadline = Some(now + self.settings().zvz);
        match progress {
            Progress::Incomplete => State::Receiving(reception),
            Progress::Complete => self.finish_reception(now, reception),
        }
    }

    fn finish_reception(&mut self, now: Instant, reception: Reception) -> State {
        match (reception.fault, reception.deframer.finish()) {
            // 6.3.3 "with block check": "If the BCC is correct and no other receive errors have
            // occurred, the CP sends the code DLE".
            (None, Ok(data)) => match self.buffer.store(data.clone()) {
                Stored::Kept | Stored::Replaced if self.settings().hold_ack => {
                    self.events.push_back(TelegramEvent::Received { data });
                    State::AwaitConfirm
                }
                Stored::Kept | Stored::Replaced => {
                    self.tx.push(vec![DLE]);
                    self.events.push_back(TelegramEvent::Received { data });
                    self.repeats = Repeats::default();
                    State::Idle
                }
                Stored::Dropped => self.fail_reception(now, ids::NO_FREE_RECEIVE_BUFFER),
            },
            (Some(cause), _) => self.fail_reception(now, cause),
            (None, Err(error)) => self.fail_reception(now, error.event()),
        }
    }

    /// Answers a failed reception with NAK ("In the event of an error, the NAK code is sent",
    /// 6.3.3) and raises its cause, plus 08 01h when it is the first of a series.
    fn fail_reception(&mut self, now: Instant, cause: EventId) -> State {
        self.tx.push(vec![NAK]);
        self.raise(cause);
        self.repeats.failures = self.repeats.failures.saturating_add(1);
        self.repeats.until = Some(now + self.settings().qvz);
        if self.repeats.failures == 1 {
            // 7.2, 08 01h "Expectation of the first repetition".
            self.raise(ids::RECEIVE_REPETITION);
        }
        State::Idle
    }

    // --- the active role ---

    /// Starts the next queued job when the station is idle.
    fn kick(&mut self) {
        if matches!(self.state, State::Idle) {
            if let Some(job) = self.queue.pop_front() {
                self.state = self.start_attempt(job);
            }
        }
    }

    fn start_attempt(&mut self, mut job: Job) -> State {
        job.setups = 0;
        job.transmissions = job.transmissions.saturating_add(1);
        self.send_stx(job)
    }

    fn send_stx(&mut self, mut job: Job) -> State {
        job.setups = job.setups.saturating_add(1);
        self.tx.push(vec![STX]);
        State::Connecting {
            job,
            deadline: None,
        }
    }

    fn connecting_byte(&mut self, job: Job, deadline: Option<Instant>, byte: u8) -> State {
        match (byte, self.settings().priority) {
            (DLE, _) => {
                self.tx.push(job.frame.clone());
                State::Sending { job, fault: None }
            }
            // 003 6.3.1 "Initialization conflict": "the station with the lower priority will
            // transmit the DLE and change to receive mode"; its send request waits (6.3.3).
            (STX, Priority::Low) if !self.can_receive() => {
                self.tx.push(vec![NAK]);
                self.raise(ids::NO_FREE_RECEIVE_BUFFER);
                State::Connecting { job, deadline }
            }
            (STX, Priority::Low) => {
                self.queue.push_front(Job {
                    setups: 0,
                    transmissions: 0,
                    ..job
                });
                self.tx.push(vec![DLE]);
                State::Receiving(self.new_reception())
            }
            // The higher-priority station keeps waiting for the partner's DLE.
            (STX, _) => State::Connecting { job, deadline },
            // 6.3.1: "The same sequence is completed when a NAK or any other character follows an
            // STX"; 7.2, 07 02h.
            _ => self.retry_setup(job, ids::SEND_SETUP_REJECTED),
        }
    }

    fn sending_fault(&mut self, mut job: Job, fault: Option<EventId>, cause: EventId) -> State {
        if fault.is_some() {
            return State::Sending { job, fault };
        }
        self.raise(cause);
        job.first.get_or_insert(cause);
        State::Sending {
            job,
            fault: Some(cause),
        }
    }

    /// A failed connection setup: repeat STX up to the setup attempts, then NAK and 07 09h.
    ///
    /// 003 6.3.1 "Timeout times": "This process is repeated 5 times after which the attempt to
    /// establish a connection is terminated by the transmission of a NAK" (6 setup attempts by
    /// default, 6.3.3).
    fn retry_setup(&mut self, mut job: Job, cause: EventId) -> State {
        self.raise(cause);
        job.first.get_or_insert(cause);
        if job.setups < self.settings().setup_attempts {
            self.note_repetition(&mut job);
            self.send_stx(job)
        } else {
            self.give_up(job, ids::SEND_SETUP_ATTEMPTS_EXHAUSTED)
        }
    }

    fn fail_transmission(&mut self, mut job: Job, cause: EventId) -> State {
        self.raise(cause);
        job.first.get_or_insert(cause);
        self.retry_transmission(job)
    }

    /// A failed transmission: repeat setup and telegram up to the transmission attempts, then NAK
    /// and 07 0Ah ("This process is also repeated 5 times after which a NAK is transmitted and
    /// the attempt is terminated", 6.3.1).
    fn retry_transmission(&mut self, mut job: Job) -> State {
        if job.transmissions < self.settings().transmission_attempts {
            self.note_repetition(&mut job);
            self.start_attempt(job)
        } else {
            self.give_up(job, ids::SEND_ATTEMPTS_EXHAUSTED)
        }
    }

    /// 7.2, 07 01h "Transmission of the first repetition".
    fn note_repetition(&mut self, job: &mut Job) {
        if !job.repeated {
            job.repeated = true;
            self.raise(ids::SEND_REPETITION);
        }
    }

    fn give_up(&mut self, job: Job, event: EventId) -> State {
        self.tx.push(vec![NAK]);
        self.raise(event);
        let first = job.first.unwrap_or(event);
        self.events.push_back(TelegramEvent::SendFailed {
            id: job.id,
            event,
            first,
        });
        State::Idle
    }

    fn raise(&mut self, id: EventId) {
        self.events.push_back(TelegramEvent::Raised { id });
    }
}

/// 7.2: a character received while our telegram is still going out: a DLE is "received too
/// early" (07 06h), anything else means "one or more characters were received" (07 04h).
fn sending_fault_of(byte: u8) -> EventId {
    if byte == DLE {
        ids::SEND_END_REJECTED
    } else {
        ids::SEND_ABORTED_BY_PARTNER
    }
}
