//! The gateway's CP memory: the M, Q, I, T, C areas and data blocks that a CP 341 in Modbus slave
//! mode reads and writes in its CPU (003 6.4.6: "the Modbus address of the message of the master
//! is transformed to the memory area of the CPU"). The gateway has no CPU, so it owns that memory.
//!
//! One [`SharedCpMemory`] is shared by everything that reaches it:
//! - the Modbus slave RTU lines, whose proto-core engine borrows it for one request at a time
//!   through [`MemoryAccess`];
//! - Modbus TCP, through a [`CpMemoryUnit`] with the same address conversion and the same
//!   exceptions as the serial slave;
//! - the process image, which mirrors the mapped part of the memory under a unit id
//!   ([`SharedCpMemory::mirror_to`]) so that zenoh and REST see it like any other tag;
//! - optionally a file ([`persist`]): loaded at start, saved periodically and at shutdown;
//! - a `modbus-slave-rtu` line's config becomes slave parameters and a memory layout in
//!   [`crate::protocols::modbus_slave::cpmem`].
//!
//! Every change goes through [`SharedCpMemory::write_bits`], [`SharedCpMemory::write_registers`],
//! [`SharedCpMemory::update`] or, for the serial engine's own writes,
//! [`SharedCpMemory::note_written`]: each bumps the generation that the persistence task watches
//! and refreshes the mirrors while the memory lock is held, so the image never shows an older
//! state than the memory after a later write.

mod mirror;
pub mod persist;
mod unit;

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

use proto_core::cpmem::{
    AccessError, AddressMap, Area, BitTable, CpMemory, MemoryAccess, MemoryLayout, RegisterTable,
    Written,
};

use crate::image::ProcessImage;

pub use mirror::Mirror;
pub use persist::{
    probe as probe_file, spawn_persistence, LoadReport, LoadStatus, PersistError, PersistSettings,
    DEFAULT_SAVE_INTERVAL,
};
pub use unit::CpMemoryUnit;

/// The memory and what hangs on its changes.
#[derive(Debug)]
struct State {
    memory: CpMemory,
    /// Image mirrors, refreshed on every change.
    mirrors: Vec<Mirror>,
}

#[derive(Debug)]
struct Inner {
    /// The sizes the memory was made with (persistence walks them: [`CpMemory`] does not list its
    /// data blocks).
    layout: MemoryLayout,
    state: Mutex<State>,
    /// Bumped on every change; the persistence task saves when it moved.
    generation: AtomicU64,
}

/// The CP memory shared between serial slave lines, Modbus TCP, the image and persistence; clones
/// are cheap and see the same memory.
#[derive(Clone, Debug)]
pub struct SharedCpMemory {
    inner: Arc<Inner>,
}

// === impl SharedCpMemory ===

impl SharedCpMemory {
    /// Zeroed memory of `layout`.
    pub fn new(layout: MemoryLayout) -> Self {
        let memory = CpMemory::new(&layout);
        Self::from_memory(layout, memory)
    }

    /// Shares `memory`, made with `layout`.
    pub fn from_memory(layout: MemoryLayout, memory: CpMemory) -> Self {
        Self {
            inner: Arc::new(Inner {
                layout,
                state: Mutex::new(State {
                    memory,
                    mirrors: Vec::new(),
                }),
                generation: AtomicU64::new(0),
            }),
        }
    }

    /// The sizes of the areas.
    pub fn layout(&self) -> &MemoryLayout {
        &self.inner.layout
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        self.inner
            .state
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
    }

    /// How many changes the memory has seen (for the persistence task).
    pub fn generation(&self) -> u64 {
        self.inner.generation.load(Ordering::Acquire)
    }

    fn changed(&self, state: &State, written: &[Written]) {
        self.inner.generation.fetch_add(1, Ordering::AcqRel);
        for mirror in &state.mirrors {
            for w in written {
                mirror.publish(&state.memory, *w);
            }
        }
    }

    /// Runs `f` on the memory for reading.
    pub fn read<R>(&self, f: impl FnOnce(&CpMemory) -> R) -> R {
        f(&self.lock().memory)
    }

    /// A copy of the whole memory.
    pub fn snapshot(&self) -> CpMemory {
        self.read(Clone::clone)
    }

    /// Changes the memory from the gateway's side (inputs, timers, counters, a REST write of a
    /// whole area): `f` runs under the lock, then every mirror is refreshed as a whole.
    pub fn update<R>(&self, f: impl FnOnce(&mut CpMemory) -> R) -> R {
        let mut state = self.lock();
        let result = f(&mut state.memory);
        let all = whole_areas(&self.inner.layout);
        self.changed(&state, &all);
        result
    }

    /// A write the serial slave engine made (its `SlaveEvent::Written`): counts the change and
    /// refreshes the mirrors from the memory as it is now.
    pub fn note_written(&self, written: Written) {
        let state = self.lock();
        self.changed(&state, &[written]);
    }

    /// FC 01 and FC 02 with the conversion of `map` (003 6.4.8.1, 6.4.8.2).
    pub fn read_bits(
        &self,
        map: &AddressMap,
        table: BitTable,
        start: u16,
        quantity: u16,
    ) -> Result<Vec<bool>, AccessError> {
        self.lock().memory.read_bits(map, table, start, quantity)
    }

    /// FC 03 and FC 04 with the conversion of `map` (003 6.4.8.3, 6.4.8.4).
    pub fn read_registers(
        &self,
        map: &AddressMap,
        table: RegisterTable,
        start: u16,
        quantity: u16,
    ) -> Result<Vec<u16>, AccessError> {
        self.lock()
            .memory
            .read_registers(map, table, start, quantity)
    }

