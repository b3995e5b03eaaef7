//! A precise one-shot timer for the serial line runtime.
//!
//! tokio's timer wheel counts whole milliseconds: a `sleep_until` wakes at the first tick after
//! its deadline, up to a millisecond and more late. A serial line's timing is finer than that: at
//! 115200 Bd 8E1 a character takes 95 µs and the end-of-frame silence t3.5 is 1.75 ms (003 6.4.3
//! "CRC-CHECK": a frame ends after 3.5 character times; Modbus over Serial Line V1.02, 2.5.1.1:
//! 1.75 ms above 19200 Bd). A master that waits its t3.5 before the next request on tokio's timer
//! leaves a gap of t3.5 plus 1.2 ms on average, and a paced link that delivers bytes on it leaves
//! gaps inside a frame longer than t3.5.
//!
//! [`LineTimer`] on Linux arms a timerfd (`CLOCK_MONOTONIC`, absolute deadline) registered with
//! tokio's reactor: the kernel's high-resolution timer wakes the reactor, and the task runs tens of
//! microseconds later when a core is free. That wake-up lateness is most of what a master line
//! spends between an answer's end and its next request (at 115200 Bd a cycle of one register takes
//! 3.6 ms), so the timer learns it: it is armed ahead of the deadline by the running mean of how
//! late its last expiries were served (at most [`MAX_LEAD`]), and a wake-up that comes before the
//! deadline spins the rest (`std::hint::spin_loop`, on average the spread of the lateness, never
//! more than the lead). Where there is no timerfd (other systems, or creating one failed, or no
//! tokio runtime) it falls back to tokio's sleep.
//!
//! The deadline is a [`tokio::time::Instant`] and a sleep ends only once
//! `tokio::time::Instant::now()` has reached it, checked against the clock after every wake-up:
//! the timer is never early, and a stale or spurious wake-up only loops. A tokio sleep runs
//! alongside the timerfd as the fallback wake-up. Under tokio's paused test clock the timerfd
//! expires on the real clock while tokio's stands still; the first such expiry switches the timer
//! to tokio's sleep for good, so in paused tests it behaves exactly like
//! `tokio::time::sleep_until` (re-arming a real timer again and again would keep the runtime
//! from ever advancing its paused clock).
//!
//! One timer serves one task: [`LineTimer::sleep_until`] takes `&mut self` and re-arms the same
//! timerfd for each deadline (no system call when the deadline did not change). A sleep future
//! dropped before it finished (a `select!` that took another branch) leaves the timerfd armed;
//! its expiry is then one spurious wake-up, or [`LineTimer::cancel`] disarms it. Dropping the
//! timer closes the timerfd and removes it from the reactor.

use std::time::Duration;

use tokio::time::Instant;

/// The most a timerfd is armed ahead of its deadline, and so the longest a wake-up spins: the
/// lateness of a wake-up on a free core (tens of microseconds); a machine busier than that is
/// served late whatever the lead.
pub const MAX_LEAD: Duration = Duration::from_micros(50);

/// A one-shot timer precise to tens of microseconds on Linux (see the module doc).
#[derive(Debug)]
pub struct LineTimer {
    #[cfg(target_os = "linux")]
    fd: Option<timerfd::TimerFd>,
}

impl Default for LineTimer {
    fn default() -> Self {
        Self::new()
    }
}

// === impl LineTimer ===

impl LineTimer {
    /// A disarmed timer. Inside a tokio runtime (which must have its IO driver enabled, as every
    /// runtime of the gateway has) on Linux it uses a timerfd; elsewhere tokio's sleep.
    pub fn new() -> Self {
        Self {
            #[cfg(target_os = "linux")]
            fd: timerfd::TimerFd::new()
                .inspect_err(|err| {
                    tracing::warn!(%err, "no timerfd: line timing falls back to tokio's millisecond timer");
                })
                .ok(),
        }
    }

    /// Sleeps until `deadline` has passed on tokio's clock (at once if it has already).
    pub async fn sleep_until(&mut self, deadline: Instant) {
        #[cfg(target_os = "linux")]
        if let Some(fd) = self.fd.as_mut() {
            let waited = tokio::select! {
                biased;
                waited = fd.wait(deadline) => waited,
                () = tokio::time::sleep_until(deadline) => Ok(timerfd::Waited::Deadline),
            };
            match waited {
                Ok(timerfd::Waited::Deadline) => return,
                Ok(timerfd::Waited::ClockPaused) => {
                    // A test paused tokio's clock: the monotonic clock cannot wake it.
                    tracing::debug!("tokio's clock is paused: the line timer follows it");
                    self.fd = None;
                }
                Err(err) => {
                    tracing::warn!(%err, "timerfd failed: line timing falls back to tokio's millisecond timer");
                    self.fd = None;
                }
            }
        }
        tokio::time::sleep_until(deadline).await;
    }

