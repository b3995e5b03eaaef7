//! The journals' checks: at start, each telegram line's journal opened as the line opens it
//! ([`super::probe`]) and named by no other line nor the CP memory file; through the REST API,
//! each confined to `[gateway] state_dirs` (a journal is written like the persistence file).

use std::path::PathBuf;

use crate::config::check::{resolved, ApiChange, Check, Start};
use crate::config::Cx;

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
            if let Err(message) = super::probe(path) {
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
