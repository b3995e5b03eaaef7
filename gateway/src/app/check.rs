//! The checks of a configuration that need other parts of the gateway, with the config reader's
//! own rules: what `gateway check` and `gateway run` report, and what the REST API refuses.
//!
//! The reader (`config`) knows the keys, their ranges and the rules between keys. Whether the
//! CP memory can serve a slave line exactly is the CP memory's knowledge (`cpmem::config`): its
//! write limits are one byte range for M, one for Q and one range of DB numbers (003 6.4.5
//! "Limits"), so a write enable inside a byte or a DB is refused here, never silently widened.
//!
//! `gateway run` refuses more than the file's rules: the REST API's token must be readable and
//! at least 16 visible characters, a line must be startable (telegram settings, CP memory), the
//! zenoh settings must load (its `config_file` included) and a persisted CP memory file must be
//! readable ([`run_issues`], exit 64 before any port opens). `gateway check` reports all of
//! that, and also opens every RS485 line's port as the line would and closes it again: a port
//! whose driver refuses RS485 mode (a pseudo-terminal, a UART without RS485 support) never
//! works, so it is an error; a port that cannot be opened now (not plugged in, in use) is a
//! warning, because the running line opens it again with back-off.
//!
//! Exit codes: `gateway check` 0 (valid, warnings may be printed) or 1 (problems); `gateway run`
//! 64 (the configuration is refused: file, token, line settings, zenoh or CP memory file) or 70
//! (anything else).

use std::path::Path;

use crate::api::{Auth, TokenError};
use crate::config::{self, Config, ConfigErrors, ConfigIssue, Interface, ProtocolConfig};
use crate::config::{HttpConfig, TokenSource};
use crate::cpmem;
use crate::serial::{self, OpenError};

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

/// What `gateway run` refuses in `config` beyond the file's own rules: the REST API token (read
/// from its file or variable, at least 16 visible characters), what would keep a line from
/// starting, the zenoh settings (`config_file` included) and an unreadable persisted CP memory
/// file. Run exits 64 on any of them before a port is opened.
pub fn run_issues(config: &Config) -> Vec<ConfigIssue> {
    let mut issues = token_issues(&config.http, |name| std::env::var(name).ok());
    issues.extend(super::lines::start_issues(config, None));
    issues.extend(zenoh_issues(config));
    issues.extend(cp_memory_issues(config));
    issues.extend(tls_issues(config));
    issues
}

/// Modbus/TCP Security's files read and made into TLS settings as `run` makes them at start
/// (certificate chain, private key matching it, client CA): a missing, unreadable or unusable
/// file is an issue at its key, with the path.
fn tls_issues(config: &Config) -> Vec<ConfigIssue> {
    let Some(tls) = config.modbus_tcp.tls.as_ref() else {
        return Vec::new();
    };
    match crate::modbus_tcp::TlsServer::new(super::tls::files(tls), super::tls::roles(tls)) {
        Ok(_) => Vec::new(),
        Err(e) => {
            let key = match &e {
                crate::modbus_tcp::TlsError::File { what, .. } => match *what {
                    "certificate" => "modbus_tcp.tls.cert",
                    "private key" => "modbus_tcp.tls.key",
                    _ => "modbus_tcp.tls.ca",
                },
                crate::modbus_tcp::TlsError::Settings(_) => "modbus_tcp.tls",
            };
            vec![ConfigIssue {
                path: key.to_owned(),
                message: format!("Modbus/TCP Security: {e}"),
            }]
        }
    }
}

/// The zenoh session's settings as the bridge builds them at start: `config_file` read and
/// parsed, the section's keys applied on top (an unreadable or invalid file stops `run`).
fn zenoh_issues(config: &Config) -> Vec<ConfigIssue> {
    let Some(zenoh) = config.zenoh.as_ref().filter(|z| z.enabled) else {
        return Vec::new();
    };
    match zenoh.to_zenoh() {
        Ok(_) => Vec::new(),
        Err(e) => vec![ConfigIssue {
            path: if zenoh.config_file.is_some() {
                "zenoh.config_file".to_owned()
            } else {
                "zenoh".to_owned()
            },
            message: e.to_string(),
        }],
    }
}

/// The persisted CP memory, which `run` loads before the slave lines start: a file that exists
/// but cannot be read stops it (a missing file starts zeroed, a damaged one is moved aside).
fn cp_memory_issues(config: &Config) -> Vec<ConfigIssue> {
    let serves_memory = config
        .lines
        .values()
        .any(|l| matches!(l.protocol, ProtocolConfig::ModbusSlaveRtu(_)));
    let Some(path) = config
        .cp_memory
        .persist_file
        .as_ref()
        .filter(|_| serves_memory)
    else {
        return Vec::new();
    };
    match std::fs::File::open(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => vec![ConfigIssue {
            path: "cp_memory.persist_file".to_owned(),
            message: format!("cannot read {}: {e}", path.display()),
        }],
        _ => Vec::new(),
    }
}

