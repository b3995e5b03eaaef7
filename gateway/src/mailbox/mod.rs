//! Telegram mailboxes: how the telegrams of an ASCII or 3964(R) line reach Modbus TCP clients,
//! modeled on the CP's FB 7 P_RCV_RK and FB 8 P_SND_RK.
//!
//! The [`Mailbox`] of a line is the CP's receive ring buffer (003 6.2.1 "Receipt telegrams are
//! buffered in the CP at a ring buffer"): every received telegram gets a sequence number and a
//! receive time and waits in a queue of configured depth until a client acknowledges it. The
//! oldest waiting telegram is always the one shown (FB 7 hands on the oldest first). When the
//! queue is full, the [`Overflow`] policy decides, and every telegram dropped or refused is
//! counted and raised as event 08 0Ah ("There is no free receive buffer available", remedy "Call
//! FB P_RCV_RK more frequently"): nothing is lost silently.
//!
//! Sequence numbers count 1, 2, ... 65535, 1, ... (0 means "none"); every telegram taken from the
//! line gets one, also a telegram the policy then drops, so a client sees a gap where telegrams
//! were lost. Observers (zenoh, REST) get every telegram with its number
//! ([`Mailbox::subscribe`]), independent of the acknowledgements.
//!
//! With a [`journal`] ([`Mailbox::with_journal`]) every telegram that waits is on disk: written
//! and synced before it counts as received ([`Mailbox::try_deliver`]), its acknowledgement or
//! drop recorded, so that a restart finds the same telegrams under the same numbers and the
//! numbering goes on. Who acknowledges is the line's [`AckMode`]: a client (Modbus TCP, REST,
//! zenoh `<line>/ack`) or the zenoh feed once it published the telegram.
//!
//! The telegram line's `MailboxUnit` (in [`crate::protocols::telegram`]) serves the mailbox under the
//! line's unit id; [`layout`] documents the registers.

pub mod journal;
pub mod layout;
mod send_block;

use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::SystemTime;

use tokio::sync::{broadcast, Notify};

use journal::{Journal, JournalError, JournaledTelegram, Loss};
use send_block::SendBlock;

/// Telegrams a mailbox holds by default: the CP's default receive buffer (003 6.2.1 "Buffered
/// receive message frames ... 250").
pub const DEFAULT_QUEUE_DEPTH: usize = 250;
/// The most telegrams a mailbox holds (003 6.2.1: "Range of values: 1 ... 250").
pub const MAX_QUEUE_DEPTH: usize = 250;
/// Capacity of the broadcast of received telegrams; a receiver that falls further behind is told
/// how many it missed (tokio's `Lagged`).
const RX_CHANNEL_CAPACITY: usize = 1024;

/// What a full mailbox does with the next telegram.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Overflow {
    /// Leave it with the protocol driver, which refuses further telegrams: 3964(R) answers STX
    /// with NAK (003 6.3.1 "When the driver is not ready yet at reception of the STX, it sends a
    /// NAK"), the ASCII driver stops the partner with XOFF or RTS = OFF under data flow control.
    /// The partner sees the refusal; nothing is lost in the gateway. One telegram more than the
    /// depth waits in the driver.
    #[default]
    Refuse,
    /// 003 6.2.1 "Prevent overwriting": the new telegram is dropped.
    DropNew,
    /// The oldest waiting telegram is dropped to make room (003 6.2.1 allows overwriting only
    /// with one buffer; the gateway allows it at any depth, for 3964(R)), raising 08 0Ah.
    DropOldest,
    /// 003 6.2.1 "Prevent overwriting" off (a buffer of one): the new telegram replaces the held
    /// one. That is the configured behaviour, not a lack of room: no 08 0Ah, no overflow counted.
    Overwrite,
}

// === impl Overflow ===

impl Overflow {
    /// The code of register 529.
    pub const fn code(self) -> u16 {
        match self {
            Self::Refuse => 0,
            Self::DropNew => 1,
            Self::DropOldest => 2,
            Self::Overwrite => 3,
        }
    }

    /// The policy's name for logs and status ("refuse", "drop-new", "drop-oldest").
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Refuse => "refuse",
            Self::DropNew => "drop-new",
            Self::DropOldest => "drop-oldest",
            Self::Overwrite => "overwrite",
        }
    }
}

