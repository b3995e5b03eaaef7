//! How a Modbus master line probes a device that stopped answering: a device that stops
//! answering is backed off so that it cannot starve the others.
//!
//! The seeds are silent on offline devices: the CP 341 sends what the S7 program asks and waits
//! the interface's reply monitoring time for every request (003 6.4.2.1: 5..65500 ms, default
//! 2000 ms), and "during the latency the communication with another slaves is not possible"
//! (003 6.4.1). On a half-duplex line every request to a dead device therefore holds the line
//! silent for the whole reply monitoring time. The policy below is the gateway's own:
//!
//! 1. **Detection**: an online device's polls and every command get the configured reply
//!    monitoring time and repetitions; `offline_after` polls in a row without a valid answer
//!    after them put the device offline (its values become "comm failure"); commands never do
//!    (see `scheduler`). A drive that dies costs the line
//!    `reply_timeout x (retries + 1) x offline_after` once.
//! 2. **Probes** of an offline device are one attempt, never repeated: the configured retries
//!    are for a device that answers, and a probe that fails is tried again at the next probe
//!    anyway.
//! 3. **Short probes.** A probe waits `4 x` the device's slowest recent reply delay (from the end
//!    of our request to the first byte of its reply, [`ReplyDelay`]), at least `probe_timeout_min`
//!    and at least `4 x t3.5` (a slave needs t3.5 of silence before it may answer, 003 6.4.3), at
//!    most the configured reply monitoring time. A device never heard since the line started has
//!    no reply delay: its short probes wait the floor. A device that answers within that time is
//!    found again at the first probe after it came back.
//! 4. **Every `full_probe_every`-th probe waits the full reply monitoring time**, so that a device
//!    that came back slower than before (or a slow device never heard since start) is found too,
//!    within about `full_probe_every` back-off periods. A command sent to the device while its
//!    probe is due is a probe with the full time. When bytes nobody awaited (003 7.2 0E 53h) or
//!    a garbled answer arrive while a reply to a short probe could still have started, that
//!    reply may have been the device's, late: its next probe waits the full time at once.
//! 5. **Back-off** between probes: `offline_backoff_min` doubling to `offline_backoff_max` (1 s
//!    to 5 s by default, [`crate::serial::Backoff`]). A short probe holds the line about the
//!    floor (100 ms by default) every 5 s; with the full probe once a minute a dead drive holds
//!    it about 3.4 s a minute (2 s every 32 s before, with every probe full and the back-off at
//!    30 s), and a drive that is back is polled again within 5 s.
//!
//! Half duplex: a short probe gives up while a reply that is merely slow could still come. The
//! bet is bounded by what the device itself showed (four times its slowest recent reply delay,
//! at least the floor); a reply later than that is handled by the master engine as any late
//! reply: counted (003 7.2 0E 53h "byte overflow" while the line is idle), a request not yet sent
//! waits for t3.5 of silence after it (003 6.4.3), and if it runs into the next request, that
//! request fails with the event of what it received (08 31h wrong slave, 0E 57h checksum) as any
//! disturbed exchange does. With `full_probe_every = 1` every probe waits the full time (the
//! behaviour before short probes), and `probe_timeout_min` at the reply monitoring time does the
//! same.

use std::time::Duration;

use proto_core::modbus::master::{Attempts, Framing, MasterConfig};

use crate::config::{DEFAULT_FULL_PROBE_EVERY, DEFAULT_PROBE_TIMEOUT_MIN};

/// A short probe waits this many times the device's slowest recent reply delay.
pub const PROBE_TIMEOUT_FACTOR: u32 = 4;
/// The recorded slowest reply delay moves this fraction of the way down to each faster reply
/// (at once up to a slower one).
const DELAY_RELEASE: u32 = 16;

/// How a device is probed once it is offline.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ProbeSettings {
    /// The least a short probe waits for the start of a reply.
    pub timeout_min: Duration,
    /// Every this many probes one waits the full reply monitoring time (1: every probe).
    pub full_every: u32,
}

