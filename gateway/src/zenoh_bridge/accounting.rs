//! The accounting of commands that come over zenoh (`tx`, tag `set`, and any other put or query
//! that changes something): every command ends in exactly one call of [`refused`] or
//! [`finished`], whichever part of the gateway decided its fate (the zenoh callback, the
//! dispatcher, the backend). Both count it in `gateway_writes_total{path="zenoh",result,reason}`
//! and write it to the audit log (target `audit`), rate-limited per result and reason: a flood of
//! refused puts leaves one line per [`crate::audit::AUDIT_INTERVAL`] per reason, with the number
//! left out, while the counter counts every one.
//!
//! A handler of a new command key calls these two and nothing else for its accounting, and logs
//! nothing of its own at WARN or above for what a peer sends (the peer decides how often that
//! happens); see the test at the end of `zenoh_bridge/mod.rs`.

use std::fmt::Display;

use crate::audit::AuditMetrics;
pub use crate::audit::WriteReason;
use crate::audit::{self, WritePath, WriteResult};

/// The audit source of every write over zenoh (zenoh carries no client identity the gateway
/// could trust).
pub const SOURCE: &str = "zenoh";

/// Records a command refused for `reason` before it reached a device or a line: counted, audited
/// (rate-limited). `target` names what it asked for (`drive/atv71/ACC = 5`, `r3964/tx (5
/// bytes)`), `detail` why it was refused (the text its result carries).
pub fn refused(
    metrics: Option<&AuditMetrics>,
    target: &dyn Display,
    reason: WriteReason,
    detail: &dyn Display,
) {
    audit::record_reason(
        metrics,
        WritePath::Zenoh,
        &SOURCE,
        target,
        WriteResult::Refused,
        reason,
        detail,
    );
}

/// Records a command that was carried out: `ok` when the device or line took it, else it
/// failed there (`detail` says how).
pub fn finished(
    metrics: Option<&AuditMetrics>,
    target: &dyn Display,
    ok: bool,
    detail: &dyn Display,
) {
    let result = if ok {
        WriteResult::Accepted
    } else {
        WriteResult::Failed
    };
    audit::record_reason(
        metrics,
        WritePath::Zenoh,
        &SOURCE,
        target,
        result,
        WriteReason::None,
        detail,
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_refusal_is_counted_by_its_reason() {
        let registry = prometheus::Registry::new();
        let metrics = AuditMetrics::register(&registry).expect("register");
        for _ in 0..1000 {
            refused(
                Some(&metrics),
                &"drive/atv71/ACC",
                WriteReason::WritesOff,
                &"off",
            );
        }
        refused(
            Some(&metrics),
            &"r3964/tx (9 bytes)",
            WriteReason::TooLarge,
            &"large",
        );
        finished(Some(&metrics), &"drive/atv71/ACC = 5", true, &"ok");
        finished(Some(&metrics), &"drive/atv71/ACC = 5", false, &"timeout");
        let text = crate::metrics::encode_text(&registry);
        for line in [
            r#"gateway_writes_total{path="zenoh",reason="writes_off",result="refused"} 1000"#,
            r#"gateway_writes_total{path="zenoh",reason="too_large",result="refused"} 1"#,
            r#"gateway_writes_total{path="zenoh",reason="queue_full",result="refused"} 0"#,
            r#"gateway_writes_total{path="zenoh",reason="none",result="accepted"} 1"#,
            r#"gateway_writes_total{path="zenoh",reason="none",result="failed"} 1"#,
            r#"gateway_writes_total{path="rest",reason="policy",result="refused"} 0"#,
        ] {
            assert!(text.contains(line), "{line} missing in\n{text}");
        }
    }
}