/// Who acknowledges the telegrams of a line (`ack` of a telegram line).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum AckMode {
    /// A client acknowledges each telegram: Modbus TCP (register 600), REST or a zenoh put on
    /// `<prefix>/<line>/ack`.
    #[default]
    Explicit,
    /// The gateway acknowledges a telegram itself once zenoh took its publication on
    /// `<prefix>/<line>/rx`.
    OnPublish,
}

// === impl AckMode ===

impl AckMode {
    /// The config's name ("explicit", "on-publish").
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::Explicit => "explicit",
            Self::OnPublish => "on-publish",
        }
    }
}

/// The mailbox of one telegram line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct MailboxSettings {
    /// Telegrams held until acknowledged (1..=250).
    pub queue_depth: usize,
    /// What a full queue does.
    pub overflow: Overflow,
    /// Who acknowledges.
    pub ack: AckMode,
}

impl Default for MailboxSettings {
    fn default() -> Self {
        Self {
            queue_depth: DEFAULT_QUEUE_DEPTH,
            overflow: Overflow::Refuse,
            ack: AckMode::Explicit,
        }
    }
}

/// What a telegram line hands to the line that replaces it (a configuration change restarted
/// it): the waiting telegrams, already confirmed to the partner, with their numbers, and the
/// counters, so that none is lost and the numbering goes on.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Carried {
    /// The waiting telegrams, oldest first.
    pub telegrams: Vec<JournaledTelegram>,
    /// The last sequence number given.
    pub last_seq: u16,
    /// The last sequence number acknowledged.
    pub last_acked: u16,
    /// The journal the telegrams were kept in (`None`: in memory only).
    pub journal: Option<std::path::PathBuf>,
}

/// What a mailbox found in its journal when it opened.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Restored {
    /// Telegrams waiting again.
    pub telegrams: usize,
    /// The last sequence number given before (the next one follows it).
    pub last_seq: u16,
    /// The unreadable tail that was cut off, if any.
    pub loss: Option<Loss>,
}

/// A received telegram with its sequence number and receive time.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TelegramRx {
    /// The line's name.
    pub line: Arc<str>,
    /// Its sequence number on the line (1..=65535, wrapping to 1).
    pub seq: u16,
    /// When the driver delivered it complete.
    pub received: SystemTime,
    /// The user data (3964(R): without control codes; ASCII: as received, end characters
    /// included).
    pub data: Arc<[u8]>,
    /// On a 3964(R) tap line, the partner that sent it (`None` on every other line).
    pub side: Option<proto_core::proc3964::tap::Side>,
}

impl TelegramRx {
    /// The telegram as a journal keeps it (and a replaced line carries it).
    fn journaled(&self) -> JournaledTelegram {
        JournaledTelegram {
            seq: self.seq,
            received: self.received,
            data: self.data.to_vec(),
        }
    }
}

/// What became of a telegram handed to the mailbox.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Delivery {
    /// Queued under `seq`.
    Kept {
        /// Its sequence number.
        seq: u16,
    },
    /// The queue was full: the new telegram `seq` was dropped.
    DroppedNew {
        /// The dropped telegram's number.
        seq: u16,
    },
    /// The queue was full: the oldest telegram `dropped` made room for `seq`.
    DroppedOldest {
        /// The new telegram's number.
        seq: u16,
        /// The dropped telegram's number.
        dropped: u16,
    },
    /// Overwriting allowed ([`Overflow::Overwrite`]): `seq` replaced the held telegram
    /// `replaced`.
    Overwritten {
        /// The new telegram's number.
        seq: u16,
        /// The replaced telegram's number.
        replaced: u16,
    },
}

/// Why an acknowledgement was refused (exception 03 on Modbus TCP).
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum AckError {
    /// The number is not that of the oldest waiting telegram (nor the last one acknowledged).
    #[error("sequence number {given} is not the oldest waiting telegram ({expected:?})")]
    WrongSeq {
        /// The number written.
        given: u16,
        /// The oldest waiting telegram's number, `None` when nothing waits.
        expected: Option<u16>,
    },
}

