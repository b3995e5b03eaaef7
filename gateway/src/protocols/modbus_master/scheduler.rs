//! Which request a Modbus master line sends next.
//!
//! Order (the fairness rule of the bus): queued writes first, then on-demand reads and other
//! commands, then the poll that has been due longest; but while a poll is due, at most
//! `commands_in_row` commands go in a row before that poll goes. So a due poll waits at most for
//! the request in flight and `commands_in_row` commands for each poll ahead of it, and polls get
//! at least one request in `commands_in_row + 1` while any is due: the cycle of a poll group
//! stretches to at most `period + (commands_in_row + 1) x blocks x longest exchange`
//! ([`cycle_bound`]), whatever the clients send. An on-demand read that a due poll covers rides
//! on that poll ([`Scheduler::riders`]) instead of taking the bus again.
//!
//! Offline: only the device's own polls count. After `offline_after` polls in a row without a
//! valid answer the device goes offline: its polls stop and one probe is sent after a
//! back-off that doubles up to its maximum. A command that gets no answer fails for its own
//! client and changes nothing else. A probe is a single attempt that mostly waits a short
//! time derived from the device's own reply delay, and every n-th probe the full reply
//! monitoring time ([`super::probe`]), so a silent device costs the line little and the other
//! devices keep their rate. The scheduler has no clock and no I/O: `now` is an argument, which
//! keeps it testable.

use std::collections::VecDeque;
use std::time::Duration;

use proto_core::modbus::master::{Attempts, MasterConfig};
use tokio::time::Instant;

use super::probe::{Probe, Prober};
use super::{AddrRange, DeviceSettings, ReadBlock};
use crate::image::Table;
use crate::protocols::DEFAULT_COMMANDS_IN_ROW;
use crate::serial::Backoff;

/// The longest a poll block of `period` waits between two polls while the line carries
/// `blocks` poll blocks, at most `commands_in_row` commands go in a row while a poll is due, and
/// one exchange (request, every repetition, reply) takes at most `exchange`: its period, plus the
/// request in flight when it fell due, plus for every block (itself included) one poll and the
/// commands allowed before it.
pub(crate) fn cycle_bound(
    period: Duration,
    blocks: usize,
    commands_in_row: u32,
    exchange: Duration,
) -> Duration {
    let per_block = exchange.saturating_mul(commands_in_row.saturating_add(1));
    let blocks = u32::try_from(blocks).unwrap_or(u32::MAX);
    period
        .saturating_add(exchange)
        .saturating_add(per_block.saturating_mul(blocks))
}

/// What an on-demand read asks for: the device, the table and the range. A queued read with
/// one can be answered from a poll of its device that covers the range.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct ReadKey {
    /// Index of the device.
    pub(crate) device: usize,
    /// The table read.
    pub(crate) table: Table,
    /// The addresses read.
    pub(crate) range: AddrRange,
}

/// The achieved cycle of one poll block.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct BlockCycle {
    /// The block.
    pub(crate) read: ReadBlock,
    /// The time between its last two polls (`None` before two polls in a row while online).
    pub(crate) last: Option<Duration>,
    /// The longest time between two of its polls while the device was online.
    pub(crate) max: Option<Duration>,
}

/// What the line does next.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum Job<C> {
    /// A queued command (a write or an on-demand read).
    Command(C),
    /// A poll of one read block of one device.
    Poll(PollJob),
}

/// A poll: device and block index.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct PollJob {
    /// Index of the device.
    pub(crate) device: usize,
    /// Index of the block within the device.
    pub(crate) block: usize,
    /// The read.
    pub(crate) read: ReadBlock,
}

/// How an answer or its absence changed a device's state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Transition {
    /// Nothing changed.
    Unchanged,
    /// The device stopped answering; it is probed again after `retry_in`.
    WentOffline {
        /// The back-off before the probe.
        retry_in: Duration,
    },
    /// The device is still offline after a failed probe; next probe after `retry_in`.
    StillOffline {
        /// The back-off before the next probe.
        retry_in: Duration,
    },
    /// An offline device answered again.
    CameBack,
}

#[derive(Debug)]
struct BlockState {
    read: ReadBlock,
    next_due: Instant,
    /// When its last poll ended while the device was online.
    last_done: Option<Instant>,
    /// The time between its last two polls.
    last_cycle: Option<Duration>,
    /// The longest time between two of its polls.
    max_cycle: Option<Duration>,
}

