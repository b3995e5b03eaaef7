//! Exponential back-off between attempts (reopening a port, retrying an offline device).

use std::time::Duration;

/// Why a back-off could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum InvalidBackoff {
    /// The minimum is zero (the attempts would spin).
    #[error("back-off minimum must be above zero")]
    ZeroMinimum,
    /// The maximum is below the minimum.
    #[error("back-off maximum {max:?} is below the minimum {min:?}")]
    MaxBelowMin {
        /// The minimum delay.
        min: Duration,
        /// The maximum delay.
        max: Duration,
    },
}

/// Exponential back-off without jitter: `min`, `2 x min`, `4 x min`, ... capped at `max`, back to
/// `min` after [`Backoff::reset`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Backoff {
    min: Duration,
    max: Duration,
    /// The delay the next call of [`Backoff::next_delay`] returns.
    next: Duration,
}

// === impl Backoff ===

impl Backoff {
    /// A back-off from `min` to `max`.
    pub fn try_new(min: Duration, max: Duration) -> Result<Self, InvalidBackoff> {
        if min.is_zero() {
            return Err(InvalidBackoff::ZeroMinimum);
        }
        if max < min {
            return Err(InvalidBackoff::MaxBelowMin { min, max });
        }
        Ok(Self {
            min,
            max,
            next: min,
        })
    }

    /// A back-off from `min` (at least 1 ms) to `max` (at least `min`): never fails, for settings
    /// validated elsewhere.
    pub fn clamped(min: Duration, max: Duration) -> Self {
        let min = min.max(Duration::from_millis(1));
        Self {
            min,
            max: max.max(min),
            next: min,
        }
    }

    /// The delay before the next attempt; each call doubles the following one up to the maximum.
    pub fn next_delay(&mut self) -> Duration {
        let delay = self.next;
        self.next = self.next.saturating_mul(2).min(self.max);
        delay
    }

    /// Starts again from the minimum (after a success).
    pub fn reset(&mut self) {
        self.next = self.min;
    }

    /// The smallest delay.
    pub fn min(&self) -> Duration {
        self.min
    }

    /// The largest delay.
    pub fn max(&self) -> Duration {
        self.max
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn doubles_up_to_the_maximum_and_resets() {
        let ms = Duration::from_millis;
        let mut b = Backoff::try_new(ms(100), ms(700)).unwrap();
        let delays: Vec<_> = (0..5).map(|_| b.next_delay()).collect();
        assert_eq!(delays, vec![ms(100), ms(200), ms(400), ms(700), ms(700)]);
        b.reset();
        assert_eq!(b.next_delay(), ms(100));
    }

    #[test]
    fn rejects_zero_and_inverted_bounds() {
        let ms = Duration::from_millis;
        assert_eq!(
            Backoff::try_new(ms(0), ms(10)),
            Err(InvalidBackoff::ZeroMinimum)
        );
        assert_eq!(
            Backoff::try_new(ms(20), ms(10)),
            Err(InvalidBackoff::MaxBelowMin {
                min: ms(20),
                max: ms(10)
            })
        );
        assert!(Backoff::try_new(ms(10), ms(10)).is_ok());
        let mut c = Backoff::clamped(ms(0), ms(0));
        assert_eq!((c.next_delay(), c.next_delay()), (ms(1), ms(1)));
    }
}
