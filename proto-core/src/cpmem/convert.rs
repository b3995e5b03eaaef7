//! The address conversion of the CP 341 Modbus slave (manual 003 6.4.8, same in 000 6.4.8): pure
//! functions from a Modbus address and quantity to a place in the CPU memory, and the access
//! errors with their exception codes and events.

use core::fmt;

use super::params::{AddressMap, BitMapping};
use super::Area;
use crate::event::{ids, EventId};

/// 003 6.4.8.1/6.4.8.2/6.4.8.8: "Values between 1 and 2040 are permitted as bit_number".
pub const MAX_BITS: u16 = 2040;
/// 003 6.4.8.3/6.4.8.9: "Values between 1 and 127 are permitted as register_number".
pub const MAX_REGISTERS: u16 = 127;
/// 003 6.4.8: "a maximum data block length of 512 data words"; start_register / 512 selects the
/// DB, start_register % 512 the word (table "Further values").
pub const WORDS_PER_DB: u16 = 512;
/// 003 6.4.8.1 "Conversion counter and timer": one timer or counter is 16 bits of the request.
pub const BITS_PER_WORD: u16 = 16;
/// 003 6.4.8.1: "Maximally 16 timers and counters may be accessed" (16 x 16 bits).
pub const MAX_TIMER_COUNTER_BITS: u16 = 16 * BITS_PER_WORD;

/// Which of the two bit tables a request uses (003 6.4.5 "FC 01, 05, 15, 02").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BitTable {
    /// FC 01 (read), 05 and 15 (write): M, Q, T, C.
    Coils,
    /// FC 02 (read only): M, I.
    Inputs,
}

/// Which base DB a register request uses (003 6.4.5 "FC 03, 06, 16, 04").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum RegisterTable {
    /// FC 03 (read), 06 and 16 (write).
    Holding,
    /// FC 04 (read only), its own base DB.
    Input,
}

/// Where the first bit of a bit request lands.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BitLocation {
    /// M, Q or I: "Byte address = ((start_addr - Param-start-address) / 8) + PLC-area", "Rest-bit-number
    /// = (start_addr - Param-start-address) % 8".
    Byte {
        /// M, Q or I.
        area: Area,
        /// The byte number (may lie beyond the configured area; the memory checks it).
        byte: u32,
        /// The bit within the byte, 0..7.
        bit: u8,
    },
    /// T or C: "Word address = ((start_addr - Param-start-address) / 16) + PLC-area".
    Word {
        /// T or C.
        area: Area,
        /// The timer or counter number.
        word: u32,
    },
}

impl fmt::Display for BitLocation {
    /// As the manual writes it: `M 1062.1`, `T 172`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Byte { area, byte, bit } => write!(f, "{area} {byte}.{bit}"),
            Self::Word { area, word } => write!(f, "{area} {word}"),
        }
    }
}

/// Where the first register of a register request lands.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct RegisterLocation {
    /// "Data block DB = Base-DB-Number + start_register-offset_DB_no."
    pub db: u16,
    /// The word number within the DB, 0..511 (start_register % 512).
    pub word: u16,
}

// === impl RegisterLocation ===

impl RegisterLocation {
    /// "Data word DBW = start_register-word_no. x 2": the byte address of the word.
    pub const fn dbw(self) -> u32 {
        self.word as u32 * 2
    }
}

impl fmt::Display for RegisterLocation {
    /// `DB801.DBW776`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "DB{}.DBW{}", self.db, self.dbw())
    }
}