#[derive(Debug)]
struct DeviceState {
    slave: u8,
    blocks: Vec<BlockState>,
    online: bool,
    backoff: Backoff,
    /// When an offline device is probed next.
    retry_at: Instant,
    /// How it is probed while offline.
    prober: Prober,
    /// The probe in flight, if the request in flight is one.
    probe: Option<Probe>,
    /// Polls in a row without a valid answer.
    failed_polls: u32,
    /// That many put it offline.
    offline_after: u32,
}

/// The poll schedule and command queues of one line.
#[derive(Debug)]
pub(crate) struct Scheduler<C> {
    devices: Vec<DeviceState>,
    writes: VecDeque<C>,
    reads: VecDeque<(C, Option<ReadKey>)>,
    /// Commands sent in a row while a poll was due.
    in_row: u32,
    /// At most this many commands in a row while a poll is due.
    commands_in_row: u32,
    /// The device of the last failed short probe, and until when its reply could still start.
    late_watch: Option<(usize, Instant)>,
}

// === impl BlockState ===

impl BlockState {
    /// A poll of the block ended at `now`.
    fn record_cycle(&mut self, now: Instant) {
        if let Some(last) = self.last_done {
            let cycle = now.saturating_duration_since(last);
            self.last_cycle = Some(cycle);
            self.max_cycle = Some(self.max_cycle.map_or(cycle, |m| m.max(cycle)));
        }
        self.last_done = Some(now);
    }
}

// === impl Scheduler ===

