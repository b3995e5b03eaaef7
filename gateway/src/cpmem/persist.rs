//! Keeping the CP memory across restarts: a small binary file, written atomically (temporary file,
//! fsync, rename, fsync of the directory), loaded at start and saved periodically and at shutdown.
//!
//! A real CPU keeps its retentive memory and data blocks over a power cycle; the gateway does the
//! same when a file is configured. The seeds say nothing about the format, so it is our own:
//!
//! ```text
//! "GWCPMEM1"                                  magic and version, 8 bytes
//! { tag u8, db u16, len u32, data[len] } ..   one record an area: tag 'M' 'Q' 'I' (bytes),
//!                                             'T' 'C' 'D' (big-endian words; db for 'D' only)
//! crc u16 (little-endian)                     CRC-16/Modbus of everything before it
//! ```
//!
//! A file made with other sizes loads as far as it fits: what the file has beyond an area's size is
//! dropped, what it lacks stays zero, and the [`LoadReport`] says which areas differed. A memory
//! file that does not decode (it starts with the header but is damaged) is renamed to
//! `<file>.corrupt` and the memory starts zeroed, with an error in the log: the file is never
//! overwritten before someone could look at it. A file that does not start with the header is
//! not a memory file (a journal, another program's file): it is refused ([`probe`] at every
//! door, [`SharedCpMemory::open`] at start) and left as it is, never renamed or overwritten. An
//! empty file is no memory yet.

use std::io::{self, Write as _};
use std::path::{Path, PathBuf};
use std::time::Duration;

use proto_core::checksum::crc16_modbus;
use proto_core::codec::{CodecError, Reader, Writer};
use proto_core::cpmem::{Area, CpMemory, MemoryLayout};
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

use super::SharedCpMemory;
use crate::config::check::{create_and_remove, not_regular, parent_dir, takes_new_file};

/// The first 8 bytes of a memory file.
const MAGIC: &[u8; 8] = b"GWCPMEM1";
/// What [`probe`] reads of an existing file before it decides: the header only.
const HEADER_LEN: u64 = MAGIC.len() as u64;
/// How often a changed memory is saved by default.
pub const DEFAULT_SAVE_INTERVAL: Duration = Duration::from_secs(10);

const TAG_M: u8 = b'M';
const TAG_Q: u8 = b'Q';
const TAG_I: u8 = b'I';
const TAG_T: u8 = b'T';
const TAG_C: u8 = b'C';
const TAG_DB: u8 = b'D';

/// Where and how often the memory is saved.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PersistSettings {
    /// The memory file.
    pub path: PathBuf,
    /// How often the memory is saved when it changed (and once more at shutdown).
    pub interval: Duration,
}

impl PersistSettings {
    /// Saving to `path` every [`DEFAULT_SAVE_INTERVAL`].
    pub fn new(path: impl Into<PathBuf>) -> Self {
        Self {
            path: path.into(),
            interval: DEFAULT_SAVE_INTERVAL,
        }
    }
}

/// Why a memory file could not be used.
#[derive(Debug, thiserror::Error)]
pub enum PersistError {
    /// Reading or writing the file failed.
    #[error("memory file {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        #[source]
        source: io::Error,
    },
    /// The file is not a memory file or is damaged.
    #[error("memory file is damaged: {0}")]
    Corrupt(String),
    /// The file is not a memory file at all (no header): it is left as it is.
    #[error("{0}")]
    Foreign(String),
}

impl From<CodecError> for PersistError {
    fn from(error: CodecError) -> Self {
        Self::Corrupt(error.to_string())
    }
}

/// How a load went.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum LoadStatus {
    /// No file yet: the memory starts zeroed.
    NoFile,
    /// The file was loaded.
    Loaded,
    /// The file did not decode; it was moved to `moved_to` and the memory starts zeroed.
    Corrupt {
        /// What was wrong.
        reason: String,
        /// Where the damaged file is now.
        moved_to: PathBuf,
    },
}

