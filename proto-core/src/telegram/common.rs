//! Types shared by the telegram engines: the ASCII driver and the 3964(R) procedure.

use core::time::Duration;
use std::collections::VecDeque;

use crate::event::{ids, EventId};

/// Identifies one telegram handed to `send`; unique within one engine, counting from 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct TelegramId(u64);

// === impl TelegramId ===

impl TelegramId {
    pub(crate) const fn new(n: u64) -> Self {
        Self(n)
    }

    /// The sequence number of the telegram within its engine.
    pub const fn get(self) -> u64 {
        self.0
    }
}

impl core::fmt::Display for TelegramId {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "#{}", self.0)
    }
}

/// What a telegram engine reports through `poll_event`.
///
/// Every diagnostic event of chapter 7.2 is reported exactly once as [`TelegramEvent::Raised`];
/// [`TelegramEvent::SendFailed`] repeats the final one as the result of the send job.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TelegramEvent {
    /// A telegram arrived complete and without error. It is also kept in the engine's receive
    /// buffer until `take_received` (the CP's ring buffer); this is a copy for observers.
    Received {
        /// The user data (3964(R): DLE doubling removed, without DLE ETX BCC).
        data: Vec<u8>,
    },
    /// The telegram `id` was sent (3964(R): the partner acknowledged it with DLE).
    Sent {
        /// The telegram, as returned by `send`.
        id: TelegramId,
    },
    /// The telegram `id` was given up.
    SendFailed {
        /// The telegram, as returned by `send`.
        id: TelegramId,
        /// The event that ended the job (e.g. 07 09h, 07 0Ah, 07 08h, 08 18h).
        event: EventId,
        /// The first error of the job; 7.2, 07 01h: "an error number describing the first error
        /// that occurred is output". Equal to `event` when the job failed at its first error.
        first: EventId,
    },
    /// A diagnostic event of chapter 7.2 occurred (for the STATUS word, the diagnostic buffer and
    /// the event counters).
    Raised {
        /// The event.
        id: EventId,
    },
}

/// Why `send` refused a telegram.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SendError {
    /// No bytes to send (7.2, 1E 41h: LEN is 1..1024 bytes).
    #[error("an empty telegram cannot be sent")]
    Empty,
    /// More bytes than the engine's limit allows.
    #[error("telegram of {len} bytes is longer than the {max} bytes allowed")]
    TooLong {
        /// The length offered.
        len: usize,
        /// The configured limit.
        max: usize,
    },
    /// The bounded send queue is full; try again after a `Sent` or `SendFailed` event.
    #[error("send queue full ({capacity} telegrams waiting)")]
    QueueFull {
        /// The queue's capacity.
        capacity: usize,
    },
    /// A byte does not fit in 7 data bits.
    #[error("byte 0x{value:02X} at offset {offset} does not fit in 7 data bits")]
    EighthBit {
        /// Position of the first such byte.
        offset: usize,
        /// Its value.
        value: u8,
    },
}

// === impl SendError ===

impl SendError {
    /// The CP event the manual gives for this refusal, if it has one: 1E 41h for an empty
    /// telegram (LEN outside 1..1024), 05 17h for one that is too long (7.2).
    pub const fn event(&self) -> Option<EventId> {
        match self {
            Self::Empty => Some(ids::BACKPLANE_LEN_ILLEGAL),
            Self::TooLong { .. } => Some(ids::TRANSFER_LENGTH_INVALID),
            Self::QueueFull { .. } | Self::EighthBit { .. } => None,
        }
    }
}

pub use crate::serial_marks::LineError;

/// The physical interface of the line.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Interface {
    /// RS232 (000): full duplex, with the modem signals RTS/CTS/DTR/DSR (000 5.4).
    Rs232,
    /// RS422 four-wire full duplex (003 6.2.1 "Interface": the default).
    #[default]
    Rs422,
    /// RS485 two-wire half duplex (003 6.2.1: ASCII only, without data flow control).
    Rs485,
}

// === impl Interface ===

impl Interface {
    /// Whether data can be sent and received at the same time (003 6.1 "Character frame").
    pub const fn is_full_duplex(self) -> bool {
        !matches!(self, Self::Rs485)
    }
}

