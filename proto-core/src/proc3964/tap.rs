//! A listen-only observer of a 3964(R) point-to-point link seen through a Y-cable, sans-IO.
//!
//! The tap never transmits. It receives the two directions of the link separately (side A's
//! transmit line and side B's) and follows the procedure of 003 6.3.1 with both at once:
//!
//! ```text
//!  sender (A or B)                         receiver (the other side)
//!   STX  ─────────────────────────────▶     connection request
//!        ◀───────────────────────────── DLE  (NAK: setup refused)
//!   data (DLE doubled) DLE ETX [BCC] ──▶
//!        ◀───────────────────────────── DLE  telegram good (NAK: bad, the sender repeats)
//! ```
//!
//! # Calling order
//!
//! ```text
//! loop {
//!     while let Some(event) = tap.poll_event() { record / count }
//!     wait for bytes from either side, or until tap.poll_timeout()
//!     bytes    -> tap.handle_rx(side, now, &bytes)
//!     deadline -> tap.handle_timeout(now)
//! }
//! ```
//!
//! Bytes of both sides must be handed over in the order they arrived; a deadline that passed
//! before `now` is handled before the bytes given with `now`.
//!
//! # What is reported
//!
//! A telegram is [`TapEvent3964::Telegram`] only when the receiver acknowledged it with DLE and
//! the tap found it well formed (DLE doubling undone, 3964R: the BCC checked with
//! [`frame::Deframer`]). Everything else is a [`Fault`]: a NAK, a DLE that did not come within
//! the acknowledgement delay time, a bad BCC or other malformed telegram, an initialization
//! conflict, bytes outside any exchange. A connection request of a side whose previous attempt
//! failed is a repetition (003 6.3.1: after NAK or QVZ expiry the sender repeats, up to the
//! setup and transmission attempts).

use std::collections::VecDeque;
use std::time::Duration;

use crate::serial_marks::LineError;
use crate::time::Instant;

use super::frame::{Deframer, FrameError, Progress};
use super::{Variant, DEFAULT_MAX_LEN, DEFAULT_QVZ, DEFAULT_ZVZ, DLE, MAX_LEN_LIMIT, NAK, STX};

/// One direction of the link: the bytes one partner transmits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Side {
    /// The partner whose transmit line feeds the tap's first port.
    A,
    /// The partner whose transmit line feeds the tap's second port.
    B,
}

// === impl Side ===

impl Side {
    /// The partner on the other end.
    pub const fn other(self) -> Self {
        match self {
            Self::A => Self::B,
            Self::B => Self::A,
        }
    }

    /// A short stable name (metrics label, monitor direction).
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::A => "a",
            Self::B => "b",
        }
    }

    const fn index(self) -> usize {
        match self {
            Self::A => 0,
            Self::B => 1,
        }
    }
}

/// The tap's settings: those of the two partners (003 6.3.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TapConfig3964 {
    /// With or without block check.
    pub variant: Variant,
    /// Character delay time: the longest gap inside a telegram.
    pub zvz: Duration,
    /// Acknowledgement delay time: the longest wait for DLE after STX and after the telegram.
    pub qvz: Duration,
    /// The most user bytes of one telegram (1..=1024).
    pub max_len: u16,
}

// === impl TapConfig3964 ===

impl TapConfig3964 {
    /// The manual's defaults with block check (003 6.3.3: ZVZ 220 ms, QVZ 2000 ms, 250 bytes).
    pub const fn new(variant: Variant) -> Self {
        Self {
            variant,
            zvz: DEFAULT_ZVZ,
            qvz: match variant {
                Variant::P3964R => DEFAULT_QVZ,
                Variant::P3964 => super::DEFAULT_QVZ_WITHOUT_BCC,
            },
            max_len: DEFAULT_MAX_LEN,
        }
    }
}