/// What [`SharedCpMemory::open`] found.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LoadReport {
    /// Whether a file was loaded.
    pub status: LoadStatus,
    /// Areas whose size in the file differs from the layout (loaded as far as they fit), and
    /// areas of the file the layout does not have (dropped), e.g. `"DB 802 (not configured)"`.
    pub differences: Vec<String>,
}

/// The file image of `memory` made with `layout`.
pub fn encode(layout: &MemoryLayout, memory: &CpMemory) -> Vec<u8> {
    let mut out = Vec::new();
    let mut w = Writer::new(&mut out);
    w.bytes(MAGIC);
    for (tag, bytes) in [
        (TAG_M, memory.m()),
        (TAG_Q, memory.q()),
        (TAG_I, memory.i()),
    ] {
        w.u8(tag).u16_be(0).u32_be(len32(bytes.len())).bytes(bytes);
    }
    let mut words = |tag: u8, db: u16, data: &[u16]| {
        w.u8(tag).u16_be(db).u32_be(len32(data.len() * 2));
        for word in data {
            w.u16_be(*word);
        }
    };
    words(TAG_T, 0, memory.timers());
    words(TAG_C, 0, memory.counters());
    for &(n, _) in &layout.data_blocks {
        if let Some(data) = memory.db(n) {
            words(TAG_DB, n, data);
        }
    }
    let crc = crc16_modbus(&out);
    Writer::new(&mut out).u16_le(crc);
    out
}

fn len32(n: usize) -> u32 {
    u32::try_from(n).unwrap_or(u32::MAX)
}

/// Copies `from` into the start of `to`; notes a size difference.
fn fill<T: Copy>(to: &mut [T], from: &[T], what: &str, differences: &mut Vec<String>) {
    let n = to.len().min(from.len());
    if let (Some(dst), Some(src)) = (to.get_mut(..n), from.get(..n)) {
        dst.copy_from_slice(src);
    }
    if to.len() != from.len() {
        differences.push(format!(
            "{what}: {} in the file, {} configured",
            from.len(),
            to.len()
        ));
    }
}

/// The memory of `layout` filled from a file image, and the differences in size.
pub fn decode(
    layout: &MemoryLayout,
    bytes: &[u8],
) -> Result<(CpMemory, Vec<String>), PersistError> {
    let body_len = bytes
        .len()
        .checked_sub(2)
        .ok_or_else(|| PersistError::Corrupt("shorter than its checksum".into()))?;
    let mut r = Reader::new(bytes);
    let body = r.take(body_len)?;
    let crc = r.u16_le()?;
    if crc16_modbus(body) != crc {
        return Err(PersistError::Corrupt("checksum mismatch".into()));
    }
    let mut r = Reader::new(body);
    if r.take(MAGIC.len())? != MAGIC {
        return Err(PersistError::Corrupt("not a memory file".into()));
    }
    let mut memory = CpMemory::new(layout);
    let mut differences = Vec::new();
    let mut seen: Vec<Area> = Vec::new();
    while !r.is_empty() {
        let tag = r.u8()?;
        let db = r.u16_be()?;
        let len = usize::try_from(r.u32_be()?)
            .map_err(|_| PersistError::Corrupt("record too long".into()))?;
        let data = r.take(len)?;
        let words = || -> Result<Vec<u16>, PersistError> {
            if len % 2 != 0 {
                return Err(PersistError::Corrupt(format!(
                    "odd length {len} of a word record"
                )));
            }
            Ok(proto_core::codec::u16s_be(data))
        };
        let area = match tag {
            TAG_M => {
                fill(memory.m_mut(), data, "M bytes", &mut differences);
                Area::M
            }
            TAG_Q => {
                fill(memory.q_mut(), data, "Q bytes", &mut differences);
                Area::Q
            }
            TAG_I => {
                fill(memory.i_mut(), data, "I bytes", &mut differences);
                Area::I
            }
            TAG_T => {
                fill(memory.timers_mut(), &words()?, "timers", &mut differences);
                Area::T
            }
            TAG_C => {
                fill(
                    memory.counters_mut(),
                    &words()?,
                    "counters",
                    &mut differences,
                );
                Area::C
            }
            TAG_DB => {
                let data = words()?;
                match memory.db_mut(db) {
                    Some(to) => fill(to, &data, &format!("DB {db} words"), &mut differences),
                    None => differences.push(format!("DB {db} (not configured): dropped")),
                }
                Area::Db(db)
            }
            other => {
                return Err(PersistError::Corrupt(format!(
                    "unknown record tag {other:#04x}"
                )))
            }
        };
        if seen.contains(&area) {
            return Err(PersistError::Corrupt(format!("{area} twice")));
        }
        seen.push(area);
    }
    for &(n, _) in &layout.data_blocks {
        if !seen.contains(&Area::Db(n)) {
            differences.push(format!("DB {n} (not in the file): zeroed"));
        }
    }
    Ok((memory, differences))
}

