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

use super::reader::Cx;
use super::serial::SerialConfig;

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
