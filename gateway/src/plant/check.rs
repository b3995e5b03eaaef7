//! The checks of a whole configuration: the scopes that hold one ([`Start`]: what would keep
//! `run` from starting, through any door; [`ApiChange`]: the paths a REST change names) and the
//! checks of this layer's parts that walk it: the `[gateway]` directories, the serial ports, the
//! template directories, the zenoh file, the CP memory's file and exactness, the journals. They
//! sit here, above the protocols, because they read the lines of the configuration; the part
//! they guard keeps the probe that opens its file as `run` opens it
//! (`crate::cpmem::persist::probe`, `crate::mailbox::journal::probe`). The trait and the scopes
//! of one line or one device are `crate::config::check`'s.

use std::path::{Path, PathBuf};

use super::Config;
use crate::config::check::{confine, inside, issue, parent_dir, resolved, Check};
use crate::config::{no_such_port, PTY_PREFIX};
use crate::config::{ConfigIssue, Cx};
use crate::cpmem::persist::{missing_dir, probe};
use crate::protocols::modbus_slave::cpmem::check as cp_memory_check;

/// A whole configuration at start, through any door: what would keep `run` from starting (the
/// files it names opened as `run` opens them). A key in `refused` (its path outside the
/// directories a REST change may name) is not opened.
pub(crate) struct Start<'a> {
    /// The configuration checked.
    pub(crate) config: &'a Config,
    /// The keys the path checks of a REST change refused already.
    pub(crate) refused: &'a [String],
}

impl Start<'_> {
    /// Whether the path checks refused `key` (its file is then not opened).
    pub(crate) fn refused(&self, key: &str) -> bool {
        self.refused.iter().any(|p| p == key)
    }
}

/// A change over the REST API: the paths `new` names, confined to the directories the
/// `[gateway]` of `in_force` allows for them. A path that is the one in force (the host set it)
/// is not checked again. A new key that names a file confines it in its part's check.
pub(crate) struct ApiChange<'a> {
    /// The configuration the change makes.
    pub(crate) new: &'a Config,
    /// The configuration in force, which the change is made from.
    pub(crate) in_force: &'a Config,
}

impl ApiChange<'_> {
    /// A file written like the CP memory file, at `key`: confined to `state_dirs`.
    pub(crate) fn state_file(
        &self,
        cx: &mut Cx,
        key: &str,
        new: Option<&Path>,
        old: Option<&Path>,
    ) {
        let dirs = ("state_dirs", self.in_force.gateway.state_dirs.as_slice());
        cx.issues.extend(confine(key, new, old, dirs));
    }

    /// A file the gateway reads its settings or secrets from, at `key`: confined to
    /// `config_dirs`.
    pub(crate) fn config_file(
        &self,
        cx: &mut Cx,
        key: &str,
        new: Option<&Path>,
        old: Option<&Path>,
    ) {
        let dirs = ("config_dirs", self.in_force.gateway.config_dirs.as_slice());
        cx.issues.extend(confine(key, new, old, dirs));
    }
}

/// The directories of `[gateway]` that confine a REST change: changed only in the host's file.
pub(crate) struct GatewayDirs;

impl Check<ApiChange<'_>> for GatewayDirs {
    fn check(&self, change: &ApiChange<'_>, cx: &mut Cx) {
        let (new, old) = (&change.new.gateway, &change.in_force.gateway);
        for (key, new_dirs, old_dirs) in [
            ("gateway.port_dirs", &new.port_dirs, &old.port_dirs),
            ("gateway.state_dirs", &new.state_dirs, &old.state_dirs),
            ("gateway.config_dirs", &new.config_dirs, &old.config_dirs),
        ] {
            if new_dirs != old_dirs {
                cx.issue(
                    key,
                    "changed only in the configuration file on the host, not over the API",
                );
            }
        }
    }
}

/// The template directories a REST change adds: templates are read like the files of
/// settings, so each is confined to `[gateway] config_dirs`.
pub(crate) struct TemplateDirs;

impl Check<ApiChange<'_>> for TemplateDirs {
    fn check(&self, change: &ApiChange<'_>, cx: &mut Cx) {
        let known = &change.in_force.gateway.template_dirs;
        for (i, dir) in change.new.gateway.template_dirs.iter().enumerate() {
            if !known.contains(dir) {
                let key = format!("gateway.template_dirs[{i}]");
                let resolved = super::template_dir_resolved(dir);
                change.config_file(cx, &key, Some(&resolved), None);
            }
        }
    }
}

