//! The `[cp_memory]` section: the gateway's own CP memory (M, Q, I, T, C and data blocks) that a
//! `modbus-slave-rtu` line serves (003 6.4.5 to 6.4.8) and Modbus TCP shares.

use std::path::PathBuf;
use std::time::Duration;

use serde::Serialize;

use super::reader::{Cx, Fields};

/// How often a changed memory is saved by default.
pub const DEFAULT_SAVE_INTERVAL: Duration = Duration::from_secs(10);
/// Longest save interval accepted.
pub const MAX_SAVE_INTERVAL: Duration = Duration::from_secs(3600);
/// Words of a data block by default: the slave driver serves at most 512 data words per DB
/// (003 6.4.8, register areas).
pub const DEFAULT_DB_WORDS: u16 = 512;

/// One data block of the CP memory.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct DataBlock {
    /// The DB number.
    pub db: u16,
    /// Its size in words, 1..=512.
    pub words: u16,
}

/// The `[cp_memory]` section.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct CpMemoryConfig {
    /// Where the memory is kept across restarts; none: it starts zeroed at every start.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub persist_file: Option<PathBuf>,
    /// How often a changed memory is saved (and once more at shutdown).
    #[serde(with = "humantime_serde")]
    pub save_interval: Duration,
    /// The data blocks and their sizes; empty: a DB of 512 words for each base DB of the slave
    /// lines and each DB their write enables reach.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub data_blocks: Vec<DataBlock>,
}

impl Default for CpMemoryConfig {
    fn default() -> Self {
        Self::new()
    }
}

impl CpMemoryConfig {
    /// The defaults: not persisted, saved every 10 s when persisted, DBs derived from the lines.
    pub fn new() -> Self {
        Self {
            persist_file: None,
            save_interval: DEFAULT_SAVE_INTERVAL,
            data_blocks: Vec::new(),
        }
    }

    pub(crate) fn read(cx: &mut Cx, mut f: Fields<'_>) -> Self {
        let persist_file = f.string(cx, "persist_file").map(PathBuf::from);
        let save_interval = f.duration_or(
            cx,
            "save_interval",
            Duration::from_millis(100)..=MAX_SAVE_INTERVAL,
            DEFAULT_SAVE_INTERVAL,
            "",
        );
        let mut data_blocks: Vec<DataBlock> = Vec::new();
        for (path, value) in f.array(cx, "data_blocks") {
            let Some(mut item) = Fields::of(cx, value, path.clone()) else {
                continue;
            };
            let db = item.required_int::<u16>(cx, "db", 1..=u16::MAX, "");
            let words = item.int_or::<u16>(
                cx,
                "words",
                1..=DEFAULT_DB_WORDS,
                DEFAULT_DB_WORDS,
                "003 6.4.8",
            );
            item.finish(cx);
            if let Some(db) = db {
                if data_blocks.iter().any(|d| d.db == db) {
                    cx.issue(path, format!("DB {db} is listed twice"));
                } else {
                    data_blocks.push(DataBlock { db, words });
                }
            }
        }
        f.finish(cx);
        Self {
            persist_file,
            save_interval,
            data_blocks,
        }
    }
}
