//! The checks of a configuration that need other parts of the gateway, with the config reader's
//! own rules: what `gateway check` and `gateway run` report, and what the REST API refuses.
//!
//! The reader (`config`) knows the keys, their ranges and the rules between keys. Whether the
//! CP memory can serve a slave line exactly is the slave protocol's knowledge
//! (`protocols/modbus_slave/cpmem.rs`): its
//! write limits are one byte range for M, one for Q and one range of DB numbers (003 6.4.5
//! "Limits"), so a write enable inside a byte or a DB is refused there
//! (`crate::plant::check::config_issues`, which [`load_config`] hands the reader), never silently
//! widened.
//!
//! Beyond the file's rules, one function, [`start_issues`], collects the start checks (each a
//! `config::check::Check` next to what it checks, listed in [`start_checks`] and
//! [`path_checks`]), and every door calls it: `gateway check`, `gateway run` (exit 64 before any
//! port opens), a SIGHUP re-read (`super::reload`), `POST /config/validate` and
//! `PUT /config...` (through the supervisor's `validate`: 422, nothing saved). Before, the REST API saved what `run` refused at
//! the next start, and systemd does not restart on 64: a gateway changed over REST stayed down
//! after the next reboot. The checks: every REST token readable and at least 16 visible
//! characters, no two alike; every line startable (telegram settings, CP memory); the zenoh
//! settings loadable (`config_file` included); the Modbus/TCP Security files loadable; a
//! persisted CP memory file readable. Through the REST API the paths a change names are confined
//! first ([`api_path_issues`]: ports under `port_dirs`, the CP memory file and journals under
//! `state_dirs`, template directories, token, zenoh and TLS files under `config_dirs`), and a
//! file outside is never opened.
//!
//! `gateway check` also opens every RS485 line's port as the line would and closes it again: a
//! port whose driver refuses RS485 mode (a pseudo-terminal, a UART without RS485 support) never
//! works, so it is an error that says what to set instead; a port that does not exist or cannot
//! be opened now (not plugged in, in use) is a warning, because the running line opens it again
//! with back-off. It warns, too, about keys another key's value leaves without effect
//! (`crate::plant::validate::ignored_keys`) and tags that no poll group reads.
//!
//! Exit codes: `gateway check` 0 (valid, warnings may be printed) or 1 (problems); `gateway run`
//! 64 (the configuration is refused: file, token, line settings, zenoh or CP memory file) or 70
//! (anything else).

use std::path::Path;

use super::lines::LineStarts;
use super::tls::ModbusTlsFiles;
use crate::api::auth::ApiTokens;
use crate::api::tls::HttpsFiles;
use crate::config::check::{issue, Check};
use crate::config::{self, no_such_port, ConfigErrors, ConfigIssue, Cx, Interface};
use crate::plant::check::{
    persist_dir_warnings, ApiChange, GatewayDirs, Journals, PersistFile, SerialPorts, Start,
    TemplateDirs, ZenohFile,
};
use crate::plant::Config;
use crate::serial::{self, OpenError};

/// Reads, parses and validates the configuration file at `path`: the reader's rules and
/// the CP memory's ([`crate::plant::check::config_issues`]), every problem in one answer.
pub fn load_config(path: &Path) -> Result<Config, ConfigErrors> {
    crate::plant::load_with(path, &crate::plant::check::config_issues)
}

/// Where a configuration comes from, for [`start_issues`].
#[derive(Clone, Copy, Debug)]
pub enum Door<'a> {
    /// The host's file (`gateway check`, `gateway run`, a SIGHUP re-read): it may name any path.
    File,
    /// A change over the REST API (`PUT /config...`, `POST /config/validate`): a path it changes
    /// must lie inside the directories `in_force`'s `[gateway]` allows for it.
    Api {
        /// The configuration in force, which the change is made from.
        in_force: &'a Config,
    },
}

/// What `gateway run` refuses in `config` beyond the file's own rules ([`start_issues`] for
/// the host's file). Run exits 64 on any of them before a port is opened.
pub fn run_issues(config: &Config) -> Vec<ConfigIssue> {
    start_issues(config, Door::File)
}

/// The start checks, in the order of the answer: the API tokens (`api/auth/check.rs`), each
/// line's start (`app/lines.rs`), the zenoh file, the CP memory file and the journals
/// (`plant/check.rs`), the Modbus/TCP Security files (`app/tls.rs`) and the HTTPS files
/// (`api/tls.rs`).
fn start_checks() -> [&'static dyn for<'a> Check<Start<'a>>; 7] {
    [
        &ApiTokens,
        &LineStarts,
        &ZenohFile,
        &PersistFile,
        &Journals,
        &ModbusTlsFiles,
        &HttpsFiles,
    ]
}

/// The path checks of a REST change, in the order of the answer, each next to what its paths
/// guard: the lines' serial ports, the `[gateway]` directories themselves, the CP memory file,
/// the journals, the template directories (`plant/check.rs`), the token files, the zenoh file
/// and the TLS files.
fn path_checks() -> [&'static dyn for<'a> Check<ApiChange<'a>>; 9] {
    [
        &SerialPorts,
        &GatewayDirs,
        &PersistFile,
        &Journals,
        &TemplateDirs,
        &ApiTokens,
        &ZenohFile,
        &ModbusTlsFiles,
        &HttpsFiles,
    ]
}

