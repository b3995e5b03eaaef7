//! The configuration file on disk, replaced atomically.
//!
//! A change made over the REST API is written so that a crash (power loss, `SIGKILL`) at any
//! moment leaves at `path` either the complete previous file or the complete new one, never a
//! mixture or an empty file:
//!
//! 1. the new text goes to a temporary file in the same directory (`.<name>.tmp`), which is
//!    flushed to the disk (`fsync`);
//! 2. the current file is linked (or, where links are refused, copied and flushed) to
//!    `.<name>.prev.tmp` and renamed over `<name>.prev`, so the previous version stays at hand;
//! 3. the temporary file is renamed over `path` (`rename(2)` replaces the name atomically);
//! 4. the directory is flushed, so that the renames themselves survive a power loss.
//!
//! A crash between steps 2 and 3 leaves `<name>.prev` equal to the current file; it is never
//! newer than it.
//!
//! A change is written into the file as the operator wrote it: comments, the order of tables and
//! keys and the keys left out stay; only what changed is written. The REST API keeps the text
//! ([`ConfigText`]) and merges the client's document into it ([`edit::merge_table`]: the
//! client's keys and order where the file had nothing, the file's spelling where the value is
//! the same). A file that cannot be edited so (missing, not TOML, or no longer the
//! configuration in force) is replaced by the whole new configuration.
//!
//! Only one writer may save at a time: [`ConfigStore::save_atomic`] holds an in-process lock, and
//! the gateway is the only process that writes its configuration. A temporary file left by a
//! crash is overwritten by the next save and never read.

use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError, Weak};

use crate::config::ConfigErrors;
use crate::plant::Config;

/// Where the running configuration is kept.
#[derive(Debug)]
pub struct ConfigStore {
    /// The configuration file.
    path: PathBuf,
    /// Serializes the writers of this store.
    write_lock: Mutex<()>,
}

/// The configuration as its operator wrote it: the TOML text (comments, order, spelling, the keys
/// left out) and the configuration it reads as. `GET /config` shows it; a change over the REST
/// API edits it ([`edit::merge_table`]) and writes it to the file.
///
/// The configuration is the one in force, shared (a large one holds every tag of every device:
/// one copy in the process), and the text is shared by the clones: a clone costs two counts.
#[derive(Debug, Clone)]
pub struct ConfigText {
    text: PackedText,
    config: Arc<Config>,
}

/// A [`ConfigText`] kept aside without holding its configuration: when that configuration is
/// no longer in force (replaced by a SIGHUP re-read or a change), it is freed, and the text is
/// read again to follow the one in force.
#[derive(Debug, Clone)]
pub struct KeptText {
    text: PackedText,
    config: Weak<Config>,
}

/// The operator's text as the process keeps it: LZ4-compressed, shared by the clones. The text
/// is read only when `GET /config` shows it or a change edits it, while a large configuration's
/// text stays for the life of the process: 100 000 tags are a 6 MB file, about a tenth of the
/// memory one gateway may take (docs/benchmarks.md, the ceiling rows); packed, a few hundred KB.
#[derive(Clone, PartialEq, Eq)]
struct PackedText(Arc<[u8]>);

// === impl PackedText ===

impl PackedText {
    fn new(text: &str) -> Self {
        Self(lz4_flex::compress_prepend_size(text.as_bytes()).into())
    }

    /// The text. Only texts packed by [`Self::new`] exist, so unpacking cannot fail; were the
    /// bytes ever damaged, the answer is an empty text (which reads as no configuration) rather
    /// than a panic.
    fn unpack(&self) -> String {
        lz4_flex::decompress_size_prepended(&self.0)
            .ok()
            .and_then(|bytes| String::from_utf8(bytes).ok())
            .unwrap_or_default()
    }
}

impl std::fmt::Debug for PackedText {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "PackedText({} bytes packed)", self.0.len())
    }
}

// === impl ConfigText ===