/// What went wrong in an exchange.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    /// The receiver answered NAK: to the connection request (`after_telegram` false) or to the
    /// telegram (003 6.3.1).
    Nak {
        /// Whether the NAK answered the telegram rather than the STX.
        after_telegram: bool,
    },
    /// No DLE within the acknowledgement delay time: after the STX (`after_telegram` false) or
    /// after the telegram (003 6.3.1: the acknowledgement delay time ran out).
    MissingDle {
        /// Whether the DLE after the telegram was missing rather than after the STX.
        after_telegram: bool,
    },
    /// The telegram as the tap received it is malformed: a bad BCC (7.2 08 08h), DLE followed by
    /// another code (08 05h), too long (08 16h) or cut off by the character delay time (08 06h).
    Frame(FrameError),
    /// Both partners sent STX (003 6.3.3 "Priority": initialization conflict).
    Conflict,
    /// Bytes outside any exchange (line noise, or an answer whose request the tap missed).
    Stray {
        /// How many bytes.
        len: usize,
    },
    /// The tap's UART received a character of this side with a parity or framing error, a
    /// BREAK, or lost characters to an overrun (7.2 08 0Ch, 08 0Dh): inside a telegram the
    /// tap's copy is damaged and is not delivered, even if the receiver acknowledged its own.
    LineError {
        /// What the UART reported.
        error: LineError,
    },
}

// === impl Fault ===

impl Fault {
    /// Every name [`Self::as_str`] gives, in a fixed order (to create the metrics' series).
    pub const REASONS: [&'static str; 7] = [
        "nak",
        "missing_dle",
        "bad_bcc",
        "bad_telegram",
        "conflict",
        "stray",
        "line_error",
    ];

    /// A short stable name (metrics label), one of [`Self::REASONS`].
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Nak { .. } => "nak",
            Self::MissingDle { .. } => "missing_dle",
            Self::Frame(FrameError::BadBcc { .. }) => "bad_bcc",
            Self::Frame(_) => "bad_telegram",
            Self::Conflict => "conflict",
            Self::Stray { .. } => "stray",
            Self::LineError { .. } => "line_error",
        }
    }
}

/// What the tap saw.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TapEvent3964 {
    /// A telegram `side` sent and the other side acknowledged with DLE, user data only.
    Telegram {
        /// The sender.
        side: Side,
        /// The user data, DLE doubling undone.
        data: Vec<u8>,
        /// When the acknowledging DLE arrived.
        at: Instant,
    },
    /// A fault in an exchange `side` started (for [`Fault::Stray`]: the side that sent the bytes).
    Fault {
        /// The sender of the exchange, or of the stray bytes.
        side: Side,
        /// What went wrong.
        fault: Fault,
    },
    /// `side` sent STX again after its previous attempt failed (NAK or no DLE).
    Repetition {
        /// The repeating sender.
        side: Side,
    },
}

/// What the tap counted since it was created, per sending side where it says so.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TapCounters3964 {
    /// Acknowledged telegrams, by sender (A, B).
    pub telegrams: [u64; 2],
    /// NAK answers.
    pub naks: u64,
    /// Missing DLE acknowledgements (QVZ expired).
    pub missing_dle: u64,
    /// Telegrams with a bad BCC.
    pub bad_bcc: u64,
    /// Other malformed telegrams.
    pub bad_telegrams: u64,
    /// Repeated connection requests.
    pub repetitions: u64,
    /// Initialization conflicts.
    pub conflicts: u64,
    /// Bytes outside any exchange.
    pub stray_bytes: u64,
    /// Line errors the tap's UART reported (parity, framing, BREAK, overrun).
    pub line_errors: u64,
}

#[derive(Clone, Debug)]
enum State {
    /// No exchange in progress.
    Idle,
    /// STX sent by the sides marked, waiting for the partner's DLE or NAK.
    Setup {
        pending: [bool; 2],
        deadline: Instant,
    },
    /// The receiver answered DLE; the sender's telegram is coming.
    Data(Receiving),
    /// The telegram ended (or was cut off); waiting for the receiver's DLE or NAK.
    Ack(Awaiting),
}

/// A telegram on its way from `sender`.
#[derive(Clone, Debug)]
struct Receiving {
    sender: Side,
    deframer: Deframer,
    deadline: Instant,
    /// A line error inside the telegram: the tap's copy is damaged.
    damaged: Option<LineError>,
}

/// A telegram of `sender` that ended (`result`), waiting for the receiver's answer.
#[derive(Clone, Debug)]
struct Awaiting {
    sender: Side,
    result: Result<Vec<u8>, FrameError>,
    deadline: Instant,
    damaged: Option<LineError>,
}

