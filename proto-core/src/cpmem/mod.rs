//! The CP memory areas (M, Q, I, T, C, DBs) and the Modbus slave address conversion (manual 003,
//! 6.4.8).
//!
//! On the CP 341 the Modbus slave driver converts a Modbus address into a place in the memory of
//! the CPU (6.4.6 "the Modbus address of the message of the master is transformed to the memory
//! area of the CPU"). The gateway has no CPU: [`CpMemory`] is that memory, owned by the gateway,
//! and the same [`AddressMap`] serves the serial slave and the Modbus TCP view of it.
//!
//! - [`params`]: [`SlaveParams`], [`AddressMap`], [`WriteLimits`] with the manual's defaults;
//! - [`convert`]: the pure conversion ([`locate_bits`], [`locate_registers`]) and [`AccessError`];
//! - here: the memory and the four accesses [`CpMemory::read_bits`], [`CpMemory::write_bits`],
//!   [`CpMemory::read_registers`], [`CpMemory::write_registers`].
//!
//! Byte order: S7 memory is big-endian, "word = high byte | low byte" (6.4.6). Registers are DB
//! words. A timer or counter is a word whose 16 bits are read as 16 coils in memory byte order:
//! coils 0..7 are bits 0..7 of the high byte, coils 8..15 bits 0..7 of the low byte, as if the word
//! were two bytes of a byte area (the manual does not give the bit order within the word).

pub mod convert;
pub mod params;

use core::fmt;
use std::collections::BTreeMap;

pub use convert::{
    locate_bits, locate_registers, AccessError, BitLocation, BitTable, RegisterLocation,
    RegisterTable, MAX_BITS, MAX_REGISTERS, WORDS_PER_DB,
};
pub use params::{AddressMap, BitMapping, OperatingMode, ParamError, SlaveParams, WriteLimits};

/// A memory area of the CPU.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Area {
    /// Memory bits ("Merker"), bytes.
    M,
    /// Outputs, bytes.
    Q,
    /// Inputs, bytes.
    I,
    /// Timers, words.
    T,
    /// Counters, words.
    C,
    /// A data block, words.
    Db(u16),
}

impl fmt::Display for Area {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::M => f.write_str("M"),
            Self::Q => f.write_str("Q"),
            Self::I => f.write_str("I"),
            Self::T => f.write_str("T"),
            Self::C => f.write_str("C"),
            Self::Db(n) => write!(f, "DB{n}"),
        }
    }
}

/// The sizes of the memory areas. The CPU's sizes are "CPU type-dependent" (6.4.7.1, ERROR_NR
/// 14..17); the defaults are those of a mid-size S7-300 CPU and cover the manual's example map.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MemoryLayout {
    /// Memory bytes MB 0..
    pub m_bytes: u32,
    /// Output bytes QB 0..
    pub q_bytes: u32,
    /// Input bytes IB 0..
    pub i_bytes: u32,
    /// Timers T 0..
    pub timers: u32,
    /// Counters C 0..
    pub counters: u32,
    /// Data blocks: number and length in words (the slave reaches the first 512 words, 6.4.8).
    pub data_blocks: Vec<(u16, u16)>,
}

impl Default for MemoryLayout {
    /// M, Q and I 2048 bytes, 256 timers and counters, DB 800 and DB 801 of 512 words (the DBs of
    /// the manual's examples, 6.4.8.3).
    fn default() -> Self {
        Self {
            m_bytes: 2048,
            q_bytes: 2048,
            i_bytes: 2048,
            timers: 256,
            counters: 256,
            data_blocks: vec![(800, 512), (801, 512)],
        }
    }
}

/// What a write changed, for the caller's change notifications.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Written {
    /// The area written.
    pub area: Area,
    /// The first byte (M, Q) or word (DB) written.
    pub first: u32,
    /// How many bytes or words were touched.
    pub len: u32,
}

/// The memory areas of the CP's CPU, owned by the gateway.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CpMemory {
    m: Vec<u8>,
    q: Vec<u8>,
    i: Vec<u8>,
    t: Vec<u16>,
    c: Vec<u16>,
    dbs: BTreeMap<u16, Vec<u16>>,
}

/// Sizes above this are cut to it: the addressable range of a byte area, timers, counters.
const MAX_AREA: u32 = 0x1_0000;

fn size(n: u32) -> usize {
    usize::try_from(n.min(MAX_AREA)).unwrap_or(0)
}

/// Bit `n` (counted from `bit` of byte 0) of `bytes`.
fn get_bit(bytes: &[u8], bit: u8, n: usize) -> Option<bool> {
    let index = usize::from(bit) + n;
    bytes.get(index / 8).map(|b| b & (1 << (index % 8)) != 0)
}

fn set_bit(bytes: &mut [u8], bit: u8, n: usize, value: bool) {
    let index = usize::from(bit) + n;
    if let Some(b) = bytes.get_mut(index / 8) {
        let mask = 1 << (index % 8);
        if value {
            *b |= mask;
        } else {
            *b &= !mask;
        }
    }
}

// === impl CpMemory ===