/// A parameter set the manual does not allow. The text is meant for the operator.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ConfigError {
    /// A number outside the manual's range of values.
    #[error("{name} must be within {min}..={max}, got {value}")]
    OutOfRange {
        /// The parameter.
        name: &'static str,
        /// The value given.
        value: u64,
        /// The smallest value allowed.
        min: u64,
        /// The largest value allowed.
        max: u64,
    },
    /// A time shorter than the manual's minimum for the baud rate.
    #[error("{name} of {value_ms} ms is below the minimum of {min_ms} ms at {baud} bit/s")]
    BelowBaudMinimum {
        /// The parameter.
        name: &'static str,
        /// The value given, in milliseconds.
        value_ms: u64,
        /// The minimum at this baud rate, in milliseconds.
        min_ms: u64,
        /// The baud rate.
        baud: u32,
    },
    /// 003 6.3.3 "3964(R) Interface": half duplex (RS485) "is not available with 3964(R)".
    #[error("3964(R) needs a full-duplex line (RS232 or RS422 four-wire); two-wire RS485 is not possible")]
    TwoWireNotSupported,
    /// 003 6.2.1: "At half-duplex parameterization with RS485 data flow control is not possible."
    #[error("data flow control is not possible on a two-wire RS485 line")]
    FlowControlNeedsFullDuplex,
    /// RTS/CTS and the automatic V24 signal handling need the RS232 modem signals (000 5.4).
    #[error("{0} needs an RS232 line with modem signals")]
    NeedsRs232(&'static str),
    /// 003 6.2.1 "Prevent overwriting": may only be switched off with one buffered telegram.
    #[error("overwriting may only be allowed with 1 buffered receive telegram, not {buffers}")]
    OverwriteNeedsSingleBuffer {
        /// The number of buffered telegrams configured.
        buffers: u16,
    },
    /// A code above 7Fh with 7 data bits (003 6.2.1: "0...7Fh/FFh (7/8 data bits)").
    #[error("{name} 0x{value:02X} does not fit in 7 data bits")]
    CodeTooWide {
        /// The parameter.
        name: &'static str,
        /// The code given.
        value: u8,
    },
    /// 003 6.2.1 "Send with end character" exists only "as soon as 'End character' is activated
    /// at the end ID".
    #[error(
        "sending up to the end characters needs received telegrams to end with end characters"
    )]
    SendLengthNeedsEndChars,
    /// Two control codes that must differ are equal.
    #[error("{first} and {second} must differ (both 0x{value:02X})")]
    SameCode {
        /// One parameter.
        first: &'static str,
        /// The other parameter.
        second: &'static str,
        /// The shared code.
        value: u8,
    },
}

/// The serial speeds the gateway drives (the CP itself offers 300..76800 bit/s, 6.2.1 "Speed").
pub(crate) const BAUD_RANGE: (u32, u32) = (150, 115_200);

pub(crate) fn check_range(
    name: &'static str,
    value: u64,
    min: u64,
    max: u64,
) -> Result<(), ConfigError> {
    if (min..=max).contains(&value) {
        Ok(())
    } else {
        Err(ConfigError::OutOfRange {
            name,
            value,
            min,
            max,
        })
    }
}

pub(crate) fn check_baud(baud: u32) -> Result<(), ConfigError> {
    check_range(
        "baud rate",
        baud.into(),
        BAUD_RANGE.0.into(),
        BAUD_RANGE.1.into(),
    )
}

/// Checks a time parameter against its range in milliseconds (sub-millisecond parts count).
pub(crate) fn check_millis(
    name: &'static str,
    value: Duration,
    min_ms: u64,
    max_ms: u64,
) -> Result<(), ConfigError> {
    if value < Duration::from_millis(min_ms) || value > Duration::from_millis(max_ms) {
        let value = u64::try_from(value.as_millis()).unwrap_or(u64::MAX);
        Err(ConfigError::OutOfRange {
            name,
            value,
            min: min_ms,
            max: max_ms,
        })
    } else {
        Ok(())
    }
}

/// The minimum of a time parameter at `baud` from a table of (baud rate, minimum ms) rows in
/// ascending baud order: the row of the highest listed rate not above `baud`. Below the first row
/// the minimum grows in proportion to the character time (an extrapolation: the manual's tables
/// start at 300 bit/s).
pub(crate) fn baud_minimum_ms(table: &[(u32, u64)], baud: u32) -> u64 {
    let Some(&(first_baud, first_ms)) = table.first() else {
        return 0;
    };
    if baud < first_baud {
        let baud = u64::from(baud.max(1));
        return (first_ms * u64::from(first_baud)).div_ceil(baud);
    }
    table
        .iter()
        .rev()
        .find(|(rate, _)| *rate <= baud)
        .map_or(first_ms, |&(_, ms)| ms)
}

pub(crate) fn check_baud_minimum(
    name: &'static str,
    value: Duration,
    table: &[(u32, u64)],
    baud: u32,
) -> Result<(), ConfigError> {
    let min_ms = baud_minimum_ms(table, baud);
    if value < Duration::from_millis(min_ms) {
        let value_ms = u64::try_from(value.as_millis()).unwrap_or(u64::MAX);
        Err(ConfigError::BelowBaudMinimum {
            name,
            value_ms,
            min_ms,
            baud,
        })
    } else {
        Ok(())
    }
}