impl Default for ProbeSettings {
    fn default() -> Self {
        Self {
            timeout_min: DEFAULT_PROBE_TIMEOUT_MIN,
            full_every: DEFAULT_FULL_PROBE_EVERY,
        }
    }
}

/// The slowest recent reply delay of a device: up at once to a slower reply, down by 1/16 of the
/// difference with each faster one (a single slow reply is remembered for a few dozen polls).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct ReplyDelay {
    peak: Option<Duration>,
}

impl ReplyDelay {
    /// Records the reply delay of one answer.
    pub(crate) fn record(&mut self, delay: Duration) {
        self.peak = Some(match self.peak {
            Some(peak) if peak > delay => peak - (peak - delay) / DELAY_RELEASE,
            _ => delay,
        });
    }

    /// The slowest recent reply delay, if the device ever answered.
    pub(crate) fn peak(&self) -> Option<Duration> {
        self.peak
    }
}

/// One probe: how long it waits, and whether that is the full reply monitoring time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Probe {
    /// The reply monitoring time of its single attempt.
    pub(crate) reply_timeout: Duration,
    /// Whether that is the configured reply monitoring time.
    pub(crate) full: bool,
    /// How much longer the configured time would have waited (zero for a full probe): the
    /// window after a short probe in which a reply may still start.
    pub(crate) cut: Duration,
}

impl Probe {
    /// The master's attempts for this probe: one, with its own time.
    pub(crate) fn attempts(self) -> Attempts {
        Attempts {
            reply_timeout: Some(self.reply_timeout),
            retries: Some(0),
        }
    }
}

/// The probing state of one device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Prober {
    settings: ProbeSettings,
    delay: ReplyDelay,
    /// Probes since the last wait of the full reply monitoring time.
    short_since_full: u32,
    /// Unexpected bytes came after a short probe: the next probe waits the full time.
    maybe_slow: bool,
}

impl Prober {
    pub(crate) fn new(settings: ProbeSettings) -> Self {
        Self {
            settings,
            delay: ReplyDelay::default(),
            short_since_full: 0,
            maybe_slow: false,
        }
    }

    /// The device answered after `delay` (none known: nothing to learn).
    pub(crate) fn answered(&mut self, delay: Option<Duration>) {
        if let Some(delay) = delay {
            self.delay.record(delay);
        }
        self.short_since_full = 0;
        self.maybe_slow = false;
    }

    /// A request waited the full reply monitoring time in vain (the poll that put the device
    /// offline, a command, a full probe).
    pub(crate) fn full_wait_failed(&mut self) {
        self.short_since_full = 0;
        self.maybe_slow = false;
    }

    /// Bytes nobody awaited, or a garbled answer, came while a reply to this device's last short
    /// probe could still have started: it may be alive and slower than before, so its next probe
    /// waits the full time (without waiting for its turn among `full_probe_every`).
    pub(crate) fn late_reply_suspected(&mut self) {
        self.maybe_slow = true;
    }

    /// The next probe on a line with the master settings `line`.
    pub(crate) fn next(&self, line: &MasterConfig) -> Probe {
        let full = Probe {
            reply_timeout: line.reply_timeout,
            full: true,
            cut: Duration::ZERO,
        };
        if self.maybe_slow || self.short_since_full.saturating_add(1) >= self.settings.full_every {
            return full;
        }
        let gap = match line.framing {
            Framing::Rtu { timing } => timing.t35,
            Framing::Ascii { .. } => Duration::ZERO,
        };
        let base = self.delay.peak().unwrap_or_default().max(gap);
        let wait = base
            .saturating_mul(PROBE_TIMEOUT_FACTOR)
            .max(self.settings.timeout_min);
        if wait >= line.reply_timeout {
            full
        } else {
            Probe {
                reply_timeout: wait,
                full: false,
                cut: line.reply_timeout - wait,
            }
        }
    }

    /// A probe failed.
    pub(crate) fn probe_failed(&mut self, probe: Probe) {
        if probe.full {
            self.short_since_full = 0;
            self.maybe_slow = false;
        } else {
            self.short_since_full = self.short_since_full.saturating_add(1);
        }
    }