impl ConfigText {
    /// `text` when it reads as `config`; otherwise `text` with only what differs written into it
    /// (e.g. the demo's `pty:` placeholders replaced by the ports it made); `config` written out
    /// whole when `text` is not a configuration.
    pub fn new(text: &str, config: &Arc<Config>) -> Self {
        match crate::plant::parse(text) {
            Ok(read) if read == **config => Self {
                text: PackedText::new(text),
                config: Arc::clone(config),
            },
            Ok(read) => {
                let edited = toml::Table::try_from(&read)
                    .ok()
                    .zip(toml::Table::try_from(&**config).ok())
                    .and_then(|(old, new)| edit::edit_in_place(text, &old, &new))
                    .filter(|edited| crate::plant::parse(edited).is_ok_and(|c| c == **config));
                match edited {
                    Some(text) => Self {
                        text: PackedText::new(&text),
                        config: Arc::clone(config),
                    },
                    None => Self::of(config),
                }
            }
            Err(_) => Self::of(config),
        }
    }

    /// `text` if it reads as `config` (and nothing else).
    pub fn read(text: String, config: &Arc<Config>) -> Option<Self> {
        crate::plant::parse(&text).ok().filter(|c| c == &**config)?;
        Some(Self {
            text: PackedText::new(&text),
            config: Arc::clone(config),
        })
    }

    /// `config` written out whole (every key, defaults included): for a configuration that was
    /// never text.
    pub fn of(config: &Arc<Config>) -> Self {
        Self {
            text: PackedText::new(&toml::to_string(&**config).unwrap_or_default()),
            config: Arc::clone(config),
        }
    }

    /// An edited document and the configuration it reads as (the caller read it).
    pub(crate) fn edited(doc: &toml_edit::DocumentMut, config: Arc<Config>) -> Self {
        Self {
            text: PackedText::new(&doc.to_string()),
            config,
        }
    }

    /// The TOML text (unpacked for the caller).
    pub fn text(&self) -> String {
        self.text.unpack()
    }

    /// The configuration it reads as.
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// This text kept aside without its configuration ([`KeptText`]).
    pub fn keep(&self) -> KeptText {
        KeptText {
            text: self.text.clone(),
            config: Arc::downgrade(&self.config),
        }
    }

    /// The text as a document to edit or show.
    pub fn document(&self) -> toml_edit::DocumentMut {
        self.text.unpack().parse().unwrap_or_else(|_| {
            // Only texts that read as a configuration are kept; this is never reached.
            toml_edit::DocumentMut::new()
        })
    }
}

impl PartialEq for ConfigText {
    fn eq(&self, other: &Self) -> bool {
        self.text == other.text
            && (Arc::ptr_eq(&self.config, &other.config) || self.config == other.config)
    }
}

// === impl KeptText ===

impl KeptText {
    /// The TOML text (unpacked for the caller).
    pub fn text(&self) -> String {
        self.text.unpack()
    }

    /// The kept text, when the configuration it reads as is `in_force` (still in force, or an
    /// equal one).
    pub fn reading_as(&self, in_force: &Arc<Config>) -> Option<ConfigText> {
        let config = self.config.upgrade()?;
        (Arc::ptr_eq(&config, in_force) || config == *in_force).then(|| ConfigText {
            text: self.text.clone(),
            config: Arc::clone(in_force),
        })
    }

    /// This text, or (when the configuration in force is no longer the one it reads as) this
    /// text edited to read as `in_force`.
    pub fn following(&self, in_force: &Arc<Config>) -> ConfigText {
        self.reading_as(in_force)
            .unwrap_or_else(|| ConfigText::new(&self.text.unpack(), in_force))
    }
}

/// What failed while saving; the file at the store's path is unchanged unless the error says the
/// new file is in place.
#[derive(Debug, thiserror::Error)]
pub enum PersistError {
    #[error("cannot serialize the configuration: {0}")]
    Serialize(String),
    #[error("{step} {}: {source}", path.display())]
    Io {
        /// What was being done.
        step: &'static str,
        /// The file concerned.
        path: PathBuf,
        source: io::Error,
    },
}

// === impl ConfigStore ===

impl ConfigStore {
    /// A store for the file at `path` (which need not exist yet).
    pub fn new(path: impl Into<PathBuf>) -> Self {
        Self {
            path: path.into(),
            write_lock: Mutex::new(()),
        }
    }

    /// The configuration file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Where the version before the last save is kept: `<file>.prev`.
    pub fn previous_path(&self) -> PathBuf {
        sibling(&self.path, "", ".prev")
    }

