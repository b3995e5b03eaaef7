//! Reception of a reply, byte by byte, for RTU and ASCII framing, and the framing of requests.
//!
//! A reply ends
//! - RTU: after 3.5 character times of silence ([`SilenceFramer`]; 003 6.4.3 "CRC-CHECK": "The
//!   driver for Modbus Master recognizes message end, when no transmission takes place during the
//!   time period for the transmission of 3.5 times character delay time"), never on length
//!   alone: the frame is
//!   everything that arrived before the silence. A frame longer than its function code and byte
//!   count announce fails with 0E 53h (7.2 "byte overflow"), whatever its CRC, and none of its
//!   values are taken;
//! - ASCII: with LF (003 6.4.2.2; Modbus over Serial Line V1.02, 2.5.2.1: ':' ... CR LF); a gap
//!   longer than the character delay time inside the frame makes it void (003 6.4.2.2 "Character
//!   Delay Time": "the message is ignored and an error is indicated").
//!
//! Once the attempt has an error, the rest of the frame is only waited for (the line must fall
//! silent before the next request), at most one reply monitoring time long.

use super::{Framing, MasterConfig, OperatingMode, Transaction};
use crate::event::{ids, EventId};
use crate::modbus::ascii::{AsciiEvent, AsciiFrameAssembler};
use crate::modbus::rtu::framer::{Fault, Outcome, SilenceFramer};
use crate::modbus::{ascii, rtu, FrameError};
use crate::time::Instant;

/// What a received chunk did to the reception.
pub(super) enum Feed<'a> {
    /// The frame goes on; the events raised by the chunk.
    More { raised: Vec<EventId> },
    /// The frame ended inside the chunk; `rest` are the bytes after it.
    Complete {
        raised: Vec<EventId>,
        frame_end: FrameEnd,
        rest: &'a [u8],
    },
}

/// How a frame ended.
pub(super) enum FrameEnd {
    /// The bytes of a frame to decode.
    Frame(Vec<u8>),
    /// The attempt failed with this event (already raised).
    Failed(EventId),
}

/// A reply being received.
#[derive(Debug)]
pub(super) struct Receiving {
    /// The transaction the reply belongs to.
    tx: Transaction,
    /// RTU: ends the frame after t3.5 of silence and checks it against the length its function
    /// code and byte count announce, and its CRC.
    framer: Option<SilenceFramer>,
    /// When the last byte (or line error) arrived.
    last_rx: Instant,
    /// The first error of the attempt; the rest of the frame is then only waited for.
    error: Option<EventId>,
    /// When waiting for the end of a failed frame stops even if bytes keep coming.
    give_up_at: Option<Instant>,
    /// ASCII: cuts the characters into frames (RTU leaves it empty).
    assembler: AsciiFrameAssembler,
}

// === impl Receiving ===

impl Receiving {
    /// A reception that starts at `now`.
    pub(super) fn new(config: &MasterConfig, tx: Transaction, now: Instant) -> Self {
        let framer = match config.framing {
            Framing::Rtu { timing } => {
                Some(SilenceFramer::new(timing).check_length(rtu::expected_response_len))
            }
            Framing::Ascii { .. } => None,
        };
        Self {
            tx,
            framer,
            last_rx: now,
            error: None,
            give_up_at: None,
            assembler: AsciiFrameAssembler::new(),
        }
    }

    /// The transaction.
    pub(super) fn tx(&self) -> &Transaction {
        &self.tx
    }

    /// The line was busy at `now`.
    pub(super) fn touch(&mut self, now: Instant) {
        self.last_rx = now;
        if let Some(framer) = self.framer.as_mut() {
            framer.fail(now, Fault::LineError);
        }
    }

    /// Records the attempt's first error; waiting for the frame's end stops at `give_up_at`.
    pub(super) fn fail(&mut self, event: EventId, give_up_at: Instant) {
        if self.error.is_none() {
            self.error = Some(event);
            self.give_up_at = Some(give_up_at);
        }
    }

