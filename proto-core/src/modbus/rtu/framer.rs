//! The end of an RTU frame by silence, written once for every RTU receiver: the master's reply
//! ([`crate::modbus::master`]), the slave's requests ([`crate::modbus::slave`]), the tap's
//! traffic ([`crate::modbus::tap`]) and the frame monitor's cutter ([`crate::monitor`], which
//! ends any line's received frames by the same silence, the line's gap in place of t3.5).
//!
//! A frame ends when no character arrives for 3.5 character times (003 6.4.3 "CRC-CHECK": the
//! message end is "when no transmission takes place during the time period for the transmission
//! of 3.5 times character delay time"), scaled by the CP's "multiplier character delay time"
//! 1..10 (003 6.4.2.1, applied by [`CharTiming::with_multiplier`] before the timing is given
//! here). The frame is everything that arrived before the silence, never less: length is only
//! checked once the silence has come.
//!
//! Bytes and line errors go in with their time; [`SilenceFramer::poll`] gives the frame once its
//! silence has passed, either good (length and CRC checked) or discarded with its [`Fault`], and
//! [`SilenceFramer::deadline`] says when to ask. What the engine does with a fault (events,
//! counters, the operating mode's treatment of line errors) stays the engine's.
//!
//! Optional checks, each asked for by the engine that needs it:
//! - t1.5: a silence of more than 1.5 character times inside a frame makes it bad (Modbus over
//!   Serial Line V1.02, 2.5.1.1: the frame "must be transmitted as a continuous stream of
//!   characters"); the time given with a chunk is the arrival of its last byte, so the gap before
//!   its first byte is the time since the previous chunk less the chunk's own transmission time;
//! - the length the function code and byte counts announce ([`super::expected_request_len`]): a
//!   frame longer than that carries trailing bytes ([`Fault::TrailingData`]).

use super::{CharTiming, FrameLen, MAX_FRAME_LEN};
use crate::modbus::FrameError;
use crate::time::Instant;

/// Why a frame ended by silence is not a good frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Fault {
    /// The CRC does not match (003 7.2 0E 57h).
    BadCrc,
    /// Fewer bytes than address, function code and CRC.
    TooShort,
    /// More bytes than the largest frame ([`MAX_FRAME_LEN`]).
    TooLong,
    /// A silence above t1.5 inside the frame (only when checked).
    GapInsideFrame,
    /// A character with a parity or framing error, a BREAK or an overrun inside the frame
    /// (003 7.2 08 0Ch, 08 0Dh), as the engine reported it ([`SilenceFramer::fail`]).
    LineError,
    /// More bytes before the silence than the function code and byte count announce (only when
    /// checked).
    TrailingData,
}

// === impl Fault ===

impl From<&FrameError> for Fault {
    /// The one mapping of a failed RTU frame check to a fault.
    fn from(error: &FrameError) -> Self {
        match error {
            FrameError::BadCrc { .. } => Self::BadCrc,
            FrameError::TooLong { .. } => Self::TooLong,
            _ => Self::TooShort,
        }
    }
}

/// Why received RTU bytes were not used, for every RTU receiver that reports it (the slave and
/// the tap): one vocabulary, one mapping from a [`Fault`] (and so from a [`FrameError`]), and one
/// metric label per reason ([`Self::as_str`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DiscardReason {
    /// A good frame for another slave address (the slave ignores it, 003 6.4.6).
    OtherAddress(u8),
    /// The CRC does not match (003 7.2 0E 57h).
    BadCrc,
    /// A silence above t1.5 inside the frame (only where t1.5 is checked: the tap).
    GapInsideFrame,
    /// A character with a parity or framing error, a BREAK or an overrun inside the frame
    /// (003 7.2 08 0Ch, 08 0Dh).
    LineError,
    /// Fewer bytes than address, function code and CRC.
    TooShort,
    /// More bytes than the largest frame (slave: event 08 16h); the rest until the silence is
    /// dropped.
    TooLong,
    /// More bytes before the silence than the function code and byte count announce (003 6.4.6:
    /// the frame ends by silence only; only where the length is checked: the slave).
    TrailingData,
    /// Neither a request nor the answer awaited (the tap).
    Unpaired,
}