/// The start checks, one function for every door (`gateway check`, `gateway run`, a SIGHUP
/// re-read, `POST /config/validate`, `PUT /config` and `PUT /config/lines/{line}`): every token
/// read from its file or variable (at least 16 visible characters, no two alike), what would
/// keep a line from starting, the zenoh settings (`config_file` read and parsed), the
/// Modbus/TCP Security files loaded, a persisted CP memory file readable. Through the API
/// ([`Door::Api`]) the paths a change names are confined first ([`api_path_issues`]), and a
/// file outside its directories is not opened at all. Every problem comes with its path.
pub fn start_issues(config: &Config, door: Door<'_>) -> Vec<ConfigIssue> {
    let mut issues = match door {
        Door::File => Vec::new(),
        Door::Api { in_force } => api_path_issues(config, in_force),
    };
    let refused: Vec<String> = issues.iter().map(|i| i.path.clone()).collect();
    let start = Start {
        config,
        refused: &refused,
    };
    let mut cx = Cx::default();
    for check in start_checks() {
        check.check(&start, &mut cx);
    }
    issues.extend(cx.issues);
    issues
}

/// The paths a change over the REST API names, each confined to the directories the host's file
/// allows for it (`[gateway]` of `in_force`): a serial port (that must exist, and not be a
/// demo `pty:`) under `port_dirs`, the CP memory file and the journals under `state_dirs`,
/// template directories, token files, the zenoh config file and the TLS files under
/// `config_dirs`. A path that is the one in force (the host set it) is not checked again. The
/// directories themselves change only in the host's file.
///
/// A new key that names a file is confined by its part's check in the [`ApiChange`] scope.
pub fn api_path_issues(new: &Config, in_force: &Config) -> Vec<ConfigIssue> {
    let change = ApiChange { new, in_force };
    let mut cx = Cx::default();
    for check in path_checks() {
        check.check(&change, &mut cx);
    }
    cx.issues
}

/// What to set instead when a port's driver refuses RS485 mode.
const RS485_INSTEAD: &str = "with an adapter that switches its transmitter itself (automatic \
     send/receive, as most USB-RS485 adapters do) set interface = \"rs422\" (the port as it is, \
     no kernel RS485 mode); on a UART with a transceiver on RTS, switch the driver's RS485 \
     support on (device tree linux,rs485-enabled-at-boot-time, or a driver with TIOCSRS485)";

/// The ports of every line: one that does not exist is a warning (the line opens it with
/// back-off until it appears), in the words the REST API refuses it with; an RS485 line's port
/// is opened with its settings and closed again: a refused RS485 mode is an error (the line
/// could never work) that says what to set instead, a port that cannot be opened now a
/// warning.
pub fn port_issues(config: &Config) -> (Vec<ConfigIssue>, Vec<ConfigIssue>) {
    let (mut errors, mut warnings) = (Vec::new(), Vec::new());
    for (name, line) in &config.lines {
        let ports = [
            ("port", Some(line.serial.port.as_str())),
            ("port_b", line.second_port()),
        ];
        let mut present = true;
        for (key, port) in ports {
            let Some(port) = port.filter(|p| !p.is_empty() && !p.starts_with(config::PTY_PREFIX))
            else {
                continue;
            };
            if !Path::new(port).exists() {
                present = false;
                warnings.push(issue(
                    format!("lines.{name}.{key}"),
                    format!(
                        "{} (the line opens it with back-off until it appears)",
                        no_such_port(port)
                    ),
                ));
            }
        }
        if !present
            || !matches!(line.serial.interface, Interface::Rs485)
            || line.serial.pty_name().is_some()
        {
            continue;
        }
        let interface = format!("lines.{name}.interface");
        match serial::probe(&crate::protocols::start::port_settings(&line.serial)) {
            Ok(()) => {}
            Err(e @ OpenError::Rs485Refused { .. }) => {
                errors.push(issue(&interface, format!("{e}; {RS485_INSTEAD}")));
            }
            Err(e @ OpenError::Flags { .. }) => errors.push(issue(&interface, e.to_string())),
            Err(e @ (OpenError::Open { .. } | OpenError::NotFound { .. })) => warnings.push(issue(
                format!("lines.{name}.port"),
                format!("{e}; RS485 mode not tested (the line opens the port again with back-off)"),
            )),
        }
    }
    (errors, warnings)
}

/// The tags that no poll group of their device reads, fully (by name or by an address range
/// that covers all its registers): they are read from the device on demand only (REST, zenoh
/// queries) and never published on change. A config tag is named at its own path; the
/// profile's unpolled tags are listed in one warning per device.
pub fn unpolled_tags(config: &Config) -> Vec<ConfigIssue> {
    use proto_core::profiles::Table as T;
    let directory = crate::tags::TagDirectory::from_config(config);
    let mut warnings = Vec::new();
    for (line_name, line) in &config.lines {
        if !line.protocol.kind().is_master() {
            // A tap line polls nothing: its values come from another master's traffic.
            continue;
        }
        for (device_name, device) in line.devices() {
            let polled = |name: &str, table: T, address: u16, words: u16| {
                let table = match table {
                    T::Coils => config::ModbusTable::Coil,
                    T::DiscreteInputs => config::ModbusTable::Discrete,
                    T::InputRegisters => config::ModbusTable::Input,
                    T::HoldingRegisters => config::ModbusTable::Holding,
                };
                device.poll.iter().any(|group| {
                    group.tags.iter().any(|t| t.eq_ignore_ascii_case(name))
                        || group
                            .ranges
                            .iter()
                            .any(|r| r.covers(table, address, u32::from(words)))
                })
            };
            let path = format!("lines.{line_name}.devices.{device_name}");
            let mut from_profile = Vec::new();
            for entry in directory
                .iter()
                .filter(|e| e.line() == line_name && e.device() == device_name)
            {
                let name = entry.name();
                if polled(name, entry.table(), entry.address(), entry.words()) {
                    continue;
                }
                match device.tags.iter().position(|t| &*t.name == name) {
                    Some(i) => warnings.push(issue(
                        format!("{path}.tags[{i}]"),
                        format!(
                            "tag {name:?} is read by no poll group: it is read from the device only on demand and never published on change"
                        ),
                    )),
                    None => from_profile.push(name),
                }
            }
            if !from_profile.is_empty() {
                warnings.push(issue(
                    format!("{path}.poll"),
                    format!(
                        "{} tags of the profile are read by no poll group (read on demand only, never published on change): {}",
                        from_profile.len(),
                        listed(&from_profile)
                    ),
                ));
            }
        }
    }
    warnings
}

