//! The Modbus slave RTU engine of the CP 341 (manual 003, 6.4.5 to 6.4.8), sans-IO.
//!
//! The engine frames RTU requests, serves them from the CP memory with the address conversion of
//! 6.4.8 ([`crate::cpmem`]) and hands back the answers, timed as the manual requires.
//!
//! # Calling order
//!
//! ```text
//! loop {
//!     while let Some(frame) = slave.poll_transmit() { write frame to the port }
//!     while let Some(event) = slave.poll_event() { count / log / notify }
//!     wait for bytes from the port, or until slave.poll_timeout()
//!     bytes    -> slave.handle_rx(now, &bytes)
//!     deadline -> slave.handle_timeout(now)
//! }
//! ```
//!
//! - [`Slave::handle_rx`] and [`Slave::handle_timeout`] are the only inputs; both may queue
//!   answers and events and move the next deadline.
//! - [`Slave::poll_transmit`] returns the next complete RTU frame to send (address, PDU, CRC).
//! - [`Slave::poll_timeout`] is the next instant at which [`Slave::handle_timeout`] has work:
//!   the end of the current frame (t3.5 after its last byte) or the answer time of a request.
//! - [`Slave::poll_event`] returns what happened, in order.
//!
//! # Framing and timing
//!
//! A request ends when no byte arrives for t3.5 ([`rtu::SilenceFramer`]; 003 6.4.6 "CRC-CHECK":
//! "message end, when no transmission takes place during the time period for the transmission of
//! 3.5 times character delay time"; 6.4.5.1 "Multiplier character delay time" scales it by
//! 1..10), and only then: the
//! frame is everything that arrived before the silence. A frame longer than the length its
//! function code announces ([`rtu::expected_request_len`]) carries trailing bytes and is
//! discarded and counted ([`DiscardReason::TrailingData`]), not answered. A good request is
//! carried out and answered as soon as that silence has passed, t3.5 after its last byte: that is
//! also the silence the master needs to see its request ended (Modbus over Serial Line V1.02,
//! 2.5.1.1; the seeds give no turnaround time).
//! The inter-character time-out t1.5 of the Modbus specification is not checked: the CP's
//! parameters only know the end-of-frame time.
//!
//! # Memory
//!
//! The engine owns a handle `M` to the memory it serves ([`MemoryAccess`]): a [`CpMemory`] of its
//! own (the default), a `&mut CpMemory`, or a handle of the caller that lends the memory for one
//! call (a lock shared with the Modbus TCP view). The memory is touched only inside
//! [`Slave::handle_rx`] and [`Slave::handle_timeout`], once per request, at its answer time.

mod serve;

use std::collections::VecDeque;

use crate::cpmem::{CpMemory, MemoryAccess, OperatingMode, SlaveParams, Written};
use crate::event::{ids, EventId};
use crate::modbus::pdu::{ExceptionCode, ExceptionResponse, FunctionCode, Limits, Request};
use crate::modbus::rtu::framer::{Fault, Outcome as Framed, SilenceFramer};
use crate::modbus::rtu::{self, CharTiming};
use crate::time::Instant;

/// The quantity limits of the CP 341 slave (003 6.4.8: 1..2040 bits for FC 01/02/15, 1..127
/// registers for FC 03/04/16). The slave has no FC 23; its limits are the specification's.
pub const CP_SLAVE_LIMITS: Limits = Limits {
    read_bits: 2040,
    read_registers: 127,
    write_bits: 2040,
    write_registers: 127,
    read_write_read_registers: Limits::SPEC.read_write_read_registers,
    read_write_write_registers: Limits::SPEC.read_write_write_registers,
};

/// The broadcast address (003 6.4.6 "ADDR": "With slave address 0 (Broadcast Message) every slave
/// at the bus is addressed by the master. This is only permitted in conjunction with the writing
/// function codes").
pub const BROADCAST: u8 = 0;

/// What became of a request for this slave.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// Served and answered.
    Answered,
    /// Refused and answered with this exception (003 6.4.6 "Response of the slave").
    Exception(ExceptionCode),
    /// A broadcast write, applied and not answered (000 6.4.6 "ADDR": "Hierbei sendet der Slave
    /// kein Antwort-Telegramm", the slave sends no answer; 003 words it "not applied").
    BroadcastApplied,
    /// A broadcast that was not applied (not a write, or refused with this exception) and, as
    /// every broadcast, not answered.
    BroadcastRefused(ExceptionCode),
}

/// Why received bytes were not served: the RTU receivers' one vocabulary.
pub use crate::modbus::rtu::DiscardReason;

/// The reasons of bytes lost to the line (every reason the slave reports but a frame for another
/// slave, which is normal on a multi-drop bus).
pub const LOST: [DiscardReason; 5] = [
    DiscardReason::BadCrc,
    DiscardReason::TooShort,
    DiscardReason::TooLong,
    DiscardReason::LineError,
    DiscardReason::TrailingData,
];