/// Writes `bytes` to `path` atomically: a temporary file next to it, fsync, rename over `path`,
/// fsync of the directory (so the rename itself survives a power loss).
pub fn save_atomic(path: &Path, bytes: &[u8]) -> Result<(), PersistError> {
    let io_err = |source| PersistError::Io {
        path: path.to_owned(),
        source,
    };
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let mut file = std::fs::File::create(&tmp).map_err(io_err)?;
    file.write_all(bytes).map_err(io_err)?;
    file.sync_all().map_err(io_err)?;
    drop(file);
    std::fs::rename(&tmp, path).map_err(io_err)?;
    // Directories open read-only on Unix; fsync makes the new entry durable.
    std::fs::File::open(parent_dir(path))
        .and_then(|d| d.sync_all())
        .map_err(io_err)
}

/// Why `path`, which is not a regular file, cannot be the memory file.
fn not_a_file(path: &Path, meta: &std::fs::Metadata) -> String {
    format!(
        "{} is {}, not a CP memory file",
        path.display(),
        not_regular(meta)
    )
}

/// Why a file without the header is refused.
fn foreign(path: &Path) -> String {
    format!(
        "{} is not a CP memory file: it does not start with the header GWCPMEM1 (a file the \
         gateway did not write); the gateway neither renames nor overwrites it: name another file",
        path.display()
    )
}

/// The start check of the memory file (`gateway check`, `run`, a SIGHUP re-read and every REST
/// change), changing nothing: an existing file must be a regular file that can be read and
/// starts with the header (only the header is read) or is empty; its directory must take a new
/// file, since a save writes `<path>.tmp` and renames it (the check creates and removes
/// `<path>.probe-<pid>`); a missing file is created (`O_CREAT | O_EXCL`) and removed again.
///
/// # Errors
///
/// Why the path cannot be the memory file, naming it.
pub fn probe(path: &Path) -> Result<(), String> {
    use std::io::Read as _;
    let shown = path.display();
    match std::fs::metadata(path) {
        Ok(meta) if !meta.is_file() => Err(not_a_file(path, &meta)),
        Ok(_) => {
            let mut head = Vec::new();
            std::fs::File::open(path)
                .and_then(|f| f.take(HEADER_LEN).read_to_end(&mut head))
                .map_err(|e| format!("cannot read {shown}: {e}"))?;
            if !head.is_empty() && head != MAGIC {
                return Err(foreign(path));
            }
            takes_new_file(path, "a save")
        }
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            create_and_remove(path).map_err(|e| format!("cannot create {shown}: {e}"))
        }
        Err(e) => Err(format!("cannot read {shown}: {e}")),
    }
}

// === impl SharedCpMemory (persistence) ===

