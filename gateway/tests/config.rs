//! The configuration: defaults against the manuals, the demo and the example file, unknown keys,
//! range checks and cross-field checks, all problems of a file reported at once. The helpers live
//! here, the tests in `config/`.

use std::collections::BTreeSet;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use gateway::config::{
    ByteOrder, DataBits, DataType, Interface, ModbusTable, Parity, Profile, ScannerConfig, StopBits,
};
use gateway::plant::Config;
use gateway::protocols::{
    EndCriterion, FlowControl, LineConfig, OperatingMode, Overflow3964, Priority, ProtocolConfig,
};

#[path = "config/defaults.rs"]
mod defaults;
#[path = "config/files.rs"]
mod files;
#[path = "config/keys.rs"]
mod keys;
#[path = "config/rules.rs"]
mod rules;
#[path = "config/security.rs"]
mod security;

/// The example as shipped, its relative `template_dirs` made absolute (the tests read it from
/// text or copy it elsewhere; `gateway check` takes it from the file's directory).
static EXAMPLE: std::sync::LazyLock<String> = std::sync::LazyLock::new(|| {
    include_str!("../../deploy/gateway.example.toml").replace(
        "template_dirs = [\"templates\"]",
        &format!(
            "template_dirs = [{:?}]",
            concat!(env!("CARGO_MANIFEST_DIR"), "/../deploy/templates")
        ),
    )
});

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

/// The issues of `text` as (path, message) pairs; panics if it parses.
fn issues(text: &str) -> Vec<(String, String)> {
    match gateway::plant::parse(text) {
        Ok(c) => panic!("expected issues, parsed {c:#?}"),
        Err(e) => e.issues.into_iter().map(|i| (i.path, i.message)).collect(),
    }
}

fn parse(text: &str) -> Config {
    gateway::plant::parse(text).unwrap_or_else(|e| panic!("{e}\n---\n{text}"))
}

/// A config with one line `a` of `protocol` plus `extra` keys in the line table.
fn one_line(protocol: &str, extra: &str) -> String {
    format!("[lines.a]\nport = \"/dev/ttyS0\"\nprotocol = \"{protocol}\"\n{extra}\n")
}

fn line(c: &Config) -> &LineConfig {
    c.lines.get("a").expect("line a")
}

/// Asserts that `text` yields exactly one issue, at `path`, whose message contains `needle`.
#[track_caller]
fn one_issue(text: &str, path: &str, needle: &str) {
    let got = issues(text);
    assert_eq!(got.len(), 1, "expected one issue at {path}, got {got:#?}");
    assert_eq!(got[0].0, path, "{got:#?}");
    assert!(
        got[0].1.contains(needle),
        "message {:?} lacks {needle:?}",
        got[0].1
    );
}