impl CpMemory {
    /// Zeroed memory of the given layout (a DB listed twice keeps its last length).
    pub fn new(layout: &MemoryLayout) -> Self {
        Self {
            m: vec![0; size(layout.m_bytes)],
            q: vec![0; size(layout.q_bytes)],
            i: vec![0; size(layout.i_bytes)],
            t: vec![0; size(layout.timers)],
            c: vec![0; size(layout.counters)],
            dbs: layout
                .data_blocks
                .iter()
                .map(|&(n, words)| (n, vec![0; usize::from(words)]))
                .collect(),
        }
    }

    /// Memory bytes.
    pub fn m(&self) -> &[u8] {
        &self.m
    }
    /// Memory bytes, writable by the gateway.
    pub fn m_mut(&mut self) -> &mut [u8] {
        &mut self.m
    }
    /// Output bytes.
    pub fn q(&self) -> &[u8] {
        &self.q
    }
    /// Output bytes, writable by the gateway.
    pub fn q_mut(&mut self) -> &mut [u8] {
        &mut self.q
    }
    /// Input bytes.
    pub fn i(&self) -> &[u8] {
        &self.i
    }
    /// Input bytes, writable by the gateway (the process inputs of a real CPU).
    pub fn i_mut(&mut self) -> &mut [u8] {
        &mut self.i
    }
    /// Timer words.
    pub fn timers(&self) -> &[u16] {
        &self.t
    }
    /// Timer words, writable by the gateway.
    pub fn timers_mut(&mut self) -> &mut [u16] {
        &mut self.t
    }
    /// Counter words.
    pub fn counters(&self) -> &[u16] {
        &self.c
    }
    /// Counter words, writable by the gateway.
    pub fn counters_mut(&mut self) -> &mut [u16] {
        &mut self.c
    }
    /// The words of data block `n`, if it exists.
    pub fn db(&self, n: u16) -> Option<&[u16]> {
        self.dbs.get(&n).map(Vec::as_slice)
    }
    /// The words of data block `n`, writable by the gateway.
    pub fn db_mut(&mut self, n: u16) -> Option<&mut [u16]> {
        self.dbs.get_mut(&n).map(Vec::as_mut_slice)
    }

    fn bytes(&self, area: Area) -> &[u8] {
        match area {
            Area::M => &self.m,
            Area::Q => &self.q,
            Area::I => &self.i,
            _ => &[],
        }
    }

    fn bytes_mut(&mut self, area: Area) -> &mut [u8] {
        match area {
            Area::M => &mut self.m,
            Area::Q => &mut self.q,
            Area::I => &mut self.i,
            _ => &mut [],
        }
    }

    /// The `len` bytes from `first` of a byte area, or the error of 7.2 0E 38h.
    fn byte_span(
        &self,
        area: Area,
        first: u32,
        bit: u8,
        quantity: u16,
    ) -> Result<(usize, usize), AccessError> {
        let len = (usize::from(bit) + usize::from(quantity)).div_ceil(8);
        let first = usize::try_from(first).map_err(|_| AccessError::BeyondAreaEnd { area })?;
        if first + len > self.bytes(area).len() {
            return Err(AccessError::BeyondAreaEnd { area });
        }
        Ok((first, len))
    }