    /// The file's text, if it can be read.
    pub fn read_text(&self) -> Option<String> {
        fs::read_to_string(&self.path).ok()
    }

    /// Reads, parses and validates the configuration file.
    pub fn load(&self) -> Result<Config, ConfigErrors> {
        crate::plant::load(&self.path)
    }

    /// Reads, parses and validates the version before the last save.
    pub fn load_previous(&self) -> Result<Config, ConfigErrors> {
        crate::plant::load(&self.previous_path())
    }

    /// Writes `config` as TOML in place of the file (see the module documentation).
    pub fn save(&self, config: &Config) -> Result<(), PersistError> {
        let text = toml::to_string(config).map_err(|e| PersistError::Serialize(e.to_string()))?;
        self.save_atomic(&text)
    }

    /// Writes `text` in place of the file, keeping the current file as `<file>.prev`.
    pub fn save_atomic(&self, text: &str) -> Result<(), PersistError> {
        let _guard = self
            .write_lock
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let dir = parent_dir(&self.path);
        let tmp = sibling(&self.path, ".", ".tmp");
        write_synced(&tmp, text.as_bytes(), permissions_of(&self.path))?;
        if self.path.exists() {
            self.keep_previous()?;
        }
        fs::rename(&tmp, &self.path).map_err(io_err("cannot rename over", &self.path))?;
        sync_dir(&dir)
    }

    /// Puts the current file at `<file>.prev` without a moment where `.prev` is incomplete.
    fn keep_previous(&self) -> Result<(), PersistError> {
        let prev = self.previous_path();
        let prev_tmp = sibling(&self.path, ".", ".prev.tmp");
        match fs::remove_file(&prev_tmp) {
            Ok(()) => {}
            Err(e) if e.kind() == io::ErrorKind::NotFound => {}
            Err(e) => return Err(io_err("cannot remove", &prev_tmp)(e)),
        }
        if fs::hard_link(&self.path, &prev_tmp).is_err() {
            // A file system without hard links: a copy, flushed before it takes the name.
            let text = fs::read(&self.path).map_err(io_err("cannot read", &self.path))?;
            write_synced(&prev_tmp, &text, permissions_of(&self.path))?;
        }
        fs::rename(&prev_tmp, &prev).map_err(io_err("cannot rename over", &prev))
    }
}

/// `<dir>/<prefix><file name><suffix>`.
fn sibling(path: &Path, prefix: &str, suffix: &str) -> PathBuf {
    let name = path
        .file_name()
        .map_or_else(|| "config".into(), |n| n.to_string_lossy().into_owned());
    parent_dir(path).join(format!("{prefix}{name}{suffix}"))
}

/// The directory of `path` (`.` for a bare file name).
fn parent_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

fn io_err(step: &'static str, path: &Path) -> impl FnOnce(io::Error) -> PersistError {
    let path = path.to_path_buf();
    move |source| PersistError::Io { step, path, source }
}

/// The permissions of the file at `path`, if it exists.
fn permissions_of(path: &Path) -> Option<fs::Permissions> {
    fs::metadata(path).ok().map(|m| m.permissions())
}

/// Creates or truncates `path`, writes `bytes` and flushes them to the disk.
fn write_synced(
    path: &Path,
    bytes: &[u8],
    permissions: Option<fs::Permissions>,
) -> Result<(), PersistError> {
    let mut file = OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .open(path)
        .map_err(io_err("cannot create", path))?;
    if let Some(p) = permissions {
        file.set_permissions(p)
            .map_err(io_err("cannot set permissions of", path))?;
    }
    file.write_all(bytes)
        .map_err(io_err("cannot write", path))?;
    file.sync_all().map_err(io_err("cannot flush", path))
}

/// Flushes the directory entry changes (the renames) of `dir` to the disk.
fn sync_dir(dir: &Path) -> Result<(), PersistError> {
    #[cfg(unix)]
    {
        File::open(dir)
            .and_then(|d| d.sync_all())
            .map_err(io_err("cannot flush directory", dir))
    }
    #[cfg(not(unix))]
    {
        // Directories cannot be opened for flushing here; the rename is still atomic.
        let _ = (dir, File::open);
        Ok(())
    }
}

pub(crate) mod edit;

#[cfg(test)]
mod tests;