/// The listen-only 3964(R) decoder; see the module documentation.
#[derive(Debug)]
pub struct Tap3964 {
    config: TapConfig3964,
    state: State,
    /// Whether each side's last attempt failed, so that its next STX is a repetition.
    failed: [bool; 2],
    events: VecDeque<TapEvent3964>,
    counters: TapCounters3964,
}

// === impl Tap3964 ===

impl Tap3964 {
    /// A tap with `config`; `max_len` is kept within 1..=1024 (7.2, 05 17h).
    pub fn new(mut config: TapConfig3964) -> Self {
        config.max_len = config.max_len.clamp(1, MAX_LEN_LIMIT);
        Self {
            config,
            state: State::Idle,
            failed: [false; 2],
            events: VecDeque::new(),
            counters: TapCounters3964::default(),
        }
    }

    /// The settings in use.
    pub fn config(&self) -> TapConfig3964 {
        self.config
    }

    /// The counts so far.
    pub fn counters(&self) -> TapCounters3964 {
        self.counters
    }

    /// Bytes `side` transmitted, the last of them received at `now`.
    pub fn handle_rx(&mut self, side: Side, now: Instant, bytes: &[u8]) {
        self.handle_timeout(now);
        let mut stray = 0usize;
        for &byte in bytes {
            let queued = self.events.len();
            if !self.byte(side, now, byte) {
                stray += 1;
            } else if stray > 0 {
                // Reported before what the accepted byte caused.
                self.events.insert(queued, stray_event(side, stray));
                self.count_stray(stray);
                stray = 0;
            }
        }
        if stray > 0 {
            self.events.push_back(stray_event(side, stray));
            self.count_stray(stray);
        }
    }

    /// The tap's UART reported a line error on `side`'s port at `now`, between the bytes handed
    /// over before and after it (7.2 08 0Ch, 08 0Dh). Inside a telegram of `side` the
    /// telegram is marked damaged: when it is acknowledged it is reported as a
    /// [`Fault::LineError`], not delivered. Anywhere else the error is reported at once.
    pub fn handle_line_error(&mut self, side: Side, now: Instant, error: LineError) {
        self.handle_timeout(now);
        match &mut self.state {
            State::Data(Receiving {
                sender, damaged, ..
            }) if *sender == side => {
                damaged.get_or_insert(error);
            }
            _ => self.line_error_fault(side, error),
        }
    }

    /// Handles every deadline that passed at or before `now`, each at its own time.
    pub fn handle_timeout(&mut self, now: Instant) {
        while let Some(deadline) = self.poll_timeout().filter(|&deadline| deadline <= now) {
            self.expire(deadline);
        }
    }

    /// When [`Self::handle_timeout`] must be called next, if at all.
    pub fn poll_timeout(&self) -> Option<Instant> {
        match &self.state {
            State::Idle => None,
            State::Setup { deadline, .. }
            | State::Data(Receiving { deadline, .. })
            | State::Ack(Awaiting { deadline, .. }) => Some(*deadline),
        }
    }

    /// The next event, oldest first.
    pub fn poll_event(&mut self) -> Option<TapEvent3964> {
        self.events.pop_front()
    }

    /// Takes one byte; false if it belongs to no exchange.
    fn byte(&mut self, side: Side, now: Instant, byte: u8) -> bool {
        match std::mem::replace(&mut self.state, State::Idle) {
            State::Idle => {
                if byte == STX {
                    self.request(side, now);
                    true
                } else {
                    false
                }
            }
            State::Setup { pending, .. } => self.byte_in_setup(pending, side, now, byte),
            State::Data(receiving) => self.byte_in_data(receiving, side, now, byte),
            State::Ack(awaiting) => self.byte_in_ack(awaiting, side, now, byte),
        }
    }

