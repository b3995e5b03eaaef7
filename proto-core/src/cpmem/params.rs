//! The parameters of the Modbus slave line and of its address conversion (manual 003 6.4.5.1,
//! 000 6.4.5.1), with validated constructors and the manual's defaults.

use super::Area;

/// Why a parameter set was refused.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ParamError {
    /// The own slave address is 0 (003 6.4.5.1 "Slave address": range 1..255).
    #[error("slave address 0 is the broadcast address; the own address is 1..=255")]
    SlaveAddress,
    /// The character delay multiplier is outside 1..10 (003 6.4.5.1).
    #[error("character delay multiplier {0} outside 1..=10")]
    DelayMultiplier(u8),
    /// An area that the bit table cannot map (FC 01/05/15: M, Q, T, C; FC 02: M, I; 6.4.5).
    #[error("area {area} cannot be mapped for {table}")]
    AreaNotAllowed { table: &'static str, area: Area },
    /// An area mapped twice in one bit table.
    #[error("area {area} mapped twice for {table}")]
    AreaTwice { table: &'static str, area: Area },
    /// Two areas of one bit table start at the same Modbus address.
    #[error("two areas start at Modbus address {address} for {table}")]
    SameStart { table: &'static str, address: u16 },
    /// A base DB number that is 0 or leaves no room for the 128 DBs of its block (6.4.5 "Up to 128
    /// DB may be accessed in one block"; DB 0 does not exist, 7.2 event 03 01h).
    #[error("base DB {0} invalid: must be 1..={max}", max = u16::MAX - 127)]
    BaseDb(u16),
    /// A write limit whose first element lies after its last.
    #[error("write limit for {area} is empty: {first} > {last}")]
    EmptyLimit {
        area: &'static str,
        first: u16,
        last: u16,
    },
}

/// The operating mode of the driver (003 6.4.5.1 "Operating mode").
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum OperatingMode {
    /// "Every recognized transmission error and break will result in error handling, even if the
    /// driver is in idle mode" (default).
    #[default]
    Normal,
    /// "Transmission errors and breaks are ignored when the driver is in idle mode."
    InterferenceSuppression,
}

/// One row of the dialog "FC 01, 05, 15, 02" (6.4.5, examples 6.4.8.1 and 6.4.8.2): Modbus
/// addresses from `modbus_start` on map to `area` from `plc_start` on (a byte number for M, Q and
/// I, a timer or counter number for T and C). The row ends where the next row of its table starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BitMapping {
    /// The area: M, Q, T or C for FC 01/05/15; M or I for FC 02.
    pub area: Area,
    /// "Param-start-address": the first Modbus bit address of the row.
    pub modbus_start: u16,
    /// "PLC-area": the first byte (M, Q, I) or timer/counter number (T, C).
    pub plc_start: u16,
}

/// The write-enabled parts of the CPU areas (003 6.4.5 "Limits"): "By default the whole output
/// area of the CPU is disabled for write access"; a write outside the enabled area is refused
/// with an exception.
///
/// The seeds do not list the fields of the dialog; here, as in the parameter dialog of the Siemens
/// driver, M and Q are enabled by an inclusive byte range and data blocks (FC 06/16) by an
/// inclusive range of DB numbers. `None` means not writable.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct WriteLimits {
    /// Memory bytes MB first..=last writable with FC 05/15.
    pub memory: Option<(u16, u16)>,
    /// Output bytes QB first..=last writable with FC 05/15.
    pub outputs: Option<(u16, u16)>,
    /// Data blocks DB first..=last writable with FC 06/16.
    pub data_blocks: Option<(u16, u16)>,
}

// === impl WriteLimits ===

impl WriteLimits {
    /// Nothing writable (the manual's default).
    pub const NONE: Self = Self {
        memory: None,
        outputs: None,
        data_blocks: None,
    };

    fn validate(&self) -> Result<(), ParamError> {
        for (name, range) in [
            ("M", self.memory),
            ("Q", self.outputs),
            ("DB", self.data_blocks),
        ] {
            if let Some((first, last)) = range {
                if first > last {
                    return Err(ParamError::EmptyLimit {
                        area: name,
                        first,
                        last,
                    });
                }
            }
        }
        Ok(())
    }

    /// Whether the bytes `first..=last` of a bit area may be written.
    pub(crate) fn allows_bytes(&self, area: Area, first: u32, last: u32) -> bool {
        let range = match area {
            Area::M => self.memory,
            Area::Q => self.outputs,
            _ => None,
        };
        range.is_some_and(|(lo, hi)| u32::from(lo) <= first && last <= u32::from(hi))
    }

    /// Whether data block `db` may be written.
    pub(crate) fn allows_db(&self, db: u16) -> bool {
        self.data_blocks
            .is_some_and(|(lo, hi)| (lo..=hi).contains(&db))
    }
}