/// The telegram lines whose received telegrams nothing in `config` acknowledges on its own: an
/// explicit line without a Modbus TCP mailbox (`unit_id`, Modbus TCP on) and without zenoh
/// writes (`<line>/ack`) is acknowledged over REST only; an on-publish line without zenoh by
/// nothing at all. Either fills its mailbox and then refuses telegrams (08 0Ah).
pub fn ack_warnings(config: &Config) -> Vec<ConfigIssue> {
    let zenoh_on = config.zenoh.as_ref().is_some_and(|z| z.enabled);
    let zenoh_writes = zenoh_on && config.zenoh.as_ref().is_some_and(|z| z.writes);
    let modbus_on = config.modbus_tcp.enabled;
    let mut warnings = Vec::new();
    for (name, line) in &config.lines {
        if line.protocol.section().telegrams().is_none() {
            continue;
        }
        // A client other than REST that can acknowledge: a Modbus TCP mailbox or zenoh writes.
        let client = (modbus_on && line.unit_id().is_some()) || zenoh_writes;
        let message = match crate::protocols::ack_mode(zenoh_on, line) {
            config::AckConfig::Explicit if !client => {
                format!(
                    "ack = \"explicit\" but no Modbus TCP unit_id and no zenoh writes \
                     ([zenoh] writes = true) can acknowledge its telegrams: only REST can \
                     (POST /api/v1/lines/{name}/telegrams/{{seq}}/ack); unacknowledged, the \
                     mailbox fills and the line refuses telegrams (08 0Ah). Set ack = \
                     \"on-publish\" to acknowledge on publication to zenoh"
                )
            }
            config::AckConfig::OnPublish if !zenoh_on => format!(
                "ack = \"on-publish\" but zenoh is off: nothing publishes, so nothing acknowledges \
                 lines.{name}'s telegrams; the mailbox fills and the line refuses telegrams (08 0Ah)"
            ),
            _ => continue,
        };
        warnings.push(issue(format!("lines.{name}.ack"), message));
    }
    warnings
}

/// The first names of a list, and how many more there are.
fn listed(names: &[&str]) -> String {
    const SHOWN: usize = 12;
    let mut text = names[..names.len().min(SHOWN)].join(", ");
    if names.len() > SHOWN {
        text.push_str(&format!(" and {} more", names.len() - SHOWN));
    }
    text
}

/// `gateway check --config FILE`: prints `ok: N lines, M devices`, or every issue on its own
/// line, to stdout; returns the exit code (0 valid, 1 not). The write paths open to every
/// address without credentials ([`security_warnings`]) follow on stderr, one
/// `warning: <path>: <message>` line each; they do not change the exit code.
pub fn check_command(path: &Path) -> i32 {
    let (text, code) = check_report(path);
    println!("{text}");
    if let Ok(config) = load_config(path) {
        for w in security_warnings(&config) {
            eprintln!("warning: {}: {}", w.path, w.message);
        }
    }
    code
}

/// The write paths of `config` open to every address without credentials, one warning each (at
/// the section that opens it). `check` prints them on stderr and `run` logs them;
/// neither refuses the configuration: the demo and a lab bench run like that on purpose.
pub fn security_warnings(config: &Config) -> Vec<ConfigIssue> {
    let mut warnings = Vec::new();
    let mut warn = |path: &str, message: String| warnings.push(issue(path, message));
    let tcp = &config.modbus_tcp;
    let reachable = |ip: std::net::IpAddr| !ip.is_loopback();
    if tcp.enabled
        && !tcp.read_only
        && tcp.allowed_networks.is_empty()
        && reachable(tcp.listen.ip())
    {
        warn(
            "modbus_tcp",
            format!(
                "plain Modbus TCP on {} takes writes from every address without \
             credentials; set allowed_networks, read_only or write_ranges, or serve \
             [modbus_tcp.tls] with enabled = false",
                tcp.listen
            ),
        );
    }
    let http = &config.http;
    if http.insecure_allow_unauthenticated_changes && reachable(http.listen.ip()) {
        warn(
            "http",
            format!(
            "changes without a token are allowed on {} (insecure_allow_unauthenticated_changes)",
            http.listen
        ),
        );
    }
    let has_token = http.token_source().is_some() || !http.tokens.is_empty();
    if has_token && http.tls.is_none() && reachable(http.listen.ip()) {
        warn(
            "http",
            format!(
                "the REST API on {} takes bearer tokens over plain HTTP: they cross the network \
                 in clear; serve [http.tls] or listen on loopback behind a TLS proxy",
                http.listen
            ),
        );
    }
    // One warning for the zenoh section, saying each way it is open.
    let mut zenoh_open = Vec::new();
    // zenoh is a write path only with `writes = true`.
    if let Some(zenoh) = config.zenoh.as_ref().filter(|z| z.enabled && z.writes) {
        let open: Vec<&str> = zenoh
            .listen
            .iter()
            .flatten()
            .map(config::Endpoint::as_str)
            .filter(|e| !endpoint_is_loopback(e))
            .collect();
        if !open.is_empty() && zenoh.config_file.is_none() {
            zenoh_open.push(format!(
                "`tx` and tag `set` keys take writes from every peer reaching {} without \
                 credentials; restrict them with zenoh's access_control (and TLS) in config_file",
                open.join(", ")
            ));
        }
    }
    if let Some(zenoh) = config.zenoh.as_ref().filter(|z| z.enabled) {
        if let Some(why) = unauthenticated_fabric(zenoh) {
            zenoh_open.push(format!(
                "any peer may join the fleet: {why}; without authentication any machine that \
                 reaches it can hold this gateway's name (gw/<name>) or answer as a gateway; use \
                 tls/ endpoints with enable_mtls and access_control by certificate name in \
                 config_file (docs/fleet.md, deploy/zenoh/)"
            ));
        }
    }
    if !zenoh_open.is_empty() {
        warn("zenoh", zenoh_open.join("; also "));
    }
    warnings
}