/// The counters of a telegram line, kept with its mailbox.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TelegramCounters {
    /// Telegrams received complete (each got a sequence number).
    pub received: u64,
    /// Bytes of those telegrams.
    pub received_bytes: u64,
    /// Telegrams dropped or refused because the mailbox was full (event 08 0Ah).
    pub overflows: u64,
    /// Telegrams acknowledged by a client.
    pub acknowledged: u64,
    /// Telegrams sent (3964(R): acknowledged by the partner).
    pub sent: u64,
    /// Bytes of those telegrams.
    pub sent_bytes: u64,
    /// Sends given up or refused.
    pub send_failed: u64,
}

/// The mutable part of a mailbox.
#[derive(Debug)]
struct State {
    /// Waiting telegrams, oldest first.
    queue: VecDeque<TelegramRx>,
    /// The last sequence number given (0 before the first).
    last_seq: u16,
    /// The last sequence number acknowledged (0 before the first).
    last_acked: u16,
    /// The STATUS word of the line's newest event.
    status_word: u16,
    /// Whether the line's port is open.
    port_open: bool,
    counters: TelegramCounters,
    /// The Modbus send block (FB 8 P_SND_RK).
    send: SendBlock,
    /// Where the waiting telegrams are kept on disk, if the line has a journal.
    journal: Option<Journal>,
}

/// The receive queue, counters and send block of one telegram line, shared by the line task,
/// its `MailboxUnit` and observers.
#[derive(Debug)]
pub struct Mailbox {
    line: Arc<str>,
    settings: MailboxSettings,
    /// The longest telegram the line sends.
    max_send_len: usize,
    state: Mutex<State>,
    /// Woken when an acknowledgement makes room (the line moves a refused telegram in).
    room: Notify,
    rx: broadcast::Sender<TelegramRx>,
}

/// The sequence number after `seq`: 1..=65535, skipping 0.
pub const fn next_seq(seq: u16) -> u16 {
    if seq == u16::MAX {
        1
    } else {
        seq + 1
    }
}

// === impl Mailbox ===

impl Mailbox {
    /// An empty mailbox for `line`; the depth is clamped to 1..=250.
    pub fn new(line: &str, settings: MailboxSettings, max_send_len: usize) -> Arc<Self> {
        let settings = MailboxSettings {
            queue_depth: settings.queue_depth.clamp(1, MAX_QUEUE_DEPTH),
            ..settings
        };
        let (rx, _) = broadcast::channel(RX_CHANNEL_CAPACITY);
        Arc::new(Self {
            line: Arc::from(line),
            settings,
            max_send_len: max_send_len.min(layout::MAX_DATA_BYTES),
            state: Mutex::new(State {
                queue: VecDeque::with_capacity(settings.queue_depth),
                last_seq: 0,
                last_acked: 0,
                status_word: 0,
                port_open: false,
                counters: TelegramCounters::default(),
                send: SendBlock::default(),
                journal: None,
            }),
            room: Notify::new(),
            rx,
        })
    }

    /// [`Mailbox::new`] keeping its waiting telegrams in the journal at `path`: what the
    /// journal holds waits again, under the same sequence numbers, and the numbering goes on.
    ///
    /// # Errors
    ///
    /// The journal cannot be read, created or written.
    pub fn with_journal(
        line: &str,
        settings: MailboxSettings,
        max_send_len: usize,
        path: &std::path::Path,
    ) -> Result<(Arc<Self>, Restored), JournalError> {
        let (journal, replayed) = Journal::open(path)?;
        let mailbox = Self::new(line, settings, max_send_len);
        let restored = Restored {
            telegrams: replayed.telegrams.len(),
            last_seq: replayed.last_seq,
            loss: replayed.loss,
        };
        {
            let mut state = mailbox.lock();
            mailbox.take_waiting(
                &mut state,
                replayed.telegrams,
                replayed.last_seq,
                replayed.last_acked,
            );
            state.journal = Some(journal);
            // Start from a compact file: the damaged tail is gone and the size bound holds.
            Self::compact(&mut state);
        }
        Ok((mailbox, restored))
    }

    /// [`Mailbox::new`] holding what a replaced line `carried` (in memory: the line has no
    /// journal). More telegrams than the depth may wait; the line takes new ones again (under
    /// its overflow policy) once fewer wait.
    pub fn with_carried(
        line: &str,
        settings: MailboxSettings,
        max_send_len: usize,
        carried: Carried,
    ) -> Arc<Self> {
        let mailbox = Self::new(line, settings, max_send_len);
        {
            let mut state = mailbox.lock();
            mailbox.take_waiting(
                &mut state,
                carried.telegrams,
                carried.last_seq,
                carried.last_acked,
            );
        }
        mailbox
    }

