//! The audit's Prometheus family, [`AuditMetrics`].

use prometheus::{IntCounter, IntCounterVec, Opts, Registry};

use super::{WritePath, WriteReason, WriteResult};

/// The audit's Prometheus family, `gateway_writes_total{path,result,reason}`. Clones share the
/// same series.
#[derive(Clone, Debug)]
pub struct AuditMetrics {
    writes: IntCounterVec,
}

// === impl AuditMetrics ===

impl AuditMetrics {
    /// The name of the family.
    pub const NAME: &'static str = "gateway_writes_total";

    /// Registers the family in `registry`, with the series every path can count at 0.
    pub fn register(registry: &Registry) -> Result<Self, prometheus::Error> {
        let metrics = Self {
            writes: IntCounterVec::new(
                Opts::new(
                    Self::NAME,
                    "Writes from outside (Modbus TCP, Modbus/TCP Security, REST, zenoh) by path, \
                     result and the reason of a refusal.",
                ),
                &["path", "result", "reason"],
            )?,
        };
        registry.register(Box::new(metrics.writes.clone()))?;
        for path in WritePath::ALL {
            for result in WriteResult::ALL {
                metrics.series(path, result, WriteReason::of(result));
            }
        }
        for reason in WriteReason::ZENOH_REFUSALS {
            metrics.series(WritePath::Zenoh, WriteResult::Refused, reason);
        }
        Ok(metrics)
    }

    /// Counts one audited write.
    pub fn write(&self, path: WritePath, result: WriteResult, reason: WriteReason) {
        self.series(path, result, reason).inc();
    }

    fn series(&self, path: WritePath, result: WriteResult, reason: WriteReason) -> IntCounter {
        self.writes
            .with_label_values(&[path.as_str(), result.as_str(), reason.as_str()])
    }
}