/// Why the zenoh fabric of `zenoh` does not authenticate its peers, when it does not: an
/// endpoint (listen or connect) beyond loopback that is not `tls/` or `quic/` with
/// `enable_mtls`, or multicast scouting on. `None` when every endpoint is on loopback, or every
/// one beyond it is mutual TLS. The settings are read as the bridge builds them (the zenoh file
/// with the section's keys over it); a file that does not load is reported elsewhere.
fn unauthenticated_fabric(zenoh: &config::ZenohConfig) -> Option<String> {
    let (z, mode) = zenoh.to_zenoh().ok()?;
    let mode = mode.as_str().to_owned();
    let endpoints = |key: &str| -> Vec<String> {
        let value: serde_json::Value = z
            .get_json(key)
            .ok()
            .and_then(|j| serde_json::from_str(&j).ok())
            .unwrap_or_default();
        // A list, or a list per role ({router: [...], peer: [...]}): the session's mode's.
        let list = match &value {
            serde_json::Value::Object(m) => m.get(&mode).cloned().unwrap_or_default(),
            other => other.clone(),
        };
        list.as_array()
            .into_iter()
            .flatten()
            .filter_map(serde_json::Value::as_str)
            .map(str::to_owned)
            .collect()
    };
    let mtls = z
        .get_json("transport/link/tls/enable_mtls")
        .is_ok_and(|v| v.trim() == "true");
    let mut all = endpoints("listen/endpoints");
    all.extend(endpoints("connect/endpoints"));
    let open: Vec<String> = all
        .into_iter()
        .filter(|e| !endpoint_is_loopback(e))
        .filter(|e| !(mtls && (e.starts_with("tls/") || e.starts_with("quic/"))))
        .collect();
    let scouting = z
        .get_json("scouting/multicast/enabled")
        .is_ok_and(|v| v.trim() == "true");
    match (open.is_empty(), scouting) {
        (true, false) => None,
        (false, _) => Some(format!(
            "{} beyond loopback without mutual TLS",
            open.join(", ")
        )),
        (true, true) => Some("multicast scouting is on".to_owned()),
    }
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

/// The keys of the file at `path` that take no effect ([`crate::plant::validate::ignored_keys`]);
/// none when it cannot be read or parsed (then the loader said so already).
pub fn ignored_keys_of(path: &Path) -> Vec<ConfigIssue> {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|text| text.parse::<toml::Table>().ok())
        .map(|table| crate::plant::validate::ignored_keys(&table))
        .unwrap_or_default()
}

