//! A listen-only station on a Modbus RTU bus: decodes another master's traffic, sans-IO.
//!
//! The tap never transmits. It frames the byte stream by silence as every RTU station does, pairs
//! each request with its answer and yields what the answers tell about the slaves' data: the values
//! of a read answer (FC 01..04, start and quantity from the request) and the values of a write the
//! slave confirmed (FC 05, 06, 15, 16, and both parts of FC 23), which the device now holds.
//!
//! # Calling order
//!
//! ```text
//! loop {
//!     while let Some(event) = tap.poll_event() { store / count }
//!     wait for bytes from the port, or until tap.poll_timeout()
//!     bytes      -> tap.handle_rx(now, &bytes)
//!     line error -> tap.handle_line_error(now, error)
//!     deadline   -> tap.handle_timeout(now)
//! }
//! ```
//!
//! # Framing (003 6.4.3)
//!
//! A frame ends when no character arrives for 3.5 character times ([`rtu::SilenceFramer`], the
//! framer the master and the slave use too; 003 6.4.3 "CRC-CHECK": the message end is "when no
//! transmission takes place during the time period for the transmission of 3.5 times character
//! delay time"; `CharTiming::with_multiplier` scales it as the CP's
//! "multiplier character delay time" does). A silence of more than 1.5 character times and less
//! than 3.5 inside a frame makes the frame bad (Modbus over Serial Line V1.02, 2.5.1.1: the frame
//! "must be transmitted as a continuous stream of characters"; a gap above t1.5 declares it
//! incomplete): it is discarded as [`DiscardReason::GapInsideFrame`] when it ends. The time given
//! to [`Tap::handle_rx`] is the arrival of the chunk's last byte; the gap to its first byte is
//! taken as the time since the previous chunk less the chunk's own transmission time, so that a
//! chunk the operating system delivers late is not taken for a gap. A frame with a character
//! received with a parity or framing error, a BREAK or an overrun is discarded
//! ([`DiscardReason::LineError`]), one with a bad CRC too ([`DiscardReason::BadCrc`], 003 7.2
//! 0E 57h); none of their values are taken.
//!
//! # Pairing
//!
//! A good frame from the address and with the function code (or its exception form, fn | 80h) of
//! the request waiting for its answer is that answer; any other good frame is a request. A request
//! that is followed by another request, or gets no answer within the answer timeout, is reported
//! as [`Outcome::Missing`]; a request to address 0 (broadcast, 003 6.4.3 "ADDR") expects none and
//! is reported as [`Outcome::Broadcast`] (no slave confirms it, so no values). An answer that does
//! not fit its request (003 7.2 0E 51h..0E 56h) is [`Outcome::Invalid`]. A frame that is neither a
//! request nor the answer awaited (an answer whose request was lost) is discarded as
//! [`DiscardReason::Unpaired`].

use std::collections::VecDeque;
use std::time::Duration;

use crate::modbus::pdu::{ExceptionCode, Limits, PduError, Request, Response};
use crate::modbus::rtu::framer::{Fault, Outcome as Framed, SilenceFramer};
use crate::modbus::rtu::{self, CharTiming};
use crate::modbus::Table;
use crate::serial_marks::LineError;
use crate::time::Instant;

/// How long the tap waits for the answer to a request by default: half the CP master's default
/// reply monitoring time (003 6.4.2.1 "Reply monitoring time ... Default value 2000 ms"), so that a
/// master's repetition of an unanswered request (after its own reply monitoring time) is not taken
/// for the answer.
pub const DEFAULT_ANSWER_TIMEOUT: Duration = Duration::from_millis(1000);

/// The largest request quantities the tap decodes: the CP 341 master's (003 6.4.4), above the
/// specification's, so that a CP's requests are understood.
const TAP_LIMITS: Limits = Limits::CP_MASTER_RTU;

/// The tap's settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TapConfig {
    /// t1.5 and t3.5 of the line (003 6.4.3).
    pub timing: CharTiming,
    /// How long a request waits for its answer before it is reported missing.
    pub answer_timeout: Duration,
    /// Whether a gap between t1.5 and t3.5 inside a frame makes it bad (off for adapters that
    /// deliver bytes in bursts, such as USB converters with a latency timer).
    pub check_inter_character: bool,
}

// === impl TapConfig ===

impl TapConfig {
    /// The tap of an RTU line at `baud` with `bits_per_char` (start, data, parity, stop), with the
    /// CP's exact 3.5 character times (003 6.4.3) and the default answer timeout.
    pub fn new(baud: u32, bits_per_char: u8) -> Self {
        Self {
            timing: CharTiming::exact(baud, bits_per_char),
            answer_timeout: DEFAULT_ANSWER_TIMEOUT,
            check_inter_character: true,
        }
    }
}

/// Why a received frame was not used: the RTU receivers' one vocabulary.
pub use crate::modbus::rtu::DiscardReason;

/// Every reason the tap reports, in a fixed order.
pub const DISCARD_REASONS: [DiscardReason; 6] = [
    DiscardReason::BadCrc,
    DiscardReason::GapInsideFrame,
    DiscardReason::LineError,
    DiscardReason::TooShort,
    DiscardReason::TooLong,
    DiscardReason::Unpaired,
];