/// The token of `[http]` as run reads it, with `env` for the process environment.
pub(crate) fn token_issues(
    http: &HttpConfig,
    env: impl Fn(&str) -> Option<String>,
) -> Vec<ConfigIssue> {
    match Auth::from_config_with(http, env) {
        Ok(_) => Vec::new(),
        Err(e) => vec![token_issue(http, &e)],
    }
}

/// A token error as an issue at the key that names the token's source.
pub(crate) fn token_issue(http: &HttpConfig, e: &TokenError) -> ConfigIssue {
    let path = match e {
        TokenError::Named { name, .. } => {
            let key = match http.tokens.get(name).and_then(|t| t.source()) {
                Some(TokenSource::Env(_)) => "token_env",
                _ => "token_file",
            };
            format!("http.tokens.{name}.{key}")
        }
        TokenError::Duplicate(..) => "http.tokens".to_owned(),
        _ => match http.token_source() {
            Some(TokenSource::Env(_)) => "http.token_env".to_owned(),
            _ => "http.token_file".to_owned(),
        },
    };
    ConfigIssue {
        path,
        message: e.to_string(),
    }
}

/// Opens every RS485 line's port with its settings and closes it again: a refused RS485 mode is
/// an error (the line could never work), a port that cannot be opened now a warning (the line
/// opens it again with back-off).
pub fn port_issues(config: &Config) -> (Vec<ConfigIssue>, Vec<ConfigIssue>) {
    let (mut errors, mut warnings) = (Vec::new(), Vec::new());
    for (name, line) in &config.lines {
        if !matches!(line.serial.interface, Interface::Rs485) {
            continue;
        }
        let path = format!("lines.{name}.port");
        match serial::probe(&super::build::port_settings(&line.serial)) {
            Ok(()) => {}
            Err(e @ (OpenError::Rs485Refused { .. } | OpenError::Flags { .. })) => {
                errors.push(ConfigIssue {
                    path: format!("lines.{name}.interface"),
                    message: e.to_string(),
                });
            }
            Err(e @ OpenError::Open { .. }) => warnings.push(ConfigIssue {
                path,
                message: format!(
                    "{e}; RS485 mode not tested (the line opens the port again with back-off)"
                ),
            }),
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
        if line.protocol.kind() == config::ProtocolKind::ModbusRtuTap {
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
                .filter(|e| &e.line == line_name && &e.device == device_name)
            {
                let tag = &entry.tag;
                if polled(&tag.name, tag.table, tag.address, tag.words()) {
                    continue;
                }
                match device.tags.iter().position(|t| t.name == tag.name) {
                    Some(i) => warnings.push(ConfigIssue {
                        path: format!("{path}.tags[{i}]"),
                        message: format!(
                            "tag {:?} is read by no poll group: it is read from the device only on demand and never published on change",
                            tag.name
                        ),
                    }),
                    None => from_profile.push(tag.name.as_str()),
                }
            }
            if !from_profile.is_empty() {
                warnings.push(ConfigIssue {
                    path: format!("{path}.poll"),
                    message: format!(
                        "{} tags of the profile are read by no poll group (read on demand only, never published on change): {}",
                        from_profile.len(),
                        listed(&from_profile)
                    ),
                });
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
        if !matches!(
            line.protocol,
            ProtocolConfig::Proc3964(_) | ProtocolConfig::Ascii(_)
        ) {
            continue;
        }
        // A client other than REST that can acknowledge: a Modbus TCP mailbox or zenoh writes.
        let client = (modbus_on && line.unit_id().is_some()) || zenoh_writes;
        let message = match config::ack_mode(config, line) {
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
        warnings.push(ConfigIssue {
            path: format!("lines.{name}.ack"),
            message,
        });
    }
    warnings
}

/// The first names of a list, and how many more there are.
fn listed(names: &[&str]) -> String {
    const SHOWN: usize = 12;
    let mut text = names
        .iter()
        .take(SHOWN)
        .copied()
        .collect::<Vec<_>>()
        .join(", ");
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
    let mut warn = |path: &str, message: String| {
        warnings.push(ConfigIssue {
            path: path.to_owned(),
            message,
        });
    };
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
            warn(
                "zenoh",
                format!(
                    "`tx` and tag `set` keys take writes from every peer reaching {} without \
                 credentials; restrict them with zenoh's access_control (and TLS) in config_file",
                    open.join(", ")
                ),
            );
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

/// What [`check_command`] prints, and its exit code: the counts or every problem (each with
/// its path), then every warning (`warning: <path>: <message>`).
pub fn check_report(path: &Path) -> (String, i32) {
    let config = match load_config(path) {
        Ok(c) => c,
        Err(e) => return (e.to_string(), 1),
    };
    let mut errors = run_issues(&config);
    let (port_errors, mut warnings) = port_issues(&config);
    warnings.extend(unpolled_tags(&config));
    warnings.extend(ack_warnings(&config));
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
            let config = config::parse(&text).expect("parses");
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
        let open = config::parse(
            "[modbus_tcp]\nlisten = \"0.0.0.0:502\"\n[http]\nlisten = \"0.0.0.0:8080\"\n\
             insecure_allow_unauthenticated_changes = true\n[zenoh]\nlisten = [\"tcp/0.0.0.0:7447\"]\nwrites = true\n",
        )
        .expect("parses");
        let warnings = security_warnings(&open);
        assert_eq!(warnings.len(), 3, "{warnings:#?}");
        let paths: Vec<&str> = warnings.iter().map(|w| w.path.as_str()).collect();
        assert_eq!(paths, ["modbus_tcp", "http", "zenoh"]);
        let closed = config::parse(
            "[modbus_tcp]\nlisten = \"0.0.0.0:502\"\nallowed_networks = [\"10.0.0.0/8\"]\n\
             [zenoh]\nlisten = [\"tcp/127.0.0.1:7447\"]\n",
        )
        .expect("parses");
        assert_eq!(security_warnings(&closed), Vec::<ConfigIssue>::new());
        // The demo's loopback listeners are not warned about.
        let demo = config::parse(config::demo_toml()).expect("demo parses");
        assert_eq!(security_warnings(&demo), Vec::<ConfigIssue>::new());
    }
}

#[cfg(test)]
mod token_tests {
    use super::*;

    #[test]
    fn modbus_tcp_security_files_are_loaded_as_run_loads_them() {
        let dir = tempfile::tempdir().unwrap();
        let ca_key = rcgen::KeyPair::generate().unwrap();
        let mut ca_params = rcgen::CertificateParams::new(Vec::<String>::new()).unwrap();
        ca_params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
        let ca = ca_params.self_signed(&ca_key).unwrap();
        let key = rcgen::KeyPair::generate().unwrap();
        let cert = rcgen::CertificateParams::new(vec!["localhost".to_owned()])
            .unwrap()
            .self_signed(&key)
            .unwrap();
        let path = |name: &str| dir.path().join(name);
        std::fs::write(path("ca.crt"), ca.pem()).unwrap();
        std::fs::write(path("server.crt"), cert.pem()).unwrap();
        std::fs::write(path("server.key"), key.serialize_pem()).unwrap();
        std::fs::write(path("empty.crt"), "").unwrap();
        let config = |cert: &str, key: &str, ca: &str| {
            config::parse(&format!(
                "[modbus_tcp.tls]\ncert = \"{}\"\nkey = \"{}\"\nca = \"{}\"\n",
                path(cert).display(),
                path(key).display(),
                path(ca).display()
            ))
            .expect("parses")
        };
        assert_eq!(
            tls_issues(&config("server.crt", "server.key", "ca.crt")),
            Vec::<ConfigIssue>::new()
        );
        for (c, k, a, at, file) in [
            (
                "absent.crt",
                "server.key",
                "ca.crt",
                "modbus_tcp.tls.cert",
                "absent.crt",
            ),
            (
                "server.crt",
                "absent.key",
                "ca.crt",
                "modbus_tcp.tls.key",
                "absent.key",
            ),
            (
                "server.crt",
                "server.key",
                "absent.crt",
                "modbus_tcp.tls.ca",
                "absent.crt",
            ),
            (
                "server.crt",
                "server.key",
                "empty.crt",
                "modbus_tcp.tls.ca",
                "empty.crt",
            ),
        ] {
            let issues = tls_issues(&config(c, k, a));
            assert_eq!(issues.len(), 1, "{issues:?}");
            assert_eq!(issues[0].path, at);
            assert!(issues[0].message.contains(file), "{}", issues[0].message);
        }
        // run refuses the same before a port opens.
        let issues = run_issues(&config("server.crt", "absent.key", "ca.crt"));
        assert!(
            issues.iter().any(|i| i.path == "modbus_tcp.tls.key"),
            "{issues:?}"
        );
    }

    #[test]
    fn a_named_token_that_cannot_be_read_is_an_issue_at_its_key() {
        let http = config::parse(
            "[http.tokens.ops]\nrole = \"operator\"\ntoken_env = \"OPS\"\n\
             [http.tokens.eng]\nrole = \"admin\"\ntoken_file = \"/nonexistent/eng.token\"\n",
        )
        .expect("parses")
        .http;
        let issues = token_issues(&http, |_| Some("ops-token-0123456789".to_owned()));
        assert_eq!(issues.len(), 1, "{issues:?}");
        assert_eq!(issues[0].path, "http.tokens.eng.token_file");
        assert!(
            issues[0].message.contains("/nonexistent/eng.token"),
            "{}",
            issues[0].message
        );
        let issues = token_issues(&http, |_| None);
        assert_eq!(issues[0].path, "http.tokens.eng.token_file");
    }
}