/// Why an access was refused. `ExceptionCode::from` (in `modbus::slave::serve`, the one place of
/// that mapping) gives the exception the slave answers and [`AccessError::event`] the 7.2 event the
/// CP reports for it.
///
/// 003 6.4.6 "Error codes" lists the Modbus exception codes but not which error gives which; the
/// mapping follows the Modbus Application Protocol V1.1b3 (6.x state diagrams): a quantity out of
/// range is 03, an address that the server cannot serve is 02.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum AccessError {
    /// Quantity outside 1..=max (6.4.8: 1..2040 bits, 1..127 registers; timers and counters: a
    /// multiple of 16, at most 256).
    #[error("quantity {quantity} not allowed (1..={max}{grid})", grid = if *.timer_grid { ", a multiple of 16" } else { "" })]
    IllegalQuantity {
        /// The requested quantity.
        quantity: u16,
        /// The largest allowed.
        max: u16,
        /// Whether the quantity had to be a multiple of 16 (timers, counters).
        timer_grid: bool,
    },
    /// No row of the bit table covers the start address.
    #[error("Modbus address {address} is not mapped")]
    NotMapped {
        /// The start address of the request.
        address: u16,
    },
    /// The request runs into the next row of the bit table (one request, one area).
    #[error("request at {address} crosses from {area} into the next area")]
    CrossesArea {
        /// The start address of the request.
        address: u16,
        /// The area of the start address.
        area: Area,
    },
    /// A timer or counter request that does not start on a word (6.4.8.1: "Word-by-word access may
    /// only start from word limit").
    #[error("timer/counter access at {address} does not start on a 16-bit boundary")]
    Misaligned {
        /// The start address of the request.
        address: u16,
    },
    /// A write to timers or counters (6.4.5: "With timer and counters the reading access is only
    /// possible with function code FC 01").
    #[error("{area} is read-only")]
    ReadOnly {
        /// T or C.
        area: Area,
    },
    /// The request runs past the end of its DB (6.4.8: "One DB may be accessed by one message";
    /// at most 512 - word_no. registers).
    #[error(
        "request at DB{db} word {word} with {quantity} registers crosses the end of the DB block"
    )]
    CrossesDb {
        /// The DB.
        db: u16,
        /// The first word.
        word: u16,
        /// The quantity.
        quantity: u16,
    },
    /// The target is not write-enabled (6.4.5 "Limits").
    #[error("{area} is not write-enabled")]
    WriteNotEnabled {
        /// The area (a DB as `Area::Db`).
        area: Area,
    },
    /// The CPU area is too small (7.2 0E 38h "read attempt in excess of range end").
    #[error("access beyond the end of {area}")]
    BeyondAreaEnd {
        /// M, Q, I, T or C.
        area: Area,
    },
    /// The DB does not exist or is too short (7.2 0E 39h).
    #[error("DB{db} does not exist or is too short")]
    DbMissingOrShort {
        /// The DB.
        db: u16,
    },
}

// === impl AccessError ===

impl AccessError {
    /// The 7.2 event the CP reports for this error, if the manual gives one: 0E 38h for the bit
    /// areas, 0E 39h for data blocks ("does not exist or is too short").
    pub const fn event(&self) -> Option<EventId> {
        match self {
            Self::BeyondAreaEnd { .. } => Some(ids::SLAVE_BIT_AREA_ERROR),
            Self::DbMissingOrShort { .. } => Some(ids::SLAVE_DB_ERROR),
            _ => None,
        }
    }
}

/// The row of `rows` (sorted by Modbus start) that holds `address`, and where the row ends
/// (exclusive, as a 17-bit number).
fn row_of(rows: &[BitMapping], address: u16) -> Option<(BitMapping, u32)> {
    let index = rows.iter().rposition(|row| row.modbus_start <= address)?;
    let row = *rows.get(index)?;
    let end = rows
        .get(index + 1)
        .map_or(0x1_0000, |next| u32::from(next.modbus_start));
    Some((row, end))
}

/// Where `quantity` bits from Modbus address `start` land (003 6.4.8.1 FC 01, 6.4.8.2 FC 02,
/// 6.4.8.5 FC 05, 6.4.8.8 FC 15). `write` refuses timers and counters. The area sizes and write
/// limits are checked by [`super::CpMemory`].
pub fn locate_bits(
    map: &AddressMap,
    table: BitTable,
    start: u16,
    quantity: u16,
    write: bool,
) -> Result<BitLocation, AccessError> {
    if !(1..=MAX_BITS).contains(&quantity) {
        return Err(AccessError::IllegalQuantity {
            quantity,
            max: MAX_BITS,
            timer_grid: false,
        });
    }
    let rows = match table {
        BitTable::Coils => map.coils(),
        BitTable::Inputs => map.inputs(),
    };
    let (row, row_end) = row_of(rows, start).ok_or(AccessError::NotMapped { address: start })?;
    // One request stays inside one row: the manual's rows are "from 0 ... 1023", "from 1024 ...
    // 2047"; it does not say what a request across two rows does, so it is refused.
    if u32::from(start) + u32::from(quantity) > row_end {
        return Err(AccessError::CrossesArea {
            address: start,
            area: row.area,
        });
    }
    let offset = start - row.modbus_start;
    match row.area {
        Area::T | Area::C => {
            if write {
                return Err(AccessError::ReadOnly { area: row.area });
            }
            if offset % BITS_PER_WORD != 0 {
                return Err(AccessError::Misaligned { address: start });
            }
            if quantity % BITS_PER_WORD != 0 || quantity > MAX_TIMER_COUNTER_BITS {
                return Err(AccessError::IllegalQuantity {
                    quantity,
                    max: MAX_TIMER_COUNTER_BITS,
                    timer_grid: true,
                });
            }
            Ok(BitLocation::Word {
                area: row.area,
                word: u32::from(offset / BITS_PER_WORD) + u32::from(row.plc_start),
            })
        }
        area => Ok(BitLocation::Byte {
            area,
            byte: u32::from(offset / 8) + u32::from(row.plc_start),
            // `offset % 8` is below 8.
            bit: (offset % 8) as u8,
        }),
    }
}

