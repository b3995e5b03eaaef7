//! When each byte leaves a paced line: the pure arithmetic of the relay, tested without a clock.
//!
//! A UART sends one character after the other. A byte that is handed to it while the line is idle
//! starts at once and is complete one character time later; a byte handed to it while another is on
//! the wire starts when that one ends. So the end of byte `k` is
//! `max(arrival_k, end_(k-1)) + char_time`.
//!
//! The ends are computed from an anchor (the arrival that found the line idle) and the number of
//! characters sent back to back since then, `anchor + n * bits * 1e9 / baud` nanoseconds, so that a
//! long burst accumulates no rounding error: the n-th end is exact to the nanosecond however long
//! the burst runs.

use std::time::Duration;

use tokio::time::Instant;

use super::PacedSettings;

/// The delivery times of one direction of a paced line.
#[derive(Clone, Debug)]
pub(crate) struct Schedule {
    /// Bits per character times 10^9 (the numerator of the character time in nanoseconds).
    bit_nanos: u128,
    /// Baud rate (the denominator), at least 1.
    baud: u128,
    /// The arrival that found the line idle, and the characters sent back to back since then.
    burst: Option<(Instant, u64)>,
}

// === impl Schedule ===

impl Schedule {
    /// An idle line with the settings' character time.
    pub(crate) fn new(settings: PacedSettings) -> Self {
        Self {
            bit_nanos: u128::from(settings.bits_per_char.max(1)) * 1_000_000_000,
            baud: u128::from(settings.baud.max(1)),
            burst: None,
        }
    }

    /// The offset of the end of the `n`-th character of a burst from its start.
    fn offset(&self, n: u64) -> Duration {
        let nanos = u128::from(n) * self.bit_nanos / self.baud;
        Duration::from_nanos(u64::try_from(nanos).unwrap_or(u64::MAX))
    }

    /// Schedules one byte handed over at `arrival`; returns when it has been received completely
    /// at the far end (its delivery time).
    pub(crate) fn next(&mut self, arrival: Instant) -> Instant {
        let (anchor, n) = match self.burst {
            // Still sending when this byte arrives: it follows back to back.
            Some((anchor, n)) if anchor + self.offset(n) >= arrival => (anchor, n + 1),
            // Idle: the byte starts the moment it arrives.
            _ => (arrival, 1),
        };
        self.burst = Some((anchor, n));
        anchor + self.offset(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(baud: u32, bits_per_char: u8) -> PacedSettings {
        PacedSettings {
            baud,
            bits_per_char,
        }
    }

    #[test]
    fn an_idle_line_delivers_one_character_time_after_arrival() {
        let t0 = Instant::now();
        let mut s = Schedule::new(settings(9600, 10));
        // 10 bits at 9600 Bd: 1041666 ns.
        assert_eq!(s.next(t0), t0 + Duration::from_nanos(1_041_666));
    }

    #[test]
    fn a_burst_is_back_to_back_without_rounding_drift() {
        let t0 = Instant::now();
        // 11 bits at 115200 Bd: 95486.11 ns a character, not a whole number of nanoseconds.
        let mut s = Schedule::new(settings(115_200, 11));
        let mut last = t0;
        for _ in 0..1_000_000u32 {
            last = s.next(t0);
        }
        // 10^6 characters take exactly 11 * 10^6 / 115200 s = 95.486111111 s.
        assert_eq!(last - t0, Duration::from_nanos(95_486_111_111));
        // A byte arriving later in the burst still queues behind it.
        let mid = t0 + Duration::from_secs(10);
        assert_eq!(s.next(mid), t0 + Duration::from_nanos(95_486_206_597));
    }

    #[test]
    fn a_gap_restarts_the_burst_at_the_arrival() {
        let t0 = Instant::now();
        let mut s = Schedule::new(settings(19_200, 11));
        let c = Duration::from_nanos(572_916);
        assert_eq!(s.next(t0), t0 + c);
        assert_eq!(s.next(t0), t0 + Duration::from_nanos(1_145_833));
        // Arrives after the line went idle: starts at its own arrival.
        let late = t0 + Duration::from_millis(5);
        assert_eq!(s.next(late), late + c);
        // Arrives exactly when the previous byte ends: back to back.
        let end = late + c;
        assert_eq!(s.next(end), late + Duration::from_nanos(1_145_833));
    }

    #[test]
    fn zero_settings_do_not_divide_by_zero() {
        let t0 = Instant::now();
        let mut s = Schedule::new(settings(0, 0));
        // Taken as 1 bit at 1 Bd: one second a character.
        assert_eq!(s.next(t0), t0 + Duration::from_secs(1));
    }
}