/// What [`check_command`] prints, and its exit code: the counts or every problem (each with
/// its path), then every warning (`warning: <path>: <message>`).
pub fn check_report(path: &Path) -> (String, i32) {
    let config = match load_config(path) {
        Ok(c) => c,
        Err(e) => return (e.to_string(), 1),
    };
    let mut errors = run_issues(&config);
    let (port_errors, mut warnings) = port_issues(&config);
    warnings.extend(ignored_keys_of(path));
    warnings.extend(unpolled_tags(&config));
    warnings.extend(ack_warnings(&config));
    warnings.extend(persist_dir_warnings(&config));
    errors.extend(port_errors);
    let code = i32::from(!errors.is_empty());
    let mut text = if errors.is_empty() {
        format!(
            "ok: {} lines, {} devices",
            config.lines.len(),
            config.device_count()
        )
    } else {
        ConfigErrors { issues: errors }.to_string()
    };
    for w in &warnings {
        text.push_str(&format!("\nwarning: {}: {}", w.path, w.message));
    }
    (text, code)
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
    fn a_telegram_line_nothing_but_rest_can_acknowledge_is_warned_about() {
        let line = |keys: &str| {
            format!("[lines.r]\nport = \"/dev/ttyS1\"\nprotocol = \"3964r\"\n{keys}\n")
        };
        let zenoh = "[zenoh]\nlisten = [\"tcp/127.0.0.1:7447\"]\n";
        let warned = |text: String| {
            let config = crate::plant::parse(&text).expect("parses");
            ack_warnings(&config)
                .into_iter()
                .map(|w| (w.path, w.message))
                .collect::<Vec<_>>()
        };
        // No unit_id, no zenoh: explicit by default, and only REST can acknowledge.
        let w = warned(line(""));
        assert_eq!(w.len(), 1, "{w:?}");
        assert_eq!(w[0].0, "lines.r.ack");
        assert!(w[0].1.contains("only REST can"), "{}", w[0].1);
        // No unit_id, zenoh on: on-publish by default, nothing to warn about.
        assert_eq!(warned(format!("{}{zenoh}", line(""))), []);
        // Explicit on purpose with zenoh writes off: warned; with writes on: not.
        assert_eq!(
            warned(format!("{}{zenoh}", line("ack = \"explicit\""))).len(),
            1
        );
        assert_eq!(
            warned(format!(
                "{}{zenoh}writes = true\n",
                line("ack = \"explicit\"")
            )),
            []
        );
        // A Modbus TCP mailbox acknowledges.
        assert_eq!(warned(line("unit_id = 100")), []);
        // On-publish without zenoh: nothing publishes.
        let w = warned(line("ack = \"on-publish\""));
        assert!(w[0].1.contains("zenoh is off"), "{w:?}");
    }

    #[test]
    fn open_write_paths_are_warned_about() {
        let open = crate::plant::parse(
            "[modbus_tcp]\nlisten = \"0.0.0.0:502\"\n[http]\nlisten = \"0.0.0.0:8080\"\n\
             insecure_allow_unauthenticated_changes = true\n[zenoh]\nlisten = [\"tcp/0.0.0.0:7447\"]\nwrites = true\n",
        )
        .expect("parses");
        let warnings = security_warnings(&open);
        assert_eq!(warnings.len(), 3, "{warnings:#?}");
        // A token over plain HTTP off loopback; not with [http.tls], not on loopback.
        let token = |listen: &str, tls: &str| {
            crate::plant::parse(&format!(
                "[http]\nlisten = \"{listen}\"\ntoken_env = \"T\"\n{tls}"
            ))
            .expect("parses")
        };
        let http = |c: &Config| -> Vec<ConfigIssue> {
            security_warnings(c)
                .into_iter()
                .filter(|w| w.path == "http")
                .collect()
        };
        let clear = http(&token("0.0.0.0:8080", ""));
        assert_eq!(clear.len(), 1, "{clear:#?}");
        assert!(
            clear[0].message.contains("in clear"),
            "{}",
            clear[0].message
        );
        let tls = "[http.tls]\ncert = \"/c\"\nkey = \"/k\"\n";
        assert_eq!(http(&token("0.0.0.0:8080", tls)), Vec::new());
        assert_eq!(http(&token("127.0.0.1:8080", "")), Vec::new());
        let paths: Vec<&str> = warnings.iter().map(|w| w.path.as_str()).collect();
        assert_eq!(paths, ["modbus_tcp", "http", "zenoh"]);
        let closed = crate::plant::parse(
            "[modbus_tcp]\nlisten = \"0.0.0.0:502\"\nallowed_networks = [\"10.0.0.0/8\"]\n\
             [zenoh]\nlisten = [\"tcp/127.0.0.1:7447\"]\n",
        )
        .expect("parses");
        assert_eq!(security_warnings(&closed), Vec::<ConfigIssue>::new());
        // The demo's loopback listeners are not warned about.
        let demo = crate::plant::parse(crate::plant::demo_toml()).expect("demo parses");
        assert_eq!(security_warnings(&demo), Vec::<ConfigIssue>::new());
    }

    #[test]
    fn a_fabric_without_authentication_is_warned_about() {
        let zenoh = |section: &str| -> Vec<ConfigIssue> {
            let c = crate::plant::parse(&format!("[zenoh]\n{section}")).expect("parses");
            security_warnings(&c)
                .into_iter()
                .filter(|w| w.path == "zenoh")
                .collect()
        };
        let client = zenoh("mode = \"client\"\nconnect = [\"tcp/10.1.0.1:7447\"]\n");
        assert_eq!(client.len(), 1, "{client:#?}");
        assert!(
            client[0].message.contains("any peer may join the fleet")
                && client[0].message.contains("tcp/10.1.0.1:7447"),
            "{}",
            client[0].message
        );
        let listener = zenoh("listen = [\"tcp/0.0.0.0:7447\"]\n");
        assert!(
            listener[0].message.contains("tcp/0.0.0.0:7447"),
            "{listener:#?}"
        );
        let scouting = zenoh("multicast_scouting = true\n");
        assert!(
            scouting[0].message.contains("multicast scouting"),
            "{scouting:#?}"
        );
        assert_eq!(zenoh("listen = [\"tcp/127.0.0.1:7447\"]\n"), Vec::new());
        // tls/ with mutual TLS from the zenoh file: authenticated, no warning; without
        // enable_mtls the peers are not authenticated.
        let dir = tempfile::tempdir().expect("temp dir");
        let file = |mtls: bool| {
            let path = dir.path().join(format!("z{mtls}.json5"));
            std::fs::write(
                &path,
                format!(
                    "{{ transport: {{ link: {{ tls: {{ enable_mtls: {mtls}, \
                     root_ca_certificate: \"/etc/gateway/zenoh/ca.crt\" }} }} }} }}"
                ),
            )
            .expect("write");
            path
        };
        let tls = |path: &Path| {
            zenoh(&format!(
                "mode = \"client\"\nconnect = [\"tls/10.1.0.1:7448\"]\nconfig_file = \"{}\"\n",
                path.display()
            ))
        };
        assert_eq!(tls(&file(true)), Vec::new());
        assert_eq!(tls(&file(false)).len(), 1);
    }
}

#[cfg(test)]
mod tls_tests {
    use super::*;
    use crate::api::tls::http_tls_issues;