/// The UART errors every engine of the crate takes (003 7.2: 08 0Ch parity, stop bit and
/// overflow errors, 08 0Dh break).
pub use crate::serial_marks::LineError;

/// What happened, in order (see [`Slave::poll_event`]).
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum SlaveEvent {
    /// A request to this slave or a broadcast was handled.
    Request {
        /// The address of the request: the own address or [`BROADCAST`].
        address: u8,
        /// Its function code (without the exception bit).
        function: FunctionCode,
        /// What became of it.
        outcome: Outcome,
    },
    /// A write changed the memory (also for broadcasts), for change notifications.
    Written(Written),
    /// Received bytes that were not served. After an overlong frame or a line fault the bytes
    /// are dropped up to the next silence and reported then, all of them in one event.
    Discarded {
        /// Why.
        reason: DiscardReason,
        /// How many bytes.
        len: usize,
    },
    /// An event of the CP 341 catalog (003 7.2) for the line's counters and diagnostic buffer.
    Diagnostic(EventId),
}

// === impl SlaveEvent ===

impl SlaveEvent {
    /// A stable name of the event's kind, usable as a metric label or log field.
    pub const fn kind(&self) -> &'static str {
        match self {
            Self::Request { .. } => "request",
            Self::Written(_) => "written",
            Self::Discarded { .. } => "discarded",
            Self::Diagnostic(_) => "diagnostic",
        }
    }
}

/// A complete frame waiting for its answer time.
#[derive(Clone, Debug)]
struct Ready {
    /// Address, PDU and CRC as received.
    frame: Vec<u8>,
    /// t3.5 after its last byte.
    due: Instant,
}

/// The Modbus slave RTU engine (see the module doc for the calling order).
#[derive(Debug)]
pub struct Slave<M: MemoryAccess = CpMemory> {
    /// Own address, operating mode, address conversion.
    params: SlaveParams,
    /// The memory served.
    memory: M,
    /// Ends the requests by t3.5 of silence (multiplier applied), checks their announced length
    /// and CRC. After an overlong frame or a line fault the bytes up to the next silence are
    /// reported in one [`SlaveEvent::Discarded`] when the silence comes.
    framer: SilenceFramer,
    /// Frames complete by length, in order, waiting for their answer time.
    ready: VecDeque<Ready>,
    /// Answers to send.
    transmit: VecDeque<Vec<u8>>,
    /// Events not yet polled.
    events: VecDeque<SlaveEvent>,
}

// === impl Slave ===

impl<M: MemoryAccess> Slave<M> {
    /// A slave with `params`, the line's character `timing` (e.g. [`CharTiming::exact`] for the
    /// CP's own table) and the memory it serves. The multiplier of `params` is applied to t3.5
    /// here, so `timing` is passed without it.
    pub fn new(params: SlaveParams, timing: CharTiming, memory: M) -> Self {
        let timing = timing.with_multiplier(params.delay_multiplier());
        Self {
            params,
            memory,
            framer: SilenceFramer::new(timing).check_length(rtu::expected_request_len),
            ready: VecDeque::new(),
            transmit: VecDeque::new(),
            events: VecDeque::new(),
        }
    }

    /// The parameters.
    pub fn params(&self) -> &SlaveParams {
        &self.params
    }

    /// The timing in use (multiplier applied).
    pub fn timing(&self) -> CharTiming {
        self.framer.timing()
    }

    /// The memory handle.
    pub fn memory(&self) -> &M {
        &self.memory
    }

    /// Bytes received at `now` (the arrival of the chunk's last byte).
    ///
    /// Ends and serves a frame whose silence already passed, then collects the bytes; the frame
    /// they belong to ends t3.5 after the last of them (see [`Slave::poll_timeout`]).
    pub fn handle_rx(&mut self, now: Instant, bytes: &[u8]) {
        self.advance(now);
        if self.framer.push(now, bytes) == Some(Fault::TooLong) {
            // More bytes than the largest request: the event now, the bytes at the silence.
            self.events
                .push_back(SlaveEvent::Diagnostic(ids::FRAME_TOO_LONG));
        }
    }

    /// The deadline of [`Slave::poll_timeout`] passed (or any later time): ends the frame being
    /// received after its silence and serves the requests whose answer time came.
    pub fn handle_timeout(&mut self, now: Instant) {
        self.advance(now);
    }

    /// A fault of the serial line at `now` (003 6.4.5.1 "Operating mode"): in normal operation
    /// every fault raises its event (08 0Ch, 08 0Dh); with interference suppression a fault while
    /// no frame is being received is ignored. A fault inside a frame drops the frame.
    pub fn handle_line_error(&mut self, now: Instant, error: LineError) {
        self.advance(now);
        let idle = !self.framer.is_open();
        if idle && self.params.mode() == OperatingMode::InterferenceSuppression {
            return;
        }
        self.events.push_back(SlaveEvent::Diagnostic(error.event()));
        if !idle {
            // A second cause while dropping: the bytes so far go with the first.
            if let Some((earlier, len)) = self.framer.take_fault() {
                self.events.push_back(SlaveEvent::Discarded {
                    reason: DiscardReason::from(earlier),
                    len,
                });
            }
            self.framer.fail(now, Fault::LineError);
        }
    }