    /// When the frame ends unless more bytes come.
    pub(super) fn deadline(&self, config: &MasterConfig) -> Instant {
        let end = self
            .framer
            .as_ref()
            .and_then(SilenceFramer::deadline)
            .unwrap_or_else(|| self.last_rx + config.burst_gap());
        self.give_up_at.map_or(end, |at| end.min(at))
    }

    /// The frame ended by silence (or the wait for a failed frame was given up).
    pub(super) fn timed_out(
        mut self,
        config: &MasterConfig,
        now: Instant,
    ) -> (Transaction, FrameEnd, Vec<EventId>) {
        let framed = self.framer.as_mut().and_then(|framer| framer.poll(now));
        match (self.error, config.is_ascii()) {
            (Some(error), _) => (self.tx, FrameEnd::Failed(error), Vec::new()),
            // 003 6.4.3: the end of an RTU frame is 3.5 character times of silence.
            (None, false) => match framed.map(|cut| cut.outcome) {
                Some(Outcome::Discard { fault, .. }) => {
                    let error = fault_event(fault);
                    (self.tx, FrameEnd::Failed(error), vec![error])
                }
                Some(Outcome::Frame(frame)) => (self.tx, FrameEnd::Frame(frame), Vec::new()),
                None => (self.tx, FrameEnd::Frame(Vec::new()), Vec::new()),
            },
            // 003 6.4.2.2: a gap longer than the character delay time voids the ASCII frame
            // (7.2 08 06h "character delay time exceeded").
            (None, true) => {
                let error = ids::CHARACTER_DELAY_EXCEEDED;
                (self.tx, FrameEnd::Failed(error), vec![error])
            }
        }
    }

    /// Takes the bytes received at `now`.
    pub(super) fn feed<'a>(
        &mut self,
        config: &MasterConfig,
        now: Instant,
        bytes: &'a [u8],
    ) -> Feed<'a> {
        self.last_rx = now;
        let give_up_at = now + config.reply_timeout;
        let mut raised = Vec::new();
        for (i, &byte) in bytes.iter().enumerate() {
            let rest = bytes.get(i + 1..).unwrap_or_default();
            let end = if config.is_ascii() {
                self.push_ascii(byte, give_up_at, &mut raised)
            } else {
                self.push_rtu(config, now, byte, give_up_at, &mut raised)
            };
            if let Some(frame_end) = end {
                return Feed::Complete {
                    raised,
                    frame_end,
                    rest,
                };
            }
        }
        Feed::More { raised }
    }

    fn push_rtu(
        &mut self,
        config: &MasterConfig,
        now: Instant,
        byte: u8,
        give_up_at: Instant,
        raised: &mut Vec<EventId>,
    ) -> Option<FrameEnd> {
        let framer = self.framer.as_mut()?;
        let first = !framer.is_open();
        // Every byte moves the end of the frame, also those of a failed one.
        let fault = framer.push(now, &[byte]);
        if self.error.is_some() {
            return None;
        }
        if first && config.mode == OperatingMode::Normal && byte != self.tx.slave {
            // 003 7.2 08 31h: "The first character in the reply message from the slave is
            // different from the slave address sent in the request message (for operating mode
            // 'normal')".
            raised.push(ids::MODBUS_WRONG_SLAVE_CHAR);
            self.fail(ids::MODBUS_WRONG_SLAVE_CHAR, give_up_at);
            return None;
        }
        if fault == Some(Fault::TooLong) {
            // 003 7.2 08 32h: "Overflow of receive buffer in CP during reception of the reply".
            raised.push(ids::MODBUS_RECEIVE_OVERFLOW);
            self.fail(ids::MODBUS_RECEIVE_OVERFLOW, give_up_at);
            return None;
        }
        // The frame ends by silence only (see the module doc), never here.
        None
    }

    fn push_ascii(
        &mut self,
        byte: u8,
        give_up_at: Instant,
        raised: &mut Vec<EventId>,
    ) -> Option<FrameEnd> {
        if let Some(error) = self.error {
            // A failed frame ends with its LF (or by silence).
            return (byte == ascii::LF).then_some(FrameEnd::Failed(error));
        }
        match self.assembler.push(byte)? {
            AsciiEvent::Frame(frame) => Some(FrameEnd::Frame(frame)),
            AsciiEvent::WrongStart { .. } => {
                // 003 7.2 08 33h: "A wrong start character was received. This was not a ':'".
                raised.push(ids::MODBUS_ASCII_WRONG_START);
                self.fail(ids::MODBUS_ASCII_WRONG_START, give_up_at);
                None
            }
            AsciiEvent::Restarted { .. } => {
                // 003 7.2 08 34h: "A start character was received within a message. The first
                // part of the message is discarded and reception starts again with the second
                // start character ... This does not in itself fail the send job."
                raised.push(ids::MODBUS_ASCII_START_IN_FRAME);
                None
            }
            AsciiEvent::Overflow { .. } => {
                // 003 7.2 08 32h: "Overflow of receive buffer in CP during reception of the reply".
                raised.push(ids::MODBUS_RECEIVE_OVERFLOW);
                self.fail(ids::MODBUS_RECEIVE_OVERFLOW, give_up_at);
                None
            }
        }
    }

    /// The transaction, once the frame has ended.
    pub(super) fn into_tx(self) -> Transaction {
        self.tx
    }
}

