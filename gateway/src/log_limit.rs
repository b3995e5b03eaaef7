//! Rate-limited warnings: a warning that can repeat once per frame or per request (a rejected
//! Modbus TCP frame, a line event) is logged at its first occurrence, then at most once per
//! [`INTERVAL`] with the number of occurrences left out since the last line (`suppressed`).
//! The log stays readable under a fuzzing client or a disturbed line; the counters in
//! `/metrics` still count every occurrence.
//!
//! Keys are bounded like the metrics' labels: a fixed message, or a line name and an event id
//! from the configuration and the event catalog, never a client address.

use std::collections::BTreeMap;
use std::sync::{Mutex, PoisonError};
use std::time::{Duration, Instant};

/// At most one line per key in this interval.
pub const INTERVAL: Duration = Duration::from_secs(10);

/// Logs the warning of `$key` (anything that is `Into<String>`) unless one was logged within
/// [`INTERVAL`]; the fields and message are `tracing::warn!`'s, with `suppressed` (occurrences
/// left out since the last line) added.
#[macro_export]
macro_rules! warn_limited {
    ($key:expr, $($arg:tt)+) => {
        if let Some(suppressed) = $crate::log_limit::LIMITER.admit($key, std::time::Instant::now()) {
            tracing::warn!(suppressed, $($arg)+);
        }
    };
}

/// [`warn_limited!`] at ERROR level (the same limiter and keys).
#[macro_export]
macro_rules! error_limited {
    ($key:expr, $($arg:tt)+) => {
        if let Some(suppressed) = $crate::log_limit::LIMITER.admit($key, std::time::Instant::now()) {
            tracing::error!(suppressed, $($arg)+);
        }
    };
}

/// The gateway's limiter, shared by every warning site.
pub static LIMITER: Limiter = Limiter::new(INTERVAL);

/// When each key was last logged, and how often it was left out since.
#[derive(Debug)]
pub struct Limiter {
    interval: Duration,
    keys: Mutex<BTreeMap<String, Seen>>,
}

/// The most keys a limiter remembers. Keys whose interval is over are forgotten first (their
/// next occurrence is logged as a first one); should that not make room, the new keys share
/// [`OVERFLOW_KEY`], one line per interval for all of them.
pub const MAX_KEYS: usize = 1024;

/// The key of the occurrences a full limiter has no room for.
pub const OVERFLOW_KEY: &str = "(more keys than the limiter keeps)";

#[derive(Debug, Clone, Copy)]
struct Seen {
    logged: Instant,
    suppressed: u64,
}

// === impl Limiter ===

impl Limiter {
    /// A limiter of one line per key and `interval`.
    pub const fn new(interval: Duration) -> Self {
        Self {
            interval,
            keys: Mutex::new(BTreeMap::new()),
        }
    }

    /// Whether an occurrence of `key` at `now` is logged: `Some(n)` with the `n` occurrences
    /// left out since the last line, `None` to leave it out (it is counted).
    pub fn admit(&self, key: impl Into<String>, now: Instant) -> Option<u64> {
        self.admit_since(key, now).map(|(suppressed, _)| suppressed)
    }

