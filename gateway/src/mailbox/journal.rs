//! The mailbox journal: the telegrams of a line that wait for their acknowledgement, on disk, so
//! that a restart or a `kill -9` loses none of them and the sequence numbers go on.
//!
//! Why a journal and not a snapshot: a telegram must be on disk before the partner gets its
//! acknowledgement (3964(R): the DLE after the BCC, 003 6.3.1), i.e. once per telegram, on the
//! line's own time. Appending one record costs one `write` and one `fdatasync`; a snapshot would
//! rewrite every waiting telegram each time.
//!
//! # Format
//!
//! ```text
//! header   "GWMBXJ01"                                   8 bytes, once
//! record   len: u32 LE | kind: u8 | payload (len bytes) | crc: u32 LE
//!          crc = CRC-32 (IEEE) over len, kind and payload
//! kinds    1 telegram   seq: u16 LE | received: u64 LE (µs since 1970) | data
//!          2 removed    seq: u16 LE | acked: u8 (1: acknowledged, 0: dropped by the policy)
//!          3 state      last_seq: u16 LE | last_acked: u16 LE
//! ```
//!
//! The header marks the file as a journal and names its format version: a file that does not
//! start with it (another program's file, the CP memory file, a directory) is refused with an
//! error at start and by the start check ([`probe`]), never renamed, truncated or written. Every
//! journal the gateway has written starts with `GWMBXJ01` (the header came with the first
//! version of the format), so there is no older layout to recognise. An empty file, or one cut
//! short inside the header (a crash while the journal was being created), is a new journal.
//!
//! Replaying the records in order gives the waiting telegrams (oldest first), the last sequence
//! number given and the last one acknowledged. Reading stops at the first record that is cut
//! short or whose checksum does not match: that record and everything after it are reported as
//! lost ([`Loss`]) and cut off, and the line starts with what came before.
//!
//! # Guarantees
//!
//! - A telegram record is written and `fdatasync`ed before [`Journal::append_telegram`] returns:
//!   it survives a crash of the gateway (`kill -9`) and of the machine (power loss).
//! - Removal and state records are written (to the kernel) but not synced: they survive a crash
//!   of the gateway, not a power loss. After a power loss a telegram acknowledged shortly before
//!   may wait again, under its old sequence number (at least once, never lost).
//!
//! # Size bound (compaction)
//!
//! After each append the journal is compacted when it holds more than
//! `2 x live + COMPACT_SLACK` bytes, where `live` is what the waiting telegrams take as records:
//! the new file (header, one state record, one record per waiting telegram) is written beside
//! the journal, synced, renamed over it and the directory synced. So the file never exceeds
//! `2 x live + COMPACT_SLACK + one record`; with `depth` telegrams of at most `max_len` bytes
//! waiting, `live <= depth x (max_len + RECORD_OVERHEAD + 10)` ([`size_bound`]). Each compaction
//! writes at most half of what was appended since the previous one, so the cost per telegram
//! stays constant.

use std::collections::VecDeque;
use std::fs::{self, File, OpenOptions};
use std::io::{self, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use crate::config::check::{create_and_remove, not_regular, parent_dir, takes_new_file};

/// The first bytes of every journal (name and format version 01).
pub const MAGIC: &[u8; 8] = b"GWMBXJ01";
/// Bytes a record adds to its payload: length (4), kind (1), CRC (4).
pub const RECORD_OVERHEAD: u64 = 9;
/// What a telegram record adds to the telegram: sequence number (2) and receive time (8).
pub const TELEGRAM_HEADER: u64 = 10;
/// Appended bytes tolerated beyond twice the live records before the journal is compacted.
pub const COMPACT_SLACK: u64 = 64 * 1024;
/// The longest payload a record may announce: a telegram of the CP's 1024-byte buffer with its
/// header (a larger length is corruption, not a telegram).
const MAX_PAYLOAD: u32 = 1024 + TELEGRAM_HEADER as u32;

const KIND_TELEGRAM: u8 = 1;
const KIND_REMOVED: u8 = 2;
const KIND_STATE: u8 = 3;

/// The most bytes a journal of a mailbox with `depth` telegrams of at most `max_len` bytes
/// holds (see the module doc).
pub const fn size_bound(depth: u64, max_len: u64) -> u64 {
    let live = MAGIC.len() as u64
        + RECORD_OVERHEAD
        + 4
        + depth * (max_len + TELEGRAM_HEADER + RECORD_OVERHEAD);
    2 * live + COMPACT_SLACK + max_len + TELEGRAM_HEADER + RECORD_OVERHEAD
}

/// A telegram as the journal keeps it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct JournaledTelegram {
    /// Its sequence number.
    pub seq: u16,
    /// When it was received.
    pub received: SystemTime,
    /// Its bytes.
    pub data: Vec<u8>,
}