// === impl DiscardReason ===

impl DiscardReason {
    /// A stable name, the metric label (`gateway_frames_discarded_total{reason}`).
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::OtherAddress(_) => "other_address",
            Self::BadCrc => "bad_crc",
            Self::GapInsideFrame => "gap_inside_frame",
            Self::LineError => "line_error",
            Self::TooShort => "too_short",
            Self::TooLong => "too_long",
            Self::TrailingData => "trailing_data",
            Self::Unpaired => "unpaired",
        }
    }
}

impl From<Fault> for DiscardReason {
    /// The one mapping of a frame the framer discarded to its reason.
    fn from(fault: Fault) -> Self {
        match fault {
            Fault::BadCrc => Self::BadCrc,
            Fault::TooShort => Self::TooShort,
            Fault::TooLong => Self::TooLong,
            Fault::GapInsideFrame => Self::GapInsideFrame,
            Fault::LineError => Self::LineError,
            Fault::TrailingData => Self::TrailingData,
        }
    }
}

impl From<&FrameError> for DiscardReason {
    /// A failed RTU frame check, through its [`Fault`].
    fn from(error: &FrameError) -> Self {
        Fault::from(error).into()
    }
}

/// What a frame ended by silence is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// A frame with a good length and CRC: address, PDU, CRC as received.
    Frame(Vec<u8>),
    /// A frame that is not used.
    Discard {
        /// Why.
        fault: Fault,
        /// How many bytes arrived in it.
        received: usize,
        /// How many of them were kept (at most [`MAX_FRAME_LEN`]).
        kept: usize,
    },
}

/// A frame ended by silence.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Cut {
    /// When it ended: t3.5 after its last byte (or line error).
    pub end: Instant,
    /// What it is.
    pub outcome: Outcome,
}

/// The frame being received.
#[derive(Debug)]
struct Open {
    /// The bytes so far, at most [`MAX_FRAME_LEN`].
    bytes: Vec<u8>,
    /// Every byte that arrived, kept or not.
    received: usize,
    /// The arrival of the last byte (or line error).
    last: Instant,
    /// Why the frame is already bad.
    fault: Option<Fault>,
}

/// Cuts an RTU byte stream into frames by silence (see the module doc).
#[derive(Debug)]
pub struct SilenceFramer {
    /// t1.5 and t3.5 (multiplier applied).
    timing: CharTiming,
    /// Whether a gap above t1.5 inside a frame makes it bad.
    check_t15: bool,
    /// The length the frame's start announces, when checked.
    expected_len: Option<fn(&[u8]) -> FrameLen>,
    /// The frame being received.
    open: Option<Open>,
}

// === impl SilenceFramer ===

impl SilenceFramer {
    /// A framer for a line with `timing` (its t3.5 ends a frame; the multiplier is applied by the
    /// caller), without the optional checks.
    pub const fn new(timing: CharTiming) -> Self {
        Self {
            timing,
            check_t15: false,
            expected_len: None,
            open: None,
        }
    }

    /// Whether a gap above t1.5 inside a frame makes it bad ([`Fault::GapInsideFrame`]).
    #[must_use]
    pub const fn check_t15(mut self, check: bool) -> Self {
        self.check_t15 = check;
        self
    }

    /// Checks a frame ended by silence against the length `expected_len` derives from its start
    /// ([`Fault::TrailingData`] when longer).
    #[must_use]
    pub const fn check_length(mut self, expected_len: fn(&[u8]) -> FrameLen) -> Self {
        self.expected_len = Some(expected_len);
        self
    }

    /// The timing in use.
    pub const fn timing(&self) -> CharTiming {
        self.timing
    }

    /// Whether a frame is being received (bytes or a line error since the last silence).
    pub const fn is_open(&self) -> bool {
        self.open.is_some()
    }