/// The values of one block of a table.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Values {
    /// Coils or discrete inputs.
    Bits(Vec<bool>),
    /// Holding or input registers.
    Words(Vec<u16>),
}

/// Values a device holds, as its answer showed them.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Block {
    /// The table.
    pub table: Table,
    /// The first address.
    pub start: u16,
    /// The values from `start` on.
    pub values: Values,
}

/// What became of a request.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// Answered: the values the answer shows (empty for functions without table data, such as
    /// diagnostics), in the order the device applied them.
    Answered(Vec<Block>),
    /// Answered with an exception.
    Exception(ExceptionCode),
    /// An answer that does not fit the request (003 7.2 0E 51h..0E 56h): nothing taken.
    Invalid(PduError),
    /// No answer before the next request or the answer timeout.
    Missing,
    /// A request to address 0, which no slave answers.
    Broadcast,
}

/// One request and what became of it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Exchange {
    /// The slave address of the request.
    pub address: u8,
    /// The request.
    pub request: Request,
    /// Its answer, or why there is none.
    pub outcome: Outcome,
}

/// What the tap saw.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TapEvent {
    /// A frame ended by silence (every frame, good or bad), `len` bytes long.
    Frame { len: usize },
    /// A frame that was not used.
    Discarded { reason: DiscardReason, len: usize },
    /// A request with its answer (or without).
    Exchange(Exchange),
}

/// What the tap counted since it was created.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TapCounters {
    /// Frames ended by silence.
    pub frames: u64,
    /// Requests with their answer (normal or exception).
    pub pairs: u64,
    /// Requests without an answer.
    pub missing_answers: u64,
    /// Frames with a bad CRC.
    pub bad_crc: u64,
    /// Other frames not used (gap, line error, length, unpaired, answer not fitting).
    pub discarded: u64,
}

/// A request waiting for its answer.
#[derive(Debug)]
struct Pending {
    address: u8,
    function: u8,
    request: Request,
    /// When it is reported missing.
    deadline: Instant,
}

/// The listen-only decoder of one RTU bus.
#[derive(Debug)]
pub struct Tap {
    config: TapConfig,
    /// Ends the frames by t3.5 of silence, checks t1.5 if configured, and the CRC.
    framer: SilenceFramer,
    pending: Option<Pending>,
    events: VecDeque<TapEvent>,
    counters: TapCounters,
}

// === impl Tap ===

impl Tap {
    /// A tap that has seen nothing yet.
    pub fn new(config: TapConfig) -> Self {
        Self {
            config,
            framer: SilenceFramer::new(config.timing).check_t15(config.check_inter_character),
            pending: None,
            events: VecDeque::new(),
            counters: TapCounters::default(),
        }
    }

    /// What it counted.
    pub fn counters(&self) -> TapCounters {
        self.counters
    }

    /// Bytes received at `now` (the arrival of the chunk's last byte).
    pub fn handle_rx(&mut self, now: Instant, bytes: &[u8]) {
        if bytes.is_empty() {
            return;
        }
        self.advance(now);
        self.framer.push(now, bytes);
    }

    /// A character received with a parity or framing error, a BREAK or an overrun at `now`: the
    /// frame it belongs to is bad.
    pub fn handle_line_error(&mut self, now: Instant, _error: LineError) {
        self.advance(now);
        self.framer.fail(now, Fault::LineError);
    }

    /// The deadline of [`Tap::poll_timeout`] passed (or any later time).
    pub fn handle_timeout(&mut self, now: Instant) {
        self.advance(now);
    }

    /// When [`Tap::handle_timeout`] has work next: t3.5 after the last byte of the frame being
    /// received, or the answer timeout of the request waiting.
    pub fn poll_timeout(&self) -> Option<Instant> {
        self.framer
            .deadline()
            .or_else(|| self.pending.as_ref().map(|p| p.deadline))
    }

    /// The next event.
    pub fn poll_event(&mut self) -> Option<TapEvent> {
        self.events.pop_front()
    }

    /// Ends the frame whose silence passed by `now`, then reports a request whose answer timeout
    /// passed while no frame is being received (an answer already begun may still complete it).
    fn advance(&mut self, now: Instant) {
        if let Some(cut) = self.framer.poll(now) {
            self.end_of_frame(cut.outcome, cut.end);
        }
        if !self.framer.is_open() && self.pending.as_ref().is_some_and(|p| now >= p.deadline) {
            self.missing();
        }
    }

    fn missing(&mut self) {
        if let Some(p) = self.pending.take() {
            self.counters.missing_answers += 1;
            self.events.push_back(TapEvent::Exchange(Exchange {
                address: p.address,
                request: p.request,
                outcome: Outcome::Missing,
            }));
        }
    }

    fn discard(&mut self, reason: DiscardReason, len: usize) {
        if reason == DiscardReason::BadCrc {
            self.counters.bad_crc += 1;
        } else {
            self.counters.discarded += 1;
        }
        self.events.push_back(TapEvent::Discarded { reason, len });
    }

