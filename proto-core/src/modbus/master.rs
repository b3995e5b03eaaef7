//! The Modbus master engine (manual 003, 6.4.1 to 6.4.4 and the checks of 7.2), sans-IO, for RTU
//! and ASCII framing.
//!
//! The master carries one transaction at a time (003 6.4.1 "the master can only communicate with
//! one slave at a time ... During the latency the communication with another slaves is not
//! possible"):
//!
//! ```text
//!            submit                poll_transmit + handle_tx_done
//!   Idle ─────────────▶ [Gap] ─▶ Sending ─────────────────────────▶ AwaitReply ──▶ Receiving
//!    ▲  (t3.5 since the line      │ broadcast                          │ 08 30h        │ frame end
//!    │   was last busy)            ▼                                    ▼               ▼
//!    └──── Gap ◀──────────── Turnaround ◀─ (Completed / retry via Gap) ◀──────────────────┘
//! ```
//!
//! Call order (the runtime's driver loop):
//! 1. [`Master::submit`] a request when [`Master::is_idle`] (or at any time: a request submitted
//!    while the inter-frame gap still runs is queued; a second one is refused with
//!    [`SubmitError::Busy`]).
//! 2. [`Master::poll_transmit`] hands out the whole ADU once the line has been silent long enough;
//!    write it, then call [`Master::handle_tx_done`] with the (estimated) instant the last byte
//!    left the UART: the reply monitoring time starts there.
//! 3. Feed received bytes to [`Master::handle_rx`] and UART errors to
//!    [`Master::handle_line_error`]; call [`Master::handle_timeout`] when the instant of
//!    [`Master::poll_timeout`] has passed.
//! 4. Drain [`Master::poll_event`] after every `handle_*` call: every diagnostic event is
//!    [`MasterEvent::Raised`], every transaction ends with exactly one [`MasterEvent::Completed`]
//!    (also a 16-bit request sent as a 32-bit register job on a line with `registers32`; only a
//!    job of [`Master::submit_registers32`] ends with [`MasterEvent::Completed32`]).
//!
//! Decisions where the manual leaves room, each with its reason:
//! - **Wrong slave address** (RTU, normal operation): the first character of the reply differs
//!   from the address sent -> 08 31h at once (003 7.2). The attempt fails, but only once the rest
//!   of that frame has passed (3.5 character times of silence), so that the next request never
//!   collides with the foreign reply. In interference suppression mode and in ASCII the address is
//!   checked on the complete, checksum-correct frame -> 0E 50h (003 7.2 "slave address incorrect").
//! - **Line errors** (parity, framing, overrun, break) during a transaction raise 08 0Ch / 08 0Dh
//!   and fail the attempt when the frame ends ("every recognized transmission error and break will
//!   result in error handling", 003 6.4.2.1); while idle they are raised in normal operation and
//!   ignored with interference suppression (same section).
//! - **Bytes while idle** (a late reply, trailing bytes after a complete reply, noise) are
//!   discarded; in normal operation each burst raises 0E 53h "byte overflow: amount of characters
//!   received is more than should have resulted" (003 7.2), the manual's only event for characters
//!   nobody asked for; with interference suppression they are ignored.
//! - **Repetitions**: the CP never repeats a Modbus request; [`MasterConfig::retries`] (default
//!   0) repeats an attempt that failed for any reason but an exception response, which is a valid
//!   answer. Each failed attempt raises its event; the outcome carries the last attempt's first
//!   error. [`Master::submit_with`] sets them and the reply monitoring time for one request (the
//!   seeds know one time per interface, 003 6.4.2.1); a reply after a shortened time is a late
//!   reply ("bytes while idle" above).
//! - **ASCII character delay time** exceeded inside a reply: "the message is ignored and an error
//!   is indicated" (003 6.4.2.2) -> 08 06h "character delay time exceeded" (003 7.2), the attempt
//!   fails.
//! - **t1.5** (Modbus over Serial Line V1.02, 2.5.1.1) is not checked inside an RTU frame: the CP
//!   names only the 3.5-character end of frame (003 6.4.3), and USB adapters and ptys deliver
//!   characters in bursts; the CRC catches a frame that was cut and merged.
//! - **Quantity limits** are the manual's per framing (003 6.4.4): RTU 1..2040 bits, 1..127
//!   registers; ASCII 1..2008 bits read, 1..1976 written, 1..125 registers read, 1..123 written;
//!   32-bit registers 1..62 read, 1..61 written.

