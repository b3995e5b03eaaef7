//! The KS vario's value store: one value per integer address, read and written through the
//! integer, fix point and float addresses (001 4.1, 4.2, 4.4, 4.5).

use std::collections::BTreeMap;

use proto_core::modbus::pdu::ExceptionCode;
use proto_core::profiles::ksvario::{self, Address, Format};

/// The content of one datum.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Datum {
    /// A value (floats are the device's native resolution).
    Value(f32),
    /// The function behind the datum is switched off (reads 32000, 001 4.1).
    Off,
}

/// One defined datum.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Entry {
    pub(crate) datum: Datum,
    pub(crate) writable: bool,
    /// The adjustable limits; a write outside answers 03 (001 4.2.2 "ausserhalb des
    /// einstellbaren Bereichs").
    pub(crate) min: f32,
    pub(crate) max: f32,
}

// === impl Entry ===

impl Entry {
    /// A read-only datum.
    pub(crate) const fn read_only(value: f32) -> Self {
        Self {
            datum: Datum::Value(value),
            writable: false,
            min: f32::MIN,
            max: f32::MAX,
        }
    }

    /// A writable datum with limits.
    pub(crate) const fn adjustable(value: f32, min: f32, max: f32) -> Self {
        Self {
            datum: Datum::Value(value),
            writable: true,
            min,
            max,
        }
    }
}

/// The data by integer address; an address not in the map is not defined.
#[derive(Clone, Debug, Default)]
pub(crate) struct Store {
    entries: BTreeMap<u16, Entry>,
}

/// The integer word of a value in a format scaled by `factor` (1 or 10), with the special values
/// of 001 4.1.
fn integer_word(datum: Datum, factor: f32) -> u16 {
    match datum {
        Datum::Off => ksvario::OFF,
        Datum::Value(value) => {
            let scaled = (value * factor).round();
            if scaled.is_nan()
                || scaled < ksvario::INT_MIN as f32
                || scaled > ksvario::INT_MAX as f32
            {
                ksvario::OUT_OF_RANGE
            } else {
                scaled as i16 as u16
            }
        }
    }
}

/// The float of a datum (001 4.5: every datum is converted to float, status words too; the
/// manual defines no float for "switched off", so the integer special value 32000 is sent as a
/// float).
fn float_of(datum: Datum) -> f32 {
    match datum {
        Datum::Off => f32::from(ksvario::OFF),
        Datum::Value(value) => value,
    }
}

fn float_half(value: f32, low: bool) -> u16 {
    let bits = value.to_bits();
    if low {
        bits as u16
    } else {
        (bits >> 16) as u16
    }
}

/// How a written register value becomes a datum value.
fn written_value(format: Format, raw: u16) -> Result<f32, ExceptionCode> {
    let number = i32::from(raw as i16);
    // 001 4.1 "Übertragbare Werte": integers -30000..+32000 (fix point -3000.0..+3200.0).
    if !(ksvario::INT_MIN..=ksvario::INT_MAX).contains(&number) {
        return Err(ExceptionCode::IllegalDataValue);
    }
    Ok(match format {
        Format::FixPoint1 => number as f32 / 10.0,
        _ => number as f32,
    })
}

// === impl Store ===

impl Store {
    /// Defines (or redefines) the datum at integer address `index`.
    pub(crate) fn define(&mut self, index: u16, entry: Entry) {
        self.entries.insert(index, entry);
    }

    /// The datum at integer address `index`.
    pub(crate) fn get(&self, index: u16) -> Option<&Entry> {
        self.entries.get(&index)
    }

    /// Sets a datum's content without checks; false when it is not defined.
    pub(crate) fn set(&mut self, index: u16, datum: Datum) -> bool {
        match self.entries.get_mut(&index) {
            Some(entry) => {
                entry.datum = datum;
                true
            }
            None => false,
        }
    }

    /// The word a read returns at `register`: the datum in the register's format, or the "not
    /// defined" value of that format (31000, or half of 1.5E37) when no datum is there.
    pub(crate) fn read_register(&self, register: u16) -> u16 {
        let (address, low) = Address::locate(register);
        let datum = self.entries.get(&address.index).map(|e| e.datum);
        match (address.format, datum) {
            (Format::Integer, Some(datum)) => integer_word(datum, 1.0),
            (Format::FixPoint1, Some(datum)) => integer_word(datum, 10.0),
            (Format::Float, Some(datum)) => float_half(float_of(datum), low),
            (Format::Integer | Format::FixPoint1, None) => ksvario::NOT_DEFINED,
            (Format::Float, None) => float_half(ksvario::FLOAT_NOT_DEFINED, low),
        }
    }

