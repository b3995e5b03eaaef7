//! Which request a Modbus master line sends next.
//!
//! Order: queued writes first, then on-demand reads, then the poll that has been due longest.
//! A device that does not answer goes offline: its polls stop and one probe is sent after a
//! back-off that doubles up to its maximum. A probe is a single attempt that mostly waits a short
//! time derived from the device's own reply delay, and every n-th probe the full reply
//! monitoring time ([`super::probe`]), so a silent device costs the line little and the other
//! devices keep their rate. The scheduler has no clock and no I/O: `now` is an argument, which
//! keeps it testable.

use std::collections::VecDeque;
use std::time::Duration;

use proto_core::modbus::master::{Attempts, MasterConfig};
use tokio::time::Instant;

use super::probe::{Probe, Prober};
use super::{DeviceSettings, ReadBlock};
use crate::serial::Backoff;

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
}

/// The poll schedule and command queues of one line.
#[derive(Debug)]
pub(crate) struct Scheduler<C> {
    devices: Vec<DeviceState>,
    writes: VecDeque<C>,
    reads: VecDeque<C>,
    /// The device of the last failed short probe, and until when its reply could still start.
    late_watch: Option<(usize, Instant)>,
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
                    })
                    .collect(),
                online: true,
                backoff: Backoff::clamped(d.backoff_min, d.backoff_max),
                retry_at: now,
                prober: Prober::new(d.probe),
                probe: None,
            })
            .collect();
        Self {
            devices,
            writes: VecDeque::new(),
            reads: VecDeque::new(),
            late_watch: None,
        }
    }

    /// Queues a write (sent before any read).
    pub(crate) fn push_write(&mut self, command: C) {
        self.writes.push_back(command);
    }

    /// Queues an on-demand read (sent before the polls).
    pub(crate) fn push_read(&mut self, command: C) {
        self.reads.push_back(command);
    }

    /// Takes every queued command (to answer them when the line cannot send).
    pub(crate) fn drain_commands(&mut self) -> Vec<C> {
        self.writes.drain(..).chain(self.reads.drain(..)).collect()
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

    /// The next job due at `now`, if any.
    pub(crate) fn next_job(&mut self, now: Instant) -> Option<Job<C>> {
        if let Some(c) = self.writes.pop_front().or_else(|| self.reads.pop_front()) {
            return Some(Job::Command(c));
        }
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
        best.map(|(_, job)| Job::Poll(job))
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

    /// Records that `device` answered (`true`, an exception counts) or not after all retries.
    pub(crate) fn observe(&mut self, device: usize, answered: bool, now: Instant) -> Transition {
        let Some(d) = self.devices.get_mut(device) else {
            return Transition::Unchanged;
        };
        let probe = d.probe.take();
        match (d.online, answered) {
            (true, true) => Transition::Unchanged,
            (false, true) => {
                d.online = true;
                d.backoff.reset();
                for b in &mut d.blocks {
                    b.next_due = now;
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
        if let Some(b) = self
            .devices
            .get_mut(job.device)
            .and_then(|d| d.blocks.get_mut(job.block))
        {
            b.next_due = (b.next_due + job.read.period).max(now);
        }
        self.observe(job.device, answered, now)
    }
}

#[cfg(test)]
mod probing;
#[cfg(test)]
mod tests;