/// One record.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Record {
    /// A telegram now waits.
    Telegram(JournaledTelegram),
    /// The telegram `seq` no longer waits.
    Removed {
        /// Its number.
        seq: u16,
        /// Acknowledged by a client (else dropped by the overflow policy).
        acked: bool,
    },
    /// The counters, at the start of a compacted journal and when a number is given to a
    /// telegram that is not kept.
    State {
        /// The last sequence number given.
        last_seq: u16,
        /// The last sequence number acknowledged.
        last_acked: u16,
    },
}

/// What a journal holds, replayed.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Replayed {
    /// The waiting telegrams, oldest first.
    pub telegrams: VecDeque<JournaledTelegram>,
    /// The last sequence number given (0: none yet).
    pub last_seq: u16,
    /// The last sequence number acknowledged (0: none yet).
    pub last_acked: u16,
    /// The unreadable tail, if there was one.
    pub loss: Option<Loss>,
}

/// An unreadable tail of a journal.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Loss {
    /// Where the first unreadable record starts.
    pub offset: u64,
    /// How many bytes were cut off from there.
    pub bytes: u64,
    /// Why: `"cut short"`, `"checksum mismatch"`, `"bad length"`, `"unknown record"`, `"not a
    /// journal"`.
    pub reason: &'static str,
}

/// A journal operation that failed.
#[derive(Debug, thiserror::Error)]
#[error("journal {}: {step}: {source}", path.display())]
pub struct JournalError {
    /// The journal's path.
    pub path: PathBuf,
    /// What was being done.
    pub step: &'static str,
    /// The system's error.
    #[source]
    pub source: io::Error,
}

// === impl Record ===

impl Record {
    /// The record as written: length, kind, payload, CRC.
    pub fn encode(&self, out: &mut Vec<u8>) {
        let mut payload = Vec::new();
        let kind = match self {
            Self::Telegram(t) => {
                payload.extend_from_slice(&t.seq.to_le_bytes());
                payload.extend_from_slice(&micros_since_epoch(t.received).to_le_bytes());
                payload.extend_from_slice(&t.data);
                KIND_TELEGRAM
            }
            Self::Removed { seq, acked } => {
                payload.extend_from_slice(&seq.to_le_bytes());
                payload.push(u8::from(*acked));
                KIND_REMOVED
            }
            Self::State {
                last_seq,
                last_acked,
            } => {
                payload.extend_from_slice(&last_seq.to_le_bytes());
                payload.extend_from_slice(&last_acked.to_le_bytes());
                KIND_STATE
            }
        };
        let len = u32::try_from(payload.len())
            .unwrap_or(u32::MAX)
            .to_le_bytes();
        let mut crc = crc32fast::Hasher::new();
        crc.update(&len);
        crc.update(&[kind]);
        crc.update(&payload);
        out.extend_from_slice(&len);
        out.push(kind);
        out.extend_from_slice(&payload);
        out.extend_from_slice(&crc.finalize().to_le_bytes());
    }

    /// The record at the start of `bytes` and its length, or why there is none.
    fn decode(bytes: &[u8]) -> Result<(Self, usize), &'static str> {
        let header = bytes.get(..5).ok_or("cut short")?;
        let len_bytes = [header[0], header[1], header[2], header[3]];
        let len = u32::from_le_bytes(len_bytes);
        if len > MAX_PAYLOAD {
            return Err("bad length");
        }
        let kind = header[4];
        let end = 5 + len as usize;
        let payload = bytes.get(5..end).ok_or("cut short")?;
        let stored = bytes.get(end..end + 4).ok_or("cut short")?;
        let mut crc = crc32fast::Hasher::new();
        crc.update(&len_bytes);
        crc.update(&[kind]);
        crc.update(payload);
        if crc.finalize().to_le_bytes() != stored {
            return Err("checksum mismatch");
        }
        let u16_at = |i: usize| {
            payload
                .get(i..i + 2)
                .map(|b| u16::from_le_bytes([b[0], b[1]]))
        };
        let record = match kind {
            KIND_TELEGRAM => {
                let seq = u16_at(0).ok_or("bad length")?;
                let micros = payload.get(2..10).ok_or("bad length")?;
                let micros = u64::from_le_bytes(micros.try_into().map_err(|_| "bad length")?);
                Self::Telegram(JournaledTelegram {
                    seq,
                    received: UNIX_EPOCH + Duration::from_micros(micros),
                    data: payload[10..].to_vec(),
                })
            }
            KIND_REMOVED if len == 3 => Self::Removed {
                seq: u16_at(0).ok_or("bad length")?,
                acked: payload[2] != 0,
            },
            KIND_STATE if len == 4 => Self::State {
                last_seq: u16_at(0).ok_or("bad length")?,
                last_acked: u16_at(2).ok_or("bad length")?,
            },
            _ => return Err("unknown record"),
        };
        Ok((record, end + 4))
    }
}

fn micros_since_epoch(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_micros()).unwrap_or(u64::MAX))
}

// === impl Replayed ===

