//! The gateway configuration (TOML): typed, validated at load time, every problem reported at once.
//!
//! ```toml
//! [gateway]
//! name = "plant-a"
//!
//! [modbus_tcp]
//! listen = "0.0.0.0:502"
//!
//! [lines.drive]                 # the line name: [a-z0-9_-], used in metric labels and zenoh keys
//! port = "/dev/ttyS1"
//! interface = "rs485"
//! baud = 19200
//! protocol = "modbus-master-rtu"
//!
//! [lines.drive.devices.atv71]
//! profile = "altivar71"
//! address = 2
//! ```
//!
//! The sections every part of the configuration shares (`[gateway]`, `[modbus_tcp]`,
//! `[cp_memory]`, `[http]`, `[zenoh]`, the serial keys of a line, devices, tags and templates),
//! with the defaults and ranges of their keys, the one reader (`reader::Fields`) and the one error
//! type ([`ConfigIssue`]). It names no protocol and imports no other module of the gateway: each
//! protocol's section lives in its folder under `protocols/`, and the document that holds them all
//! ([`crate::plant::Config`], read by [`crate::plant::parse`]) sits above both.
//! `deploy/gateway.example.toml` lists every key with its default and the manual section it comes
//! from. A `port` that starts with `pty:` (as in the embedded demo) names a pseudo-terminal that
//! `gateway demo` creates and puts in its place.

pub(crate) mod check;
mod cpmem;
mod device;
mod http;
pub(crate) mod reader;
pub(crate) mod section;
mod serial;
mod server;
pub(crate) mod tag;
pub(crate) mod template;
mod zenoh;

use std::fmt;
use std::path::PathBuf;

use serde::{Deserialize, Deserializer, Serialize};

pub use cpmem::*;
pub use device::*;
pub use http::*;
pub use section::{AckConfig, TelegramKeys};
pub use serial::*;
pub use server::*;
pub use tag::*;
pub use template::DEVICE_ONLY_KEYS as TEMPLATE_DEVICE_ONLY_KEYS;
// `self::`: the module, not the zenoh crate.
pub use self::zenoh::*;

pub(crate) use reader::Cx;
use reader::Fields;

/// `[gateway] name`: used as the zenoh prefix `gw/<name>` and in logs.
pub const DEFAULT_GATEWAY_NAME: &str = "gateway";
/// 003 7.3: "The diagnostic buffer is a ring buffer for a maximum of 9 diagnostic entries."
pub const DEFAULT_DIAG_BUFFER_DEPTH: u16 = 9;
/// Largest diagnostic buffer per line.
pub const MAX_DIAG_BUFFER_DEPTH: u16 = 1000;

pub fn default_gateway_name() -> String {
    DEFAULT_GATEWAY_NAME.to_owned()
}
pub fn default_diag_buffer_depth() -> u16 {
    DEFAULT_DIAG_BUFFER_DEPTH
}

/// The `[gateway]` section.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct GatewaySection {
    /// [a-z0-9_-], 1..=64 characters.
    pub name: String,
    /// Entries kept per line in the diagnostic buffer, newest first (003 7.3).
    pub diag_buffer_depth: u16,
    /// Directories a configuration change over the API may name a serial port in.
    pub port_dirs: Vec<PathBuf>,
    /// Directories a configuration change over the API may name a persistence file in.
    pub state_dirs: Vec<PathBuf>,
    /// Directories a configuration change over the API may name a file the gateway reads its
    /// settings or secrets from in: token files, the zenoh config file, TLS files.
    pub config_dirs: Vec<PathBuf>,
    /// Directories device templates are read from (`NAME.toml`), in order; a relative one is
    /// taken from the configuration file's directory.
    pub template_dirs: Vec<PathBuf>,
}

/// Default of `[gateway] port_dirs`: the device directory.
pub const DEFAULT_PORT_DIR: &str = "/dev";
/// Default of `[gateway] state_dirs`: the gateway's state directory (systemd `StateDirectory`).
pub const DEFAULT_STATE_DIR: &str = "/var/lib/gateway";
/// Default of `[gateway] config_dirs`: the gateway's configuration directory (systemd
/// `ConfigurationDirectory`, where deploy/ puts the token and TLS files).
pub const DEFAULT_CONFIG_DIR: &str = "/etc/gateway";

impl Default for GatewaySection {
    fn default() -> Self {
        Self {
            name: default_gateway_name(),
            diag_buffer_depth: DEFAULT_DIAG_BUFFER_DEPTH,
            port_dirs: vec![PathBuf::from(DEFAULT_PORT_DIR)],
            state_dirs: vec![PathBuf::from(DEFAULT_STATE_DIR)],
            config_dirs: vec![PathBuf::from(DEFAULT_CONFIG_DIR)],
            template_dirs: Vec::new(),
        }
    }
}

/// One problem in a configuration.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConfigIssue {
    /// Where: `lines.drive.baud`, `lines.kv.devices.ctrl.tags[2].scale`; empty for problems of
    /// the whole file (syntax, I/O).
    pub path: String,
    /// What is wrong, with the manual section where a rule comes from.
    pub message: String,
}

impl fmt::Display for ConfigIssue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.path.is_empty() {
            f.write_str(&self.message)
        } else {
            write!(f, "{}: {}", self.path, self.message)
        }
    }
}

/// Every problem found in a configuration.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConfigErrors {
    pub issues: Vec<ConfigIssue>,
}

impl fmt::Display for ConfigErrors {
    /// One line per issue: `path: message`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, issue) in self.issues.iter().enumerate() {
            if i > 0 {
                f.write_str("\n")?;
            }
            write!(f, "{issue}")?;
        }
        Ok(())
    }
}

impl std::error::Error for ConfigErrors {}

/// Reads one section through its reader, for the section types' `Deserialize`: unknown keys are
/// refused and every problem is reported, with paths under `path`.
fn read_section<'de, D, T>(
    deserializer: D,
    path: &str,
    read: fn(&mut Cx, Fields<'_>) -> T,
) -> Result<T, D::Error>
where
    D: Deserializer<'de>,
{
    let table = toml::Table::deserialize(deserializer)?;
    let mut cx = Cx::default();
    let section = read(&mut cx, Fields::new(&table, path.to_owned()));
    if cx.issues.is_empty() {
        Ok(section)
    } else {
        Err(serde::de::Error::custom(ConfigErrors { issues: cx.issues }))
    }
}

/// `syntax error at line L, column C: <what>`.
pub(crate) fn syntax_message(text: &str, e: &toml::de::Error) -> String {
    let what = e.message().trim().replace('\n', "; ");
    match e.span() {
        Some(span) => {
            let before = text.get(..span.start).unwrap_or(text);
            let line = before.matches('\n').count() + 1;
            let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
            let near = text
                .get(span.clone())
                .filter(|t| !t.is_empty() && t.len() <= 40 && !t.contains('\n'));
            match near {
                Some(t) => {
                    format!("TOML syntax error at line {line}, column {column}: {what} (at `{t}`)")
                }
                None => format!("TOML syntax error at line {line}, column {column}: {what}"),
            }
        }
        None => format!("TOML syntax error: {what}"),
    }
}