mod config;
mod image16;
mod job;
mod registers32;
mod rx;
mod state;
mod types;

use std::collections::VecDeque;

pub use self::config::{
    ConfigError, Framing, MasterConfig, OperatingMode, DEFAULT_CHAR_DELAY, DEFAULT_REPLY_TIMEOUT,
    MAX_CHAR_DELAY, MAX_REPLY_TIMEOUT, MAX_TURNAROUND_DELAY, MIN_CHAR_DELAY, MIN_REPLY_TIMEOUT,
};
pub use self::job::JobError;
pub use self::registers32::{
    narrow, widen_read, Request32, Response32, FC_READ_32, FC_WRITE_MULTIPLE_32,
    FC_WRITE_SINGLE_32, IMAGE_WORDS,
};
pub use self::types::{Attempts, MasterEvent, Outcome, RequestId, SubmitError};
/// The UART errors every engine of the crate takes (003 7.2: 08 0Ch parity, stop bit and
/// overflow errors, 08 0Dh break).
pub use crate::telegram::LineError;

use self::job::{exception_event, Job, Reply};
use self::rx::{Feed, Receiving};
use self::state::{AwaitReply, Quiet, Sending, State, Transaction};
use crate::event::{ids, EventId};
use crate::modbus::pdu::Request;
use crate::time::Instant;

/// The Modbus master engine. See the module documentation for the call order.
#[derive(Debug)]
pub struct Master {
    config: MasterConfig,
    state: State,
    /// The next request id.
    next_id: u64,
    /// Events not yet polled.
    events: VecDeque<MasterEvent>,
    /// When the line was last busy: a byte received, a line error, the end of our transmission.
    last_activity: Option<Instant>,
    /// Whether the current burst of unexpected bytes has been reported.
    stray_reported: bool,
    /// From the end of transmission to the first byte of the reply, in the current transaction.
    reply_delay: Option<core::time::Duration>,
    /// The 32-bit job function of the last completed transaction ([`Master::job_function`]).
    job_function: Option<u8>,
}

/// How many timer steps one [`Master::handle_timeout`] call takes at most (each step changes the
/// state, so a handful suffices; the bound makes termination obvious).
const MAX_TIMER_STEPS: usize = 8;

// === impl Master ===

impl Master {
    /// A master in the idle state. `config` should have passed [`MasterConfig::validate`]; values
    /// outside the manual's ranges are used as they are.
    pub fn new(config: MasterConfig) -> Self {
        Self {
            config,
            state: State::Idle,
            next_id: 0,
            events: VecDeque::new(),
            last_activity: None,
            stray_reported: false,
            reply_delay: None,
            job_function: None,
        }
    }

    /// The parameters the master runs with.
    pub fn config(&self) -> &MasterConfig {
        &self.config
    }

    /// Queues one request (the bus carries one transaction at a time; a second submit while busy
    /// returns `Err(SubmitError::Busy)`). `slave` 0 = broadcast, writes only.
    ///
    /// The request is checked as the CP checks a job (003 7.2, 0E 42h..0E 49h); a refused request
    /// raises its event and returns [`SubmitError::Invalid`].
    pub fn submit(
        &mut self,
        now: Instant,
        slave: u8,
        request: Request,
    ) -> Result<RequestId, SubmitError> {
        self.submit_with(now, slave, request, Attempts::default())
    }

    /// [`Master::submit`] with its own reply monitoring time or repetitions (e.g. one short
    /// attempt at a device that stopped answering); the inter-frame gap is the same.
    ///
    /// On an ASCII line with `registers32` (003 6.4.4) a request to the holding registers goes out
    /// as the 32-bit register job it stands for (two 16-bit registers per 32-bit register of the
    /// slave, the high word first: 43h, 46h, 50h) and ends with the [`MasterEvent::Completed`] of
    /// the 16-bit request; [`Master::job_function`] tells the job's function code. A range that
    /// splits a 32-bit register is refused with [`SubmitError::HalfRegister`].
    pub fn submit_with(
        &mut self,
        now: Instant,
        slave: u8,
        request: Request,
        attempts: Attempts,
    ) -> Result<RequestId, SubmitError> {
        match image16::to_32bit(&request).filter(|_| self.config.framing.registers32()) {
            Some(Ok(job)) => self.submit_job(now, slave, Job::Registers32(job), attempts, true),
            Some(Err(e)) => Err(e),
            None => self.submit_job(now, slave, Job::Standard(request), attempts, false),
        }
    }