    /// A byte while STX waits for its answer (6.3.1, 6.3.3).
    fn byte_in_setup(
        &mut self,
        mut pending: [bool; 2],
        side: Side,
        now: Instant,
        byte: u8,
    ) -> bool {
        let qvz = self.config.qvz;
        let other = side.other();
        match byte {
            // 6.3.1 "Establishing a send connection": the partner answers STX with DLE.
            DLE if pending[other.index()] => {
                self.state = State::Data(Receiving {
                    sender: other,
                    deframer: Deframer::new(self.config.variant, usize::from(self.config.max_len)),
                    deadline: now + self.config.zvz,
                    damaged: None,
                });
                true
            }
            NAK if pending[other.index()] => {
                self.fail(
                    other,
                    Fault::Nak {
                        after_telegram: false,
                    },
                );
                pending[other.index()] = false;
                self.setup_or_idle(pending, now + qvz);
                true
            }
            STX if pending[side.index()] => {
                // The sender's own QVZ ran out before the tap's: it repeats the STX.
                self.fail(
                    side,
                    Fault::MissingDle {
                        after_telegram: false,
                    },
                );
                self.request(side, now);
                true
            }
            STX => {
                // 6.3.3 "Priority": both partners want to send; the one with the lower
                // priority answers with DLE, which tells the tap who won.
                self.counters.conflicts += 1;
                self.events.push_back(TapEvent3964::Fault {
                    side,
                    fault: Fault::Conflict,
                });
                pending[side.index()] = true;
                self.setup_or_idle(pending, now + qvz);
                true
            }
            _ => {
                self.state = State::Setup {
                    pending,
                    deadline: now + qvz,
                };
                false
            }
        }
    }

    /// A byte while the sender's telegram comes (6.3.1 "Sending data").
    fn byte_in_data(
        &mut self,
        mut receiving: Receiving,
        side: Side,
        now: Instant,
        byte: u8,
    ) -> bool {
        let sender = receiving.sender;
        if side == sender {
            if receiving.deframer.push(byte) == Progress::Complete {
                self.state = State::Ack(Awaiting {
                    sender,
                    result: receiving.deframer.finish(),
                    deadline: now + self.config.qvz,
                    damaged: receiving.damaged,
                });
            } else {
                receiving.deadline = now + self.config.zvz;
                self.state = State::Data(receiving);
            }
            true
        } else if byte == NAK {
            // The receiver gave up during the telegram (7.2 08 06h: ZVZ on its clock).
            self.fail(sender, Fault::Frame(FrameError::Incomplete));
            self.fail(
                sender,
                Fault::Nak {
                    after_telegram: true,
                },
            );
            true
        } else {
            self.state = State::Data(receiving);
            false
        }
    }

    /// A byte while the telegram waits for the receiver's DLE or NAK (6.3.1).
    fn byte_in_ack(&mut self, awaiting: Awaiting, side: Side, now: Instant, byte: u8) -> bool {
        let receiver = awaiting.sender.other();
        let fault = match byte {
            DLE if side == receiver => {
                self.acknowledged(awaiting, now);
                return true;
            }
            NAK if side == receiver => Fault::Nak {
                after_telegram: true,
            },
            // A new request before the acknowledgement: the one awaited is missing.
            STX => Fault::MissingDle {
                after_telegram: true,
            },
            _ => {
                self.state = State::Ack(awaiting);
                return false;
            }
        };
        let Awaiting {
            sender,
            result,
            damaged,
            ..
        } = awaiting;
        self.telegram_failed(sender, &result, damaged, fault);
        if byte == STX {
            self.request(side, now);
        }
        true
    }

    /// The receiver answered the telegram of `awaiting` with DLE.
    fn acknowledged(&mut self, awaiting: Awaiting, now: Instant) {
        let Awaiting {
            sender,
            result,
            damaged,
            ..
        } = awaiting;
        match result {
            // The receiver took it, but the tap's copy has a line error in it.
            Ok(_) if damaged.is_some() => {
                self.failed[sender.index()] = false;
                self.damaged(sender, damaged);
            }
            Ok(data) => {
                self.failed[sender.index()] = false;
                self.counters.telegrams[sender.index()] += 1;
                self.events.push_back(TapEvent3964::Telegram {
                    side: sender,
                    data,
                    at: now,
                });
            }
            // The receiver took a telegram the tap received damaged: reported, not
            // delivered.
            Err(error) => {
                self.damaged(sender, damaged);
                self.frame_fault(sender, error);
            }
        }
    }