    /// Sleeps until `deadline`, or forever when there is none (for `select!`).
    pub async fn sleep_until_opt(&mut self, deadline: Option<Instant>) {
        match deadline {
            Some(deadline) => self.sleep_until(deadline).await,
            None => std::future::pending().await,
        }
    }

    /// Sleeps for `duration` from now.
    pub async fn sleep(&mut self, duration: Duration) {
        self.sleep_until(Instant::now() + duration).await;
    }

    /// Disarms the timer: a deadline armed by a sleep that was dropped does not wake the task.
    pub fn cancel(&mut self) {
        #[cfg(target_os = "linux")]
        if let Some(fd) = self.fd.as_mut() {
            if let Err(err) = fd.disarm() {
                tracing::warn!(%err, "timerfd failed: line timing falls back to tokio's millisecond timer");
                self.fd = None;
            }
        }
    }
}

/// The Linux timerfd behind [`LineTimer`].
#[cfg(target_os = "linux")]
mod timerfd {
    use std::io;
    use std::os::fd::OwnedFd;
    use std::time::Duration;

    use rustix::time::{
        clock_gettime, timerfd_create, timerfd_settime, ClockId, Itimerspec, TimerfdClockId,
        TimerfdFlags, TimerfdTimerFlags, Timespec,
    };
    use tokio::io::unix::AsyncFd;
    use tokio::io::Interest;
    use tokio::time::Instant;

    use super::MAX_LEAD;

    /// The longest a timerfd is armed ahead; a later deadline is reached by re-arming on the way
    /// (the tokio sleep alongside wakes the task then).
    const MAX_AHEAD: Duration = Duration::from_secs(24 * 3600);

