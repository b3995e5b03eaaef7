//! A table of 16-bit parameters with the Altivar's access rules (002 "Ausnahmeantworten" and
//! "Lesen nicht vorhandener oder geschützter Parameter").

use std::collections::{BTreeMap, BTreeSet};

use proto_core::modbus::pdu::ExceptionCode;
use proto_core::profiles::altivar::NOT_AVAILABLE;
use proto_core::profiles::{DataType, Tag};

/// One parameter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Word {
    /// The current value.
    pub(crate) value: u16,
    /// Whether a master may write it.
    pub(crate) writable: bool,
    /// The values a write may carry (signed when the word is), if narrower than 16 bits.
    pub(crate) range: Option<(i32, i32)>,
    /// Whether the word is two's complement (for the range check).
    pub(crate) signed: bool,
}

// === impl Word ===

impl Word {
    /// A read-only word.
    pub(crate) const fn read_only(value: u16) -> Self {
        Self {
            value,
            writable: false,
            range: None,
            signed: false,
        }
    }

    /// A writable word without range.
    pub(crate) const fn read_write(value: u16) -> Self {
        Self {
            value,
            writable: true,
            range: None,
            signed: false,
        }
    }

    /// The word a profile tag describes, holding `value`.
    pub(crate) fn from_tag(tag: &Tag, value: u16) -> Self {
        Self {
            value,
            writable: tag.writable,
            range: tag.raw_range,
            signed: tag.data_type == DataType::I16,
        }
    }

    /// Whether `value` is inside the word's range.
    fn accepts(&self, value: u16) -> bool {
        let Some((min, max)) = self.range else {
            return true;
        };
        let number = if self.signed {
            i32::from(value as i16)
        } else {
            i32::from(value)
        };
        (min..=max).contains(&number)
    }
}

/// Parameters by logical address; an address not in the table does not exist.
#[derive(Clone, Debug, Default)]
pub(crate) struct WordMap {
    words: BTreeMap<u16, Word>,
    protected: BTreeSet<u16>,
}

// === impl WordMap ===

impl WordMap {
    /// Adds (or replaces) a parameter.
    pub(crate) fn insert(&mut self, address: u16, word: Word) {
        self.words.insert(address, word);
    }

    /// The value a read returns, `None` when the parameter does not exist or is protected.
    pub(crate) fn get(&self, address: u16) -> Option<u16> {
        if self.protected.contains(&address) {
            return None;
        }
        self.words.get(&address).map(|w| w.value)
    }

    /// Sets a value without the access checks (the drive's own updates, test presets). Returns
    /// false when the parameter does not exist.
    pub(crate) fn set(&mut self, address: u16, value: u16) -> bool {
        match self.words.get_mut(&address) {
            Some(word) => {
                word.value = value;
                true
            }
            None => false,
        }
    }

    /// Protects a parameter (it then reads as 16#8000) or lifts the protection.
    pub(crate) fn set_protected(&mut self, address: u16, protected: bool) {
        if protected {
            self.protected.insert(address);
        } else {
            self.protected.remove(&address);
        }
    }

    /// The exception a write of `value` to `address` answers, if any: 02 for a parameter that
    /// does not exist or is protected, 04 for a read-only one (002 "Ausnahmeantworten": writing
    /// ETA answers 04), 03 for a value outside its range.
    pub(crate) fn check_write(&self, address: u16, value: u16) -> Result<(), ExceptionCode> {
        if self.protected.contains(&address) {
            return Err(ExceptionCode::IllegalDataAddress);
        }
        let word = self
            .words
            .get(&address)
            .ok_or(ExceptionCode::IllegalDataAddress)?;
        if !word.writable {
            return Err(ExceptionCode::ServerDeviceFailure);
        }
        if !word.accepts(value) {
            return Err(ExceptionCode::IllegalDataValue);
        }
        Ok(())
    }
}

/// Reads `quantity` words from `start`: a word that does not exist or is protected reads as
/// 16#8000, and only when every word is so the answer is exception 02 (002 "Lesen nicht
/// vorhandener oder geschützter Parameter").
pub(crate) fn read_block(
    start: u16,
    quantity: u16,
    mut read: impl FnMut(u16) -> Option<u16>,
) -> Result<Vec<u16>, ExceptionCode> {
    let values: Vec<Option<u16>> = (0..quantity).map(|i| read(start.wrapping_add(i))).collect();
    if values.iter().all(Option::is_none) {
        return Err(ExceptionCode::IllegalDataAddress);
    }
    Ok(values
        .into_iter()
        .map(|v| v.unwrap_or(NOT_AVAILABLE))
        .collect())
}

/// The addresses and values of a block write, in order. Writers check every word first and store
/// only when all pass, so that a refused block changes nothing; 002 documents only the single-word
/// case (ETA, exception 04), checking the whole block first is the simulator's choice.
pub(crate) fn addressed(start: u16, values: &[u16]) -> impl Iterator<Item = (u16, u16)> + '_ {
    (0u16..)
        .zip(values)
        .map(move |(i, v)| (start.wrapping_add(i), *v))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_and_access() {
        let mut map = WordMap::default();
        map.insert(1, Word::read_only(7));
        map.insert(
            2,
            Word {
                value: 0,
                writable: true,
                range: Some((-5, 5)),
                signed: true,
            },
        );
        assert_eq!(
            map.check_write(1, 0),
            Err(ExceptionCode::ServerDeviceFailure)
        );
        assert_eq!(map.check_write(2, (-5i16) as u16), Ok(()));
        assert_eq!(map.check_write(2, 6), Err(ExceptionCode::IllegalDataValue));
        assert_eq!(
            map.check_write(3, 0),
            Err(ExceptionCode::IllegalDataAddress)
        );
        map.set_protected(2, true);
        assert_eq!(map.get(2), None);
        assert_eq!(
            map.check_write(2, 0),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            read_block(0, 3, |a| map.get(a)),
            Ok(vec![0x8000, 7, 0x8000])
        );
        assert_eq!(
            read_block(2, 2, |a| map.get(a)),
            Err(ExceptionCode::IllegalDataAddress)
        );
    }
}