    /// `side` sent STX with nothing else pending.
    fn request(&mut self, side: Side, now: Instant) {
        if std::mem::take(&mut self.failed[side.index()]) {
            self.counters.repetitions += 1;
            self.events.push_back(TapEvent3964::Repetition { side });
        }
        let mut pending = [false; 2];
        pending[side.index()] = true;
        self.state = State::Setup {
            pending,
            deadline: now + self.config.qvz,
        };
    }

    fn setup_or_idle(&mut self, pending: [bool; 2], deadline: Instant) {
        self.state = if pending.iter().any(|&p| p) {
            State::Setup { pending, deadline }
        } else {
            State::Idle
        };
    }

    /// The deadline of the current state passed at `now`.
    fn expire(&mut self, now: Instant) {
        match std::mem::replace(&mut self.state, State::Idle) {
            State::Idle => {}
            State::Setup { pending, .. } => {
                for side in [Side::A, Side::B] {
                    if pending[side.index()] {
                        self.fail(
                            side,
                            Fault::MissingDle {
                                after_telegram: false,
                            },
                        );
                    }
                }
            }
            State::Data(Receiving {
                sender,
                deframer,
                damaged,
                ..
            }) => {
                // 7.2 08 06h: the character delay time ran out inside the telegram. The receiver
                // answers NAK; it is awaited like the acknowledgement.
                let error = deframer.error().unwrap_or(FrameError::Incomplete);
                self.state = State::Ack(Awaiting {
                    sender,
                    result: Err(error),
                    deadline: now + self.config.qvz,
                    damaged,
                });
            }
            State::Ack(Awaiting {
                sender,
                result,
                damaged,
                ..
            }) => {
                self.telegram_failed(
                    sender,
                    &result,
                    damaged,
                    Fault::MissingDle {
                        after_telegram: true,
                    },
                );
            }
        }
    }

    /// `sender`'s telegram was not acknowledged (`fault`: a NAK, or no DLE): what the tap found
    /// wrong with its own copy is reported first (a line error inside, a malformed telegram).
    fn telegram_failed(
        &mut self,
        sender: Side,
        result: &Result<Vec<u8>, FrameError>,
        damaged: Option<LineError>,
        fault: Fault,
    ) {
        self.damaged(sender, damaged);
        if let Err(error) = result {
            self.frame_fault(sender, *error);
        }
        self.fail(sender, fault);
    }

    /// Reports the line error inside `sender`'s telegram, if there was one.
    fn damaged(&mut self, sender: Side, damaged: Option<LineError>) {
        if let Some(error) = damaged {
            self.line_error_fault(sender, error);
        }
    }

    fn line_error_fault(&mut self, side: Side, error: LineError) {
        self.counters.line_errors += 1;
        self.events.push_back(TapEvent3964::Fault {
            side,
            fault: Fault::LineError { error },
        });
    }

    fn frame_fault(&mut self, sender: Side, error: FrameError) {
        match error {
            FrameError::BadBcc { .. } => self.counters.bad_bcc += 1,
            _ => self.counters.bad_telegrams += 1,
        }
        self.events.push_back(TapEvent3964::Fault {
            side: sender,
            fault: Fault::Frame(error),
        });
    }

    /// An attempt of `sender` failed: counted, reported, its next STX is a repetition.
    fn fail(&mut self, sender: Side, fault: Fault) {
        match fault {
            Fault::Nak { .. } => self.counters.naks += 1,
            Fault::MissingDle { .. } => self.counters.missing_dle += 1,
            Fault::Frame(error) => {
                self.frame_fault(sender, error);
                self.failed[sender.index()] = true;
                return;
            }
            Fault::Conflict => self.counters.conflicts += 1,
            Fault::Stray { len } => self.count_stray(len),
            Fault::LineError { error } => {
                self.line_error_fault(sender, error);
                return;
            }
        }
        self.failed[sender.index()] = true;
        self.events.push_back(TapEvent3964::Fault {
            side: sender,
            fault,
        });
    }

    fn count_stray(&mut self, len: usize) {
        self.counters.stray_bytes = self
            .counters
            .stray_bytes
            .saturating_add(u64::try_from(len).unwrap_or(u64::MAX));
    }
}

const fn stray_event(side: Side, len: usize) -> TapEvent3964 {
    TapEvent3964::Fault {
        side,
        fault: Fault::Stray { len },
    }
}

#[cfg(test)]
mod tests;
