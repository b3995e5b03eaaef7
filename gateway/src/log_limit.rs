//! Rate limits for log lines that a client can cause: a flood of refused requests or failed
//! handshakes writes a few lines a window and then one line saying how many were left out, so it
//! cannot fill the disk.

use std::sync::{Mutex, PoisonError};
use std::time::{Duration, Instant};

/// Lets `burst` lines through per `window`; counts the others.
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
}

#[cfg(test)]
mod tests {
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
}