    /// FC 01 (`BitTable::Coils`) and FC 02 (`BitTable::Inputs`): `quantity` bits from `start`.
    pub fn read_bits(
        &self,
        map: &AddressMap,
        table: BitTable,
        start: u16,
        quantity: u16,
    ) -> Result<Vec<bool>, AccessError> {
        let n = usize::from(quantity);
        match locate_bits(map, table, start, quantity, false)? {
            BitLocation::Byte { area, byte, bit } => {
                let (first, len) = self.byte_span(area, byte, bit, quantity)?;
                let bytes = self
                    .bytes(area)
                    .get(first..first + len)
                    .ok_or(AccessError::BeyondAreaEnd { area })?;
                (0..n)
                    .map(|k| get_bit(bytes, bit, k).ok_or(AccessError::BeyondAreaEnd { area }))
                    .collect()
            }
            BitLocation::Word { area, word } => {
                let words = if area == Area::T { &self.t } else { &self.c };
                let first =
                    usize::try_from(word).map_err(|_| AccessError::BeyondAreaEnd { area })?;
                let count = n / usize::from(convert::BITS_PER_WORD);
                let words = words
                    .get(first..first + count)
                    .ok_or(AccessError::BeyondAreaEnd { area })?;
                let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_be_bytes()).collect();
                (0..n)
                    .map(|k| get_bit(&bytes, 0, k).ok_or(AccessError::BeyondAreaEnd { area }))
                    .collect()
            }
        }
    }

    /// FC 05 (one value) and FC 15: writes `values` from coil address `start` into M or Q, if the
    /// bytes touched are write-enabled.
    pub fn write_bits(
        &mut self,
        map: &AddressMap,
        start: u16,
        values: &[bool],
    ) -> Result<Written, AccessError> {
        let quantity = u16::try_from(values.len()).unwrap_or(u16::MAX);
        let BitLocation::Byte { area, byte, bit } =
            locate_bits(map, BitTable::Coils, start, quantity, true)?
        else {
            // `locate_bits` refuses timers and counters for writes.
            return Err(AccessError::NotMapped { address: start });
        };
        let len = (u32::from(bit) + u32::from(quantity)).div_ceil(8);
        if !map.limits().allows_bytes(area, byte, byte + len - 1) {
            return Err(AccessError::WriteNotEnabled { area });
        }
        let (first, len) = self.byte_span(area, byte, bit, quantity)?;
        let bytes = self
            .bytes_mut(area)
            .get_mut(first..first + len)
            .ok_or(AccessError::BeyondAreaEnd { area })?;
        for (k, value) in values.iter().enumerate() {
            set_bit(bytes, bit, k, *value);
        }
        Ok(Written {
            area,
            first: byte,
            len: u32::try_from(len).unwrap_or(u32::MAX),
        })
    }

    /// The words a register request reaches, or the error of 7.2 0E 39h.
    fn db_words(&self, at: RegisterLocation, quantity: u16) -> Result<&[u16], AccessError> {
        let first = usize::from(at.word);
        self.dbs
            .get(&at.db)
            .and_then(|words| words.get(first..first + usize::from(quantity)))
            .ok_or(AccessError::DbMissingOrShort { db: at.db })
    }

    /// FC 03 (`RegisterTable::Holding`) and FC 04 (`RegisterTable::Input`).
    pub fn read_registers(
        &self,
        map: &AddressMap,
        table: RegisterTable,
        start: u16,
        quantity: u16,
    ) -> Result<Vec<u16>, AccessError> {
        let at = locate_registers(map, table, start, quantity)?;
        self.db_words(at, quantity).map(<[u16]>::to_vec)
    }

    /// FC 06 (one value) and FC 16: writes `values` from register `start` (FC 03/06/16 base DB), if
    /// the DB is write-enabled.
    pub fn write_registers(
        &mut self,
        map: &AddressMap,
        start: u16,
        values: &[u16],
    ) -> Result<Written, AccessError> {
        let quantity = u16::try_from(values.len()).unwrap_or(u16::MAX);
        let at = locate_registers(map, RegisterTable::Holding, start, quantity)?;
        if !map.limits().allows_db(at.db) {
            return Err(AccessError::WriteNotEnabled {
                area: Area::Db(at.db),
            });
        }
        self.db_words(at, quantity)?;
        let first = usize::from(at.word);
        let words = self
            .dbs
            .get_mut(&at.db)
            .and_then(|words| words.get_mut(first..first + values.len()))
            .ok_or(AccessError::DbMissingOrShort { db: at.db })?;
        words.copy_from_slice(values);
        Ok(Written {
            area: Area::Db(at.db),
            first: u32::from(at.word),
            len: u32::from(quantity),
        })
    }
}

impl Default for CpMemory {
    /// Zeroed memory of [`MemoryLayout::default`].
    fn default() -> Self {
        Self::new(&MemoryLayout::default())
    }
}

/// How an engine reaches the memory it serves: the memory itself, a `&mut` to it, or a handle of
/// the caller's (e.g. a lock shared with the Modbus TCP server) that lends it for one call.
pub trait MemoryAccess {
    /// Runs `f` on the memory.
    fn with_memory<R>(&mut self, f: impl FnOnce(&mut CpMemory) -> R) -> R;
}

impl MemoryAccess for CpMemory {
    fn with_memory<R>(&mut self, f: impl FnOnce(&mut Self) -> R) -> R {
        f(self)
    }
}

impl MemoryAccess for &mut CpMemory {
    fn with_memory<R>(&mut self, f: impl FnOnce(&mut CpMemory) -> R) -> R {
        f(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timer_bits_in_memory_byte_order() {
        let mut mem = CpMemory::default();
        mem.timers_mut()[100] = 0x8001;
        let bits = mem
            .read_bits(&AddressMap::manual_example(), BitTable::Coils, 2048, 16)
            .expect("T 100");
        // High byte 80h first: coil 7 set; low byte 01h: coil 8 set.
        let set: Vec<usize> = bits
            .iter()
            .enumerate()
            .filter(|(_, b)| **b)
            .map(|(k, _)| k)
            .collect();
        assert_eq!(set, vec![7, 8]);
    }

    #[test]
    fn unaligned_bit_writes_touch_only_their_bits() {
        let limits = WriteLimits {
            memory: Some((1000, 1001)),
            ..WriteLimits::NONE
        };
        let map = AddressMap::manual_example()
            .with_limits(limits)
            .expect("valid");
        let mut mem = CpMemory::default();
        mem.m_mut()[1000] = 0xFF;
        let written = mem
            .write_bits(&map, 6, &[false, false, true, false])
            .expect("M 1000.6 .. 1001.1");
        assert_eq!(
            written,
            Written {
                area: Area::M,
                first: 1000,
                len: 2
            }
        );
        assert_eq!(&mem.m()[1000..1002], &[0x3F, 0x01]);
        assert_eq!(
            mem.write_bits(&map, 14, &[true; 3]),
            Err(AccessError::WriteNotEnabled { area: Area::M })
        );
    }
}
