//! One stored value of the process image, packed small.
//!
//! The image holds a slot per polled register or bit (100 000 and more on a big gateway), so a
//! slot keeps its times as integers instead of `SystemTime`, `Instant` and `Option<Duration>`
//! (16 bytes each): 24 bytes a slot instead of 56. The conversions lose nothing the image's users
//! see, with these documented edges:
//!
//! - the wall-clock time is kept to the microsecond since the Unix epoch; a clock set before 1970
//!   stores the epoch;
//! - the monotonic time is kept to the nanosecond since the image was created ([`Clock`]), so an
//!   `Instant` comes back exactly (u64 nanoseconds last 584 years);
//! - the freshness limit is kept in whole milliseconds, rounded up (a poll period of 10.5 ms times
//!   3 turns stale after 32 ms, never earlier than asked); a limit past [`MAX_AGE_MS_LIMIT`]
//!   (about 49.7 days, far beyond the longest poll period of one day times the default stale
//!   factor) is clamped to it, and [`NEVER_STALE`] marks a value that is not polled.

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use tokio::time::Instant;

use super::Quality;

/// `max_age` of a value that never turns stale (written on demand only, not polled).
pub(super) const NEVER_STALE: u32 = u32::MAX;
/// The longest freshness limit a slot can keep, in milliseconds; longer ones are clamped to it.
pub(super) const MAX_AGE_MS_LIMIT: u32 = NEVER_STALE - 1;

const NANOS_PER_MILLI: u64 = 1_000_000;

/// One stored value.
#[derive(Clone, Copy, Debug)]
pub(super) struct Slot {
    /// The register value, or 0/1 for a bit.
    pub(super) value: u16,
    /// The quality as stored (before the staleness check).
    pub(super) quality: Quality,
    /// Wall-clock time of the read in microseconds since the Unix epoch, for display
    /// ([`wall_micros`]).
    pub(super) updated: u64,
    /// Monotonic time of the read in nanoseconds since the image was created, for the age
    /// ([`Clock::ticks`]).
    pub(super) at: u64,
    /// Age in milliseconds after which the value is stale; [`NEVER_STALE`]: never, e.g. written
    /// on demand only ([`max_age_millis`]).
    pub(super) max_age: u32,
}

// 56 bytes with `SystemTime`, `Instant` and `Option<Duration>`; the image's memory budget counts
// on this.
const _: () = assert!(size_of::<Slot>() <= 24);

// === impl Slot ===

impl Slot {
    /// Whether the value was stored with a poll period (it can turn stale).
    pub(super) fn polled(&self) -> bool {
        self.max_age != NEVER_STALE
    }

    /// The freshness limit in nanoseconds of the image's clock (`None`: never stale).
    pub(super) fn max_age_nanos(&self) -> Option<u64> {
        self.polled()
            .then(|| u64::from(self.max_age) * NANOS_PER_MILLI)
    }

    /// The quality at `now` (ticks of the image's [`Clock`]): a good value older than its
    /// freshness limit is stale.
    pub(super) fn effective_quality(&self, now: u64) -> Quality {
        match self.max_age_nanos() {
            Some(max) if self.quality == Quality::Good && now.saturating_sub(self.at) > max => {
                Quality::Stale
            }
            _ => self.quality,
        }
    }

    /// The wall-clock time of the read.
    pub(super) fn updated(&self) -> SystemTime {
        wall_time(self.updated)
    }
}

/// The image's monotonic clock: `Instant`s as nanoseconds since the image was created.
#[derive(Clone, Copy, Debug)]
pub(super) struct Clock {
    origin: Instant,
}

// === impl Clock ===

impl Clock {
    /// A clock starting now.
    pub(super) fn new() -> Self {
        Self {
            origin: Instant::now(),
        }
    }

    /// Nanoseconds from the clock's start to `at`: 0 for an earlier instant, `u64::MAX` after
    /// 584 years.
    pub(super) fn ticks(&self, at: Instant) -> u64 {
        let since = at.saturating_duration_since(self.origin);
        u64::try_from(since.as_nanos()).unwrap_or(u64::MAX)
    }

    /// The `Instant` of `ticks` (exact for ticks from [`Self::ticks`] of a later instant).
    pub(super) fn instant(&self, ticks: u64) -> Instant {
        // Cannot overflow for ticks taken from a real instant; the origin is the only fallback
        // that is still a time of this clock.
        self.origin
            .checked_add(Duration::from_nanos(ticks))
            .unwrap_or(self.origin)
    }
}

/// Microseconds since the Unix epoch; a time before the epoch counts as the epoch, one past
/// `u64::MAX` microseconds (584 000 years) as that.
pub(super) fn wall_micros(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_micros()).unwrap_or(u64::MAX))
}

/// The wall-clock time of [`wall_micros`].
pub(super) fn wall_time(micros: u64) -> SystemTime {
    UNIX_EPOCH
        .checked_add(Duration::from_micros(micros))
        .unwrap_or(UNIX_EPOCH)
}