impl Replayed {
    /// Replays the bytes of a journal file: the header, then records up to the first unreadable
    /// one. An empty file (or one cut short inside the header) is a new journal.
    pub fn from_bytes(bytes: &[u8]) -> Self {
        let mut out = Self::default();
        let total = bytes.len() as u64;
        if !MAGIC.starts_with(&bytes[..bytes.len().min(MAGIC.len())]) {
            out.loss = Some(Loss {
                offset: 0,
                bytes: total,
                reason: "not a journal",
            });
        }
        if out.loss.is_some() || bytes.len() < MAGIC.len() {
            return out;
        }
        let mut at = MAGIC.len();
        while at < bytes.len() {
            match Record::decode(&bytes[at..]) {
                Ok((record, len)) => {
                    out.apply(record);
                    at += len;
                }
                Err(reason) => {
                    out.loss = Some(Loss {
                        offset: at as u64,
                        bytes: total - at as u64,
                        reason,
                    });
                    break;
                }
            }
        }
        out
    }

    fn apply(&mut self, record: Record) {
        match record {
            Record::Telegram(t) => {
                self.last_seq = t.seq;
                self.telegrams.push_back(t);
            }
            Record::Removed { seq, acked } => {
                if let Some(i) = self.telegrams.iter().position(|t| t.seq == seq) {
                    self.telegrams.remove(i);
                }
                if acked {
                    self.last_acked = seq;
                }
            }
            Record::State {
                last_seq,
                last_acked,
            } => {
                self.last_seq = last_seq;
                self.last_acked = last_acked;
            }
        }
    }

    /// Where the readable part ends.
    fn readable_len(&self, total: u64) -> u64 {
        self.loss.as_ref().map_or(total, |l| l.offset)
    }
}

/// An open journal file, appended to.
#[derive(Debug)]
pub struct Journal {
    path: PathBuf,
    file: File,
    /// Bytes in the file.
    size: u64,
    /// Bytes the records of the waiting telegrams take (what a compaction would write).
    live: u64,
    /// Encoding buffer, reused.
    buf: Vec<u8>,
}

// === impl Journal ===

impl Journal {
    /// Opens (or creates) the journal at `path` and replays it. An unreadable tail is cut off
    /// (reported in [`Replayed::loss`]); a file that is not a journal (no header, another
    /// format version, not a regular file) is refused and left as it is.
    ///
    /// # Errors
    ///
    /// The file is not a journal, or cannot be read, created or written.
    pub fn open(path: &Path) -> Result<(Self, Replayed), JournalError> {
        // A FIFO or a device would block or be written to: only a regular file is opened.
        match fs::metadata(path) {
            Ok(meta) if !meta.is_file() => {
                return Err(err(path, "open")(not_a_journal(not_regular(&meta))));
            }
            _ => {}
        }
        let mut bytes = Vec::new();
        match File::open(path) {
            Ok(mut f) => {
                f.read_to_end(&mut bytes).map_err(err(path, "read"))?;
            }
            Err(e) if e.kind() == io::ErrorKind::NotFound => {}
            Err(e) => return Err(err(path, "open")(e)),
        }
        if let Err(why) = header_check(&bytes) {
            return Err(err(path, "check the header")(not_a_journal(&why)));
        }
        // A compaction that a crash interrupted leaves its temporary file: never read.
        let _ = fs::remove_file(temp_path(path));
        let replayed = Replayed::from_bytes(&bytes);
        let total = bytes.len() as u64;
        let mut file = OpenOptions::new()
            .create(true)
            .read(true)
            .write(true)
            .truncate(false)
            .open(path)
            .map_err(err(path, "open"))?;
        let mut size = replayed.readable_len(total).min(total);
        if size < MAGIC.len() as u64 {
            file.set_len(0).map_err(err(path, "truncate"))?;
            file.write_all(MAGIC).map_err(err(path, "write"))?;
            size = MAGIC.len() as u64;
        } else if size < total {
            file.set_len(size).map_err(err(path, "truncate"))?;
        }
        file.seek(SeekFrom::Start(size))
            .map_err(err(path, "seek"))?;
        file.sync_all().map_err(err(path, "sync"))?;
        sync_dir(path).map_err(err(path, "sync directory"))?;
        let live = replayed.telegrams.iter().map(telegram_record_len).sum();
        Ok((
            Self {
                path: path.to_owned(),
                file,
                size,
                live,
                buf: Vec::new(),
            },
            replayed,
        ))
    }

    /// The journal's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The bytes in the file now.
    pub fn size(&self) -> u64 {
        self.size
    }

    /// Appends a telegram record and syncs it to the disk.
    ///
    /// # Errors
    ///
    /// Writing or syncing failed; what was written of the record is cut off again (a record
    /// that is not on disk must not be replayed later).
    pub fn append_telegram(&mut self, telegram: &JournaledTelegram) -> Result<(), JournalError> {
        let len = telegram_record_len(telegram);
        self.append(&Record::Telegram(telegram.clone()), true)?;
        self.live += len;
        Ok(())
    }