/// `[zenoh] config_file`: at start, the session's settings as the bridge builds them (the file
/// read and parsed, the section's keys applied on top: an unreadable or invalid file stops
/// `run`); through the REST API, the file confined to `[gateway] config_dirs`.
pub(crate) struct ZenohFile;

impl Check<Start<'_>> for ZenohFile {
    fn check(&self, start: &Start<'_>, cx: &mut Cx) {
        if start.refused("zenoh.config_file") {
            return;
        }
        let Some(zenoh) = start.config.zenoh.as_ref().filter(|z| z.enabled) else {
            return;
        };
        if let Err(e) = zenoh.to_zenoh() {
            let key = if zenoh.config_file.is_some() {
                "zenoh.config_file"
            } else {
                "zenoh"
            };
            cx.issue(key, e.to_string());
        }
    }
}

impl Check<ApiChange<'_>> for ZenohFile {
    fn check(&self, change: &ApiChange<'_>, cx: &mut Cx) {
        let file = |c: &Config| c.zenoh.as_ref().and_then(|z| z.config_file.clone());
        let (new, old) = (file(change.new), file(change.in_force));
        change.config_file(cx, "zenoh.config_file", new.as_deref(), old.as_deref());
    }
}

/// `[cp_memory] persist_file`: at start, the persisted CP memory opened as `run` opens it
/// before the slave lines start ([`probe`]); through the REST API, the file confined to
/// `[gateway] state_dirs`.
pub(crate) struct PersistFile;

impl Check<Start<'_>> for PersistFile {
    fn check(&self, start: &Start<'_>, cx: &mut Cx) {
        if !start.refused(PERSIST_KEY) {
            cx.issues.extend(persist_file_issues(start.config));
        }
    }
}

impl Check<ApiChange<'_>> for PersistFile {
    fn check(&self, change: &ApiChange<'_>, cx: &mut Cx) {
        let file = |c: &Config| c.cp_memory.persist_file.clone();
        let (new, old) = (file(change.new), file(change.in_force));
        change.state_file(cx, PERSIST_KEY, new.as_deref(), old.as_deref());
    }
}

/// The key of the persistence file.
const PERSIST_KEY: &str = "cp_memory.persist_file";

/// The persisted CP memory of a configuration with slave lines, opened as `run` opens it
/// ([`probe`]): a directory, a file that is not a CP memory file (no header: it is never
/// renamed or overwritten), a read-only directory or file system is an issue at
/// `cp_memory.persist_file`. A missing file is created and removed again. A missing directory
/// is not refused, as `run` does not refuse it (the memory starts zeroed, and saves are retried
/// until the directory exists: systemd's `StateDirectory=` makes it when the service starts);
/// `gateway check` warns about it ([`persist_dir_warnings`]). A REST change cannot name one
/// (`state_dirs` confines it to existing directories).
fn persist_file_issues(config: &Config) -> Vec<ConfigIssue> {
    let Some(path) = config
        .cp_memory
        .persist_file
        .as_ref()
        .filter(|_| serves_memory(config))
    else {
        return Vec::new();
    };
    if missing_dir(path) {
        return Vec::new();
    }
    probe(path)
        .err()
        .map(|m| issue(PERSIST_KEY, m))
        .into_iter()
        .collect()
}

/// Whether a line of `config` serves the CP memory.
fn serves_memory(config: &Config) -> bool {
    config
        .lines
        .values()
        .any(|l| l.protocol.cp_memory_slave().is_some())
}

/// `gateway check`'s warning about a CP memory file whose directory does not exist (yet).
pub(crate) fn persist_dir_warnings(config: &Config) -> Vec<ConfigIssue> {
    match &config.cp_memory.persist_file {
        Some(path) if serves_memory(config) && missing_dir(path) => vec![issue(
            PERSIST_KEY,
            format!(
                "the directory {} does not exist: the memory starts zeroed and every save fails \
                 (logged) until it exists (systemd's StateDirectory= makes it when the service \
                 starts)",
                parent_dir(path).display()
            ),
        )],
        _ => Vec::new(),
    }
}