    /// [`Master::submit_with`] with the request sent as it is even on a line with `registers32`:
    /// for 16-bit holding registers a slave keeps beside its 32-bit ones (a drive's scanner words).
    pub fn submit_plain(
        &mut self,
        now: Instant,
        slave: u8,
        request: Request,
        attempts: Attempts,
    ) -> Result<RequestId, SubmitError> {
        self.submit_job(now, slave, Job::Standard(request), attempts, false)
    }

    /// Queues a 32-bit register job of the ASCII master (003 6.4.4 "32bit access with Modbus
    /// Master ASCII"); needs [`Framing::Ascii`] with `registers32`, else it is refused with 0E 42h.
    /// It ends with [`MasterEvent::Completed32`].
    pub fn submit_registers32(
        &mut self,
        now: Instant,
        slave: u8,
        request: Request32,
    ) -> Result<RequestId, SubmitError> {
        self.submit_job(
            now,
            slave,
            Job::Registers32(request),
            Attempts::default(),
            false,
        )
    }

    /// Whether no transaction is in flight or queued and the inter-frame gap has elapsed.
    pub fn is_idle(&self) -> bool {
        matches!(self.state, State::Idle)
    }

    /// From the end of the request's transmission to the first byte of the reply, in the last
    /// attempt of the current or last transaction that received one: the span the reply
    /// monitoring time watches (003 7.2 08 30h). `None` when no byte came.
    pub fn reply_delay(&self) -> Option<core::time::Duration> {
        self.reply_delay
    }

    /// The function code of the CP's job (003 6.4.4: 43h, 46h, 50h) when the last completed
    /// transaction was a 32-bit register job made from a 16-bit request ([`Master::submit_with`]
    /// on a line with `registers32`); `None` for any other.
    pub fn job_function(&self) -> Option<u8> {
        self.job_function
    }

    /// Bytes received from the line at `now`.
    pub fn handle_rx(&mut self, now: Instant, bytes: &[u8]) {
        if bytes.is_empty() {
            return;
        }
        let state = self.take_state();
        let awaited = match &state {
            State::Sending(sending) => sending.handed_out,
            State::AwaitReply(_) | State::Receiving(_) => true,
            State::Idle | State::Gap(_) | State::Turnaround(_) => false,
        };
        if !awaited {
            self.stray(now);
        }
        self.last_activity = Some(now);
        match state {
            State::Idle => self.state = self.quiet_after(now, None),
            State::Gap(quiet) => self.state = State::Gap(self.extend(quiet, now)),
            State::Turnaround(quiet) => self.state = State::Turnaround(self.extend(quiet, now)),
            State::Sending(Sending {
                tx,
                handed_out: false,
                ..
            }) => {
                // The line became busy before the request went out: wait for silence again.
                self.state = State::Gap(self.requeue(tx, now));
            }
            State::Sending(Sending { tx, error, .. }) => {
                // The reply started before the runtime reported the end of transmission.
                self.reply_delay = Some(core::time::Duration::ZERO);
                let mut receiving = Receiving::new(&self.config, tx, now);
                if let Some(error) = error {
                    receiving.fail(error, now + self.config.reply_timeout);
                }
                self.receive(now, receiving, bytes);
            }
            State::AwaitReply(AwaitReply { tx, sent_end, .. }) => {
                self.reply_delay = Some(now.saturating_duration_since(sent_end));
                self.receive(now, Receiving::new(&self.config, tx, now), bytes)
            }
            State::Receiving(receiving) => self.receive(now, receiving, bytes),
        }
    }