/// The ADU that carries `pdu` to `slave`.
pub(super) fn encode_adu(config: &MasterConfig, slave: u8, pdu: &[u8]) -> Vec<u8> {
    let mut adu = Vec::new();
    if config.is_ascii() {
        ascii::encode_frame(slave, pdu, &mut adu);
    } else {
        rtu::encode_frame(slave, pdu, &mut adu);
    }
    adu
}

/// Checks a complete frame and splits it into the slave address and the PDU.
pub(super) fn decode_adu(config: &MasterConfig, frame: &[u8]) -> Result<(u8, Vec<u8>), EventId> {
    if config.is_ascii() {
        ascii::decode_frame(frame).map_err(|e| frame_event(&e))
    } else {
        rtu::decode_frame(frame)
            .map(|f| (f.address, f.pdu.to_vec()))
            .map_err(|e| frame_event(&e))
    }
}

/// The CP's event for an RTU frame the framer discarded (003 7.2).
fn fault_event(fault: Fault) -> EventId {
    match fault {
        // 0E 53h: "Byte overflow: Amount of characters received is more than should have
        // resulted according to byte counter or function code".
        Fault::TrailingData => ids::MODBUS_BYTE_OVERFLOW,
        // "Byte underflow: Amount of characters received is less than ... expected".
        Fault::TooShort => ids::MODBUS_BYTE_UNDERFLOW,
        // The receive buffer holds at most the longest frame (264 bytes).
        Fault::TooLong => ids::MODBUS_RECEIVE_OVERFLOW,
        Fault::BadCrc => ids::MODBUS_CHECKSUM_ERROR,
        // Never the outcome of a frame that has not failed yet: a line error fails the attempt
        // when it comes (`touch` goes with `fail`), and the master does not check t1.5.
        Fault::LineError | Fault::GapInsideFrame => ids::RECEIVE_LOGICAL_ERROR,
    }
}

/// The CP's event for a frame that fails its framing checks (003 7.2).
fn frame_event(error: &FrameError) -> EventId {
    match error {
        // "Byte underflow: Amount of characters received is less than ... expected".
        FrameError::TooShort { .. } | FrameError::OddHexLength => ids::MODBUS_BYTE_UNDERFLOW,
        // The receive buffer holds at most the longest frame (RTU 264 bytes, ASCII 513 characters).
        FrameError::TooLong { .. } => ids::MODBUS_RECEIVE_OVERFLOW,
        FrameError::BadCrc { .. } | FrameError::BadLrc { .. } => ids::MODBUS_CHECKSUM_ERROR,
        FrameError::BadHexDigit { .. } => ids::MODBUS_ASCII_INVALID_CHARACTER,
        FrameError::MissingStart => ids::MODBUS_ASCII_WRONG_START,
        // LF without CR: the frame's end is malformed, a character is not what it must be.
        FrameError::MissingEnd => ids::MODBUS_ASCII_INVALID_CHARACTER,
    }
}