    /// The next frame to send: a complete RTU answer (address, PDU, CRC low byte first).
    ///
    /// Changes after [`Slave::handle_rx`] and [`Slave::handle_timeout`].
    pub fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.transmit.pop_front()
    }

    /// When [`Slave::handle_timeout`] has work next: t3.5 after the last byte of the frame being
    /// received, or the answer time of the oldest complete request; `None` when idle.
    ///
    /// Changes after [`Slave::handle_rx`], [`Slave::handle_timeout`] and [`Slave::handle_line_error`].
    pub fn poll_timeout(&self) -> Option<Instant> {
        let frame_end = self.framer.deadline();
        let answer = self.ready.front().map(|r| r.due);
        match (frame_end, answer) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<SlaveEvent> {
        self.events.pop_front()
    }

    /// Ends the frame being received if its silence passed by `now`, then serves every complete
    /// request whose answer time came.
    fn advance(&mut self, now: Instant) {
        if let Some(cut) = self.framer.poll(now) {
            match cut.outcome {
                // A good frame ended by silence: served in order at its end.
                Framed::Frame(frame) => self.ready.push_back(Ready {
                    frame,
                    due: cut.end,
                }),
                Framed::Discard {
                    fault, received, ..
                } => {
                    // An overlong frame and a line fault raised their events when they came.
                    let event = (fault == Fault::BadCrc).then_some(ids::MODBUS_CHECKSUM_ERROR);
                    self.discard(DiscardReason::from(fault), received, event);
                }
            }
        }
        while self.ready.front().is_some_and(|r| r.due <= now) {
            if let Some(ready) = self.ready.pop_front() {
                self.serve_frame(&ready.frame);
            }
        }
    }

    fn discard(&mut self, reason: DiscardReason, len: usize, event: Option<EventId>) {
        if let Some(id) = event {
            self.events.push_back(SlaveEvent::Diagnostic(id));
        }
        self.events.push_back(SlaveEvent::Discarded { reason, len });
    }

    /// Serves one frame with a good CRC.
    fn serve_frame(&mut self, frame: &[u8]) {
        let Ok(rtu::RtuFrame { address, pdu }) = rtu::decode_frame(frame) else {
            // Only frames with a good CRC are queued.
            self.discard(
                DiscardReason::BadCrc,
                frame.len(),
                Some(ids::MODBUS_CHECKSUM_ERROR),
            );
            return;
        };
        let broadcast = address == BROADCAST;
        if !broadcast && address != self.params.address() {
            self.discard(DiscardReason::OtherAddress(address), frame.len(), None);
            return;
        }
        let first = pdu.first().copied().unwrap_or(0);
        let function = FunctionCode(first & !FunctionCode::EXCEPTION_BIT);
        let result = match Request::decode_with(pdu, &CP_SLAVE_LIMITS) {
            Err(error) => Err(serve::Refusal {
                code: ExceptionCode::from(&error),
                event: None,
            }),
            // 003 6.4.6 "ADDR": broadcast "is only permitted in conjunction with the writing
            // function codes"; any other broadcast is not carried out.
            Ok(request) if broadcast && !request.is_broadcastable() => Err(serve::Refusal {
                code: ExceptionCode::IllegalFunction,
                event: None,
            }),
            Ok(request) => {
                let map = self.params.map();
                self.memory
                    .with_memory(|mem| serve::serve(map, mem, &request))
            }
        };
        let outcome = match result {
            Ok((response, written)) => {
                if let Some(written) = written {
                    self.events.push_back(SlaveEvent::Written(written));
                }
                if broadcast {
                    Outcome::BroadcastApplied
                } else {
                    let mut pdu = Vec::new();
                    response.encode(&mut pdu);
                    self.send(address, &pdu);
                    Outcome::Answered
                }
            }
            Err(refusal) => {
                if let Some(id) = refusal.event {
                    self.events.push_back(SlaveEvent::Diagnostic(id));
                }
                if broadcast {
                    Outcome::BroadcastRefused(refusal.code)
                } else {
                    let mut pdu = Vec::new();
                    ExceptionResponse::new(function, refusal.code).encode(&mut pdu);
                    self.send(address, &pdu);
                    Outcome::Exception(refusal.code)
                }
            }
        };
        self.events.push_back(SlaveEvent::Request {
            address,
            function,
            outcome,
        });
    }

    fn send(&mut self, address: u8, pdu: &[u8]) {
        let mut frame = Vec::with_capacity(pdu.len() + 3);
        rtu::encode_frame(address, pdu, &mut frame);
        self.transmit.push_back(frame);
    }
}
