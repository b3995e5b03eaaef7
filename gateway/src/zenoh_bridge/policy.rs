//! The publishing policy of tag values (`[zenoh.publish]`): deadbands and heartbeats.
//!
//! A tag whose policy sets neither (the default) is published on every change, as the image
//! announces it, and nothing is kept for it here. For a tag with a deadband or a heartbeat the
//! last value published is kept (its key, names, value, quality and when): a new value is
//! published when its quality differs, or when it differs from the last one and, for a number,
//! moved by more than every deadband set (the image announces the whole range a poll changed, so
//! this also holds back the unchanged tags next to a changed one); the heartbeat task publishes the current value of every tag with nothing
//! published for its heartbeat period. A published value always carries the time its poll read
//! it (`timestamp` in the JSON), whether a change, the first value or a heartbeat sent it.

use std::collections::HashMap;
use std::sync::{Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use serde_json::Value;
use tokio::time::Instant;

use super::TagValue;
use crate::config::{PublishConfig, TagPolicy};

/// How often the heartbeat task looks at most, and at least.
const TICK_MIN: Duration = Duration::from_millis(50);
const TICK_MAX: Duration = Duration::from_secs(1);

/// What was last published for a tag with an active policy.
#[derive(Debug)]
struct Last {
    line: String,
    device: String,
    tag: String,
    value: Value,
    quality: &'static str,
    at: Instant,
    policy: TagPolicy,
}

/// The policy of every tag and the last publications it needs.
#[derive(Debug, Default)]
pub(crate) struct Publishing {
    config: PublishConfig,
    /// By `<line>/<device>/<tag>`.
    last: Mutex<HashMap<String, Last>>,
}

/// What to do with a new value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Verdict {
    /// Publish it.
    Publish,
    /// It is the last published value, or stayed within its deadband, with the same quality.
    WithinDeadband,
}

// === impl Publishing ===

impl Publishing {
    pub(crate) fn new(config: PublishConfig) -> Self {
        Self {
            config,
            last: Mutex::default(),
        }
    }

    fn lock(&self) -> MutexGuard<'_, HashMap<String, Last>> {
        // A panic while holding the lock leaves whole entries behind.
        self.last.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Whether `value` of tag `names` is published now; when it is, it becomes the tag's last
    /// published value.
    pub(crate) fn admit(
        &self,
        (line, device, tag): (&str, &str, &str),
        value: &TagValue,
        now: Instant,
    ) -> Verdict {
        let policy = self.config.policy(line, device, tag);
        if !policy.is_active() {
            return Verdict::Publish;
        }
        let key = format!("{line}/{device}/{tag}");
        let mut last = self.lock();
        if let Some(l) = last.get_mut(&key) {
            if l.quality == value.quality
                && (l.value == value.value || within_deadband(&policy, &l.value, &value.value))
            {
                return Verdict::WithinDeadband;
            }
            l.value.clone_from(&value.value);
            l.quality = value.quality;
            l.at = now;
            l.policy = policy;
        } else {
            last.insert(
                key,
                Last {
                    line: line.to_owned(),
                    device: device.to_owned(),
                    tag: tag.to_owned(),
                    value: value.value.clone(),
                    quality: value.quality,
                    at: now,
                    policy,
                },
            );
        }
        Verdict::Publish
    }

    /// Whether tag `<line>/<device>/<tag>` has a deadband or a heartbeat.
    pub(crate) fn has_policy(&self, line: &str, device: &str, tag: &str) -> bool {
        self.config.policy(line, device, tag).is_active()
    }

    /// Records `value` of tag `names` as published by a heartbeat (whatever the deadband says).
    pub(crate) fn record(
        &self,
        (line, device, tag): (&str, &str, &str),
        value: &TagValue,
        now: Instant,
    ) {
        if let Some(l) = self.lock().get_mut(&format!("{line}/{device}/{tag}")) {
            l.value.clone_from(&value.value);
            l.quality = value.quality;
            l.at = now;
        }
    }

    /// The tags `(line, device, tag)` whose heartbeat is due at `now`.
    pub(crate) fn due(&self, now: Instant) -> Vec<(String, String, String)> {
        self.lock()
            .values()
            .filter(|l| {
                !l.policy.heartbeat.is_zero()
                    && now.saturating_duration_since(l.at) >= l.policy.heartbeat
            })
            .map(|l| (l.line.clone(), l.device.clone(), l.tag.clone()))
            .collect()
    }

    /// How often the heartbeat task looks: a quarter of the shortest heartbeat, 50 ms to 1 s;
    /// `None` when no policy has a heartbeat.
    pub(crate) fn tick(&self) -> Option<Duration> {
        std::iter::once(&self.config.default)
            .chain(self.config.tags.iter().map(|r| &r.policy))
            .map(|p| p.heartbeat)
            .filter(|h| !h.is_zero())
            .min()
            .map(|h| (h / 4).clamp(TICK_MIN, TICK_MAX))
    }
}

