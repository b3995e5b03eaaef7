//! Prometheus metrics at the bottom of the gateway: the label vocabulary every family shares
//! ([`labels`]), the text encoding and the minimal `/metrics` listener ([`serve_metrics`]). No
//! global registry, no default registry: `main` creates the one registry and hands it down.
//!
//! This module imports nothing of the gateway's subsystems: each owns its families in its own
//! `metrics.rs`, and `app::Metrics` registers them all in the registry it is given.
//!
//! Label sets are bounded:
//! - `line`, `device`, `protocol` come from the configuration (line and device names, the
//!   `protocol` key), so there are as many as the configuration has;
//! - `class`, `event`, `class_name` come from the event catalog of 003 7.2 (`class` two upper-case
//!   hex digits such as `"08"`, `event` four such as `"0830"`, `class_name` the manual's class title
//!   in lower case, `"unknown"` for a class the catalog does not list);
//! - `function` is two upper-case hex digits for the functions the gateway knows and `"other"`
//!   for the rest, `result` is `ok`, `exception_NN`, `exception_other`, `timeout` or `error`
//!   (see [`labels`]);
//! - `direction`, `reason`, `kind` are enums.
//!
//! No label carries a client address, a register address or a telegram's content.

use prometheus::{Registry, TextEncoder};

mod http;
pub mod labels;

pub use http::serve_metrics;
pub use labels::{Direction, RequestResult};

/// The registry in the Prometheus text exposition format 0.0.4, for `/metrics`.
///
/// Encoding the families this module registers cannot fail; should it fail anyway, the error is
/// logged and returned as a comment line, which scrapers skip.
pub fn encode_text(registry: &Registry) -> String {
    match TextEncoder::new().encode_to_string(&registry.gather()) {
        Ok(text) => text,
        Err(error) => {
            tracing::error!(%error, "encoding the metrics failed");
            format!("# encoding the metrics failed: {error}\n")
        }
    }
}

/// The `Content-Type` of [`encode_text`]'s output.
pub const TEXT_CONTENT_TYPE: &str = "text/plain; version=0.0.4; charset=utf-8";

#[cfg(test)]
mod tests {
    /// metrics/ stays at the bottom: none of its files names a module of the gateway outside it
    /// (the families belong to their subsystems, the bundle to app/).
    #[test]
    fn metrics_imports_nothing_of_the_gateway() {
        let crate_path = concat!("crate", "::");
        let own_path = concat!("crate", "::metrics");
        for (file, text) in [
            ("mod.rs", include_str!("mod.rs")),
            ("http.rs", include_str!("http.rs")),
            ("labels.rs", include_str!("labels.rs")),
        ] {
            for line in text.lines().filter(|line| line.contains(crate_path)) {
                assert!(
                    line.replace(own_path, "").find(crate_path).is_none(),
                    "metrics/{file} names a module above it: {line}"
                );
            }
        }
        let files: Vec<_> = std::fs::read_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/src/metrics"))
            .expect("src/metrics")
            .map(|entry| entry.expect("entry").file_name())
            .collect();
        assert_eq!(
            files.len(),
            3,
            "a new file in metrics/ joins this test: {files:?}"
        );
    }
}