    #[test]
    fn https_files_are_loaded_as_run_loads_them() {
        let dir = tempfile::tempdir().unwrap();
        let key = rcgen::KeyPair::generate().unwrap();
        let cert = rcgen::CertificateParams::new(vec!["localhost".to_owned()])
            .unwrap()
            .self_signed(&key)
            .unwrap();
        let path = |name: &str| dir.path().join(name);
        std::fs::write(path("server.crt"), cert.pem()).unwrap();
        std::fs::write(path("server.key"), key.serialize_pem()).unwrap();
        std::fs::write(
            path("other.key"),
            rcgen::KeyPair::generate().unwrap().serialize_pem(),
        )
        .unwrap();
        let config = |cert: &str, key: &str, ca: Option<&str>| {
            let ca = ca
                .map(|ca| format!("ca = \"{}\"\n", path(ca).display()))
                .unwrap_or_default();
            crate::plant::parse(&format!(
                "[http.tls]\ncert = \"{}\"\nkey = \"{}\"\n{ca}",
                path(cert).display(),
                path(key).display(),
            ))
            .expect("parses")
        };
        assert_eq!(
            http_tls_issues(&config("server.crt", "server.key", None)),
            Vec::<ConfigIssue>::new()
        );
        // The self-signed certificate as the clients' CA.
        assert_eq!(
            http_tls_issues(&config("server.crt", "server.key", Some("server.crt"))),
            Vec::<ConfigIssue>::new()
        );
        for (c, k, ca, at) in [
            ("absent.crt", "server.key", None, "http.tls.cert"),
            ("server.crt", "absent.key", None, "http.tls.key"),
            (
                "server.crt",
                "server.key",
                Some("absent.crt"),
                "http.tls.ca",
            ),
            ("server.crt", "other.key", None, "http.tls"),
        ] {
            let issues = run_issues(&config(c, k, ca));
            assert_eq!(issues.len(), 1, "{issues:?}");
            assert_eq!(issues[0].path, at, "{issues:?}");
        }
    }
}

#[cfg(test)]
mod api_path_tests {
    use super::*;

    #[test]
    fn https_files_and_journals_a_rest_change_names_are_confined() {
        let dir = tempfile::tempdir().expect("temp dir");
        let text = |tls_dir: &str, journal: &str| {
            format!(
                "[gateway]\nconfig_dirs = [\"{d}/conf\"]\nstate_dirs = [\"{d}/state\"]\n\
                 [http.tls]\ncert = \"{tls_dir}/s.crt\"\nkey = \"{tls_dir}/s.key\"\n\
                 ca = \"{tls_dir}/ca.crt\"\n\
                 [lines.r]\nport = \"/dev/null\"\nprotocol = \"3964r\"\njournal = \"{journal}\"\n",
                d = dir.path().display()
            )
        };
        let in_force = crate::plant::parse(&text("/opt/tls", "/opt/r.journal")).expect("parses");
        // The paths in force were set by the host: not checked again, even outside.
        assert_eq!(api_path_issues(&in_force, &in_force), Vec::new());
        let changed = crate::plant::parse(&text("/etc/ssl", "/etc/r.journal")).expect("parses");
        let issues = api_path_issues(&changed, &in_force);
        let paths: Vec<&str> = issues.iter().map(|i| i.path.as_str()).collect();
        assert_eq!(
            paths,
            [
                "lines.r.journal",
                "http.tls.cert",
                "http.tls.key",
                "http.tls.ca"
            ],
            "{issues:#?}"
        );
        assert!(
            issues[0].message.contains("outside [gateway] state_dirs"),
            "{}",
            issues[0].message
        );
        assert!(
            issues[1].message.contains("outside [gateway] config_dirs"),
            "{}",
            issues[1].message
        );
        // Inside their directories: not refused by the confinement.
        let conf = dir.path().join("conf").display().to_string();
        let state = dir.path().join("state");
        std::fs::create_dir_all(&state).expect("mkdir");
        std::fs::create_dir_all(&conf).expect("mkdir");
        let journal = state.join("r.journal").display().to_string();
        let inside_dirs = crate::plant::parse(&text(&conf, &journal)).expect("parses");
        assert_eq!(api_path_issues(&inside_dirs, &in_force), Vec::new());
    }