/// A freshness limit in whole milliseconds, rounded up and clamped to [`MAX_AGE_MS_LIMIT`];
/// `None` (never stale) is [`NEVER_STALE`].
pub(super) fn max_age_millis(max_age: Option<Duration>) -> u32 {
    max_age.map_or(NEVER_STALE, |d| {
        let ms = d.as_nanos().div_ceil(u128::from(NANOS_PER_MILLI));
        u32::try_from(ms).map_or(MAX_AGE_MS_LIMIT, |ms| ms.min(MAX_AGE_MS_LIMIT))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wall_times_keep_the_microsecond_and_clamp_before_the_epoch() {
        let t = UNIX_EPOCH + Duration::from_nanos(1_700_000_000_123_456_789);
        assert_eq!(wall_micros(t), 1_700_000_000_123_456);
        assert_eq!(
            wall_time(wall_micros(t)),
            UNIX_EPOCH + Duration::from_micros(1_700_000_000_123_456)
        );
        let before = UNIX_EPOCH - Duration::from_secs(1);
        assert_eq!(wall_micros(before), 0);
        assert_eq!(wall_time(wall_micros(before)), UNIX_EPOCH);
        assert_eq!(wall_time(0), UNIX_EPOCH);
        let now = SystemTime::now();
        let back = wall_time(wall_micros(now));
        assert!(back <= now && now.duration_since(back).unwrap() < Duration::from_micros(1));
    }

    #[tokio::test(start_paused = true)]
    async fn instants_come_back_exactly() {
        let clock = Clock::new();
        let start = Instant::now();
        assert_eq!(clock.ticks(start), 0);
        assert_eq!(clock.instant(0), start);
        tokio::time::advance(Duration::from_nanos(1_234_567_891)).await;
        let later = Instant::now();
        assert_eq!(clock.ticks(later), 1_234_567_891);
        assert_eq!(clock.instant(clock.ticks(later)), later);
        // Before the clock's start: its start.
        let early = Clock { origin: later };
        assert_eq!(early.ticks(start), 0);
        // The largest ticks (584 years on): no panic.
        assert!(early.instant(u64::MAX) > later);
    }

    #[test]
    fn max_ages_round_up_to_the_millisecond_and_clamp() {
        assert_eq!(max_age_millis(None), NEVER_STALE);
        assert_eq!(max_age_millis(Some(Duration::ZERO)), 0);
        assert_eq!(max_age_millis(Some(Duration::from_millis(300))), 300);
        assert_eq!(max_age_millis(Some(Duration::from_micros(31_500))), 32);
        assert_eq!(max_age_millis(Some(Duration::from_nanos(1))), 1);
        // The longest poll period (one day) times the default stale factor fits.
        let day3 = Duration::from_secs(3 * 86_400);
        assert_eq!(max_age_millis(Some(day3)), 259_200_000);
        // Too long to keep: clamped to the longest, which still turns stale.
        let limit = Duration::from_millis(u64::from(MAX_AGE_MS_LIMIT));
        assert_eq!(max_age_millis(Some(limit)), MAX_AGE_MS_LIMIT);
        assert_eq!(
            max_age_millis(Some(limit + Duration::from_nanos(1))),
            MAX_AGE_MS_LIMIT
        );
        assert_eq!(max_age_millis(Some(Duration::MAX)), MAX_AGE_MS_LIMIT);
    }

    #[test]
    fn staleness_at_the_edges() {
        let slot = |max_age| Slot {
            value: 1,
            quality: Quality::Good,
            updated: 0,
            at: 5,
            max_age,
        };
        let ms = NANOS_PER_MILLI;
        // Stale only once strictly older than the limit, to the nanosecond.
        let fresh = slot(max_age_millis(Some(Duration::from_millis(300))));
        assert_eq!(fresh.effective_quality(5 + 300 * ms), Quality::Good);
        assert_eq!(fresh.effective_quality(5 + 300 * ms + 1), Quality::Stale);
        // Read before it was stored (never happens, but no underflow): good.
        assert_eq!(fresh.effective_quality(0), Quality::Good);
        // Never stale, whatever the age.
        let never = slot(max_age_millis(None));
        assert!(!never.polled());
        assert_eq!(never.effective_quality(u64::MAX), Quality::Good);
        // A clamped limit still turns stale after about 49.7 days.
        let clamped = slot(max_age_millis(Some(Duration::MAX)));
        assert!(clamped.polled());
        let limit = u64::from(MAX_AGE_MS_LIMIT) * ms;
        assert_eq!(clamped.effective_quality(5 + limit), Quality::Good);
        assert_eq!(clamped.effective_quality(5 + limit + 1), Quality::Stale);
        // Another quality is kept as stored.
        let rejected = Slot {
            quality: Quality::Rejected,
            ..fresh
        };
        assert_eq!(rejected.effective_quality(u64::MAX), Quality::Rejected);
    }
}