    /// A frame ended by silence at `end`.
    fn end_of_frame(&mut self, framed: Framed, end: Instant) {
        // The length of a frame is the bytes kept of it (at most the largest frame).
        let len = match &framed {
            Framed::Frame(bytes) => bytes.len(),
            Framed::Discard { kept, .. } => *kept,
        };
        self.counters.frames += 1;
        self.events.push_back(TapEvent::Frame { len });
        let bytes = match framed {
            Framed::Frame(bytes) => bytes,
            Framed::Discard { fault, .. } => {
                self.discard(DiscardReason::from(fault), len);
                return;
            }
        };
        let Ok(decoded) = rtu::decode_frame(&bytes) else {
            // The framer checked the frame already.
            self.discard(DiscardReason::TooShort, len);
            return;
        };
        let function = decoded.pdu.first().copied().unwrap_or_default();
        let answers = self.pending.as_ref().is_some_and(|p| {
            p.address == decoded.address
                && (function == p.function || function == p.function | 0x80)
        });
        if answers {
            if let Some(p) = self.pending.take() {
                self.answer(p, decoded.pdu, len);
            }
            return;
        }
        match Request::decode_with(decoded.pdu, &TAP_LIMITS) {
            Ok(request) => {
                // A new request: the one before it got no answer.
                self.missing();
                if decoded.address == 0 {
                    self.events.push_back(TapEvent::Exchange(Exchange {
                        address: 0,
                        request,
                        outcome: Outcome::Broadcast,
                    }));
                } else {
                    self.pending = Some(Pending {
                        address: decoded.address,
                        function,
                        request,
                        deadline: end + self.config.answer_timeout,
                    });
                }
            }
            Err(_) => self.discard(DiscardReason::Unpaired, len),
        }
    }

    /// The answer `pdu` (a frame of `len` bytes) to `pending`.
    fn answer(&mut self, pending: Pending, pdu: &[u8], len: usize) {
        let outcome = match Response::decode_for(&pending.request, pdu) {
            Ok(Ok(response)) => {
                self.counters.pairs += 1;
                Outcome::Answered(blocks(&pending.request, response))
            }
            Ok(Err(exception)) => {
                self.counters.pairs += 1;
                Outcome::Exception(exception.code)
            }
            Err(err) => {
                self.counters.discarded += 1;
                self.events.push_back(TapEvent::Discarded {
                    reason: DiscardReason::Unpaired,
                    len,
                });
                Outcome::Invalid(err)
            }
        };
        self.events.push_back(TapEvent::Exchange(Exchange {
            address: pending.address,
            request: pending.request,
            outcome,
        }));
    }
}

/// The values a device holds after it answered `request` with `response`: what a read returned,
/// what a confirmed write wrote (FC 23 writes before it reads, Modbus Application Protocol V1.1b3
/// 6.17: the read part comes last).
fn blocks(request: &Request, response: Response) -> Vec<Block> {
    let words = |table, start, values: Vec<u16>| Block {
        table,
        start,
        values: Values::Words(values),
    };
    let bits = |table, start, values: Vec<bool>| Block {
        table,
        start,
        values: Values::Bits(values),
    };
    match (request, response) {
        (Request::ReadCoils { address, .. }, Response::ReadCoils(v)) => {
            vec![bits(Table::Coils, *address, v)]
        }
        (Request::ReadDiscreteInputs { address, .. }, Response::ReadDiscreteInputs(v)) => {
            vec![bits(Table::DiscreteInputs, *address, v)]
        }
        (Request::ReadHoldingRegisters { address, .. }, Response::ReadHoldingRegisters(v)) => {
            vec![words(Table::HoldingRegisters, *address, v)]
        }
        (Request::ReadInputRegisters { address, .. }, Response::ReadInputRegisters(v)) => {
            vec![words(Table::InputRegisters, *address, v)]
        }
        (Request::WriteSingleCoil { address, value }, Response::WriteSingleCoil { .. }) => {
            vec![bits(Table::Coils, *address, vec![*value])]
        }
        (Request::WriteSingleRegister { address, value }, Response::WriteSingleRegister { .. }) => {
            vec![words(Table::HoldingRegisters, *address, vec![*value])]
        }
        (Request::WriteMultipleCoils { address, values }, Response::WriteMultipleCoils { .. }) => {
            vec![bits(Table::Coils, *address, values.clone())]
        }
        (
            Request::WriteMultipleRegisters { address, values },
            Response::WriteMultipleRegisters { .. },
        ) => vec![words(Table::HoldingRegisters, *address, values.clone())],
        (
            Request::ReadWriteMultipleRegisters {
                read_address,
                write_address,
                values,
                ..
            },
            Response::ReadWriteMultipleRegisters(read),
        ) => vec![
            words(Table::HoldingRegisters, *write_address, values.clone()),
            words(Table::HoldingRegisters, *read_address, read),
        ],
        _ => Vec::new(),
    }
}

#[cfg(test)]
mod tests;