    /// The runtime's estimate of when the last byte of the ADU left the UART; the reply
    /// monitoring time starts here (and the turnaround delay after a broadcast).
    pub fn handle_tx_done(&mut self, now: Instant) {
        match self.take_state() {
            State::Sending(Sending {
                tx,
                handed_out: true,
                error,
            }) => {
                self.last_activity = Some(now);
                if let Some(error) = error {
                    let mut receiving = Receiving::new(&self.config, tx, now);
                    receiving.fail(error, now + self.config.reply_timeout);
                    self.state = State::Receiving(receiving);
                } else if tx.slave == 0 {
                    // 003 6.4.3 "ADDR": a broadcast is not answered; 6.4.2.2 "Turnaround Delay":
                    // "the time ... for which the master has to be waiting for between two
                    // broadcast messages".
                    let until = now + self.config.turnaround_delay.max(self.config.frame_gap());
                    self.complete(tx, Finish::Broadcast);
                    self.state = State::Turnaround(Quiet {
                        until,
                        queued: None,
                    });
                } else {
                    let deadline = now + tx.reply_timeout;
                    self.state = State::AwaitReply(AwaitReply {
                        tx,
                        deadline,
                        sent_end: now,
                    });
                }
            }
            other => {
                // Not expected here (no ADU handed out): nothing to start.
                self.state = other;
            }
        }
    }

    /// A parity, framing or overrun error or a break reported by the UART at `now`; ignored while
    /// idle in [`OperatingMode::InterferenceSuppression`] (003 6.4.2.1).
    pub fn handle_line_error(&mut self, now: Instant, error: LineError) {
        let event = error.event();
        self.last_activity = Some(now);
        match self.take_state() {
            state @ (State::Idle
            | State::Gap(_)
            | State::Turnaround(_)
            | State::Sending(Sending {
                handed_out: false, ..
            })) => {
                if self.config.mode == OperatingMode::Normal {
                    self.raise(event, 0);
                }
                self.state = match state {
                    State::Gap(quiet) => State::Gap(self.extend(quiet, now)),
                    State::Turnaround(quiet) => State::Turnaround(self.extend(quiet, now)),
                    State::Sending(sending) => State::Gap(self.requeue(sending.tx, now)),
                    _ => self.quiet_after(now, None),
                };
            }
            State::Sending(mut sending) => {
                self.raise(event, sending.tx.slave);
                sending.error.get_or_insert(event);
                self.state = State::Sending(sending);
            }
            State::AwaitReply(AwaitReply { tx, .. }) => {
                // A disturbed character is the start of a reply: it ends when the line is silent.
                self.raise(event, tx.slave);
                let mut receiving = Receiving::new(&self.config, tx, now);
                receiving.fail(event, now + self.config.reply_timeout);
                self.state = State::Receiving(receiving);
            }
            State::Receiving(mut receiving) => {
                self.raise(event, receiving.tx().slave);
                receiving.touch(now);
                receiving.fail(event, now + self.config.reply_timeout);
                self.state = State::Receiving(receiving);
            }
        }
    }

    /// Runs every timer that has expired at `now`.
    pub fn handle_timeout(&mut self, now: Instant) {
        for _ in 0..MAX_TIMER_STEPS {
            match self.poll_timeout() {
                Some(at) if at <= now => self.on_timer(now),
                _ => return,
            }
        }
    }

