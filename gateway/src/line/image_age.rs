//! `gateway_device_image_age_seconds`: the age of each device's image, computed at scrape time.
//!
//! A gauge set by the poller would only be as fresh as its last poll, and would freeze exactly when
//! a device stops answering. This collector instead keeps the instant of each device's last image
//! update and reports `now - updated` whenever the registry is gathered.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Instant;

use prometheus::core::{Collector, Desc};
use prometheus::proto::MetricFamily;
use prometheus::{GaugeVec, Opts};

/// Last update per (line, device).
type Updated = BTreeMap<(String, String), Instant>;

/// The collector registered for the image age family; clones share their state.
#[derive(Clone, Debug)]
pub(crate) struct ImageAge {
    /// The family, set from `updated` at every collect.
    gauge: GaugeVec,
    /// When each device's image was last updated, written by the pollers.
    updated: Arc<Mutex<Updated>>,
}

// === impl ImageAge ===

impl ImageAge {
    pub(crate) fn new(name: &str, help: &str) -> Result<Self, prometheus::Error> {
        Ok(Self {
            gauge: GaugeVec::new(Opts::new(name, help), &["line", "device"])?,
            updated: Arc::default(),
        })
    }

    /// Records that the image of `device` on `line` was updated at `at`; an older instant than
    /// the one recorded is ignored.
    pub(crate) fn updated(&self, line: &str, device: &str, at: Instant) {
        let mut updated = self.lock();
        let key = (line.to_owned(), device.to_owned());
        let slot = updated.entry(key).or_insert(at);
        if at > *slot {
            *slot = at;
        }
    }

    /// Drops the series of a device that left the configuration.
    pub(crate) fn forget(&self, line: &str, device: &str) {
        self.lock().remove(&(line.to_owned(), device.to_owned()));
        // Absent when never collected: nothing to remove then.
        let _ = self.gauge.remove_label_values(&[line, device]);
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Updated> {
        self.updated.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl Collector for ImageAge {
    fn desc(&self) -> Vec<&Desc> {
        self.gauge.desc()
    }

    fn collect(&self) -> Vec<MetricFamily> {
        let now = Instant::now();
        let updated = self.lock();
        for ((line, device), at) in updated.iter() {
            let age = now.saturating_duration_since(*at).as_secs_f64();
            self.gauge.with_label_values(&[line, device]).set(age);
        }
        self.gauge.collect()
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    fn sample(age: &ImageAge) -> Vec<(String, f64)> {
        age.collect()
            .iter()
            .flat_map(|family| family.get_metric().iter())
            .map(|metric| {
                let labels: Vec<_> = metric.get_label().iter().map(|l| l.value()).collect();
                (labels.join("/"), metric.get_gauge().get_value())
            })
            .collect()
    }

    #[test]
    fn age_is_computed_at_collect_and_never_goes_back() {
        let age = ImageAge::new("gateway_device_image_age_seconds", "age").expect("valid");
        let long_ago = Instant::now()
            .checked_sub(Duration::from_secs(30))
            .expect("the clock runs longer than 30 s");
        age.updated("drive", "atv71", long_ago);
        let older = long_ago.checked_sub(Duration::from_secs(5)).expect("older");
        age.updated("drive", "atv71", older);
        let samples = sample(&age);
        assert_eq!(samples.len(), 1);
        let (labels, value) = &samples[0];
        // Label pairs come sorted by name: device, line.
        assert_eq!(labels, "atv71/drive");
        assert!(*value >= 30.0 && *value < 300.0, "age {value}");

        age.forget("drive", "atv71");
        assert!(sample(&age).is_empty());
    }
}