/// What the CP memory cannot serve exactly in the slave lines of `config`, each issue with its
/// path (`lines.<line>.<key>`): the check the app hands the config reader
/// (`config::ExtraCheck`). A key the reader reported already (in `found`) is not reported twice.
pub(crate) fn config_issues(config: &Config, found: &[ConfigIssue]) -> Vec<ConfigIssue> {
    let mut issues: Vec<ConfigIssue> = Vec::new();
    for (name, line) in &config.lines {
        let Some(slave) = line.protocol.cp_memory_slave() else {
            continue;
        };
        for issue in cp_memory_check(slave) {
            let key = format!("lines.{name}.{}", issue.key);
            let known = |i: &ConfigIssue| i.path.starts_with(&key);
            if !found.iter().any(known) && !issues.iter().any(known) {
                issues.push(self::issue(key, issue.message));
            }
        }
    }
    issues
}

/// The serial ports a REST change names (`port`, `port_b`): a port that exists, not a demo
/// `pty:`, under `[gateway] port_dirs`.
pub(crate) struct SerialPorts;

impl Check<ApiChange<'_>> for SerialPorts {
    fn check(&self, change: &ApiChange<'_>, cx: &mut Cx) {
        let dirs = &change.in_force.gateway.port_dirs;
        for (name, line) in &change.new.lines {
            let old = change.in_force.lines.get(name);
            let ports = [
                (
                    "port",
                    Some(line.serial.port.as_str()),
                    old.map(|o| o.serial.port.as_str()),
                ),
                (
                    "port_b",
                    line.second_port(),
                    old.and_then(|o| o.second_port()),
                ),
            ];
            for (key, port, old_port) in ports {
                let Some(port) = port.filter(|p| !p.is_empty() && Some(*p) != old_port) else {
                    continue;
                };
                let path = format!("lines.{name}.{key}");
                if port.starts_with(PTY_PREFIX) {
                    cx.issue(
                        path,
                        "a pty: port is created by `gateway demo` at start only; name an \
                         existing port",
                    );
                } else if !Path::new(port).exists() {
                    cx.issue(path, no_such_port(port));
                } else if !inside(Path::new(port), dirs) {
                    cx.issue(
                        path,
                        format!(
                            "{port} is outside [gateway] port_dirs {dirs:?}: a change over the \
                             API names serial ports there only"
                        ),
                    );
                }
            }
        }
    }
}

/// The journals of the telegram lines.
pub(crate) struct Journals;

impl Check<Start<'_>> for Journals {
    /// A directory, a file that is not a journal (no header: never renamed or overwritten), a
    /// read-only directory or file system, a missing directory is an issue at
    /// `lines.<line>.journal`; so is a journal that another line or the CP memory file names
    /// too (resolved: links and `..` followed). A journal whose key the path checks refused is
    /// not opened.
    fn check(&self, start: &Start<'_>, cx: &mut Cx) {
        let config = start.config;
        let mut seen: Vec<(String, PathBuf)> = Vec::new();
        if let Some(persist) = &config.cp_memory.persist_file {
            seen.push(("cp_memory.persist_file".to_owned(), resolved(persist)));
        }
        for (name, line) in &config.lines {
            let Some(path) = line.journal() else {
                continue;
            };
            let key = format!("lines.{name}.journal");
            if start.refused(&key) {
                continue;
            }
            let here = resolved(path);
            if let Some((other, _)) = seen.iter().find(|(_, p)| *p == here) {
                cx.issue(
                    key,
                    format!(
                        "{} is the file {other} names too: every line needs its own journal, \
                         apart from the CP memory file",
                        path.display()
                    ),
                );
                continue;
            }
            seen.push((key.clone(), here));
            if let Err(message) = crate::mailbox::journal::probe(path) {
                cx.issue(key, message);
            }
        }
    }
}

impl Check<ApiChange<'_>> for Journals {
    fn check(&self, change: &ApiChange<'_>, cx: &mut Cx) {
        for (name, line) in &change.new.lines {
            let old = change.in_force.lines.get(name).and_then(|o| o.journal());
            change.state_file(cx, &format!("lines.{name}.journal"), line.journal(), old);
        }
    }
}
