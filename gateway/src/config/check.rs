//! The one trait every check of a configuration implements, next to what it checks, and the
//! scopes it is asked in. A leaf: it knows no section.
//!
//! A key's own range is the reader's (`reader::Fields`). Everything that spans keys is a
//! [`Check`] of one scope, implemented where the thing checked lives: a protocol's section in
//! `config/<protocol>.rs` ([`Line`]), a device in `config/device/check.rs` ([`Device`]), a file a
//! configuration names by the part of the gateway that opens it ([`Start`]: the API tokens, the
//! TLS files, the zenoh file, the CP memory file, the journals, each line's start), and the
//! paths a REST change names by what they guard ([`ApiChange`]). The collectors only iterate:
//! `validate::check` over the lines' sections and devices, the app's `start_issues` over its
//! lists of start and path checks.

use std::path::{Path, PathBuf};

use super::reader::Cx;
use super::serial::SerialConfig;
use super::ConfigIssue;

/// A check of a configuration in scope `S`: the issues it finds go into `cx`, each with its
/// path.
pub(crate) trait Check<S> {
    /// Checks `self` in `scope`; a part without checks in a scope finds nothing.
    fn check(&self, _scope: &S, _cx: &mut Cx) {}
}

/// A line's protocol section as read, with the line's serial settings (timing minimums by baud
/// rate, the protocol against the interface).
pub(crate) struct Line<'a> {
    /// `lines.<name>`.
    pub(crate) path: &'a str,
    /// The line's serial settings.
    pub(crate) serial: &'a SerialConfig,
}

/// A device as read, at `lines.<line>.devices.<name>`.
pub(crate) struct Device<'a> {
    /// `lines.<line>.devices.<name>`.
    pub(crate) path: &'a str,
}

/// A file a change over the REST API names at `key`, confined to `allowed` (the `[gateway]`
/// key and its directories): an issue when `new` is set, is not `old` (the path in force, set
/// by the host) and does not lie inside one of the directories ([`inside`]).
pub(crate) fn confine(
    key: &str,
    new: Option<&Path>,
    old: Option<&Path>,
    (dirs_key, dirs): (&str, &[PathBuf]),
) -> Option<ConfigIssue> {
    let new = new?;
    if Some(new) == old || inside(new, dirs) {
        return None;
    }
    Some(issue(
        key,
        format!(
            "{} is outside [gateway] {dirs_key} {dirs:?}: a change over the API names this file \
             there only",
            new.display()
        ),
    ))
}

/// Whether `path` (resolved: symbolic links and `..` followed; a file that does not exist yet by
/// its directory) lies inside one of `dirs`.
pub(crate) fn inside(path: &Path, dirs: &[PathBuf]) -> bool {
    let Ok(resolved) = resolve(path) else {
        return false;
    };
    dirs.iter().any(|dir| {
        let dir = std::fs::canonicalize(dir).unwrap_or_else(|_| dir.clone());
        resolved.starts_with(dir)
    })
}

/// `path` resolved as [`inside`] resolves it, or as given when its directory does not exist
/// either.
pub(crate) fn resolved(path: &Path) -> PathBuf {
    resolve(path).unwrap_or_else(|_| path.to_owned())
}

/// `path` with symbolic links and `..` followed; a file that does not exist by its directory.
fn resolve(path: &Path) -> std::io::Result<PathBuf> {
    std::fs::canonicalize(path).or_else(|_| {
        let name = path.file_name().ok_or(std::io::ErrorKind::InvalidInput)?;
        std::fs::canonicalize(parent_dir(path)).map(|dir| dir.join(name))
    })
}

/// An issue at `path`.
pub(crate) fn issue(path: impl Into<String>, message: impl Into<String>) -> ConfigIssue {
    ConfigIssue {
        path: path.into(),
        message: message.into(),
    }
}

/// The directory a file `path` names lies in (`.` for a bare name).
pub(crate) fn parent_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// What a path that is not a regular file is, for a refusal.
pub(crate) fn not_regular(meta: &std::fs::Metadata) -> &'static str {
    if meta.is_dir() {
        "a directory"
    } else {
        "not a regular file (a device, pipe or socket)"
    }
}

/// Creates `path` (which must not exist) and removes it again: a start check leaves no file.
pub(crate) fn create_and_remove(path: &Path) -> std::io::Result<()> {
    drop(
        std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(path)?,
    );
    std::fs::remove_file(path)
}

/// Whether the directory of `path` takes a new file beside it, as `writer` writes one: the
/// check creates and removes `<path>.probe-<pid>`.
pub(crate) fn takes_new_file(path: &Path, writer: &str) -> Result<(), String> {
    let mut name = path.as_os_str().to_owned();
    name.push(format!(".probe-{}", std::process::id()));
    create_and_remove(Path::new(&name)).map_err(|e| {
        format!(
            "the directory of {} takes no new file ({writer} writes one): {e}",
            path.display()
        )
    })
}

/// A key that takes effect only with another key's value: `key` is ignored unless `needs` is
/// one of `values` (`default` when `needs` is not given). A key given at `key_default`, its
/// own default, says nothing the gateway does not do (deploy/gateway.example.toml lists every
/// key so); `None`: any value is reported (`end_chars = [0x03]` with the char-delay criterion
/// is the mistake of expecting ETX to end a telegram).
pub(crate) struct Needs {
    pub(crate) key: &'static str,
    pub(crate) key_default: Option<&'static str>,
    pub(crate) needs: &'static str,
    pub(crate) values: &'static [&'static str],
    pub(crate) default: &'static str,
}

pub(crate) const fn needs(
    key: &'static str,
    key_default: Option<&'static str>,
    needs: &'static str,
    values: &'static [&'static str],
    default: &'static str,
) -> Needs {
    Needs {
        key,
        key_default,
        needs,
        values,
        default,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_are_resolved_before_they_are_compared() {
        let dir = tempfile::tempdir().expect("temp dir");
        let state = dir.path().join("state");
        std::fs::create_dir(&state).expect("mkdir");
        let dirs = [state.clone()];
        assert!(
            inside(&state.join("cp.bin"), &dirs),
            "a new file in the directory"
        );
        assert!(!inside(&state.join("../cp.bin"), &dirs), "`..` out of it");
        assert!(!inside(Path::new("/etc/passwd"), &dirs));
        assert!(
            !inside(&state.join("missing/cp.bin"), &dirs),
            "no such directory"
        );
        // A link inside pointing outside is outside.
        let link = state.join("escape");
        std::os::unix::fs::symlink("/etc", &link).expect("symlink");
        assert!(!inside(&link.join("passwd"), &dirs));
        assert!(inside(Path::new("/dev/null"), &[PathBuf::from("/dev")]));
    }
}