    /// How a wait ended.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub(super) enum Waited {
        /// tokio's clock has reached the deadline.
        Deadline,
        /// The timerfd expired (the monotonic clock passed the deadline) but tokio's clock did not
        /// follow: it is paused (`tokio::time::pause`, tests only), and only tokio's own timer can
        /// wake the task when it advances.
        ClockPaused,
    }

    /// A non-blocking `CLOCK_MONOTONIC` timerfd in tokio's reactor.
    #[derive(Debug)]
    pub(super) struct TimerFd {
        fd: AsyncFd<OwnedFd>,
        /// The instant the timerfd is armed for (its deadline less the lead) and has not yet
        /// reported.
        armed: Option<Instant>,
        /// How far ahead of a deadline the timerfd is armed: the running mean (weight 1/8) of
        /// how late the expiries were served, at most [`MAX_LEAD`].
        lead: Duration,
    }

    // === impl TimerFd ===

    impl TimerFd {
        /// A disarmed timerfd; an error outside a tokio runtime.
        pub(super) fn new() -> io::Result<Self> {
            if tokio::runtime::Handle::try_current().is_err() {
                return Err(io::Error::other("not inside a tokio runtime"));
            }
            let fd = timerfd_create(
                TimerfdClockId::Monotonic,
                TimerfdFlags::NONBLOCK | TimerfdFlags::CLOEXEC,
            )?;
            // tokio 1.54 deprecates the safe constructors of `AsyncFd` in favour of an unsafe
            // `register_with_interest` (the workspace denies unsafe code), because an arbitrary
            // `T: AsRawFd` could close or swap its descriptor while registered. An `OwnedFd` moved
            // into the `AsyncFd` cannot: it stays open and the same until the `AsyncFd` drops it,
            // which is the whole safety contract of `register_with_interest`.
            #[allow(deprecated)]
            let fd = AsyncFd::with_interest(fd, Interest::READABLE)?;
            Ok(Self {
                fd,
                armed: None,
                lead: Duration::ZERO,
            })
        }

        /// Waits until the timerfd has fired for `deadline` and tokio's clock has reached it.
        pub(super) async fn wait(&mut self, deadline: Instant) -> io::Result<Waited> {
            loop {
                let now = Instant::now();
                if now >= deadline {
                    return Ok(Waited::Deadline);
                }
                let Some(wake_at) = deadline.checked_sub(self.lead).filter(|at| *at > now) else {
                    // Sooner than a wake-up would come.
                    return Ok(spin_until(deadline));
                };
                self.arm(wake_at)?;
                let mut ready = self.fd.readable().await?;
                let mut expirations = [0u8; 8];
                let fired = match rustix::io::read(ready.get_inner(), &mut expirations) {
                    Ok(_) => true,
                    // A stale readiness (the timerfd was re-armed since it fired).
                    Err(rustix::io::Errno::AGAIN) => false,
                    Err(err) => return Err(err.into()),
                };
                ready.clear_ready();
                if fired {
                    // Disarmed until the next `arm`. It was armed no earlier than `wake_at` on
                    // the monotonic clock, which tokio's clock reads unless it is paused.
                    self.armed = None;
                    let now = Instant::now();
                    if now < wake_at {
                        return Ok(Waited::ClockPaused);
                    }
                    let late = (now - wake_at).min(MAX_LEAD);
                    self.lead = (self.lead * 7 + late) / 8;
                    // Early by at most the lead: the rest is shorter than a wake-up.
                    return Ok(spin_until(deadline));
                }
            }
        }

        /// Arms the timerfd for `at` (tokio's clock) unless it already is.
        fn arm(&mut self, at: Instant) -> io::Result<()> {
            if self.armed == Some(at) {
                return Ok(());
            }
            // tokio's clock first, then the monotonic clock: the second read is the later one, so
            // the absolute expiry is never before `at` (tokio's clock is std's Instant,
            // CLOCK_MONOTONIC on Linux, whenever it is not paused).
            let ahead = at.saturating_duration_since(Instant::now()).min(MAX_AHEAD);
            let now = clock_gettime(ClockId::Monotonic);
            let value = add(now, ahead);
            timerfd_settime(
                &self.fd,
                TimerfdTimerFlags::ABSTIME,
                &Itimerspec {
                    it_interval: ZERO,
                    it_value: value,
                },
            )?;
            self.armed = Some(at);
            Ok(())
        }

        /// Disarms the timerfd.
        pub(super) fn disarm(&mut self) -> io::Result<()> {
            timerfd_settime(
                &self.fd,
                TimerfdTimerFlags::empty(),
                &Itimerspec {
                    it_interval: ZERO,
                    it_value: ZERO,
                },
            )?;
            self.armed = None;
            Ok(())
        }

        /// Whether the timerfd has expired and not been read (for the tests).
        #[cfg(test)]
        pub(super) fn has_fired(&self) -> io::Result<bool> {
            let mut expirations = [0u8; 8];
            match rustix::io::read(self.fd.get_ref(), &mut expirations) {
                Ok(_) => Ok(true),
                Err(rustix::io::Errno::AGAIN) => Ok(false),
                Err(err) => Err(err.into()),
            }
        }
    }

    /// Spins until tokio's clock reaches `deadline`, at most [`MAX_LEAD`] away; `ClockPaused` when
    /// it has not after twice that on the real clock (tokio's clock is paused).
    fn spin_until(deadline: Instant) -> Waited {
        let start = std::time::Instant::now();
        while Instant::now() < deadline {
            if start.elapsed() > MAX_LEAD * 2 {
                return Waited::ClockPaused;
            }
            std::hint::spin_loop();
        }
        Waited::Deadline
    }

    /// An `it_value` of zero disarms a timerfd.
    const ZERO: Timespec = Timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };

    /// `at + ahead`, normalised (the monotonic clock is far from overflowing).
    fn add(at: Timespec, ahead: Duration) -> Timespec {
        let nanos = i64::from(ahead.subsec_nanos()) + at.tv_nsec;
        let secs = i64::try_from(ahead.as_secs()).unwrap_or(i64::MAX);
        let carry = nanos / 1_000_000_000;
        Timespec {
            tv_sec: at.tv_sec.saturating_add(secs).saturating_add(carry),
            tv_nsec: nanos % 1_000_000_000,
        }
    }

    #[cfg(test)]
    mod tests {
        use super::*;

        #[test]
        fn adding_carries_nanoseconds_into_seconds() {
            let at = Timespec {
                tv_sec: 10,
                tv_nsec: 999_999_000,
            };
            let sum = add(at, Duration::from_micros(1_500));
            assert_eq!((sum.tv_sec, sum.tv_nsec), (11, 1_499_000));
            let far = add(at, Duration::MAX);
            assert_eq!(far.tv_sec, i64::MAX);
        }
    }
}

#[cfg(test)]
mod tests;