    /// As [`Self::admit`], with the time since the key's last line (zero for a first one): the
    /// line can say "`n` more in the last `t`".
    pub fn admit_since(&self, key: impl Into<String>, now: Instant) -> Option<(u64, Duration)> {
        let mut keys = self.keys.lock().unwrap_or_else(PoisonError::into_inner);
        let mut key = key.into();
        if !keys.contains_key(&key) && keys.len() >= MAX_KEYS {
            let interval = self.interval;
            keys.retain(|_, seen| now.saturating_duration_since(seen.logged) < interval);
            if keys.len() >= MAX_KEYS {
                key = OVERFLOW_KEY.to_owned();
            }
        }
        let fresh = Seen {
            logged: now,
            suppressed: 0,
        };
        match keys.get_mut(&key) {
            Some(seen) if now.saturating_duration_since(seen.logged) < self.interval => {
                seen.suppressed = seen.suppressed.saturating_add(1);
                None
            }
            Some(seen) => {
                let answer = (seen.suppressed, now.saturating_duration_since(seen.logged));
                *seen = fresh;
                Some(answer)
            }
            None => {
                keys.insert(key, fresh);
                Some((0, Duration::ZERO))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_occurrence_is_logged_then_one_line_per_interval_with_the_count() {
        let limiter = Limiter::new(Duration::from_secs(10));
        let t0 = Instant::now();
        assert_eq!(limiter.admit("bad frame", t0), Some(0));
        for i in 1..=99 {
            assert_eq!(
                limiter.admit("bad frame", t0 + Duration::from_millis(i * 50)),
                None
            );
        }
        // Another key has its own count.
        assert_eq!(limiter.admit("drive/0830", t0), Some(0));
        // The interval is over: one line with the 99 left out, and the count starts again.
        assert_eq!(
            limiter.admit("bad frame", t0 + Duration::from_secs(10)),
            Some(99)
        );
        assert_eq!(
            limiter.admit("bad frame", t0 + Duration::from_secs(11)),
            None
        );
        assert_eq!(
            limiter.admit("bad frame", t0 + Duration::from_secs(20)),
            Some(1)
        );
    }

    #[test]
    fn a_full_limiter_forgets_old_keys_then_shares_one_key() {
        let limiter = Limiter::new(Duration::from_secs(10));
        let t0 = Instant::now();
        for n in 0..MAX_KEYS {
            assert_eq!(limiter.admit(format!("client {n}"), t0), Some(0));
        }
        // No room, nothing old: the new keys share one line per interval.
        assert_eq!(limiter.admit("client a", t0), Some(0));
        assert_eq!(limiter.admit("client b", t0), None);
        assert_eq!(limiter.admit("client 0", t0), None);
        // Once the old keys' interval is over they are forgotten and a new key has its line.
        let later = t0 + Duration::from_secs(10);
        assert_eq!(
            limiter.admit_since("client c", later),
            Some((0, Duration::ZERO))
        );
        assert_eq!(limiter.admit("client c", later), None);
        assert_eq!(
            limiter.admit_since("client c", later + Duration::from_secs(12)),
            Some((1, Duration::from_secs(12)))
        );
    }
}

// === a burst per window, for lines that must each be seen (audit) ===

/// Lets `burst` lines through per `window` and counts the others: for lines where each one
/// matters until a flood starts (the audit of writes, refusals by role, failed handshakes). The
/// line after the window says how many were left out.
#[derive(Debug)]
pub struct LogLimit {
    window: Duration,
    burst: u32,
    state: Mutex<Option<Window>>,
}

#[derive(Debug, Clone, Copy)]
struct Window {
    start: Instant,
    logged: u32,
    suppressed: u64,
}

/// Whether to write a line now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Write it; `suppressed` lines were left out in the window before (say so when not 0).
    Log { suppressed: u64 },
    /// Leave it out (it is counted).
    Suppress,
}

// === impl LogLimit ===

impl LogLimit {
    /// `burst` lines per `window`.
    pub const fn new(window: Duration, burst: u32) -> Self {
        Self {
            window,
            burst,
            state: Mutex::new(None),
        }
    }

    /// The verdict for a line at `now`.
    pub fn check_at(&self, now: Instant) -> Verdict {
        let mut state = self.state.lock().unwrap_or_else(PoisonError::into_inner);
        let window = match *state {
            Some(w) if now.saturating_duration_since(w.start) < self.window => w,
            previous => {
                let suppressed = previous.map_or(0, |w| w.suppressed);
                *state = Some(Window {
                    start: now,
                    logged: 1,
                    suppressed: 0,
                });
                return Verdict::Log { suppressed };
            }
        };
        if window.logged < self.burst {
            *state = Some(Window {
                logged: window.logged + 1,
                ..window
            });
            Verdict::Log { suppressed: 0 }
        } else {
            *state = Some(Window {
                suppressed: window.suppressed + 1,
                ..window
            });
            Verdict::Suppress
        }
    }

    /// The verdict for a line now.
    pub fn check(&self) -> Verdict {
        self.check_at(Instant::now())
    }

    /// When the current window ends, if lines were left out in it: the moment to say how many
    /// ([`Self::take_left_out_at`]) when no further line may come to say it.
    pub fn left_out_until(&self) -> Option<Instant> {
        let state = self.state.lock().unwrap_or_else(PoisonError::into_inner);
        state
            .filter(|w| w.suppressed > 0)
            .map(|w| w.start + self.window)
    }

    /// The lines left out in a window that is over at `now`, counted once: the caller writes
    /// one line with the number; the next line's [`Verdict::Log`] then says 0.
    pub fn take_left_out_at(&self, now: Instant) -> Option<u64> {
        let mut state = self.state.lock().unwrap_or_else(PoisonError::into_inner);
        let window = state.as_mut()?;
        if window.suppressed == 0 || now.saturating_duration_since(window.start) < self.window {
            return None;
        }
        Some(std::mem::take(&mut window.suppressed))
    }
}

#[cfg(test)]
mod burst_tests {
    use super::*;

    #[test]
    fn a_flood_writes_the_burst_then_one_line_with_the_count() {
        let limit = LogLimit::new(Duration::from_secs(10), 3);
        let t0 = Instant::now();
        for _ in 0..3 {
            assert_eq!(limit.check_at(t0), Verdict::Log { suppressed: 0 });
        }
        for _ in 0..1000 {
            assert_eq!(limit.check_at(t0), Verdict::Suppress);
        }
        let later = t0 + Duration::from_secs(10);
        assert_eq!(limit.check_at(later), Verdict::Log { suppressed: 1000 });
        assert_eq!(limit.check_at(later), Verdict::Log { suppressed: 0 });
    }

    #[test]
    fn the_lines_left_out_are_told_once_after_the_window() {
        let limit = LogLimit::new(Duration::from_secs(10), 2);
        let t0 = Instant::now();
        assert_eq!(limit.left_out_until(), None);
        for _ in 0..2 {
            assert_eq!(limit.check_at(t0), Verdict::Log { suppressed: 0 });
        }
        assert_eq!(limit.left_out_until(), None);
        for _ in 0..7 {
            assert_eq!(limit.check_at(t0), Verdict::Suppress);
        }
        let end = t0 + Duration::from_secs(10);
        assert_eq!(limit.left_out_until(), Some(end));
        assert_eq!(limit.take_left_out_at(t0 + Duration::from_secs(9)), None);
        assert_eq!(limit.take_left_out_at(end), Some(7));
        assert_eq!(limit.take_left_out_at(end), None);
        assert_eq!(limit.left_out_until(), None);
        // Told already: the next line does not count them again.
        assert_eq!(limit.check_at(end), Verdict::Log { suppressed: 0 });
    }
}