    /// When the frame being received ends unless more bytes come: t3.5 after its last byte.
    pub fn deadline(&self) -> Option<Instant> {
        self.open
            .as_ref()
            .map(|open| open.last + self.timing.t3_5())
    }

    /// Bytes received at `now` (the arrival of the chunk's last byte). Returns the fault the
    /// chunk made the frame's first ([`Fault::GapInsideFrame`], [`Fault::TooLong`]), so that the
    /// engine can raise its event at once. Nothing ends here: call [`Self::poll`] first.
    pub fn push(&mut self, now: Instant, bytes: &[u8]) -> Option<Fault> {
        if bytes.is_empty() {
            return None;
        }
        let timing = self.timing;
        let open = self.open.get_or_insert_with(|| Open {
            bytes: Vec::new(),
            received: 0,
            last: now,
            fault: None,
        });
        let had_fault = open.fault.is_some();
        if self.check_t15 && !open.bytes.is_empty() {
            // Modbus over Serial Line V1.02, 2.5.1.1: more than t1.5 between two characters
            // declares the frame incomplete.
            let since = now.saturating_duration_since(open.last);
            let gap = since.saturating_sub(timing.transmit_time(bytes.len()));
            if gap > timing.t1_5() {
                open.fault.get_or_insert(Fault::GapInsideFrame);
            }
        }
        open.last = now;
        let room = MAX_FRAME_LEN.saturating_sub(open.bytes.len());
        if bytes.len() > room {
            open.fault.get_or_insert(Fault::TooLong);
        }
        open.bytes
            .extend_from_slice(bytes.get(..room.min(bytes.len())).unwrap_or_default());
        open.received += bytes.len();
        if had_fault {
            None
        } else {
            open.fault
        }
    }

    /// The engine reports `fault` at `now` (a line error): the frame being received, or an empty
    /// one begun now, is bad for it (it replaces an earlier fault) and ends t3.5 later unless
    /// more bytes come.
    pub fn fail(&mut self, now: Instant, fault: Fault) {
        let open = self.open.get_or_insert_with(|| Open {
            bytes: Vec::new(),
            received: 0,
            last: now,
            fault: None,
        });
        open.last = now;
        open.fault = Some(fault);
    }

    /// The fault of the frame being received and how many bytes arrived in it, if it has one;
    /// the frame goes on empty and without fault (an engine that reports each cause with its own
    /// bytes takes them here before it reports the next one).
    pub fn take_fault(&mut self) -> Option<(Fault, usize)> {
        let open = self.open.as_mut()?;
        let fault = open.fault.take()?;
        let received = core::mem::take(&mut open.received);
        open.bytes.clear();
        Some((fault, received))
    }

    /// The frame being received ended without its silence (a receiver that knows other ends,
    /// such as the monitor's end marks or a transmission): it is dropped unchecked.
    pub fn clear(&mut self) {
        self.open = None;
    }

    /// Ends the frame being received if its silence has passed by `now`.
    pub fn poll(&mut self, now: Instant) -> Option<Cut> {
        let end = self.deadline()?;
        if now < end {
            return None;
        }
        let open = self.open.take()?;
        Some(Cut {
            end,
            outcome: self.check(open),
        })
    }

    /// A frame ended by silence: its fault, its length against the announced one, its CRC.
    fn check(&self, open: Open) -> Outcome {
        let (received, kept) = (open.received, open.bytes.len());
        let discard = move |fault| Outcome::Discard {
            fault,
            received,
            kept,
        };
        if let Some(fault) = open.fault {
            return discard(fault);
        }
        if let Some(FrameLen::Complete(len)) = self.expected_len.map(|f| f(&open.bytes)) {
            if len < open.bytes.len() {
                // 003 6.4.6 "CRC-CHECK": the frame is what came before the silence; a frame
                // followed by more bytes is not a valid frame.
                return discard(Fault::TrailingData);
            }
        }
        match super::decode_frame(&open.bytes) {
            Ok(_) => Outcome::Frame(open.bytes),
            Err(error) => discard(Fault::from(&error)),
        }
    }
}

#[cfg(test)]
mod tests;