    #[test]
    fn files_a_rest_change_names_are_confined_to_config_dirs_and_not_read() {
        let dir = tempfile::tempdir().expect("temp dir");
        let conf = dir.path().join("conf");
        std::fs::create_dir(&conf).expect("mkdir");
        let token = conf.join("api.token");
        std::fs::write(&token, "in-force-token-0123456789\n").expect("token");
        let text = |token_file: &str, zenoh_file: &str, tls_dir: &str| {
            format!(
                "[gateway]\nconfig_dirs = [\"{conf}\"]\n[http]\ntoken_file = \"{token_file}\"\n\
                 [http.tokens.ops]\nrole = \"operator\"\ntoken_file = \"{token_file}.ops\"\n\
                 [zenoh]\nconfig_file = \"{zenoh_file}\"\n\
                 [modbus_tcp.tls]\ncert = \"{tls_dir}/s.crt\"\nkey = \"{tls_dir}/s.key\"\nca = \"{tls_dir}/ca.crt\"\n",
                conf = conf.display()
            )
        };
        let in_force = crate::plant::parse(&text(
            &token.display().to_string(),
            "/opt/zenoh.json5",
            "/opt/tls",
        ))
        .expect("parses");
        // The paths in force were set by the host: not checked again, even outside.
        assert_eq!(api_path_issues(&in_force, &in_force), Vec::new());
        // Changed to paths outside config_dirs: every one refused at its key.
        let changed = crate::plant::parse(&text("/etc/shadow", "/etc/zenoh.json5", "/etc/ssl"))
            .expect("parses");
        let issues = api_path_issues(&changed, &in_force);
        let paths: Vec<&str> = issues.iter().map(|i| i.path.as_str()).collect();
        assert_eq!(
            paths,
            [
                "http.token_file",
                "http.tokens.ops.token_file",
                "zenoh.config_file",
                "modbus_tcp.tls.cert",
                "modbus_tcp.tls.key",
                "modbus_tcp.tls.ca",
            ],
            "{issues:#?}"
        );
        assert!(
            issues[0]
                .message
                .starts_with("/etc/shadow is outside [gateway] config_dirs"),
            "{}",
            issues[0].message
        );
        // The start checks do not open what was refused: the token issue is the confinement
        // alone (no read error of /etc/shadow), the zenoh and TLS files are not loaded.
        let all = start_issues(
            &changed,
            Door::Api {
                in_force: &in_force,
            },
        );
        assert_eq!(all, issues, "{all:#?}");
        // Inside config_dirs, a file that cannot be read is the start check's issue.
        let inside_dir = text(
            &conf.join("missing.token").display().to_string(),
            "/opt/zenoh.json5",
            "/opt/tls",
        );
        let changed = crate::plant::parse(&inside_dir).expect("parses");
        assert_eq!(api_path_issues(&changed, &in_force), Vec::new());
        let all = start_issues(
            &changed,
            Door::Api {
                in_force: &in_force,
            },
        );
        assert!(
            all.iter().any(|i| i.path == "http.token_file"
                && i.message.starts_with("cannot read the API token file")),
            "{all:#?}"
        );
        // The directories themselves cannot be widened over the API.
        let mut wider = in_force.clone();
        wider.gateway.config_dirs.push("/".into());
        let issues = api_path_issues(&wider, &in_force);
        assert_eq!(issues.len(), 1);
        assert_eq!(issues[0].path, "gateway.config_dirs");
    }
}

#[cfg(test)]
mod state_file_tests {
    //! The start check of journal and CP memory files against what `run` does with them: a
    //! config the check accepts opens at start, the check itself changes no file, and what it
    //! refuses is refused at the file's key.

    use super::*;
    use crate::cpmem;
    use proptest::prelude::*;
    use std::collections::BTreeMap;
    use std::path::PathBuf;

    /// What a configured path names.
    #[derive(Clone, Copy, Debug)]
    enum Kind {
        /// A new file in the state directory.
        New,
        /// An empty file (a journal or memory file not written yet).
        Empty,
        /// The state directory itself.
        Directory,
        /// A file in a directory that does not exist.
        MissingParent,
        /// A path under a regular file (ENOTDIR).
        UnderAFile,
        /// A directory that takes no new file (sysfs as root: EACCES; /proc: ENOENT). Tests may
        /// run as root, which a read-only permission does not stop.
        NoNewFiles,
        /// Another program's file.
        Foreign,
        /// A CP memory file.
        CpMemory,
        /// A journal with two telegrams waiting.
        Journal,
        /// The path in force (a journal the running line holds).
        InForce,
    }

    fn kind() -> impl Strategy<Value = Kind> {
        prop_oneof![
            Just(Kind::New),
            Just(Kind::Empty),
            Just(Kind::Directory),
            Just(Kind::MissingParent),
            Just(Kind::UnderAFile),
            Just(Kind::NoNewFiles),
            Just(Kind::Foreign),
            Just(Kind::CpMemory),
            Just(Kind::Journal),
            Just(Kind::InForce),
        ]
    }

    fn journal_bytes() -> Vec<u8> {
        use crate::mailbox::journal::{JournaledTelegram, Record, MAGIC};
        let mut bytes = MAGIC.to_vec();
        for seq in [7, 8] {
            Record::Telegram(JournaledTelegram {
                seq,
                received: std::time::UNIX_EPOCH,
                data: b"3964R 000007".to_vec(),
            })
            .encode(&mut bytes);
        }
        bytes
    }

    /// Makes what `kind` names for the file `name` in `state` and returns its path.
    fn make(state: &Path, name: &str, kind: Kind, no_new_files: &Path) -> PathBuf {
        let path = state.join(name);
        let write = |bytes: &[u8]| std::fs::write(&path, bytes).expect("write");
        match kind {
            Kind::New => {}
            Kind::Empty => write(b""),
            Kind::Directory => {
                std::fs::create_dir(&path).expect("mkdir");
            }
            Kind::MissingParent => return state.join("missing").join(name),
            Kind::UnderAFile => {
                write(b"a plain file");
                return path.join(name);
            }
            Kind::NoNewFiles => return no_new_files.join(format!("gateway-check-{name}")),
            Kind::Foreign => write(b"[gateway]\nname = \"x\"\n"),
            Kind::CpMemory => {
                let layout = proto_core::cpmem::MemoryLayout::default();
                let memory = proto_core::cpmem::CpMemory::new(&layout);
                write(&cpmem::persist::encode(&layout, &memory));
            }
            Kind::InForce if name.ends_with(".bin") => {
                return make(state, name, Kind::CpMemory, no_new_files);
            }
            Kind::Journal | Kind::InForce => write(&journal_bytes()),
        }
        path
    }

    /// Every file under `dir` with its bytes (a directory as its name only).
    fn tree(dir: &Path) -> BTreeMap<PathBuf, Option<Vec<u8>>> {
        let mut out = BTreeMap::new();
        let mut todo = vec![dir.to_owned()];
        while let Some(d) = todo.pop() {
            for entry in std::fs::read_dir(&d).expect("list") {
                let path = entry.expect("entry").path();
                if path.is_dir() {
                    out.insert(path.clone(), None);
                    todo.push(path);
                } else {
                    out.insert(path.clone(), Some(std::fs::read(&path).expect("read")));
                }
            }
        }
        out
    }