    /// Appends a removal record (not synced, see the module doc).
    ///
    /// # Errors
    ///
    /// Writing failed.
    pub fn append_removed(
        &mut self,
        seq: u16,
        acked: bool,
        data_len: usize,
    ) -> Result<(), JournalError> {
        self.append(&Record::Removed { seq, acked }, false)?;
        self.live = self
            .live
            .saturating_sub(data_len as u64 + TELEGRAM_HEADER + RECORD_OVERHEAD);
        Ok(())
    }

    /// Appends a state record (not synced).
    ///
    /// # Errors
    ///
    /// Writing failed.
    pub fn append_state(&mut self, last_seq: u16, last_acked: u16) -> Result<(), JournalError> {
        self.append(
            &Record::State {
                last_seq,
                last_acked,
            },
            false,
        )
    }

    fn append(&mut self, record: &Record, sync: bool) -> Result<(), JournalError> {
        self.buf.clear();
        record.encode(&mut self.buf);
        let written = self.file.write_all(&self.buf).and_then(|()| {
            if sync {
                self.file.sync_data()
            } else {
                Ok(())
            }
        });
        if let Err(source) = written {
            // Cut a partial record off, so that the next one is not appended behind garbage.
            let _ = self.file.set_len(self.size);
            let _ = self.file.seek(SeekFrom::Start(self.size));
            return Err(JournalError {
                path: self.path.clone(),
                step: if sync { "write and sync" } else { "write" },
                source,
            });
        }
        self.size += self.buf.len() as u64;
        Ok(())
    }

    /// Whether the file has grown past its bound and should be compacted.
    pub fn wants_compaction(&self) -> bool {
        self.size > 2 * (self.live + MAGIC.len() as u64 + RECORD_OVERHEAD + 4) + COMPACT_SLACK
    }

    /// Rewrites the journal with only `waiting` and the counters: a new file beside it, synced,
    /// renamed over it, the directory synced.
    ///
    /// # Errors
    ///
    /// Any step failed; the journal is then unchanged and still appended to.
    pub fn compact<'a>(
        &mut self,
        last_seq: u16,
        last_acked: u16,
        waiting: impl Iterator<Item = &'a JournaledTelegram>,
    ) -> Result<(), JournalError> {
        let (file, size, live) = write_whole(&self.path, last_seq, last_acked, waiting)?;
        self.file = file;
        self.size = size;
        self.live = live;
        Ok(())
    }
}

/// Writes a whole journal at `path` holding `waiting` and the counters: a new file beside it,
/// synced, renamed over it, the directory synced. Returns the file (positioned at its end), its
/// size and the bytes of its telegram records.
fn write_whole<'a>(
    path: &Path,
    last_seq: u16,
    last_acked: u16,
    waiting: impl Iterator<Item = &'a JournaledTelegram>,
) -> Result<(File, u64, u64), JournalError> {
    let temp = temp_path(path);
    let mut bytes = MAGIC.to_vec();
    Record::State {
        last_seq,
        last_acked,
    }
    .encode(&mut bytes);
    let mut live = 0;
    for t in waiting {
        live += telegram_record_len(t);
        Record::Telegram(t.clone()).encode(&mut bytes);
    }
    let mut file = OpenOptions::new()
        .create(true)
        .write(true)
        .truncate(true)
        .read(true)
        .open(&temp)
        .map_err(err(path, "create the compacted file"))?;
    file.write_all(&bytes)
        .and_then(|()| file.sync_all())
        .map_err(err(path, "write the compacted file"))?;
    fs::rename(&temp, path).map_err(err(path, "rename the compacted file"))?;
    sync_dir(path).map_err(err(path, "sync directory"))?;
    file.seek(SeekFrom::End(0)).map_err(err(path, "seek"))?;
    Ok((file, bytes.len() as u64, live))
}

/// The name part of the header; the two characters after it are the format version.
const MAGIC_NAME: &[u8; 6] = b"GWMBXJ";

/// Whether a file starting with `bytes` is a journal this gateway reads: the header, or an
/// empty file or one cut short inside the header (a crash while it was created: a new
/// journal). Otherwise why not (the version bytes escaped; at most 2 of them are shown).
pub fn header_check(bytes: &[u8]) -> Result<(), String> {
    let head = &bytes[..bytes.len().min(MAGIC.len())];
    if MAGIC.starts_with(head) {
        return Ok(());
    }
    if head.len() == MAGIC.len() && head.starts_with(MAGIC_NAME) {
        return Err(format!(
            "a journal of format version \"{}\" (this gateway reads 01)",
            head[MAGIC_NAME.len()..].escape_ascii()
        ));
    }
    Err(
        "it does not start with the journal header GWMBXJ01 (a file the gateway did not write)"
            .to_owned(),
    )
}

