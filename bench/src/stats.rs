//! Percentiles and means of measured durations.

use std::time::Duration;

/// The `p`-th percentile (0..=100) of `samples` by the nearest-rank method; zero when empty.
pub(crate) fn percentile(samples: &[Duration], p: f64) -> Duration {
    if samples.is_empty() {
        return Duration::ZERO;
    }
    let mut sorted = samples.to_vec();
    sorted.sort_unstable();
    let rank = ((p / 100.0) * sorted.len() as f64).ceil() as usize;
    let index = rank.clamp(1, sorted.len()) - 1;
    sorted.get(index).copied().unwrap_or_default()
}

/// The mean of `samples`; zero when empty.
pub(crate) fn mean(samples: &[Duration]) -> Duration {
    if samples.is_empty() {
        return Duration::ZERO;
    }
    let total: Duration = samples.iter().sum();
    total / u32::try_from(samples.len()).unwrap_or(u32::MAX)
}

/// p50, p99 and max of latencies, and how many of them are above 1 ms, for a row's note.
pub(crate) fn tail(samples: &[Duration]) -> String {
    let over = samples
        .iter()
        .filter(|s| **s > Duration::from_millis(1))
        .count();
    format!(
        "p50 {}, p99 {}, max {}, {over} of {} above 1 ms",
        ms(percentile(samples, 50.0)),
        ms(percentile(samples, 99.0)),
        ms(percentile(samples, 100.0)),
        samples.len()
    )
}

/// A duration in milliseconds with three decimals, for the table.
pub(crate) fn ms(d: Duration) -> String {
    format!("{:.3} ms", d.as_secs_f64() * 1e3)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_percentiles() {
        let samples: Vec<Duration> = (1..=100).map(Duration::from_millis).collect();
        assert_eq!(percentile(&samples, 50.0), Duration::from_millis(50));
        assert_eq!(percentile(&samples, 99.0), Duration::from_millis(99));
        assert_eq!(percentile(&samples, 100.0), Duration::from_millis(100));
        assert_eq!(percentile(&[], 99.0), Duration::ZERO);
        assert_eq!(mean(&samples), Duration::from_micros(50_500));
        assert_eq!(
            tail(&samples),
            "p50 50.000 ms, p99 99.000 ms, max 100.000 ms, 99 of 100 above 1 ms"
        );
    }
}