    /// Puts `telegrams` (from a journal or a replaced line) in the queue with the numbering
    /// they had.
    fn take_waiting(
        &self,
        state: &mut State,
        telegrams: impl IntoIterator<Item = JournaledTelegram>,
        last_seq: u16,
        last_acked: u16,
    ) {
        state.last_seq = last_seq;
        state.last_acked = last_acked;
        state.queue = telegrams
            .into_iter()
            .map(|t| TelegramRx {
                line: Arc::clone(&self.line),
                seq: t.seq,
                received: t.received,
                data: Arc::from(t.data),
                side: None,
            })
            .collect();
    }

    /// What the line that replaces this one takes over: the waiting telegrams, the counters
    /// and the journal's path. Call it once the line stopped (no telegram comes in any more).
    pub fn carry(&self) -> Carried {
        let state = self.lock();
        Carried {
            telegrams: state.queue.iter().map(TelegramRx::journaled).collect(),
            last_seq: state.last_seq,
            last_acked: state.last_acked,
            journal: state.journal.as_ref().map(|j| j.path().to_owned()),
        }
    }

    /// Whether the mailbox keeps its telegrams in a journal.
    pub fn journaled(&self) -> bool {
        self.lock().journal.is_some()
    }

    /// The journal's size in bytes now (`None` without a journal).
    pub fn journal_size(&self) -> Option<u64> {
        self.lock().journal.as_ref().map(Journal::size)
    }

    /// Compacts the journal when it has outgrown its bound; a failure is logged and the journal
    /// keeps growing until the next attempt.
    fn compact_if_due(state: &mut State) {
        if state
            .journal
            .as_ref()
            .is_some_and(Journal::wants_compaction)
        {
            Self::compact(state);
        }
    }