/// Where `quantity` registers from Modbus register `start` land (003 6.4.8.3 FC 03, 6.4.8.4 FC 04,
/// 6.4.8.6 FC 06, 6.4.8.9 FC 16). The DB's existence, length and write limits are checked by
/// [`super::CpMemory`].
pub fn locate_registers(
    map: &AddressMap,
    table: RegisterTable,
    start: u16,
    quantity: u16,
) -> Result<RegisterLocation, AccessError> {
    if !(1..=MAX_REGISTERS).contains(&quantity) {
        return Err(AccessError::IllegalQuantity {
            quantity,
            max: MAX_REGISTERS,
            timer_grid: false,
        });
    }
    let base = match table {
        RegisterTable::Holding => map.holding_base_db(),
        RegisterTable::Input => map.input_base_db(),
    };
    // The base is at most FFFFh - 127 (validated), start / 512 at most 127.
    let db = base.saturating_add(start / WORDS_PER_DB);
    let word = start % WORDS_PER_DB;
    // 6.4.8.3: "Maximum register_number = 512 - start_register", start_register meaning its word
    // number (the table's DB 801 rows would otherwise allow nothing).
    if u32::from(word) + u32::from(quantity) > u32::from(WORDS_PER_DB) {
        return Err(AccessError::CrossesDb { db, word, quantity });
    }
    Ok(RegisterLocation { db, word })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::modbus::pdu::ExceptionCode;

    #[test]
    fn boundaries() {
        let map = AddressMap::manual_example();
        assert!(matches!(
            locate_bits(&map, BitTable::Coils, 0, 0, false),
            Err(AccessError::IllegalQuantity { .. })
        ));
        assert!(matches!(
            locate_bits(&map, BitTable::Coils, 0, 2041, false),
            Err(AccessError::IllegalQuantity { .. })
        ));
        assert!(matches!(
            locate_bits(&map, BitTable::Coils, 1020, 5, false),
            Err(AccessError::CrossesArea { .. })
        ));
        assert!(locate_bits(&map, BitTable::Coils, 1020, 4, false).is_ok());
        assert_eq!(
            locate_bits(&map, BitTable::Coils, 2056, 16, false),
            Err(AccessError::Misaligned { address: 2056 })
        );
        assert!(matches!(
            locate_bits(&map, BitTable::Coils, 2048, 24, false),
            Err(AccessError::IllegalQuantity { .. })
        ));
        assert!(matches!(
            locate_bits(&map, BitTable::Coils, 2048, 272, false),
            Err(AccessError::IllegalQuantity { .. })
        ));
        assert!(locate_bits(&map, BitTable::Coils, 2048, 256, false).is_ok());
        assert_eq!(
            locate_bits(&map, BitTable::Coils, 2048, 16, true),
            Err(AccessError::ReadOnly { area: Area::T })
        );
        assert_eq!(
            locate_registers(&map, RegisterTable::Holding, 511, 2).map_err(ExceptionCode::from),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            locate_registers(&map, RegisterTable::Holding, 385, 127),
            Ok(RegisterLocation { db: 800, word: 385 })
        );
        assert_eq!(
            locate_registers(&map, RegisterTable::Holding, 0, 128).map_err(ExceptionCode::from),
            Err(ExceptionCode::IllegalDataValue)
        );
        assert_eq!(
            locate_registers(&map, RegisterTable::Input, 65535, 1),
            Ok(RegisterLocation { db: 927, word: 511 })
        );
        let no_bits =
            AddressMap::new(&[], &[], 1, 1, super::super::WriteLimits::NONE).expect("valid");
        assert_eq!(
            locate_bits(&no_bits, BitTable::Inputs, 0, 1, false),
            Err(AccessError::NotMapped { address: 0 })
        );
    }
}