    /// The whole ADU to write, once per attempt. Changes after [`Master::submit`] and
    /// [`Master::handle_timeout`] (end of the gap, a repetition).
    pub fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        match &mut self.state {
            State::Sending(sending) if !sending.handed_out => {
                sending.handed_out = true;
                Some(sending.tx.adu.clone())
            }
            _ => None,
        }
    }

    /// The instant [`Master::handle_timeout`] must be called at, if a timer runs. Changes after
    /// every `handle_*` and `submit` call.
    pub fn poll_timeout(&self) -> Option<Instant> {
        match &self.state {
            State::Idle | State::Sending(_) => None,
            State::Gap(quiet) | State::Turnaround(quiet) => Some(quiet.until),
            State::AwaitReply(wait) => Some(wait.deadline),
            State::Receiving(receiving) => Some(receiving.deadline(&self.config)),
        }
    }

    /// The next event, oldest first.
    pub fn poll_event(&mut self) -> Option<MasterEvent> {
        self.events.pop_front()
    }

    fn take_state(&mut self) -> State {
        core::mem::replace(&mut self.state, State::Idle)
    }

    fn submit_job(
        &mut self,
        now: Instant,
        slave: u8,
        job: Job,
        attempts: Attempts,
        image16: bool,
    ) -> Result<RequestId, SubmitError> {
        let queue_free = match &self.state {
            State::Idle => true,
            State::Gap(quiet) | State::Turnaround(quiet) => quiet.queued.is_none(),
            State::Sending(_) | State::AwaitReply(_) | State::Receiving(_) => false,
        };
        if !queue_free {
            return Err(SubmitError::Busy);
        }
        if let Err(error) = job.validate(slave, &self.config) {
            self.raise(error.event(), slave);
            return Err(SubmitError::Invalid(error));
        }
        let id = RequestId(self.next_id);
        self.next_id = self.next_id.wrapping_add(1);
        let adu = rx::encode_adu(&self.config, slave, &job.encode());
        let tx = Transaction {
            id,
            slave,
            job,
            adu,
            attempt: 0,
            reply_timeout: attempts.reply_timeout.unwrap_or(self.config.reply_timeout),
            retries: attempts.retries.unwrap_or(self.config.retries),
            image16,
        };
        self.reply_delay = None;
        let limit = now + self.config.reply_timeout;
        self.state = match self.take_state() {
            State::Gap(quiet) => State::Gap(Quiet {
                queued: Some((tx, limit)),
                ..quiet
            }),
            State::Turnaround(quiet) => State::Turnaround(Quiet {
                queued: Some((tx, limit)),
                ..quiet
            }),
            _ => self.quiet_after(now, Some(tx)),
        };
        Ok(id)
    }

    /// The state after the line was last busy: `Idle` (or `Sending` the queued request) when the
    /// gap has elapsed by `now`, else `Gap`.
    fn quiet_after(&self, now: Instant, queued: Option<Transaction>) -> State {
        let until = self
            .last_activity
            .map_or(now, |at| at + self.config.frame_gap());
        if until <= now {
            match queued {
                Some(tx) => State::Sending(Sending {
                    tx,
                    handed_out: false,
                    error: None,
                }),
                None => State::Idle,
            }
        } else {
            let limit = now + self.config.reply_timeout;
            State::Gap(Quiet {
                until,
                queued: queued.map(|tx| (tx, limit)),
            })
        }
    }

    /// A wait for silence after bytes arrived at `now`: moved to `now + gap`, but never past the
    /// queued request's limit.
    fn extend(&self, quiet: Quiet, now: Instant) -> Quiet {
        let mut until = quiet.until.max(now + self.config.frame_gap());
        if let Some((_, limit)) = &quiet.queued {
            until = until.min(*limit);
        }
        Quiet { until, ..quiet }
    }

    /// A request not yet sent waits again for the line to fall silent after activity at `now`.
    fn requeue(&self, tx: Transaction, now: Instant) -> Quiet {
        let limit = now + self.config.reply_timeout;
        self.extend(
            Quiet {
                until: now,
                queued: Some((tx, limit)),
            },
            now,
        )
    }

    /// Unexpected bytes at `now` (no reply awaited): one 0E 53h a burst in normal operation.
    fn stray(&mut self, now: Instant) {
        let new_burst = self
            .last_activity
            .is_none_or(|at| now >= at + self.config.burst_gap());
        if new_burst {
            self.stray_reported = false;
        }
        if self.config.mode == OperatingMode::Normal && !self.stray_reported {
            self.stray_reported = true;
            self.raise(ids::MODBUS_BYTE_OVERFLOW, 0);
        }
    }

    fn receive(&mut self, now: Instant, mut receiving: Receiving, bytes: &[u8]) {
        let slave = receiving.tx().slave;
        match receiving.feed(&self.config, now, bytes) {
            Feed::More { raised } => {
                self.raise_all(raised, slave);
                self.state = State::Receiving(receiving);
            }
            Feed::Complete {
                raised,
                frame_end,
                rest,
            } => {
                self.raise_all(raised, slave);
                self.end_of_frame(now, receiving.into_tx(), frame_end);
                // Bytes after a complete frame are not part of the reply: a burst of their own.
                if !rest.is_empty() {
                    self.stray_reported = false;
                    self.handle_rx(now, rest);
                }
            }
        }
    }

    fn raise_all(&mut self, ids: Vec<EventId>, slave: u8) {
        for id in ids {
            self.raise(id, slave);
        }
    }

    /// A frame ended (complete, silent, or given up): decode it or fail the attempt.
    fn end_of_frame(&mut self, now: Instant, tx: Transaction, frame_end: rx::FrameEnd) {
        match frame_end {
            rx::FrameEnd::Failed(event) => self.attempt_failed(now, tx, event),
            rx::FrameEnd::Frame(adu) => match rx::decode_adu(&self.config, &adu) {
                Err(event) => {
                    self.raise(event, tx.slave);
                    self.attempt_failed(now, tx, event);
                }
                Ok((address, _)) if address != tx.slave => {
                    self.raise(ids::MODBUS_WRONG_SLAVE, tx.slave);
                    self.attempt_failed(now, tx, ids::MODBUS_WRONG_SLAVE);
                }
                Ok((_, pdu)) => match tx.job.check_reply(&pdu) {
                    Ok(reply) => {
                        if let Reply::Exception(code) = &reply {
                            if let Some(event) = exception_event(*code) {
                                self.raise(event, tx.slave);
                            }
                        }
                        self.complete(tx, Finish::Reply(reply));
                        self.state = self.quiet_after(now, None);
                    }
                    Err(event) => {
                        self.raise(event, tx.slave);
                        self.attempt_failed(now, tx, event);
                    }
                },
            },
        }
    }

    fn on_timer(&mut self, now: Instant) {
        match self.take_state() {
            State::Gap(quiet) | State::Turnaround(quiet) if quiet.until <= now => {
                self.state = match quiet.queued {
                    Some((tx, _)) => State::Sending(Sending {
                        tx,
                        handed_out: false,
                        error: None,
                    }),
                    None => State::Idle,
                };
            }
            State::AwaitReply(wait) if wait.deadline <= now => {
                // 003 7.2 08 30h: "the reply monitoring time has elapsed without the start of a
                // reply message being recognized".
                self.raise(ids::MODBUS_NO_REPLY, wait.tx.slave);
                self.attempt_failed(now, wait.tx, ids::MODBUS_NO_REPLY);
            }
            State::Receiving(receiving) if receiving.deadline(&self.config) <= now => {
                let slave = receiving.tx().slave;
                let (tx, frame_end, raised) = receiving.timed_out(&self.config, now);
                for id in raised {
                    self.raise(id, slave);
                }
                self.end_of_frame(now, tx, frame_end);
            }
            other => self.state = other,
        }
    }

    /// An attempt failed with `event` (already raised): repeat it or give up.
    fn attempt_failed(&mut self, now: Instant, mut tx: Transaction, event: EventId) {
        if tx.attempt < tx.retries {
            tx.attempt += 1;
            self.state = self.quiet_after(now, Some(tx));
        } else {
            self.complete(tx, Finish::Failed(event));
            self.state = self.quiet_after(now, None);
        }
    }

    fn raise(&mut self, id: EventId, slave: u8) {
        self.events.push_back(MasterEvent::Raised { id, slave });
    }

    fn complete(&mut self, tx: Transaction, finish: Finish) {
        self.stray_reported = false;
        let Transaction {
            id,
            slave,
            job,
            image16,
            ..
        } = tx;
        let event = match job {
            Job::Standard(request) => {
                let outcome = match finish {
                    Finish::Reply(Reply::Standard(response)) => Outcome::Response(response),
                    Finish::Reply(Reply::Exception(code)) => Outcome::Exception(code),
                    // check_reply answers a standard job with a standard reply only.
                    Finish::Reply(Reply::Registers32(_)) => {
                        Outcome::Failed(ids::MODBUS_WRONG_FUNCTION)
                    }
                    Finish::Broadcast => Outcome::Broadcast,
                    Finish::Failed(event) => Outcome::Failed(event),
                };
                MasterEvent::Completed {
                    id,
                    slave,
                    request,
                    outcome,
                }
            }
            Job::Registers32(request) => {
                let outcome = match finish {
                    Finish::Reply(Reply::Registers32(response)) => Outcome::Response(response),
                    Finish::Reply(Reply::Exception(code)) => Outcome::Exception(code),
                    Finish::Reply(Reply::Standard(_)) => {
                        Outcome::Failed(ids::MODBUS_WRONG_FUNCTION)
                    }
                    Finish::Broadcast => Outcome::Broadcast,
                    Finish::Failed(event) => Outcome::Failed(event),
                };
                MasterEvent::Completed32 {
                    id,
                    slave,
                    request,
                    outcome,
                }
            }
        };
        let (event, function) = if image16 {
            image16::as_16bit(event)
        } else {
            (event, None)
        };
        self.job_function = function;
        self.events.push_back(event);
    }
}

/// How a transaction finishes, before it is turned into its event.
enum Finish {
    Reply(Reply),
    Broadcast,
    Failed(EventId),
}