impl SharedCpMemory {
    /// The memory of `layout`, loaded from `path` if the file exists. A damaged memory file is
    /// moved to `<path>.corrupt` and the memory starts zeroed; an empty file is no memory yet.
    /// A file without the header is refused and left as it is ([`PersistError::Foreign`]), as
    /// is a path that is not a regular file; an I/O error (other than a missing file) is an
    /// error.
    pub fn open(layout: MemoryLayout, path: &Path) -> Result<(Self, LoadReport), PersistError> {
        if let Ok(meta) = std::fs::metadata(path) {
            if !meta.is_file() {
                return Err(PersistError::Foreign(not_a_file(path, &meta)));
            }
        }
        let io_err = |source| PersistError::Io {
            path: path.to_owned(),
            source,
        };
        let bytes = match std::fs::read(path) {
            Err(err) if err.kind() == io::ErrorKind::NotFound => Vec::new(),
            read => read.map_err(io_err)?,
        };
        if bytes.is_empty() {
            let report = LoadReport {
                status: LoadStatus::NoFile,
                differences: Vec::new(),
            };
            return Ok((Self::new(layout), report));
        }
        if !bytes.starts_with(MAGIC) {
            return Err(PersistError::Foreign(foreign(path)));
        }
        match decode(&layout, &bytes) {
            Ok((memory, differences)) => {
                for difference in &differences {
                    tracing::warn!(path = %path.display(), %difference, "memory file differs from the configured sizes");
                }
                let report = LoadReport {
                    status: LoadStatus::Loaded,
                    differences,
                };
                Ok((Self::from_memory(layout, memory), report))
            }
            Err(err) => {
                let mut moved = path.as_os_str().to_owned();
                moved.push(".corrupt");
                let moved_to = PathBuf::from(moved);
                std::fs::rename(path, &moved_to).map_err(io_err)?;
                tracing::error!(path = %path.display(), moved_to = %moved_to.display(), error = %err, "memory file damaged; starting with zeroed memory");
                let report = LoadReport {
                    status: LoadStatus::Corrupt {
                        reason: err.to_string(),
                        moved_to,
                    },
                    differences: Vec::new(),
                };
                Ok((Self::new(layout), report))
            }
        }
    }

    /// Saves the memory to `path` now (blocking I/O: call from a blocking context). Returns the
    /// generation saved.
    pub fn save(&self, path: &Path) -> Result<u64, PersistError> {
        let (generation, memory) = self.read(|m| (self.generation(), m.clone()));
        save_atomic(path, &encode(self.layout(), &memory))?;
        Ok(generation)
    }
}

/// Saves `memory` to the file of `settings` every interval when it changed, and once more when
/// `shutdown` is cancelled; the task ends after that last save. Errors are logged and retried at
/// the next interval.
pub fn spawn_persistence(
    memory: SharedCpMemory,
    settings: PersistSettings,
    shutdown: CancellationToken,
) -> JoinHandle<()> {
    crate::task::spawn("cp memory persistence", async move {
        let mut saved = memory.generation();
        let mut ticker = tokio::time::interval(settings.interval.max(Duration::from_millis(10)));
        ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        ticker.tick().await;
        loop {
            let stopping = tokio::select! {
                () = shutdown.cancelled() => true,
                _ = ticker.tick() => false,
            };
            if memory.generation() != saved {
                let (m, path) = (memory.clone(), settings.path.clone());
                match tokio::task::spawn_blocking(move || m.save(&path)).await {
                    Ok(Ok(generation)) => saved = generation,
                    Ok(Err(err)) => tracing::error!(error = %err, "saving the CP memory failed"),
                    Err(err) => tracing::error!(error = %err, "the CP memory save task failed"),
                }
            }
            if stopping {
                tracing::info!(path = %settings.path.display(), "CP memory saved at shutdown");
                return;
            }
        }
    })
}