/// The address conversion of the slave (003 6.4.5 dialogs "FC 01, 05, 15, 02", "FC 03, 06, 16, 04"
/// and "Limits"; formulas 6.4.8). Shared by the serial slave and the Modbus TCP view of the same
/// memory.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AddressMap {
    /// FC 01/05/15 rows, sorted by Modbus start.
    coils: Vec<BitMapping>,
    /// FC 02 rows, sorted by Modbus start.
    inputs: Vec<BitMapping>,
    /// FC 03/06/16: the DB that Modbus register 0 maps to.
    holding_base_db: u16,
    /// FC 04: the DB that Modbus register 0 maps to.
    input_base_db: u16,
    /// Write enables.
    limits: WriteLimits,
}

// === impl AddressMap ===

impl AddressMap {
    /// The manual's example parameterization (6.4.8.1, 6.4.8.2, 6.4.8.3): FC 01/05/15 0.. -> M 1000.0,
    /// 1024.. -> Q 100.0, 2048.. -> T 100, 4064.. -> C 200; FC 02 0.. -> M 1000.0, 1024.. -> I 100.0;
    /// FC 03/06/16 from DB 800. The manual gives no FC 04 example ("identical to FC 03", 6.4.8.4),
    /// so FC 04 reads from DB 800 too. Nothing is writable.
    pub fn manual_example() -> Self {
        let row = |area, modbus_start, plc_start| BitMapping {
            area,
            modbus_start,
            plc_start,
        };
        Self {
            coils: vec![
                row(Area::M, 0, 1000),
                row(Area::Q, 1024, 100),
                row(Area::T, 2048, 100),
                row(Area::C, 4064, 200),
            ],
            inputs: vec![row(Area::M, 0, 1000), row(Area::I, 1024, 100)],
            holding_base_db: 800,
            input_base_db: 800,
            limits: WriteLimits::NONE,
        }
    }

    /// A validated address map.
    pub fn new(
        coils: &[BitMapping],
        inputs: &[BitMapping],
        holding_base_db: u16,
        input_base_db: u16,
        limits: WriteLimits,
    ) -> Result<Self, ParamError> {
        let coils = Self::table("FC 01/05/15", coils, &[Area::M, Area::Q, Area::T, Area::C])?;
        let inputs = Self::table("FC 02", inputs, &[Area::M, Area::I])?;
        for base in [holding_base_db, input_base_db] {
            if base == 0 || base > u16::MAX - 127 {
                return Err(ParamError::BaseDb(base));
            }
        }
        limits.validate()?;
        Ok(Self {
            coils,
            inputs,
            holding_base_db,
            input_base_db,
            limits,
        })
    }

    /// The same map with other write limits.
    pub fn with_limits(mut self, limits: WriteLimits) -> Result<Self, ParamError> {
        limits.validate()?;
        self.limits = limits;
        Ok(self)
    }

    fn table(
        name: &'static str,
        rows: &[BitMapping],
        allowed: &[Area],
    ) -> Result<Vec<BitMapping>, ParamError> {
        let mut sorted = rows.to_vec();
        sorted.sort_by_key(|row| row.modbus_start);
        for (i, row) in sorted.iter().enumerate() {
            if !allowed.contains(&row.area) {
                return Err(ParamError::AreaNotAllowed {
                    table: name,
                    area: row.area,
                });
            }
            if sorted
                .iter()
                .skip(i + 1)
                .any(|other| other.area == row.area)
            {
                return Err(ParamError::AreaTwice {
                    table: name,
                    area: row.area,
                });
            }
        }
        let starts = sorted.iter().map(|row| row.modbus_start);
        if let Some((address, _)) = starts.clone().zip(starts.skip(1)).find(|(a, b)| a == b) {
            return Err(ParamError::SameStart {
                table: name,
                address,
            });
        }
        Ok(sorted)
    }

    /// FC 01/05/15 rows, sorted by Modbus start.
    pub fn coils(&self) -> &[BitMapping] {
        &self.coils
    }

    /// FC 02 rows, sorted by Modbus start.
    pub fn inputs(&self) -> &[BitMapping] {
        &self.inputs
    }

    /// The base DB of FC 03/06/16.
    pub fn holding_base_db(&self) -> u16 {
        self.holding_base_db
    }

    /// The base DB of FC 04.
    pub fn input_base_db(&self) -> u16 {
        self.input_base_db
    }

    /// The write enables.
    pub fn limits(&self) -> &WriteLimits {
        &self.limits
    }
}

impl Default for AddressMap {
    /// [`AddressMap::manual_example`].
    fn default() -> Self {
        Self::manual_example()
    }
}

/// The parameters of a Modbus slave RTU line (003 6.4.5.1).
///
/// The character frame defaults of the manual (9600 bit/s, 8 data bits fixed, 1 stop bit, even
/// parity) belong to the serial port and are the constants below; the engine only needs the
/// character timing derived from them.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SlaveParams {
    /// Own slave address 1..255.
    address: u8,
    /// Error handling in idle mode.
    mode: OperatingMode,
    /// Multiplier of the end-of-frame time, 1..10.
    delay_multiplier: u8,
    /// The address conversion.
    map: AddressMap,
}