/// The error of `step` on the journal at `path`.
fn err(path: &Path, step: &'static str) -> impl FnOnce(io::Error) -> JournalError {
    let path = path.to_owned();
    move |source| JournalError { path, step, source }
}

/// The error of a file that is not a journal.
fn not_a_journal(why: &str) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!("not a journal: {why}; the file is left as it is"),
    )
}

/// What the start check found at a journal's path.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Probe {
    /// The file exists (else the check created it and removed it again).
    pub exists: bool,
    /// Telegrams that wait in it.
    pub waiting: usize,
    /// The last sequence number it gave.
    pub last_seq: u16,
}

/// The start check of a journal path (`gateway check`, `run`, a SIGHUP re-read and every REST
/// change): opens what [`Journal::open`] opens, as it opens it, and changes nothing:
///
/// - an existing file must be a regular file that opens for reading and writing and starts with
///   the header ([`header_check`]; a file without it is read no further); its directory must
///   take a new file (a compaction writes one beside it: the check creates and removes
///   `<path>.probe-<pid>`);
/// - a missing file is created (`O_CREAT | O_EXCL`) and removed again at once, so the check
///   leaves no file behind, also when the change is then refused for another reason.
///
/// A journal a running line holds is only read: records it appends meanwhile are at most a tail
/// cut short, which the check does not count as damage.
///
/// # Errors
///
/// Why the path cannot be a journal, naming it: a directory, not a regular file, a file that is
/// not a journal, a read-only file system or directory, a missing directory, a path under a file.
pub fn probe(path: &Path) -> Result<Probe, String> {
    let shown = path.display();
    match fs::metadata(path) {
        Ok(meta) if !meta.is_file() => Err(format!(
            "{shown} is {}, not a journal file",
            not_regular(&meta)
        )),
        Ok(_) => {
            let mut file = OpenOptions::new()
                .read(true)
                .write(true)
                .open(path)
                .map_err(|e| format!("cannot open {shown} for writing: {e}"))?;
            let mut bytes = Vec::new();
            (&mut file)
                .take(MAGIC.len() as u64)
                .read_to_end(&mut bytes)
                .map_err(|e| format!("cannot read {shown}: {e}"))?;
            header_check(&bytes).map_err(|why| {
                format!(
                    "{shown} is not a journal: {why}; the gateway neither renames nor overwrites \
                     it: name another file"
                )
            })?;
            file.read_to_end(&mut bytes)
                .map_err(|e| format!("cannot read {shown}: {e}"))?;
            let replayed = Replayed::from_bytes(&bytes);
            takes_new_file(path, "a compaction")?;
            Ok(Probe {
                exists: true,
                waiting: replayed.telegrams.len(),
                last_seq: replayed.last_seq,
            })
        }
        Err(e) if e.kind() == io::ErrorKind::NotFound => match create_and_remove(path) {
            Ok(()) => Ok(Probe::default()),
            Err(e) if e.kind() == io::ErrorKind::NotFound => {
                let dir = parent_dir(path);
                if dir.is_dir() {
                    // A directory that takes no files of this kind (/proc answers ENOENT).
                    Err(format!("cannot create {shown}: {e}"))
                } else {
                    Err(format!(
                        "the directory {} of the journal does not exist",
                        dir.display()
                    ))
                }
            }
            Err(e) => Err(format!("cannot create {shown}: {e}")),
        },
        Err(e) => Err(format!("cannot open {shown}: {e}")),
    }
}

/// Writes a journal at `path` that holds `waiting` and the counters: the telegrams a line
/// carries into a new journal when its `journal` path changes. A file already at `path` must
/// be a journal (or empty) with no telegram waiting; it is replaced as a compaction replaces it
/// (a new file, synced, renamed over it).
///
/// # Errors
///
/// `path` is not a journal, holds telegrams of its own, or cannot be written.
pub fn take_over(
    path: &Path,
    last_seq: u16,
    last_acked: u16,
    waiting: &[JournaledTelegram],
) -> Result<(), JournalError> {
    match fs::metadata(path) {
        Ok(meta) if !meta.is_file() => {
            return Err(err(path, "open")(not_a_journal(not_regular(&meta))))
        }
        Ok(_) => {
            let bytes = fs::read(path).map_err(err(path, "read"))?;
            header_check(&bytes)
                .map_err(|why| err(path, "check the header")(not_a_journal(&why)))?;
            let own = Replayed::from_bytes(&bytes).telegrams.len();
            if own > 0 {
                return Err(err(path, "take over")(io::Error::new(
                    io::ErrorKind::AlreadyExists,
                    format!("{own} telegrams of an earlier use wait in it"),
                )));
            }
        }
        Err(e) if e.kind() == io::ErrorKind::NotFound => {}
        Err(e) => return Err(err(path, "open")(e)),
    }
    write_whole(path, last_seq, last_acked, waiting.iter()).map(drop)
}