    /// FC 05 and FC 15 with the conversion and write limits of `map` (003 6.4.8.5, 6.4.8.8).
    pub fn write_bits(
        &self,
        map: &AddressMap,
        start: u16,
        values: &[bool],
    ) -> Result<Written, AccessError> {
        let mut state = self.lock();
        let written = state.memory.write_bits(map, start, values)?;
        self.changed(&state, &[written]);
        Ok(written)
    }

    /// FC 06 and FC 16 with the conversion and write limits of `map` (003 6.4.8.6, 6.4.8.9).
    pub fn write_registers(
        &self,
        map: &AddressMap,
        start: u16,
        values: &[u16],
    ) -> Result<Written, AccessError> {
        let mut state = self.lock();
        let written = state.memory.write_registers(map, start, values)?;
        self.changed(&state, &[written]);
        Ok(written)
    }

    /// Mirrors the memory into `image` under `unit` as `map` shows it to Modbus: coils, discrete
    /// inputs, holding and input registers, quality good, never stale. Publishes everything now
    /// and every change from then on.
    pub fn mirror_to(&self, image: ProcessImage, unit: u8, map: AddressMap) {
        let mirror = Mirror::new(image, unit, map);
        let mut state = self.lock();
        for w in whole_areas(&self.inner.layout) {
            mirror.publish(&state.memory, w);
        }
        state.mirrors.push(mirror);
    }

    /// Stops the mirrors under `unit` through `map`: later changes no longer reach the image
    /// there (what it shows stays, with its quality). Whether there was one.
    pub fn unmirror(&self, unit: u8, map: &AddressMap) -> bool {
        let mut state = self.lock();
        let before = state.mirrors.len();
        state
            .mirrors
            .retain(|m| !(m.unit() == unit && m.map() == map));
        state.mirrors.len() != before
    }
}

/// Every area of `layout` as one write each.
fn whole_areas(layout: &MemoryLayout) -> Vec<Written> {
    let whole = |area, len| Written {
        area,
        first: 0,
        len,
    };
    let mut all = vec![
        whole(Area::M, layout.m_bytes),
        whole(Area::Q, layout.q_bytes),
        whole(Area::I, layout.i_bytes),
        whole(Area::T, layout.timers),
        whole(Area::C, layout.counters),
    ];
    all.extend(
        layout
            .data_blocks
            .iter()
            .map(|&(n, words)| whole(Area::Db(n), u32::from(words))),
    );
    all
}

/// The serial slave engine borrows the memory for one request at a time. Its writes come back as
/// `SlaveEvent::Written`, which the line hands to [`SharedCpMemory::note_written`].
impl MemoryAccess for SharedCpMemory {
    fn with_memory<R>(&mut self, f: impl FnOnce(&mut CpMemory) -> R) -> R {
        f(&mut self.lock().memory)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Table;
    use proto_core::cpmem::WriteLimits;

    fn writable_map() -> AddressMap {
        AddressMap::manual_example()
            .with_limits(WriteLimits {
                memory: Some((1000, 1127)),
                outputs: Some((100, 227)),
                data_blocks: Some((800, 801)),
            })
            .expect("valid limits")
    }

    #[test]
    fn writes_bump_the_generation_and_refusals_do_not() {
        let memory = SharedCpMemory::new(MemoryLayout::default());
        let map = writable_map();
        assert_eq!(memory.generation(), 0);
        memory.write_registers(&map, 3, &[7, 8]).expect("DB 800");
        assert_eq!(memory.generation(), 1);
        assert_eq!(
            memory.write_registers(&AddressMap::manual_example(), 3, &[1]),
            Err(AccessError::WriteNotEnabled {
                area: Area::Db(800)
            })
        );
        assert_eq!(memory.generation(), 1);
        memory.note_written(Written {
            area: Area::M,
            first: 1000,
            len: 1,
        });
        assert_eq!(memory.generation(), 2);
        memory.update(|m| m.timers_mut()[100] = 5);
        assert_eq!(memory.generation(), 3);
        assert_eq!(
            memory.read(|m| m.db(800).map(|d| d[3..5].to_vec())),
            Some(vec![7, 8])
        );
    }

    #[test]
    fn an_unmirrored_unit_no_longer_follows_the_memory() {
        let memory = SharedCpMemory::new(MemoryLayout::default());
        let map = writable_map();
        let image = ProcessImage::default();
        memory.mirror_to(image.clone(), 50, map.clone());
        memory.mirror_to(image.clone(), 51, map.clone());
        let word = |unit| {
            image
                .read_words(unit, Table::HoldingRegisters, 3, 1)
                .expect("mirrored")
                .values
        };
        memory.write_registers(&map, 3, &[7]).expect("DB 800");
        assert_eq!((word(50), word(51)), (vec![7], vec![7]));
        assert!(memory.unmirror(50, &map));
        assert!(!memory.unmirror(50, &map), "only once");
        assert!(
            !memory.unmirror(51, &AddressMap::manual_example()),
            "another map"
        );
        memory.write_registers(&map, 3, &[8]).expect("DB 800");
        assert_eq!((word(50), word(51)), (vec![7], vec![8]));
    }

    #[test]
    fn the_engine_borrows_the_shared_memory() {
        let memory = SharedCpMemory::new(MemoryLayout::default());
        let mut handle = memory.clone();
        handle.with_memory(|m| m.m_mut()[1000] = 0x81);
        let bits = memory
            .read_bits(&AddressMap::manual_example(), BitTable::Coils, 0, 8)
            .expect("M 1000");
        assert_eq!(
            bits,
            vec![true, false, false, false, false, false, false, true]
        );
    }
}