impl<C> Scheduler<C> {
    /// A schedule with every poll due at `now`.
    pub(crate) fn new<'a>(
        devices: impl IntoIterator<Item = &'a DeviceSettings>,
        now: Instant,
    ) -> Self {
        let devices = devices
            .into_iter()
            .map(|d| DeviceState {
                slave: d.slave,
                blocks: d
                    .read_blocks()
                    .into_iter()
                    .map(|read| BlockState {
                        read,
                        next_due: now,
                        last_done: None,
                        last_cycle: None,
                        max_cycle: None,
                    })
                    .collect(),
                online: true,
                backoff: Backoff::clamped(d.backoff_min, d.backoff_max),
                retry_at: now,
                prober: Prober::new(d.probe),
                probe: None,
                failed_polls: 0,
                offline_after: d.offline_after.max(1),
            })
            .collect();
        Self {
            devices,
            writes: VecDeque::new(),
            reads: VecDeque::new(),
            in_row: 0,
            commands_in_row: DEFAULT_COMMANDS_IN_ROW,
            late_watch: None,
        }
    }

    /// At most `n` commands in a row while a poll is due (0: a due poll always goes first).
    pub(crate) fn with_commands_in_row(mut self, n: u32) -> Self {
        self.commands_in_row = n;
        self
    }

    /// The number of poll blocks of the line.
    pub(crate) fn blocks(&self) -> usize {
        self.devices.iter().map(|d| d.blocks.len()).sum()
    }

    /// Queues a write (sent before any read).
    pub(crate) fn push_write(&mut self, command: C) {
        self.writes.push_back(command);
    }

    /// Queues an on-demand read or another command that does not write (sent before the polls
    /// within the fairness rule); `key` says what it reads, if it is a read of one range.
    pub(crate) fn push_read(&mut self, command: C, key: Option<ReadKey>) {
        self.reads.push_back((command, key));
    }

    /// Takes every queued command (to answer them when the line cannot send).
    pub(crate) fn drain_commands(&mut self) -> Vec<C> {
        self.writes
            .drain(..)
            .chain(self.reads.drain(..).map(|(c, _)| c))
            .collect()
    }

    /// Takes the queued reads that `poll` covers: they are answered from its answer.
    pub(crate) fn riders(&mut self, poll: &PollJob) -> Vec<C> {
        let covered = |key: &Option<ReadKey>| {
            key.is_some_and(|k| {
                k.device == poll.device
                    && k.table == poll.read.table
                    && poll.read.range.contains(k.range)
            })
        };
        let mut riders = Vec::new();
        let mut kept = VecDeque::with_capacity(self.reads.len());
        for (command, key) in self.reads.drain(..) {
            if covered(&key) {
                riders.push(command);
            } else {
                kept.push_back((command, key));
            }
        }
        self.reads = kept;
        riders
    }

    /// The achieved cycles of the poll blocks of `device`.
    pub(crate) fn cycles(&self, device: usize) -> Vec<BlockCycle> {
        self.devices
            .get(device)
            .map(|d| {
                d.blocks
                    .iter()
                    .map(|b| BlockCycle {
                        read: b.read,
                        last: b.last_cycle,
                        max: b.max_cycle,
                    })
                    .collect()
            })
            .unwrap_or_default()
    }

    /// The index of the device with this slave address.
    pub(crate) fn device_index(&self, slave: u8) -> Option<usize> {
        self.devices.iter().position(|d| d.slave == slave)
    }

    /// Whether the device answers (not backed off).
    #[cfg(test)]
    pub(crate) fn is_online(&self, device: usize) -> bool {
        self.devices.get(device).is_some_and(|d| d.online)
    }

    /// Whether a command for `device` may be sent at `now`: it answers, or its back-off has run
    /// out and the command serves as the probe (a device nobody polls has no other).
    pub(crate) fn accepts_commands(&self, device: usize, now: Instant) -> bool {
        self.devices
            .get(device)
            .is_some_and(|d| d.online || d.retry_at <= now)
    }

    /// The next job due at `now`, if any: a command unless a poll is due and
    /// `commands_in_row` commands went in a row already; a read that a due poll covers takes
    /// that poll (the read rides on it, [`Self::riders`]).
    pub(crate) fn next_job(&mut self, now: Instant) -> Option<Job<C>> {
        let due = self.due_poll(now);
        if due.is_none() || self.in_row < self.commands_in_row {
            if let Some(c) = self.writes.pop_front() {
                self.count_command(due.is_some());
                return Some(Job::Command(c));
            }
            if let Some((c, key)) = self.reads.pop_front() {
                if let Some(poll) = key.and_then(|k| self.due_poll_covering(k, now)) {
                    self.reads.push_front((c, key));
                    self.in_row = 0;
                    return Some(Job::Poll(poll));
                }
                self.count_command(due.is_some());
                return Some(Job::Command(c));
            }
        }
        let poll = due?;
        self.in_row = 0;
        Some(Job::Poll(poll))
    }

    fn count_command(&mut self, poll_due: bool) {
        self.in_row = if poll_due {
            self.in_row.saturating_add(1)
        } else {
            0
        };
    }

    /// The poll that has been due longest at `now`.
    fn due_poll(&self, now: Instant) -> Option<PollJob> {
        let mut best: Option<(Instant, PollJob)> = None;
        for (di, d) in self.devices.iter().enumerate() {
            if !d.online && d.retry_at > now {
                continue;
            }
            for (bi, b) in d.blocks.iter().enumerate() {
                // An offline device's probe is due at its retry time, whatever its blocks say.
                let due = if d.online { b.next_due } else { d.retry_at };
                if due <= now && best.is_none_or(|(t, _)| due < t) {
                    best = Some((
                        due,
                        PollJob {
                            device: di,
                            block: bi,
                            read: b.read,
                        },
                    ));
                }
            }
        }
        best.map(|(_, job)| job)
    }

    /// A poll of an online device due at `now` that covers `key`.
    fn due_poll_covering(&self, key: ReadKey, now: Instant) -> Option<PollJob> {
        let d = self.devices.get(key.device).filter(|d| d.online)?;
        d.blocks.iter().enumerate().find_map(|(bi, b)| {
            (b.next_due <= now && b.read.table == key.table && b.read.range.contains(key.range))
                .then_some(PollJob {
                    device: key.device,
                    block: bi,
                    read: b.read,
                })
        })
    }

    /// How the master tries a poll of `device` on a line with the master settings `line`: as
    /// configured while the device answers, as its next probe while it is offline (one attempt,
    /// remembered until [`Self::observe`]). Commands always go as configured.
    pub(crate) fn poll_attempts(&mut self, device: usize, line: &MasterConfig) -> Attempts {
        match self.devices.get_mut(device) {
            Some(d) if !d.online => {
                let probe = d.prober.next(line);
                d.probe = Some(probe);
                probe.attempts()
            }
            _ => Attempts::default(),
        }
    }

    /// `device` answered (a response or an exception) after `reply_delay`, from the end of the
    /// request to the first byte of the answer, if known.
    pub(crate) fn heard(&mut self, device: usize, reply_delay: Option<Duration>) {
        if let Some(d) = self.devices.get_mut(device) {
            d.prober.answered(reply_delay);
        }
    }

    /// Bytes nobody awaited (003 7.2 0E 53h), or an answer that failed its checks, arrived at
    /// `now`: if a reply to the last short probe could still have started by then, it may have
    /// been that device's, late, and its next probe waits the full reply monitoring time.
    pub(crate) fn unexpected_reply(&mut self, now: Instant) {
        if let Some((device, until)) = self.late_watch.take() {
            if now <= until {
                if let Some(d) = self.devices.get_mut(device) {
                    d.prober.late_reply_suspected();
                }
            }
        }
    }

    /// When the next poll falls due (`None`: nothing is polled). Queued commands are due now.
    pub(crate) fn next_wake(&self) -> Option<Instant> {
        self.devices
            .iter()
            .flat_map(|d| {
                let offline_at = (!d.online && !d.blocks.is_empty()).then_some(d.retry_at);
                let online = d.blocks.iter().filter(|_| d.online).map(|b| b.next_due);
                offline_at.into_iter().chain(online)
            })
            .min()
    }

    /// Whether commands are queued.
    #[cfg(test)]
    pub(crate) fn has_commands(&self) -> bool {
        !self.writes.is_empty() || !self.reads.is_empty()
    }

    /// Records that a poll of `device` was answered (`true`, an exception counts) or not after
    /// all retries: `offline_after` failures in a row put an online device offline.
    pub(crate) fn observe(&mut self, device: usize, answered: bool, now: Instant) -> Transition {
        let Some(d) = self.devices.get_mut(device) else {
            return Transition::Unchanged;
        };
        if answered {
            d.failed_polls = 0;
        } else if d.online {
            d.failed_polls = d.failed_polls.saturating_add(1);
            if d.failed_polls < d.offline_after {
                d.probe = None;
                return Transition::Unchanged;
            }
        }
        self.transition(device, answered, now)
    }

    /// Records the end of a command to `device`: an answer brings an offline device back; no
    /// answer changes nothing while it is online (the command fails for its own client only),
    /// and counts as a failed probe while it is offline (its back-off had run out, or the command
    /// would not have been sent).
    pub(crate) fn command_done(
        &mut self,
        device: usize,
        answered: bool,
        now: Instant,
    ) -> Transition {
        match self.devices.get(device) {
            Some(d) if d.online && !answered => Transition::Unchanged,
            Some(_) => self.transition(device, answered, now),
            None => Transition::Unchanged,
        }
    }

    fn transition(&mut self, device: usize, answered: bool, now: Instant) -> Transition {
        let Some(d) = self.devices.get_mut(device) else {
            return Transition::Unchanged;
        };
        let probe = d.probe.take();
        match (d.online, answered) {
            (true, true) => Transition::Unchanged,
            (false, true) => {
                d.online = true;
                d.failed_polls = 0;
                d.backoff.reset();
                for b in &mut d.blocks {
                    b.next_due = now;
                    b.last_done = None;
                }
                Transition::CameBack
            }
            (online, false) => {
                match probe {
                    Some(probe) if !online => {
                        d.prober.probe_failed(probe);
                        if !probe.full {
                            self.late_watch = Some((device, now + probe.cut));
                        }
                    }
                    // The poll that put it offline, or a command: the full time, in vain.
                    _ => d.prober.full_wait_failed(),
                }
                let retry_in = d.backoff.next_delay();
                d.online = false;
                d.retry_at = now + retry_in;
                if online {
                    Transition::WentOffline { retry_in }
                } else {
                    Transition::StillOffline { retry_in }
                }
            }
        }
    }

    /// Puts a poll that could not be sent off by one period from `now`.
    pub(crate) fn postpone(&mut self, job: PollJob, now: Instant) {
        let Some(d) = self.devices.get_mut(job.device) else {
            return;
        };
        d.probe = None;
        if let Some(b) = d.blocks.get_mut(job.block) {
            b.next_due = now + job.read.period;
        }
    }

    /// Records the end of a poll at `now` and schedules the block's next read: one period after it
    /// was due, or now if the line has fallen behind (no burst of missed polls).
    pub(crate) fn poll_done(&mut self, job: PollJob, answered: bool, now: Instant) -> Transition {
        if let Some(d) = self.devices.get_mut(job.device) {
            let online = d.online;
            if let Some(b) = d.blocks.get_mut(job.block) {
                b.next_due = (b.next_due + job.read.period).max(now);
                // Only the cycles while the device answers are the line's.
                if online {
                    b.record_cycle(now);
                }
            }
        }
        let transition = self.observe(job.device, answered, now);
        if matches!(transition, Transition::WentOffline { .. }) {
            // The gap while it is offline is the device's, not the line's.
            if let Some(d) = self.devices.get_mut(job.device) {
                for b in &mut d.blocks {
                    b.last_done = None;
                }
            }
        }
        transition
    }
}

#[cfg(test)]
mod probing;
#[cfg(test)]
mod tests;