/// What became of a telegram offered to the [`ReceiveBuffer`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Stored {
    /// Appended.
    Kept,
    /// The buffer held its one telegram and overwriting is allowed: the older one was replaced.
    Replaced,
    /// The buffer is full and overwriting is prevented: the new telegram was dropped.
    Dropped,
}

/// The CP's receive ring buffer (003 6.2.1 "ASCII Receiving data"): the oldest telegram is
/// always handed on first.
#[derive(Clone, Debug)]
pub(crate) struct ReceiveBuffer {
    /// Complete telegrams, oldest first.
    telegrams: VecDeque<Vec<u8>>,
    /// How many telegrams it holds at most (1..=250).
    capacity: usize,
    /// Whether a new telegram may replace the buffered one (only with `capacity == 1`).
    overwrite: bool,
}

// === impl ReceiveBuffer ===

impl ReceiveBuffer {
    pub(crate) fn new(capacity: usize, overwrite: bool) -> Self {
        Self {
            telegrams: VecDeque::new(),
            capacity: capacity.max(1),
            overwrite,
        }
    }

    pub(crate) fn is_full(&self) -> bool {
        self.telegrams.len() >= self.capacity
    }

    pub(crate) fn len(&self) -> usize {
        self.telegrams.len()
    }

    pub(crate) fn store(&mut self, data: Vec<u8>) -> Stored {
        if !self.is_full() {
            self.telegrams.push_back(data);
            Stored::Kept
        } else if self.overwrite {
            self.telegrams.pop_front();
            self.telegrams.push_back(data);
            Stored::Replaced
        } else {
            Stored::Dropped
        }
    }

    pub(crate) fn peek(&self) -> Option<&[u8]> {
        self.telegrams.front().map(Vec::as_slice)
    }

    pub(crate) fn take(&mut self) -> Option<Vec<u8>> {
        self.telegrams.pop_front()
    }
}

/// The bytes handed to the runtime and the ones still waiting, so that the engines know when the
/// line has gone quiet (`handle_tx_done` for every buffer taken by `poll_transmit`).
#[derive(Clone, Debug, Default)]
pub(crate) struct TxQueue {
    /// Buffers not yet taken by `poll_transmit`.
    pending: VecDeque<Vec<u8>>,
    /// Buffers taken but not yet confirmed by `handle_tx_done`.
    in_flight: usize,
}

// === impl TxQueue ===

impl TxQueue {
    pub(crate) fn push(&mut self, bytes: Vec<u8>) {
        if !bytes.is_empty() {
            self.pending.push_back(bytes);
        }
    }

    pub(crate) fn pop(&mut self) -> Option<Vec<u8>> {
        let bytes = self.pending.pop_front()?;
        self.in_flight += 1;
        Some(bytes)
    }

    /// Confirms one buffer; returns whether the line is now quiet.
    pub(crate) fn done(&mut self) -> bool {
        self.in_flight = self.in_flight.saturating_sub(1);
        self.is_quiet()
    }

    /// Nothing waiting and nothing on the wire.
    pub(crate) fn is_quiet(&self) -> bool {
        self.in_flight == 0 && self.pending.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn baud_minimum_picks_the_row_at_or_below() {
        let table = [(300, 130), (600, 65), (9600, 4), (19_200, 2)];
        assert_eq!(baud_minimum_ms(&table, 300), 130);
        assert_eq!(baud_minimum_ms(&table, 1200), 65);
        assert_eq!(baud_minimum_ms(&table, 14_400), 4);
        assert_eq!(baud_minimum_ms(&table, 115_200), 2);
        assert_eq!(baud_minimum_ms(&table, 150), 260);
    }

    #[test]
    fn ring_buffer_prevents_or_allows_overwriting() {
        let mut keep = ReceiveBuffer::new(2, false);
        assert_eq!(keep.store(vec![1]), Stored::Kept);
        assert_eq!(keep.store(vec![2]), Stored::Kept);
        assert_eq!(keep.store(vec![3]), Stored::Dropped);
        assert_eq!(keep.take(), Some(vec![1]));
        let mut latest = ReceiveBuffer::new(1, true);
        assert_eq!(latest.store(vec![1]), Stored::Kept);
        assert_eq!(latest.store(vec![2]), Stored::Replaced);
        assert_eq!(latest.peek(), Some(&[2u8][..]));
    }

    #[test]
    fn tx_queue_reports_quiet_after_every_buffer_is_done() {
        let mut q = TxQueue::default();
        q.push(vec![1]);
        q.push(vec![]);
        q.push(vec![2]);
        assert_eq!(q.pop(), Some(vec![1]));
        assert!(!q.done());
        assert_eq!(q.pop(), Some(vec![2]));
        assert!(q.done());
        assert!(q.done(), "a surplus confirmation is harmless");
    }
}
