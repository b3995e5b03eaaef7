//! The CP memory as the process image shows it: the Modbus view of one address map under one unit
//! id, so that zenoh and REST reach the memory like any polled device's registers.
//!
//! The view is the inverse of the slave's address conversion (003 6.4.8): a byte of M, Q or I is
//! eight coils or discrete inputs of every bit-table row that maps its area, a timer or counter is
//! sixteen coils in memory byte order (see [`proto_core::cpmem`]), and data word `w` of DB `n` is
//! register `(n - base) x 512 + w` of the holding table (base DB of FC 03) and of the input table
//! (base DB of FC 04). Values are stored with quality good and no poll period: they never turn
//! stale, the memory is always current.

use proto_core::cpmem::{AddressMap, Area, BitMapping, CpMemory, Written, WORDS_PER_DB};

use crate::image::{ProcessImage, Table};

/// How many DBs one base DB reaches: register addresses 0..65535 in DBs of 512 words (003 6.4.5
/// "Up to 128 DB may be accessed in one block").
const DBS_PER_BLOCK: u32 = 0x1_0000 / WORDS_PER_DB as u32;

/// Bits per timer or counter word (003 6.4.8.1 "Conversion counter and timer").
const BITS_PER_WORD: u32 = 16;

/// One image view of the memory.
#[derive(Clone, Debug)]
pub struct Mirror {
    image: ProcessImage,
    unit: u8,
    map: AddressMap,
}

// === impl Mirror ===

impl Mirror {
    /// A view of the memory through `map`, kept in `image` under `unit`.
    pub fn new(image: ProcessImage, unit: u8, map: AddressMap) -> Self {
        Self { image, unit, map }
    }

    /// The unit id in the image.
    pub fn unit(&self) -> u8 {
        self.unit
    }

    /// The address map the memory is seen through.
    pub fn map(&self) -> &AddressMap {
        &self.map
    }

    /// Stores in the image the Modbus addresses that `written` covers, with the values `memory`
    /// holds now.
    pub fn publish(&self, memory: &CpMemory, written: Written) {
        match written.area {
            Area::Db(n) => self.publish_db(memory, n, written),
            area => {
                self.publish_bits(memory, Table::Coils, self.map.coils(), area, written);
                self.publish_bits(
                    memory,
                    Table::DiscreteInputs,
                    self.map.inputs(),
                    area,
                    written,
                );
            }
        }
    }

    fn publish_bits(
        &self,
        memory: &CpMemory,
        table: Table,
        rows: &[BitMapping],
        area: Area,
        written: Written,
    ) {
        for (index, row) in rows.iter().enumerate() {
            if row.area != area {
                continue;
            }
            // A row ends where the next row of its table starts (proto-core's conversion).
            let row_end = rows
                .get(index + 1)
                .map_or(0x1_0000, |next| u32::from(next.modbus_start));
            let row_len = row_end.saturating_sub(u32::from(row.modbus_start));
            let bits = row_bits(memory, *row, written, row_len);
            let Some((first, values)) = bits else {
                continue;
            };
            let Ok(start) = u16::try_from(u32::from(row.modbus_start) + first) else {
                continue;
            };
            self.image
                .store_bits(self.unit, table, start, &values, None);
        }
    }

    fn publish_db(&self, memory: &CpMemory, db: u16, written: Written) {
        let Some(words) = memory.db(db) else {
            return;
        };
        let reachable = words.len().min(usize::from(WORDS_PER_DB));
        let lo = usize::try_from(written.first).unwrap_or(usize::MAX);
        let hi = usize::try_from(written.first.saturating_add(written.len))
            .unwrap_or(usize::MAX)
            .min(reachable);
        let Some(values) = words.get(lo..hi).filter(|v| !v.is_empty()) else {
            return;
        };
        for (table, base) in [
            (Table::HoldingRegisters, self.map.holding_base_db()),
            (Table::InputRegisters, self.map.input_base_db()),
        ] {
            let Some(offset) = db.checked_sub(base).map(u32::from) else {
                continue;
            };
            if offset >= DBS_PER_BLOCK {
                continue;
            }
            let address = offset * u32::from(WORDS_PER_DB) + written.first;
            if let Ok(start) = u16::try_from(address) {
                self.image
                    .store_words(self.unit, table, start, values, None);
            }
        }
    }
}

