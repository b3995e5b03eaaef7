//! The checks of a configuration that need other parts of the gateway, with the config reader's
//! own rules: what `gateway check` and `gateway run` report, and what the REST API refuses.
//!
//! The reader (`config`) knows the keys, their ranges and the rules between keys. Whether the
//! CP memory can serve a slave line exactly is the CP memory's knowledge (`cpmem::config`): its
//! write limits are one byte range for M, one for Q and one range of DB numbers (003 6.4.5
//! "Limits"), so a write enable inside a byte or a DB is refused here, never silently widened.

use std::path::Path;

use crate::config::{self, Config, ConfigErrors, ConfigIssue, ProtocolConfig};
use crate::cpmem;

/// What the CP memory cannot serve exactly in the slave lines of `config`, each issue with its
/// path. A key the reader reported already (in `found`) is not reported twice.
pub fn config_issues(config: &Config, found: &[ConfigIssue]) -> Vec<ConfigIssue> {
    let mut issues: Vec<ConfigIssue> = Vec::new();
    for (name, line) in &config.lines {
        let ProtocolConfig::ModbusSlaveRtu(slave) = &line.protocol else {
            continue;
        };
        for issue in cpmem::config::check(slave) {
            let key = format!("lines.{name}.{}", issue.key);
            let known = |i: &ConfigIssue| i.path.starts_with(&key);
            if !found.iter().any(known) && !issues.iter().any(known) {
                issues.push(ConfigIssue {
                    path: key,
                    message: issue.message,
                });
            }
        }
    }
    issues
}

/// Reads, parses and validates the configuration file at `path`: the reader's rules and
/// [`config_issues`], every problem in one answer.
pub fn load_config(path: &Path) -> Result<Config, ConfigErrors> {
    config::load_with(path, &config_issues)
}

/// `gateway check --config FILE`: prints `ok: N lines, M devices`, or every issue on its own
/// line, to stdout; returns the exit code (0 valid, 1 not).
pub fn check_command(path: &Path) -> i32 {
    let (text, code) = check_report(path);
    println!("{text}");
    code
}

/// What [`check_command`] prints, and its exit code.
pub fn check_report(path: &Path) -> (String, i32) {
    match load_config(path) {
        Ok(c) => (
            format!("ok: {} lines, {} devices", c.lines.len(), c.device_count()),
            0,
        ),
        Err(e) => (e.to_string(), 1),
    }
}