    /// FC 03 / 04: 001 4.2.1 "Ist der 1. Parameter ... nicht definiert, so wird eine
    /// Fehlermeldung ILLEGAL DATA ADDRESS erzeugt"; later gaps read as "not defined". A float
    /// read must start on a float and cover whole floats (001 4.5: twice the count); a start in
    /// the middle of a float is an address that does not exist (02), an odd count a wrong
    /// value (03) (the manual is silent on both; Modbus Application Protocol V1.1b3, 7).
    pub(crate) fn read_block(&self, start: u16, quantity: u16) -> Result<Vec<u16>, ExceptionCode> {
        let (first, low) = Address::locate(start);
        if low {
            return Err(ExceptionCode::IllegalDataAddress);
        }
        if first.format == Format::Float && quantity % 2 == 1 {
            return Err(ExceptionCode::IllegalDataValue);
        }
        if !self.entries.contains_key(&first.index) {
            return Err(ExceptionCode::IllegalDataAddress);
        }
        Ok((0..quantity)
            .map(|i| self.read_register(start.wrapping_add(i)))
            .collect())
    }

    /// FC 06: 001 4.2.2. A float address is refused: "Eine Vorgabe im Datenformat Real ist nicht
    /// möglich, da als Wert nur 2 Byte übergeben werden können" (001 names no code; a float
    /// address is not a datum FC 06 can address, so 02). An undefined datum answers 02; a datum
    /// that cannot be written or a value outside the limits answers 03 and leaves it unchanged.
    pub(crate) fn write_single(&mut self, register: u16, raw: u16) -> Result<(), ExceptionCode> {
        let (address, _) = Address::locate(register);
        if address.format == Format::Float {
            return Err(ExceptionCode::IllegalDataAddress);
        }
        let entry = self
            .entries
            .get(&address.index)
            .ok_or(ExceptionCode::IllegalDataAddress)?;
        if !entry.writable {
            return Err(ExceptionCode::IllegalDataValue);
        }
        let value = written_value(address.format, raw)?;
        self.store(address.index, value)
    }

    /// FC 16: 001 4.4. The first datum undefined answers 02, not writable 03; later undefined or
    /// read-only data are skipped; a value outside the limits answers 03 and stops, the data
    /// accepted before it stay written. Floats take two registers each (001 4.5).
    pub(crate) fn write_multiple(
        &mut self,
        start: u16,
        values: &[u16],
    ) -> Result<(), ExceptionCode> {
        let (first, low) = Address::locate(start);
        if low {
            return Err(ExceptionCode::IllegalDataAddress);
        }
        if first.format == Format::Float && values.len() % 2 == 1 {
            return Err(ExceptionCode::IllegalDataValue);
        }
        let entry = self
            .entries
            .get(&first.index)
            .ok_or(ExceptionCode::IllegalDataAddress)?;
        if !entry.writable {
            return Err(ExceptionCode::IllegalDataValue);
        }
        let mut i = 0usize;
        while let Some(&raw) = values.get(i) {
            let register = start.wrapping_add(i as u16);
            let (address, low) = Address::locate(register);
            let (value, used) = match address.format {
                Format::Float => {
                    let Some(&next) = values.get(i + 1) else {
                        break;
                    };
                    let value = f32::from_bits((u32::from(raw) << 16) | u32::from(next));
                    // A register pair that starts on the low half of a float is no datum.
                    (if low { None } else { Some(value) }, 2)
                }
                format => (Some(written_value(format, raw)?), 1),
            };
            i += used;
            let Some(value) = value else { continue };
            match self.entries.get(&address.index) {
                Some(entry) if entry.writable => self.store(address.index, value)?,
                _ => continue,
            }
        }
        Ok(())
    }

    /// Stores a value after the limit checks (NaN and floats beyond ±1.0E37 included).
    fn store(&mut self, index: u16, value: f32) -> Result<(), ExceptionCode> {
        let entry = self
            .entries
            .get_mut(&index)
            .ok_or(ExceptionCode::IllegalDataAddress)?;
        let transferable = f64::from(value).abs() <= ksvario::FLOAT_LIMIT;
        if !transferable || !(entry.min..=entry.max).contains(&value) {
            return Err(ExceptionCode::IllegalDataValue);
        }
        entry.datum = Datum::Value(value);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_value_three_formats() {
        let mut store = Store::default();
        store.define(3415, Entry::adjustable(0.0, -3000.0, 3200.0));
        store.write_multiple(0x9AAE, &[0x435E, 0x0000]).unwrap();
        assert_eq!(store.read_register(3415), 222);
        assert_eq!(store.read_register(0x4000 + 3415), 2220);
        assert_eq!(store.read_block(0x9AAE, 2), Ok(vec![0x435E, 0x0000]));
        store.write_single(0x4000 + 3415, 15).unwrap();
        assert_eq!(store.get(3415).map(|e| e.datum), Some(Datum::Value(1.5)));
        assert_eq!(store.read_register(3415), 2);
        // Out of the integer range in fix point: 0x8000.
        store.set(3415, Datum::Value(3300.0));
        assert_eq!(store.read_register(0x4000 + 3415), 0x8000);
        assert_eq!(store.read_register(3415), 3300);
        store.set(3415, Datum::Off);
        assert_eq!(store.read_register(3415), 32000);
        // Gaps.
        assert_eq!(store.read_register(3416), 31000);
        assert_eq!(
            store.read_block(0x9AB0, 2),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            store.read_block(0x9AAF, 2),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            store.read_block(0x9AAE, 3),
            Err(ExceptionCode::IllegalDataValue)
        );
    }
}