    fn compact(state: &mut State) {
        let Some(journal) = state.journal.as_mut() else {
            return;
        };
        let waiting: Vec<JournaledTelegram> =
            state.queue.iter().map(TelegramRx::journaled).collect();
        if let Err(e) = journal.compact(state.last_seq, state.last_acked, waiting.iter()) {
            crate::warn_limited!(
                format!("journal compaction {}", journal.path().display()),
                error = %e,
                "mailbox journal not compacted; it grows until the next attempt"
            );
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The line's name.
    pub fn line(&self) -> &str {
        &self.line
    }

    /// The settings in use (depth clamped).
    pub fn settings(&self) -> MailboxSettings {
        self.settings
    }

    /// The longest telegram the line sends.
    pub fn max_send_len(&self) -> usize {
        self.max_send_len
    }

    /// Received telegrams as they arrive, with their sequence numbers.
    pub fn subscribe(&self) -> broadcast::Receiver<TelegramRx> {
        self.rx.subscribe()
    }

    /// Whether the line may take the next telegram from its driver now: always, except under
    /// [`Overflow::Refuse`] with a full queue.
    pub fn accepts(&self) -> bool {
        self.settings.overflow != Overflow::Refuse
            || self.lock().queue.len() < self.settings.queue_depth
    }

    /// Waits until an acknowledgement makes room. Create the future before checking
    /// [`Mailbox::accepts`] so that no wake-up is missed.
    pub(crate) fn room_freed(&self) -> tokio::sync::futures::Notified<'_> {
        self.room.notified()
    }

    /// Takes a telegram from the line: gives it the next sequence number, sends it to
    /// subscribers and queues it under the overflow policy. Under [`Overflow::Refuse`] the line
    /// only calls this while [`Mailbox::accepts`]; a full queue then drops the new telegram.
    pub fn deliver(&self, data: Vec<u8>, received: SystemTime) -> Delivery {
        self.deliver_from(data, received, None)
    }

    /// [`Self::deliver`] for a telegram `side` sent (a 3964(R) tap line's mailbox). Nothing is
    /// written to the journal.
    pub fn deliver_from(
        &self,
        data: Vec<u8>,
        received: SystemTime,
        side: Option<proto_core::proc3964::tap::Side>,
    ) -> Delivery {
        let guard = self.lock();
        let seq = next_seq(guard.last_seq);
        self.enqueue(guard, seq, data, received, side)
    }

    /// [`Self::deliver`] that writes the telegram to the journal first (synced) when the
    /// mailbox has one. When the write fails nothing changes (no sequence number is used) and
    /// the telegram is handed back with the error: a 3964(R) line then refuses it with NAK (the
    /// partner repeats it), an ASCII line keeps it without the journal
    /// ([`Self::deliver_unjournaled`]).
    ///
    /// # Errors
    ///
    /// The journal write failed.
    pub fn try_deliver(
        &self,
        data: Vec<u8>,
        received: SystemTime,
    ) -> Result<Delivery, (JournalError, Vec<u8>)> {
        let mut guard = self.lock();
        let state = &mut *guard;
        let seq = next_seq(state.last_seq);
        let full = state.queue.len() >= self.settings.queue_depth;
        let keeps = !full
            || matches!(
                self.settings.overflow,
                Overflow::DropOldest | Overflow::Overwrite
            );
        let data = match state.journal.as_mut() {
            Some(journal) if keeps => {
                let record = JournaledTelegram {
                    seq,
                    received,
                    data,
                };
                if let Err(e) = journal.append_telegram(&record) {
                    return Err((e, record.data));
                }
                record.data
            }
            Some(journal) => {
                // Not kept: only the number is used up, so that it is not given twice.
                if let Err(e) = journal.append_state(seq, state.last_acked) {
                    crate::warn_limited!(
                        format!("journal write {}", journal.path().display()),
                        error = %e,
                        "mailbox journal: sequence number not recorded"
                    );
                }
                data
            }
            None => data,
        };
        Ok(self.enqueue(guard, seq, data, received, None))
    }

    /// [`Self::deliver`] without writing the journal (after a failed write): the telegram waits
    /// in memory only and is lost at a restart.
    pub fn deliver_unjournaled(&self, data: Vec<u8>, received: SystemTime) -> Delivery {
        self.deliver_from(data, received, None)
    }

    /// Gives `seq` to the telegram, counts it, queues it under the overflow policy (recording
    /// what it drops in the journal) and sends it to subscribers.
    fn enqueue(
        &self,
        mut guard: MutexGuard<'_, State>,
        seq: u16,
        data: Vec<u8>,
        received: SystemTime,
        side: Option<proto_core::proc3964::tap::Side>,
    ) -> Delivery {
        let state = &mut *guard;
        state.last_seq = seq;
        state.counters.received += 1;
        state.counters.received_bytes += data.len() as u64;
        let telegram = TelegramRx {
            line: Arc::clone(&self.line),
            seq,
            received,
            data: Arc::from(data),
            side,
        };
        let mut removed = None;
        let delivery = if state.queue.len() < self.settings.queue_depth {
            state.queue.push_back(telegram.clone());
            Delivery::Kept { seq }
        } else if matches!(
            self.settings.overflow,
            Overflow::DropOldest | Overflow::Overwrite
        ) {
            removed = state.queue.pop_front();
            let old = removed.as_ref().map_or(0, |t| t.seq);
            state.queue.push_back(telegram.clone());
            if self.settings.overflow == Overflow::DropOldest {
                Delivery::DroppedOldest { seq, dropped: old }
            } else {
                Delivery::Overwritten { seq, replaced: old }
            }
        } else {
            Delivery::DroppedNew { seq }
        };
        if let (Some(old), Some(journal)) = (removed, state.journal.as_mut()) {
            if let Err(e) = journal.append_removed(old.seq, false, old.data.len()) {
                crate::warn_limited!(
                    format!("journal write {}", journal.path().display()),
                    error = %e,
                    "mailbox journal: a dropped telegram was not recorded; it may wait again after a restart"
                );
            }
        }
        Self::compact_if_due(state);
        drop(guard);
        // No subscriber: nobody to lose it.
        let _ = self.rx.send(telegram);
        delivery
    }

    /// Counts one telegram dropped or refused for want of room (event 08 0Ah).
    pub(crate) fn count_overflow(&self) {
        self.lock().counters.overflows += 1;
    }

    /// The oldest waiting telegram.
    pub fn head(&self) -> Option<TelegramRx> {
        self.lock().queue.front().cloned()
    }

    /// Every waiting telegram, oldest first.
    pub fn waiting(&self) -> Vec<TelegramRx> {
        self.lock().queue.iter().cloned().collect()
    }

    /// How many telegrams wait.
    pub fn len(&self) -> usize {
        self.lock().queue.len()
    }

    /// Whether no telegram waits.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Releases the oldest waiting telegram if `seq` is its number. Repeating the last
    /// acknowledged number is accepted and does nothing, so that a client may repeat a write
    /// whose answer it lost.
    ///
    /// # Errors
    ///
    /// [`AckError::WrongSeq`] for any other number (0 included).
    pub fn ack(&self, seq: u16) -> Result<(), AckError> {
        let mut guard = self.lock();
        let state = &mut *guard;
        let head = state.queue.front().map(|t| t.seq);
        if seq != 0 && head == Some(seq) {
            let len = state.queue.pop_front().map_or(0, |t| t.data.len());
            state.last_acked = seq;
            state.counters.acknowledged += 1;
            if let Some(journal) = state.journal.as_mut() {
                if let Err(e) = journal.append_removed(seq, true, len) {
                    crate::warn_limited!(
                        format!("journal write {}", journal.path().display()),
                        error = %e,
                        "mailbox journal: an acknowledgement was not recorded; the telegram may wait again after a restart"
                    );
                }
            }
            Self::compact_if_due(state);
            drop(guard);
            self.room.notify_one();
            Ok(())
        } else if seq != 0 && seq == state.last_acked {
            Ok(())
        } else {
            Err(AckError::WrongSeq {
                given: seq,
                expected: head,
            })
        }
    }

    /// The line's counters.
    pub fn counters(&self) -> TelegramCounters {
        self.lock().counters
    }

    /// Records the STATUS word of the line's newest event.
    pub(crate) fn set_status_word(&self, word: u16) {
        self.lock().status_word = word;
    }

    /// Records whether the port is open.
    pub(crate) fn set_port_open(&self, open: bool) {
        self.lock().port_open = open;
    }

    /// Counts the result of a send (from any client).
    pub(crate) fn count_send(&self, ok: bool, bytes: usize) {
        let mut state = self.lock();
        if ok {
            state.counters.sent += 1;
            state.counters.sent_bytes += bytes as u64;
        } else {
            state.counters.send_failed += 1;
        }
    }

    /// The value of one register of the layout.
    fn register(&self, state: &State, reg: layout::Reg) -> u16 {
        use layout::{counter_word, data_word, Reg};
        let head = state.queue.front();
        let c = &state.counters;
        match reg {
            Reg::RxStatus => state.status_word,
            Reg::RxSeq => head.map_or(0, |t| t.seq),
            Reg::RxLen => head.map_or(0, |t| u16::try_from(t.data.len()).unwrap_or(u16::MAX)),
            Reg::RxWaiting => u16::try_from(state.queue.len()).unwrap_or(u16::MAX),
            Reg::RxData(n) => head.map_or(0, |t| data_word(&t.data, n)),
            Reg::Received(high) => counter_word(c.received, high),
            Reg::Overflows(high) => counter_word(c.overflows, high),
            Reg::Sent(high) => counter_word(c.sent, high),
            Reg::SendFailed(high) => counter_word(c.send_failed, high),
            Reg::QueueDepth => u16::try_from(self.settings.queue_depth).unwrap_or(u16::MAX),
            Reg::OverflowPolicy => self.settings.overflow.code(),
            Reg::PortOpen => u16::from(state.port_open),
            Reg::MaxLen => u16::try_from(self.max_send_len).unwrap_or(u16::MAX),
            Reg::Ack => state.last_acked,
            other => state.send.register(other),
        }
    }

    /// Reads `quantity` holding registers at `address` in one consistent snapshot.
    pub(crate) fn read_registers(
        &self,
        address: u16,
        quantity: u16,
    ) -> Result<Vec<u16>, proto_core::modbus::pdu::ExceptionCode> {
        let regs = layout::read_span(address, quantity)?;
        let state = self.lock();
        Ok(regs.into_iter().map(|r| self.register(&state, r)).collect())
    }
}

#[cfg(test)]
mod tests;