// === impl SlaveParams ===

impl SlaveParams {
    /// 003 6.4.5.1 "Slave address", default value.
    pub const DEFAULT_ADDRESS: u8 = 222;
    /// 003 6.4.5.1 "Multiplier character delay time", range 1..10, default 1.
    pub const DEFAULT_DELAY_MULTIPLIER: u8 = 1;
    /// 003 6.4.5.1 "Baud rate", default 9600 bit/s.
    pub const DEFAULT_BAUD_RATE: u32 = 9600;
    /// 003 6.4.5.1 "Baud rate", range of values.
    pub const BAUD_RATES: [u32; 10] =
        [300, 600, 1200, 2400, 4800, 9600, 19200, 38400, 57600, 76800];
    /// 003 6.4.5.1 "Data bits": 8 (fixed for Modbus RTU).
    pub const DATA_BITS: u8 = 8;
    /// 003 6.4.5.1 "Stop bits": 1 or 2, default 1.
    pub const DEFAULT_STOP_BITS: u8 = 1;

    /// Validated parameters.
    pub fn new(
        address: u8,
        mode: OperatingMode,
        delay_multiplier: u8,
        map: AddressMap,
    ) -> Result<Self, ParamError> {
        if address == 0 {
            return Err(ParamError::SlaveAddress);
        }
        if !(1..=10).contains(&delay_multiplier) {
            return Err(ParamError::DelayMultiplier(delay_multiplier));
        }
        Ok(Self {
            address,
            mode,
            delay_multiplier,
            map,
        })
    }

    /// The own slave address.
    pub fn address(&self) -> u8 {
        self.address
    }

    /// The operating mode.
    pub fn mode(&self) -> OperatingMode {
        self.mode
    }

    /// The multiplier of the end-of-frame time.
    pub fn delay_multiplier(&self) -> u8 {
        self.delay_multiplier
    }

    /// The address conversion.
    pub fn map(&self) -> &AddressMap {
        &self.map
    }
}

impl Default for SlaveParams {
    /// Address 222, normal operation, multiplier 1, [`AddressMap::manual_example`].
    fn default() -> Self {
        Self {
            address: Self::DEFAULT_ADDRESS,
            mode: OperatingMode::Normal,
            delay_multiplier: Self::DEFAULT_DELAY_MULTIPLIER,
            map: AddressMap::manual_example(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation() {
        let map = AddressMap::manual_example();
        assert_eq!(
            SlaveParams::new(0, OperatingMode::Normal, 1, map.clone()),
            Err(ParamError::SlaveAddress)
        );
        assert_eq!(
            SlaveParams::new(1, OperatingMode::Normal, 11, map.clone()),
            Err(ParamError::DelayMultiplier(11))
        );
        assert_eq!(
            SlaveParams::new(1, OperatingMode::Normal, 0, map.clone()),
            Err(ParamError::DelayMultiplier(0))
        );
        assert!(SlaveParams::new(255, OperatingMode::InterferenceSuppression, 10, map).is_ok());
        let row = |area, modbus_start| BitMapping {
            area,
            modbus_start,
            plc_start: 0,
        };
        assert!(matches!(
            AddressMap::new(&[row(Area::I, 0)], &[], 1, 1, WriteLimits::NONE),
            Err(ParamError::AreaNotAllowed { .. })
        ));
        assert!(matches!(
            AddressMap::new(&[], &[row(Area::T, 0)], 1, 1, WriteLimits::NONE),
            Err(ParamError::AreaNotAllowed { .. })
        ));
        assert!(matches!(
            AddressMap::new(
                &[row(Area::M, 0), row(Area::M, 8)],
                &[],
                1,
                1,
                WriteLimits::NONE
            ),
            Err(ParamError::AreaTwice { .. })
        ));
        assert!(matches!(
            AddressMap::new(
                &[row(Area::M, 8), row(Area::Q, 8)],
                &[],
                1,
                1,
                WriteLimits::NONE
            ),
            Err(ParamError::SameStart { address: 8, .. })
        ));
        assert_eq!(
            AddressMap::new(&[], &[], 0, 1, WriteLimits::NONE),
            Err(ParamError::BaseDb(0))
        );
        assert_eq!(
            AddressMap::new(&[], &[], 1, 65409, WriteLimits::NONE),
            Err(ParamError::BaseDb(65409))
        );
        assert!(AddressMap::new(&[], &[], 65408, 1, WriteLimits::NONE).is_ok());
        let bad = WriteLimits {
            memory: Some((5, 4)),
            ..WriteLimits::NONE
        };
        assert!(matches!(
            AddressMap::manual_example().with_limits(bad),
            Err(ParamError::EmptyLimit { .. })
        ));
    }
}