/// Whether the directory of `path` does not exist (a path under a regular file is not missing:
/// `run` cannot read it).
pub(crate) fn missing_dir(path: &Path) -> bool {
    std::fs::metadata(parent_dir(path)).is_err_and(|e| e.kind() == io::ErrorKind::NotFound)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn filled() -> (MemoryLayout, CpMemory) {
        let layout = MemoryLayout::default();
        let mut memory = CpMemory::new(&layout);
        memory.m_mut()[5] = 0xA5;
        memory.q_mut()[2047] = 1;
        memory.i_mut()[0] = 0xFF;
        memory.timers_mut()[1] = 0x1234;
        memory.counters_mut()[255] = 0xFFFF;
        memory.db_mut(801).expect("DB 801")[511] = 0xBEEF;
        (layout, memory)
    }

    #[test]
    fn a_file_image_decodes_to_the_same_memory() {
        let (layout, memory) = filled();
        let bytes = encode(&layout, &memory);
        let (back, differences) = decode(&layout, &bytes).expect("decodes");
        assert_eq!(back, memory);
        assert!(differences.is_empty(), "{differences:?}");
    }

    #[test]
    fn damage_is_a_typed_error_never_a_panic() {
        let (layout, memory) = filled();
        let bytes = encode(&layout, &memory);
        for cut in [0, 1, 2, 9, 20, bytes.len() - 1] {
            assert!(matches!(
                decode(&layout, &bytes[..cut]),
                Err(PersistError::Corrupt(_))
            ));
        }
        let mut flipped = bytes.clone();
        flipped[100] ^= 0x01;
        assert!(matches!(
            decode(&layout, &flipped),
            Err(PersistError::Corrupt(reason)) if reason == "checksum mismatch"
        ));
        // A well-formed file with a record that claims more bytes than it has.
        let mut body = MAGIC.to_vec();
        Writer::new(&mut body)
            .u8(TAG_M)
            .u16_be(0)
            .u32_be(1000)
            .u8(1);
        let crc = crc16_modbus(&body);
        Writer::new(&mut body).u16_le(crc);
        assert!(matches!(
            decode(&layout, &body),
            Err(PersistError::Corrupt(_))
        ));
    }

    #[test]
    fn a_file_without_the_header_is_refused_and_left_as_it_is() {
        let dir = tempfile::tempdir().expect("dir");
        let layout = MemoryLayout::default();
        let journal = dir.path().join("r3964.journal");
        std::fs::write(&journal, b"GWMBXJ01\x04\x00\x00\x00").expect("write");
        let why = probe(&journal).expect_err("a journal");
        assert!(why.contains("not a CP memory file"), "{why}");
        assert!(matches!(
            SharedCpMemory::open(layout.clone(), &journal),
            Err(PersistError::Foreign(_))
        ));
        assert_eq!(
            std::fs::read(&journal).expect("kept"),
            b"GWMBXJ01\x04\x00\x00\x00"
        );
        let why = probe(dir.path()).expect_err("a directory");
        assert!(why.contains("is a directory"), "{why}");
        // Empty: no memory yet; a new path: creatable, nothing left behind.
        let empty = dir.path().join("empty.bin");
        std::fs::write(&empty, b"").expect("write");
        assert_eq!(probe(&empty), Ok(()));
        let (_, report) = SharedCpMemory::open(layout.clone(), &empty).expect("opens");
        assert_eq!(report.status, LoadStatus::NoFile);
        assert_eq!(probe(&dir.path().join("new.bin")), Ok(()));
        // A memory file: accepted, and a damaged one is still ours (moved to .corrupt at start).
        let (_, memory) = filled();
        let good = dir.path().join("cp.bin");
        std::fs::write(&good, encode(&layout, &memory)).expect("write");
        assert_eq!(probe(&good), Ok(()));
        let mut names: Vec<String> = std::fs::read_dir(dir.path())
            .expect("list")
            .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["cp.bin", "empty.bin", "r3964.journal"]);
    }

    #[test]
    fn other_sizes_load_as_far_as_they_fit() {
        let (layout, memory) = filled();
        let bytes = encode(&layout, &memory);
        let smaller = MemoryLayout {
            q_bytes: 1024,
            data_blocks: vec![(800, 512), (802, 16)],
            ..MemoryLayout::default()
        };
        let (back, differences) = decode(&smaller, &bytes).expect("decodes");
        assert_eq!(back.m()[5], 0xA5);
        assert_eq!(back.q().len(), 1024);
        assert_eq!(back.timers()[1], 0x1234);
        assert_eq!(back.db(802), Some(&[0u16; 16][..]));
        assert_eq!(
            differences,
            vec![
                "Q bytes: 2048 in the file, 1024 configured".to_owned(),
                "DB 801 (not configured): dropped".to_owned(),
                "DB 802 (not in the file): zeroed".to_owned(),
            ]
        );
    }
}