/// Empties the journal at `path` of its telegrams (they were carried into another journal),
/// keeping the counters; a missing file or one that is not a journal is left alone.
///
/// # Errors
///
/// The journal cannot be rewritten.
pub fn clear(path: &Path, last_seq: u16, last_acked: u16) -> Result<(), JournalError> {
    let Ok(meta) = fs::metadata(path) else {
        return Ok(());
    };
    let mut head = Vec::new();
    let is_journal = meta.is_file()
        && File::open(path)
            .and_then(|f| f.take(MAGIC.len() as u64).read_to_end(&mut head))
            .is_ok()
        && header_check(&head).is_ok();
    if !is_journal {
        return Ok(());
    }
    write_whole(path, last_seq, last_acked, std::iter::empty()).map(drop)
}

/// The bytes a telegram's record takes.
fn telegram_record_len(t: &JournaledTelegram) -> u64 {
    t.data.len() as u64 + TELEGRAM_HEADER + RECORD_OVERHEAD
}

/// `<path>.tmp`: where a compaction writes before it renames.
fn temp_path(path: &Path) -> PathBuf {
    let mut temp = path.as_os_str().to_owned();
    temp.push(".tmp");
    PathBuf::from(temp)
}

/// Flushes the directory of `path`, so that a created or renamed file survives a power loss.
fn sync_dir(path: &Path) -> io::Result<()> {
    File::open(parent_dir(path))?.sync_all()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn telegram(seq: u16, data: &[u8]) -> JournaledTelegram {
        JournaledTelegram {
            seq,
            received: UNIX_EPOCH + Duration::from_micros(1_700_000_000_123_456 + u64::from(seq)),
            data: data.to_vec(),
        }
    }

    fn journal_bytes(records: &[Record]) -> Vec<u8> {
        let mut bytes = MAGIC.to_vec();
        for r in records {
            r.encode(&mut bytes);
        }
        bytes
    }

    #[test]
    fn records_round_trip() {
        for record in [
            Record::Telegram(telegram(1, b"3964R 000001")),
            Record::Telegram(telegram(65535, b"")),
            Record::Telegram(telegram(7, &[0x10; 1024])),
            Record::Removed {
                seq: 9,
                acked: true,
            },
            Record::Removed {
                seq: 9,
                acked: false,
            },
            Record::State {
                last_seq: 300,
                last_acked: 299,
            },
        ] {
            let mut bytes = Vec::new();
            record.encode(&mut bytes);
            assert_eq!(Record::decode(&bytes), Ok((record, bytes.len())));
        }
    }

    #[test]
    fn replay_keeps_the_waiting_telegrams_and_the_numbers() {
        let bytes = journal_bytes(&[
            Record::State {
                last_seq: 10,
                last_acked: 10,
            },
            Record::Telegram(telegram(11, b"a")),
            Record::Telegram(telegram(12, b"b")),
            Record::Removed {
                seq: 11,
                acked: true,
            },
            Record::Telegram(telegram(13, b"c")),
            Record::State {
                last_seq: 14,
                last_acked: 11,
            },
        ]);
        let r = Replayed::from_bytes(&bytes);
        assert_eq!(r.loss, None);
        assert_eq!(
            r.telegrams.iter().map(|t| t.seq).collect::<Vec<_>>(),
            [12, 13]
        );
        assert_eq!((r.last_seq, r.last_acked), (14, 11));
        assert_eq!(r.telegrams[0], telegram(12, b"b"));
    }

    #[test]
    fn a_flipped_bit_anywhere_in_a_record_is_caught_by_its_checksum() {
        let good = journal_bytes(&[Record::Telegram(telegram(1, b"one"))]);
        let last = journal_bytes(&[
            Record::Telegram(telegram(1, b"one")),
            Record::Telegram(telegram(2, b"two")),
        ]);
        for i in good.len()..last.len() {
            for bit in 0..8 {
                let mut bytes = last.clone();
                bytes[i] ^= 1 << bit;
                let r = Replayed::from_bytes(&bytes);
                let loss = r.loss.expect("a loss");
                assert_eq!(loss.offset, good.len() as u64, "byte {i} bit {bit}");
                assert_eq!(loss.bytes, (last.len() - good.len()) as u64);
                assert_eq!(
                    r.telegrams.iter().map(|t| t.seq).collect::<Vec<_>>(),
                    [1],
                    "byte {i} bit {bit}"
                );
            }
        }
    }

    #[test]
    fn truncation_at_every_byte_of_the_last_record_loses_only_that_record() {
        let before = journal_bytes(&[
            Record::Telegram(telegram(1, b"one")),
            Record::Removed {
                seq: 1,
                acked: true,
            },
            Record::Telegram(telegram(2, b"two")),
        ]);
        let full = journal_bytes(&[
            Record::Telegram(telegram(1, b"one")),
            Record::Removed {
                seq: 1,
                acked: true,
            },
            Record::Telegram(telegram(2, b"two")),
            Record::Telegram(telegram(3, b"three")),
        ]);
        assert_eq!(Replayed::from_bytes(&full).telegrams.len(), 2);
        for cut in before.len()..full.len() {
            let r = Replayed::from_bytes(&full[..cut]);
            assert_eq!(
                r.telegrams.iter().map(|t| t.seq).collect::<Vec<_>>(),
                [2],
                "cut at {cut}"
            );
            assert_eq!((r.last_seq, r.last_acked), (2, 1), "cut at {cut}");
            if cut == before.len() {
                assert_eq!(r.loss, None);
            } else {
                let loss = r.loss.expect("a loss");
                assert_eq!(
                    (loss.offset, loss.bytes, loss.reason),
                    (
                        before.len() as u64,
                        (cut - before.len()) as u64,
                        "cut short"
                    ),
                    "cut at {cut}"
                );
            }
        }
    }

    #[test]
    fn a_file_cut_inside_the_header_is_new_and_other_bytes_are_not_a_journal() {
        for cut in 0..MAGIC.len() {
            let r = Replayed::from_bytes(&MAGIC[..cut]);
            assert_eq!(r, Replayed::default(), "cut at {cut}");
        }
        let r = Replayed::from_bytes(b"[gateway]\nname = \"x\"\n");
        assert_eq!(
            r.loss.map(|l| (l.offset, l.reason)),
            Some((0, "not a journal"))
        );
    }

    #[test]
    fn an_absurd_length_is_not_read_as_a_record() {
        let mut bytes = MAGIC.to_vec();
        bytes.extend_from_slice(&u32::MAX.to_le_bytes());
        bytes.extend_from_slice(&[1; 16]);
        let loss = Replayed::from_bytes(&bytes).loss.expect("a loss");
        assert_eq!((loss.offset, loss.reason), (8, "bad length"));
    }

    #[test]
    fn a_journal_survives_reopening_and_cuts_its_damaged_tail() {
        let dir = tempfile::tempdir().expect("dir");
        let path = dir.path().join("r3964.journal");
        {
            let (mut j, r) = Journal::open(&path).expect("open");
            assert_eq!(r, Replayed::default());
            j.append_telegram(&telegram(1, b"one")).expect("append");
            j.append_telegram(&telegram(2, b"two")).expect("append");
            j.append_removed(1, true, 3).expect("append");
        }
        let good_len = fs::metadata(&path).expect("meta").len();
        // A record cut short by a crash during its write.
        let mut partial = Vec::new();
        Record::Telegram(telegram(3, b"three")).encode(&mut partial);
        let mut f = OpenOptions::new().append(true).open(&path).expect("open");
        f.write_all(&partial[..7]).expect("write");
        drop(f);

        let (mut j, r) = Journal::open(&path).expect("reopen");
        assert_eq!(r.telegrams.iter().map(|t| t.seq).collect::<Vec<_>>(), [2]);
        assert_eq!((r.last_seq, r.last_acked), (2, 1));
        assert_eq!(
            r.loss,
            Some(Loss {
                offset: good_len,
                bytes: 7,
                reason: "cut short"
            })
        );
        assert_eq!(fs::metadata(&path).expect("meta").len(), good_len);
        j.append_telegram(&telegram(3, b"three")).expect("append");
        drop(j);
        let (_, r) = Journal::open(&path).expect("reopen");
        assert_eq!(r.loss, None);
        assert_eq!(
            r.telegrams.iter().map(|t| t.seq).collect::<Vec<_>>(),
            [2, 3]
        );
    }

    #[test]
    fn a_file_that_is_not_a_journal_is_refused_and_left_as_it_is() {
        let dir = tempfile::tempdir().expect("dir");
        // Another program's file, the CP memory file, a journal of another format version.
        for (name, bytes) in [
            ("j", &b"something else entirely"[..]),
            ("cp-memory.bin", &b"GWCPMEM1\x00\x01\x02\x03"[..]),
            ("v2.journal", &b"GWMBXJ02\x00\x00\x00\x00"[..]),
        ] {
            let path = dir.path().join(name);
            fs::write(&path, bytes).expect("write");
            let e = Journal::open(&path).expect_err("refused");
            assert_eq!(e.source.kind(), io::ErrorKind::InvalidData, "{e}");
            assert!(e.to_string().contains("not a journal"), "{e}");
            assert_eq!(fs::read(&path).expect("still there"), bytes, "{name}");
            let why = probe(&path).expect_err("refused by the check");
            assert!(why.contains("is not a journal"), "{why}");
        }
        let v2 = probe(&dir.path().join("v2.journal")).expect_err("refused");
        assert!(v2.contains("format version \"02\""), "{v2}");
        // Nothing was renamed or created beside them.
        let mut names: Vec<String> = fs::read_dir(dir.path())
            .expect("list")
            .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["cp-memory.bin", "j", "v2.journal"]);
    }

    #[test]
    fn the_start_check_refuses_what_open_cannot_use_and_leaves_nothing_behind() {
        let dir = tempfile::tempdir().expect("dir");
        let shown = |p: &Path| p.display().to_string();
        // A new path: fine, and no file is left.
        let new = dir.path().join("new.journal");
        assert_eq!(probe(&new), Ok(Probe::default()));
        assert!(!new.exists());
        // A directory.
        let why = probe(dir.path()).expect_err("a directory");
        assert!(why.contains("is a directory"), "{why}");
        // A missing directory.
        let why = probe(&dir.path().join("missing/r.journal")).expect_err("no directory");
        assert!(why.contains("does not exist"), "{why}");
        // A path under a file (ENOTDIR).
        let file = dir.path().join("plain");
        fs::write(&file, b"x").expect("write");
        let why = probe(&file.join("r.journal")).expect_err("under a file");
        assert!(why.contains(&shown(&file.join("r.journal"))), "{why}");
        // A FIFO: refused without being opened (an open would wait for a writer).
        let fifo = dir.path().join("fifo");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .expect("mkfifo");
        assert!(made.success());
        let why = probe(&fifo).expect_err("a FIFO");
        assert!(why.contains("not a regular file"), "{why}");
        assert!(Journal::open(&fifo).is_err());
        // An existing journal: read, counted, unchanged; an empty file is a new journal.
        let path = dir.path().join("r.journal");
        {
            let (mut j, _) = Journal::open(&path).expect("open");
            j.append_telegram(&telegram(1, b"one")).expect("append");
            j.append_telegram(&telegram(2, b"two")).expect("append");
        }
        let before = fs::read(&path).expect("read");
        assert_eq!(
            probe(&path),
            Ok(Probe {
                exists: true,
                waiting: 2,
                last_seq: 2
            })
        );
        assert_eq!(fs::read(&path).expect("read"), before);
        let empty = dir.path().join("empty.journal");
        fs::write(&empty, b"").expect("write");
        assert_eq!(probe(&empty).map(|p| p.waiting), Ok(0));
        let mut names: Vec<String> = fs::read_dir(dir.path())
            .expect("list")
            .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["empty.journal", "fifo", "plain", "r.journal"]);
    }

    #[test]
    fn telegrams_are_taken_over_by_a_new_journal_and_the_old_one_is_emptied() {
        let dir = tempfile::tempdir().expect("dir");
        let old = dir.path().join("old.journal");
        let new = dir.path().join("new.journal");
        let waiting = [telegram(56, b"a"), telegram(57, b"b")];
        {
            let (mut j, _) = Journal::open(&old).expect("open");
            for t in &waiting {
                j.append_telegram(t).expect("append");
            }
        }
        take_over(&new, 57, 55, &waiting).expect("take over");
        let (_, r) = Journal::open(&new).expect("open");
        assert_eq!(r.telegrams, waiting);
        assert_eq!((r.last_seq, r.last_acked), (57, 55));
        clear(&old, 57, 55).expect("clear");
        let (_, r) = Journal::open(&old).expect("open");
        assert!(r.telegrams.is_empty());
        assert_eq!((r.last_seq, r.last_acked), (57, 55));
        // A journal holding telegrams of its own is not taken over; a foreign file neither.
        let e = take_over(&new, 60, 55, &waiting).expect_err("refused");
        assert!(e.to_string().contains("2 telegrams"), "{e}");
        let foreign = dir.path().join("foreign");
        fs::write(&foreign, b"keep me").expect("write");
        assert!(take_over(&foreign, 1, 0, &waiting).is_err());
        clear(&foreign, 1, 0).expect("left alone");
        assert_eq!(fs::read(&foreign).expect("read"), b"keep me");
    }

    #[test]
    fn compaction_bounds_the_file_and_keeps_what_waits() {
        let dir = tempfile::tempdir().expect("dir");
        let path = dir.path().join("j");
        let (mut j, _) = Journal::open(&path).expect("open");
        let mut waiting: VecDeque<JournaledTelegram> = VecDeque::new();
        let (depth, len) = (5u64, 200usize);
        let bound = size_bound(depth, len as u64);
        let mut acked = 0;
        for seq in 1..=3000u16 {
            let t = telegram(seq, &vec![b'x'; len]);
            j.append_telegram(&t).expect("append");
            waiting.push_back(t);
            if waiting.len() as u64 > depth - 1 {
                let old = waiting.pop_front().expect("one");
                j.append_removed(old.seq, true, old.data.len())
                    .expect("append");
                acked = old.seq;
            }
            if j.wants_compaction() {
                j.compact(seq, acked, waiting.iter()).expect("compact");
            }
            assert!(j.size() <= bound, "{} > {bound} at {seq}", j.size());
            assert_eq!(fs::metadata(&path).expect("meta").len(), j.size());
        }
        drop(j);
        let (_, r) = Journal::open(&path).expect("reopen");
        assert_eq!(r.telegrams, waiting);
        assert_eq!((r.last_seq, r.last_acked), (3000, acked));
    }
}