    /// The slowest recent reply delay.
    #[cfg(test)]
    pub(crate) fn reply_delay(&self) -> Option<Duration> {
        self.delay.peak()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    /// 19200 Bd 8E1: t3.5 = 2.005 ms (003 6.4.3), the CP's 2000 ms reply monitoring time.
    fn line() -> MasterConfig {
        MasterConfig::rtu(19_200, 11)
    }

    #[test]
    fn the_reply_delay_rises_at_once_and_falls_slowly() {
        let mut d = ReplyDelay::default();
        assert_eq!(d.peak(), None);
        d.record(ms(5));
        assert_eq!(d.peak(), Some(ms(5)));
        d.record(ms(300));
        assert_eq!(d.peak(), Some(ms(300)));
        d.record(ms(140));
        assert_eq!(d.peak(), Some(ms(290)));
        for _ in 0..200 {
            d.record(ms(5));
        }
        let peak = d.peak().unwrap();
        assert!(peak >= ms(5) && peak < ms(6), "{peak:?}");
    }

    #[test]
    fn short_probes_wait_four_reply_delays_within_the_floor_and_the_ceiling() {
        let mut p = Prober::new(ProbeSettings::default());
        // Never heard: the floor.
        assert_eq!(
            p.next(&line()),
            Probe {
                reply_timeout: ms(100),
                full: false,
                cut: ms(1900)
            }
        );
        // Heard fast: still the floor.
        p.answered(Some(ms(6)));
        assert_eq!(p.next(&line()).reply_timeout, ms(100));
        // A slow device: four of its slowest replies.
        p.answered(Some(ms(150)));
        assert_eq!(p.next(&line()).reply_timeout, ms(600));
        // Slower still: the configured time, which is a full probe.
        p.answered(Some(ms(700)));
        assert_eq!(
            p.next(&line()),
            Probe {
                reply_timeout: ms(2000),
                full: true,
                cut: Duration::ZERO
            }
        );
        assert_eq!(p.reply_delay(), Some(ms(700)));
    }

    #[test]
    fn the_floor_is_four_t35_at_low_baud_rates() {
        // 300 Bd 8E1: t3.5 = 128.3 ms (003 6.4.3: "300 -> 128 ms").
        let slow = MasterConfig::rtu(300, 11);
        let p = Prober::new(ProbeSettings::default());
        let wait = p.next(&slow).reply_timeout;
        assert!(wait > ms(513) && wait < ms(514), "{wait:?}");
    }

    #[test]
    fn every_nth_probe_waits_the_full_time() {
        let settings = ProbeSettings {
            timeout_min: ms(100),
            full_every: 4,
        };
        let mut p = Prober::new(settings);
        p.full_wait_failed(); // the poll that put it offline
        let kinds: Vec<bool> = (0..9)
            .map(|_| {
                let probe = p.next(&line());
                p.probe_failed(probe);
                probe.full
            })
            .collect();
        assert_eq!(
            kinds,
            [false, false, false, true, false, false, false, true, false]
        );
        // An answer starts the count again.
        p.answered(None);
        assert!(!p.next(&line()).full);
        // A late reply suspected: the next probe is full, the count starts again after it.
        p.late_reply_suspected();
        let probe = p.next(&line());
        assert!(probe.full);
        p.probe_failed(probe);
        assert!(!p.next(&line()).full);
    }

    #[test]
    fn one_in_one_is_the_old_behaviour_and_probes_never_repeat() {
        let p = Prober::new(ProbeSettings {
            timeout_min: ms(100),
            full_every: 1,
        });
        let probe = p.next(&line());
        assert!(probe.full);
        assert_eq!(
            probe.attempts(),
            Attempts {
                reply_timeout: Some(ms(2000)),
                retries: Some(0)
            }
        );
        // A floor at the reply monitoring time: every probe full as well.
        let p = Prober::new(ProbeSettings {
            timeout_min: ms(2000),
            full_every: 12,
        });
        assert!(p.next(&line()).full);
    }
}
