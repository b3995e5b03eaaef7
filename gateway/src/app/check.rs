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
/// line, to stdout; returns the exit code (0 valid, 1 not). A valid configuration that leaves a
/// write path open to every address without credentials gets a `warning:` line on stderr for
/// each such path (the exit code stays 0: the demo and a lab bench run like that on purpose).
pub fn check_command(path: &Path) -> i32 {
    let (text, code) = check_report(path);
    println!("{text}");
    if let Ok(config) = load_config(path) {
        for warning in security_warnings(&config) {
            eprintln!("warning: {warning}");
        }
    }
    code
}

/// The write paths of `config` open to every address without credentials, one message each.
pub fn security_warnings(config: &Config) -> Vec<String> {
    let mut warnings = Vec::new();
    let tcp = &config.modbus_tcp;
    let reachable = |ip: std::net::IpAddr| !ip.is_loopback();
    if tcp.enabled
        && !tcp.read_only
        && tcp.allowed_networks.is_empty()
        && reachable(tcp.listen.ip())
    {
        warnings.push(format!(
            "modbus_tcp: plain Modbus TCP on {} takes writes from every address without \
             credentials; set allowed_networks, read_only or write_ranges, or serve \
             [modbus_tcp.tls] with enabled = false",
            tcp.listen
        ));
    }
    let http = &config.http;
    if http.insecure_allow_unauthenticated_changes && reachable(http.listen.ip()) {
        warnings.push(format!(
            "http: changes without a token are allowed on {} (insecure_allow_unauthenticated_changes)",
            http.listen
        ));
    }
    if let Some(zenoh) = config.zenoh.as_ref().filter(|z| z.enabled) {
        let open: Vec<&str> = zenoh
            .listen
            .iter()
            .flatten()
            .map(config::Endpoint::as_str)
            .filter(|e| !endpoint_is_loopback(e))
            .collect();
        if !open.is_empty() && zenoh.config_file.is_none() {
            warnings.push(format!(
                "zenoh: `tx` and tag `set` keys take writes from every peer reaching {} without \
                 credentials; restrict them with zenoh's access_control (and TLS) in config_file",
                open.join(", ")
            ));
        }
    }
    warnings
}

/// Whether a zenoh endpoint (`tcp/127.0.0.1:7447`, `tcp/[::1]:7447`, `tcp/localhost:7447`)
/// listens on loopback only.
fn endpoint_is_loopback(endpoint: &str) -> bool {
    let address = endpoint.split_once('/').map_or(endpoint, |(_, a)| a);
    let address = address.split('#').next().unwrap_or(address);
    let host = address.rsplit_once(':').map_or(address, |(h, _)| h);
    let host = host.trim_start_matches('[').trim_end_matches(']');
    host == "localhost"
        || host
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loopback_endpoints_are_recognised() {
        assert!(endpoint_is_loopback("tcp/127.0.0.1:7447"));
        assert!(endpoint_is_loopback("tcp/[::1]:7447"));
        assert!(endpoint_is_loopback("tcp/localhost:7447"));
        assert!(!endpoint_is_loopback("tcp/0.0.0.0:7447"));
        assert!(!endpoint_is_loopback("tls/10.0.0.5:7447"));
    }

    #[test]
    fn open_write_paths_are_warned_about() {
        let open = config::parse(
            "[modbus_tcp]\nlisten = \"0.0.0.0:502\"\n[http]\nlisten = \"0.0.0.0:8080\"\n\
             insecure_allow_unauthenticated_changes = true\n[zenoh]\nlisten = [\"tcp/0.0.0.0:7447\"]\n",
        )
        .expect("parses");
        let warnings = security_warnings(&open);
        assert_eq!(warnings.len(), 3, "{warnings:#?}");
        assert!(warnings[0].starts_with("modbus_tcp:"));
        assert!(warnings[1].starts_with("http:"));
        assert!(warnings[2].starts_with("zenoh:"));
        let closed = config::parse(
            "[modbus_tcp]\nlisten = \"0.0.0.0:502\"\nallowed_networks = [\"10.0.0.0/8\"]\n\
             [zenoh]\nlisten = [\"tcp/127.0.0.1:7447\"]\n",
        )
        .expect("parses");
        assert_eq!(security_warnings(&closed), Vec::<String>::new());
        // The demo's loopback listeners are not warned about.
        let demo = config::parse(config::demo_toml()).expect("demo parses");
        assert_eq!(security_warnings(&demo), Vec::<String>::new());
    }
}