    fn config(state: &Path, a: &Path, b: &Path, persist: &Path) -> Config {
        crate::plant::parse(&format!(
            "[gateway]\nstate_dirs = [\"{state}\"]\n\
             [cp_memory]\npersist_file = \"{persist}\"\n\
             [lines.a]\nport = \"/dev/null\"\nprotocol = \"3964r\"\njournal = \"{a}\"\n\
             [lines.b]\nport = \"/dev/zero\"\nprotocol = \"ascii\"\njournal = \"{b}\"\n\
             [lines.s]\nport = \"/dev/full\"\nprotocol = \"modbus-slave-rtu\"\n",
            state = state.display(),
            a = a.display(),
            b = b.display(),
            persist = persist.display(),
        ))
        .expect("parses")
    }

    /// Whether `run` can use a journal of this kind.
    fn journal_usable(kind: Kind) -> bool {
        matches!(
            kind,
            Kind::New | Kind::Empty | Kind::Journal | Kind::InForce
        )
    }

    /// Whether `run` can use a CP memory file of this kind (in a missing directory: it starts
    /// zeroed and saves once the directory exists, so only `check` warns; a REST change cannot
    /// name one, being confined to existing directories).
    fn memory_usable(kind: Kind, api: bool) -> bool {
        matches!(
            kind,
            Kind::New | Kind::Empty | Kind::CpMemory | Kind::InForce
        ) || (matches!(kind, Kind::MissingParent) && !api)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        #[test]
        fn what_the_start_check_accepts_opens_and_the_check_changes_no_file(
            a in kind(), b in kind(), persist in kind(), api in any::<bool>(),
        ) {
            let dir = tempfile::tempdir().expect("dir");
            let state = dir.path().join("state");
            std::fs::create_dir(&state).expect("mkdir");
            // As root, sysfs refuses new files; otherwise /proc, which never takes one.
            let no_new_files = if std::fs::File::create("/sys/gateway-check-probe").is_err() {
                PathBuf::from("/sys")
            } else {
                let _ = std::fs::remove_file("/sys/gateway-check-probe");
                PathBuf::from("/proc")
            };
            let pa = make(&state, "a.journal", a, &no_new_files);
            let pb = make(&state, "b.journal", b, &no_new_files);
            let pp = make(&state, "cp-memory.bin", persist, &no_new_files);
            let new = config(&state, &pa, &pb, &pp);
            let in_force = |k: Kind, p: &Path, other: &str| {
                if matches!(k, Kind::InForce) { p.to_owned() } else { state.join(other) }
            };
            let old = config(
                &state,
                &in_force(a, &pa, "a-old.journal"),
                &in_force(b, &pb, "b-old.journal"),
                &in_force(persist, &pp, "cp-old.bin"),
            );
            let before = tree(dir.path());
            let issues = if api {
                start_issues(&new, Door::Api { in_force: &old })
            } else {
                start_issues(&new, Door::File)
            };
            // The check changes nothing, accepted or refused.
            prop_assert_eq!(&tree(dir.path()), &before);
            let at = |key: &str| issues.iter().any(|i| i.path == key);
            // Outside state_dirs (sysfs, /proc) a REST change is refused by the confinement.
            for (key, kind, usable) in [
                ("lines.a.journal", a, journal_usable(a)),
                ("lines.b.journal", b, journal_usable(b)),
                ("cp_memory.persist_file", persist, memory_usable(persist, api)),
            ] {
                prop_assert_eq!(at(key), !usable, "{} {:?}: {:#?}", key, kind, issues);
            }
            prop_assert_eq!(
                issues.iter().filter(|i| !i.path.ends_with(".journal")
                    && i.path != "cp_memory.persist_file").count(),
                0,
                "{:#?}", issues
            );
            // What the check accepts, run opens.
            if journal_usable(a) {
                prop_assert!(crate::mailbox::journal::Journal::open(&pa).is_ok());
            }
            if journal_usable(b) {
                prop_assert!(crate::mailbox::journal::Journal::open(&pb).is_ok());
            }
            if memory_usable(persist, api) {
                let layout = proto_core::cpmem::MemoryLayout::default();
                prop_assert!(cpmem::SharedCpMemory::open(layout, &pp).is_ok());
            }
        }
    }

    #[test]
    fn two_lines_naming_one_journal_or_the_memory_file_are_refused() {
        let dir = tempfile::tempdir().expect("dir");
        let state = dir.path();
        let one = state.join("one.journal");
        std::fs::write(&one, b"").expect("write");
        let link = state.join("link.journal");
        std::os::unix::fs::symlink(&one, &link).expect("symlink");
        let c = config(state, &one, &link, &state.join("cp.bin"));
        let issues = start_issues(&c, Door::File);
        assert_eq!(issues.len(), 1, "{issues:#?}");
        assert_eq!(issues[0].path, "lines.b.journal");
        assert!(
            issues[0].message.contains("lines.a.journal"),
            "{}",
            issues[0].message
        );
        let c = config(state, &one, &state.join("two.journal"), &one);
        let issues = start_issues(&c, Door::File);
        assert_eq!(issues.len(), 1, "{issues:#?}");
        assert_eq!(issues[0].path, "lines.a.journal");
        assert!(
            issues[0].message.contains("cp_memory.persist_file"),
            "{}",
            issues[0].message
        );
    }
}