/// Whether `new` stays within the deadbands of `policy` around `last`: both numbers, and the
/// change at most the absolute deadband (when set) or at most the percentage of `last` (when
/// set). Without a deadband nothing is within it.
pub(crate) fn within_deadband(policy: &TagPolicy, last: &Value, new: &Value) -> bool {
    let (Some(a), Some(b)) = (last.as_f64(), new.as_f64()) else {
        return false;
    };
    let change = (b - a).abs();
    let absolute = policy.deadband.0;
    let percent = policy.deadband_percent.0;
    let within_absolute = absolute > 0.0 && change <= absolute;
    let within_percent = percent > 0.0 && change <= a.abs() * percent / 100.0;
    within_absolute || within_percent
}

#[cfg(test)]
mod tests {
    use std::time::SystemTime;

    use serde_json::json;

    use super::*;
    use crate::config::{Deadband, TagRule};

    fn policy(deadband: f64, percent: f64, heartbeat_ms: u64) -> TagPolicy {
        TagPolicy {
            deadband: Deadband(deadband),
            deadband_percent: Deadband(percent),
            heartbeat: Duration::from_millis(heartbeat_ms),
        }
    }

    fn value(v: Value, quality: &'static str) -> TagValue {
        TagValue {
            value: v,
            unit: None,
            quality,
            timestamp: SystemTime::UNIX_EPOCH,
            description: None,
        }
    }

    #[test]
    fn deadbands_absolute_and_percent() {
        let abs = policy(0.5, 0.0, 0);
        assert!(within_deadband(&abs, &json!(10.0), &json!(10.5)));
        assert!(!within_deadband(&abs, &json!(10.0), &json!(10.6)));
        assert!(within_deadband(&abs, &json!(10), &json!(9.5)));
        let pct = policy(0.0, 10.0, 0);
        assert!(within_deadband(&pct, &json!(200), &json!(220)));
        assert!(!within_deadband(&pct, &json!(200), &json!(221)));
        assert!(!within_deadband(&pct, &json!(0), &json!(1)));
        // Either deadband set holds the value back.
        let both = policy(5.0, 1.0, 0);
        assert!(within_deadband(&both, &json!(100), &json!(104)));
        assert!(!within_deadband(&both, &json!(100), &json!(106)));
        // No deadband, or no number: every change goes out.
        let none = policy(0.0, 0.0, 1000);
        assert!(!within_deadband(&none, &json!(1), &json!(1)));
        assert!(!within_deadband(&abs, &json!(true), &json!(false)));
        assert!(!within_deadband(&abs, &json!("a"), &json!("a")));
    }

    #[test]
    fn rules_match_by_key_expression_and_the_first_wins() {
        let config = PublishConfig {
            default: policy(0.0, 0.0, 0),
            tags: vec![
                TagRule {
                    key: "drive/*/SFr".into(),
                    policy: policy(1.0, 0.0, 0),
                },
                TagRule {
                    key: "drive/**".into(),
                    policy: policy(0.0, 0.0, 2000),
                },
            ],
        };
        assert_eq!(config.policy("drive", "atv71", "SFr"), policy(1.0, 0.0, 0));
        assert_eq!(
            config.policy("drive", "atv71", "ETA"),
            policy(0.0, 0.0, 2000)
        );
        assert_eq!(config.policy("ksvario", "ks", "SFr"), policy(0.0, 0.0, 0));
        let p = Publishing::new(config);
        assert_eq!(p.tick(), Some(Duration::from_millis(500)));
        assert_eq!(Publishing::default().tick(), None);
    }

    #[test]
    fn the_last_published_value_is_the_reference_and_heartbeats_fall_due() {
        let p = Publishing::new(PublishConfig {
            default: policy(1.0, 0.0, 1000),
            tags: Vec::new(),
        });
        let names = ("l", "d", "x");
        let t0 = Instant::now();
        let admit = |v: f64, q, at| p.admit(names, &value(json!(v), q), at);
        assert_eq!(admit(10.0, "good", t0), Verdict::Publish);
        assert_eq!(admit(10.6, "good", t0), Verdict::WithinDeadband);
        // Small steps do not creep past the reference: 10.6, then 11.0 is 1.0 from 10.0.
        assert_eq!(admit(11.0, "good", t0), Verdict::WithinDeadband);
        assert_eq!(admit(11.1, "good", t0), Verdict::Publish);
        // A quality change always goes out; the same value and quality again does not.
        assert_eq!(admit(11.1, "stale", t0), Verdict::Publish);
        assert_eq!(admit(11.1, "stale", t0), Verdict::WithinDeadband);
        let on = |v: bool| p.admit(("l", "d", "on"), &value(json!(v), "good"), t0);
        assert_eq!(on(true), Verdict::Publish);
        assert_eq!(on(true), Verdict::WithinDeadband);
        assert_eq!(on(false), Verdict::Publish);
        assert!(p.due(t0 + Duration::from_millis(999)).is_empty());
        let mut due = p.due(t0 + Duration::from_secs(1));
        due.sort();
        let names = |t: &str| ("l".to_owned(), "d".to_owned(), t.to_owned());
        assert_eq!(due, [names("on"), names("x")]);
        p.record(
            ("l", "d", "x"),
            &value(json!(11.2), "good"),
            t0 + Duration::from_secs(1),
        );
        assert_eq!(p.due(t0 + Duration::from_millis(1500)), [names("on")]);
    }
}