/// The bits of `row` (relative to its Modbus start) that `written` touches, clipped to the row and
/// to the area's size: the first relative bit and the values.
fn row_bits(
    memory: &CpMemory,
    row: BitMapping,
    written: Written,
    row_len: u32,
) -> Option<(u32, Vec<bool>)> {
    let plc = u32::from(row.plc_start);
    let first = written.first.saturating_sub(plc);
    let end = written
        .first
        .saturating_add(written.len)
        .saturating_sub(plc);
    match row.area {
        Area::M | Area::Q | Area::I => {
            let bytes = match row.area {
                Area::M => memory.m(),
                Area::Q => memory.q(),
                _ => memory.i(),
            };
            let bytes = bytes.get(usize::try_from(plc).ok()?..)?;
            let area_bits = u32::try_from(bytes.len()).ok()?.saturating_mul(8);
            let lo = first.saturating_mul(8);
            let hi = end.saturating_mul(8).min(row_len).min(area_bits);
            let values = (lo..hi)
                .map(|k| {
                    let byte = bytes.get(usize::try_from(k / 8).ok()?)?;
                    Some(byte & (1 << (k % 8)) != 0)
                })
                .collect::<Option<Vec<bool>>>()?;
            (!values.is_empty()).then_some((lo, values))
        }
        Area::T | Area::C => {
            let words = if row.area == Area::T {
                memory.timers()
            } else {
                memory.counters()
            };
            let words = words.get(usize::try_from(plc).ok()?..)?;
            let area_bits = u32::try_from(words.len())
                .ok()?
                .saturating_mul(BITS_PER_WORD);
            let lo = first.saturating_mul(BITS_PER_WORD);
            let hi = end
                .saturating_mul(BITS_PER_WORD)
                .min(row_len)
                .min(area_bits);
            let values = (lo..hi)
                .map(|k| {
                    let word = words.get(usize::try_from(k / BITS_PER_WORD).ok()?)?;
                    // Memory byte order: coils 0..7 in the high byte, 8..15 in the low byte.
                    let byte = word.to_be_bytes()[usize::from(k % BITS_PER_WORD >= 8)];
                    Some(byte & (1 << (k % 8)) != 0)
                })
                .collect::<Option<Vec<bool>>>()?;
            (!values.is_empty()).then_some((lo, values))
        }
        Area::Db(_) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto_core::cpmem::{BitTable, MemoryLayout, RegisterTable};

    fn whole(area: Area, len: u32) -> Written {
        Written {
            area,
            first: 0,
            len,
        }
    }

    /// Everything the image shows agrees with what the slave's conversion reads.
    #[test]
    fn the_image_shows_what_the_conversion_reads() {
        let map = AddressMap::manual_example();
        let mut memory = CpMemory::new(&MemoryLayout::default());
        memory.m_mut()[1000] = 0b1000_0001;
        memory.m_mut()[1127] = 0x80;
        memory.q_mut()[100] = 0x02;
        memory.i_mut()[100] = 0x04;
        memory.timers_mut()[100] = 0x8001;
        memory.counters_mut()[202] = 0x0100;
        memory.db_mut(800).expect("DB 800")[5] = 0x1234;
        memory.db_mut(801).expect("DB 801")[511] = 0xBEEF;
        let image = ProcessImage::default();
        let mirror = Mirror::new(image.clone(), 9, map.clone());
        for w in [
            whole(Area::M, 2048),
            whole(Area::Q, 2048),
            whole(Area::I, 2048),
            whole(Area::T, 256),
            whole(Area::C, 256),
            whole(Area::Db(800), 512),
            whole(Area::Db(801), 512),
        ] {
            mirror.publish(&memory, w);
        }
        for (table, bit_table, start, quantity) in [
            (Table::Coils, BitTable::Coils, 0, 1024),
            (Table::Coils, BitTable::Coils, 1024, 1024),
            (Table::Coils, BitTable::Coils, 2048, 256),
            (Table::Coils, BitTable::Coils, 4064, 64),
            (Table::DiscreteInputs, BitTable::Inputs, 0, 1024),
            (Table::DiscreteInputs, BitTable::Inputs, 1024, 1024),
        ] {
            let expected = memory
                .read_bits(&map, bit_table, start, quantity)
                .expect("mapped");
            let shown = image
                .read_bits(9, table, start, quantity)
                .expect("mirrored");
            assert_eq!(shown.values, expected, "{table:?} {start}+{quantity}");
        }
        for (table, register_table, start) in [
            (Table::HoldingRegisters, RegisterTable::Holding, 0),
            (Table::HoldingRegisters, RegisterTable::Holding, 512 + 400),
            (Table::InputRegisters, RegisterTable::Input, 0),
        ] {
            let expected = memory
                .read_registers(&map, register_table, start, 112)
                .expect("mapped");
            let shown = image.read_words(9, table, start, 112).expect("mirrored");
            assert_eq!(shown.values, expected, "{table:?} {start}");
        }
        // The timer rows end where the counters start: T 100..225 (2016 bits), C 200..255.
        assert_eq!(
            image.snapshot(9, Table::Coils).len(),
            1024 + 1024 + 2016 + 56 * 16
        );
        assert_eq!(image.snapshot(9, Table::HoldingRegisters).len(), 1024);
    }

    #[test]
    fn a_small_write_publishes_only_its_addresses() {
        let map = AddressMap::manual_example();
        let mut memory = CpMemory::new(&MemoryLayout::default());
        memory.q_mut()[101] = 0xFF;
        memory.db_mut(801).expect("DB 801")[3] = 77;
        let image = ProcessImage::default();
        let mirror = Mirror::new(image.clone(), 1, map);
        mirror.publish(
            &memory,
            Written {
                area: Area::Q,
                first: 101,
                len: 1,
            },
        );
        mirror.publish(
            &memory,
            Written {
                area: Area::Db(801),
                first: 3,
                len: 1,
            },
        );
        let coils = image.snapshot(1, Table::Coils);
        assert_eq!(coils.len(), 8);
        assert_eq!(coils[0].address, 1024 + 8);
        assert!(coils.iter().all(|s| s.value == 1));
        let regs = image.snapshot(1, Table::HoldingRegisters);
        assert_eq!((regs.len(), regs[0].address, regs[0].value), (1, 515, 77));
        // A write outside every row (M 0, below the row's M 1000) shows nothing.
        mirror.publish(
            &memory,
            Written {
                area: Area::M,
                first: 0,
                len: 1,
            },
        );
        assert_eq!(image.snapshot(1, Table::DiscreteInputs).len(), 0);
    }
}
