//! PMA KS vario controller system, Modbus RTU (seed manual 001).
//!
//! Every datum has one integer address (0..=16383) and is reachable in three formats (001 4.1):
//! - integer: the integer address itself (bits 15..14 = 00);
//! - fix point with one decimal: integer address + 0x4000 (bits 15..14 = 01);
//! - float: 2 x integer address + 0x8000 (bit 15 = 1), two registers, big-endian IEEE-754
//!   ("Motorola format", 001 4.5).
//!
//! Bits 13..9 of the integer address select a 512-word area: 0 device data, 1 visualisation data
//! of channels 1..30, 2..31 the data of channel 1..30.
//!
//! The full address table is the separate "Parametertabelle für KS VARIO" (9499-040-72918), which
//! is not among the seeds; the tags here are the data 001's examples name.

use super::{
    ByteOrder, DataType, DeviceProfile, Quality, Registered, RequestLimits, SpecialValues, Table,
    Tag,
};
use crate::modbus::pdu::FunctionCode;

/// The controller's slave address in 001's examples and the simulator (16#11 = 17).
pub const DEFAULT_ADDRESS: u8 = 17;

/// 001 4.1: integer special value "this datum is not defined" (a gap in a block read).
pub const NOT_DEFINED: u16 = 31000;
/// 001 4.1: integer special value "the function is switched off".
pub const OFF: u16 = 32000;
/// 001 4.1: integer special value 32768 = 0x8000, "the value lies outside the integer range".
pub const OUT_OF_RANGE: u16 = 0x8000;
/// 001 4.1: float special value "this datum is not defined".
pub const FLOAT_NOT_DEFINED: f32 = 1.5e37;
/// 001 4.1 "Übertragbare Werte": floats within -1.0E37..+1.0E37.
pub const FLOAT_LIMIT: f64 = 1.0e37;
/// 001 4.1 "Übertragbare Werte": integers within -30000..+32000.
pub const INT_MIN: i32 = -30000;
/// 001 4.1 "Übertragbare Werte": integers within -30000..+32000.
pub const INT_MAX: i32 = 32000;

/// 001 3.1: a message is read into a buffer of at most 250 bytes; a longer one is not accepted
/// and not answered.
pub const MESSAGE_BUFFER: usize = 250;
/// FC 16 request: address, function, start (2), quantity (2), byte count, data, CRC (2) must fit
/// the buffer: (250 - 9) / 2 = 120 registers, which is 001 3.1's "120 integer or 60 real data".
pub const MAX_WRITE: u16 = ((MESSAGE_BUFFER - 9) / 2) as u16;
/// 001 3.1: "at most 120 integer or 60 real data in one message" read or written.
pub const MAX_READ: u16 = 120;

/// Words of one area (001 4.1: "Bereiche von jeweils 512 Worten", bits 13..9).
pub const AREA_WORDS: u16 = 512;
/// The last integer address (channel 30 ends at 16383 = 3FFF hex, 001 4.1).
pub const MAX_INDEX: u16 = 0x3FFF;
/// 001 4.1: fix point addresses are the integer address + 4000 hex.
pub const FIX_POINT_BASE: u16 = 0x4000;
/// 001 4.5: float address = 2 x integer address + 8000 hex.
pub const FLOAT_BASE: u16 = 0x8000;

/// 001 4.2: the function codes the controller implements.
pub const FUNCTIONS: [FunctionCode; 5] = [
    FunctionCode::READ_HOLDING_REGISTERS,
    FunctionCode::READ_INPUT_REGISTERS,
    FunctionCode::WRITE_SINGLE_REGISTER,
    FunctionCode::DIAGNOSTICS,
    FunctionCode::WRITE_MULTIPLE_REGISTERS,
];

/// FC 08 sub-functions of 001 4.3.
pub mod diag {
    /// 00 return the received data.
    pub const RETURN_QUERY_DATA: u16 = 0x00;
    /// 01 restart communication (ends listen-only; no answer when it was in listen-only).
    pub const RESTART: u16 = 0x01;
    /// 02 return the diagnostic register.
    pub const DIAGNOSTIC_REGISTER: u16 = 0x02;
    /// 04 switch to listen-only mode (never answered).
    pub const LISTEN_ONLY: u16 = 0x04;
    /// 0A clear the counters and the diagnostic register.
    pub const CLEAR_COUNTERS: u16 = 0x0A;
    /// 0B messages seen on the bus (all stations, without its own answers).
    pub const BUS_MESSAGE_COUNT: u16 = 0x0B;
    /// 0C messages to this slave with a transmission error (parity or CRC).
    pub const BUS_COMMUNICATION_ERROR_COUNT: u16 = 0x0C;
    /// 0D messages answered with an exception.
    pub const EXCEPTION_COUNT: u16 = 0x0D;
    /// 0E messages for this slave.
    pub const SLAVE_MESSAGE_COUNT: u16 = 0x0E;
    /// 0F messages for this slave not answered.
    pub const NO_RESPONSE_COUNT: u16 = 0x0F;
    /// 10 messages answered with NAK.
    pub const NAK_COUNT: u16 = 0x10;
    /// 11 messages answered with busy.
    pub const BUSY_COUNT: u16 = 0x11;
    /// 12 messages too long (receive buffer overrun).
    pub const OVERRUN_COUNT: u16 = 0x12;
    /// 40 parity errors.
    pub const PARITY_ERROR_COUNT: u16 = 0x40;
    /// 41 framing errors (stop bit missing).
    pub const FRAMING_ERROR_COUNT: u16 = 0x41;
    /// 42 messages longer than the receive buffer.
    pub const BUFFER_FULL_COUNT: u16 = 0x42;

    /// Every sub-function 001 4.3 lists.
    pub const ALL: [u16; 16] = [
        RETURN_QUERY_DATA,
        RESTART,
        DIAGNOSTIC_REGISTER,
        LISTEN_ONLY,
        CLEAR_COUNTERS,
        BUS_MESSAGE_COUNT,
        BUS_COMMUNICATION_ERROR_COUNT,
        EXCEPTION_COUNT,
        SLAVE_MESSAGE_COUNT,
        NO_RESPONSE_COUNT,
        NAK_COUNT,
        BUSY_COUNT,
        OVERRUN_COUNT,
        PARITY_ERROR_COUNT,
        FRAMING_ERROR_COUNT,
        BUFFER_FULL_COUNT,
    ];

    /// Whether the sub-function returns a counter (0B..12, 40..42).
    pub const fn is_counter(sub_function: u16) -> bool {
        matches!(sub_function, 0x0B..=0x12 | 0x40..=0x42)
    }
}

/// The transfer format an address selects (001 4.1, bits 15..14).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Format {
    /// 00: the integer value.
    Integer,
    /// 01: the value x 10 as an integer (one decimal).
    FixPoint1,
    /// 1x: the value as a big-endian float in two registers.
    Float,
}

/// The 512-word area an integer address lies in (001 4.1, bits 13..9).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Area {
    /// 00000: device data (0..511).
    Device,
    /// 00001: visualisation data of channels 1..30 (512..1023).
    Visualisation,
    /// 00010..11111: the data of channel 1..30.
    Channel(u8),
}

/// An address in one of the three formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Address {
    /// The transfer format.
    pub format: Format,
    /// The integer address of the datum, 0..=16383.
    pub index: u16,
}

/// Why a register address is not the address of a datum.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum AddressError {
    /// A float address with an odd offset points into the middle of a float.
    #[error("float address {0:#06x} points into the middle of a float")]
    MidFloat(u16),
    /// An integer address beyond 16383.
    #[error("integer address {0} is beyond 16383")]
    IndexTooLarge(u16),
}

// === impl Address ===

impl Address {
    /// The datum at integer address `index` in `format`.
    pub const fn new(format: Format, index: u16) -> Self {
        Self { format, index }
    }

    /// The register address sent on the wire (001 4.1, 4.5).
    pub fn encode(self) -> Result<u16, AddressError> {
        if self.index > MAX_INDEX {
            return Err(AddressError::IndexTooLarge(self.index));
        }
        Ok(match self.format {
            Format::Integer => self.index,
            Format::FixPoint1 => FIX_POINT_BASE | self.index,
            Format::Float => FLOAT_BASE + 2 * self.index,
        })
    }

    /// The datum a register address names. A float address must be even (relative to 8000h).
    pub fn decode(register: u16) -> Result<Self, AddressError> {
        let (address, half) = Self::locate(register);
        if half {
            return Err(AddressError::MidFloat(register));
        }
        Ok(address)
    }

    /// The datum a register belongs to and, for floats, whether it is the second (low) half.
    pub const fn locate(register: u16) -> (Self, bool) {
        if register & FLOAT_BASE != 0 {
            let offset = register - FLOAT_BASE;
            (Self::new(Format::Float, offset / 2), offset % 2 == 1)
        } else if register & FIX_POINT_BASE != 0 {
            (
                Self::new(Format::FixPoint1, register - FIX_POINT_BASE),
                false,
            )
        } else {
            (Self::new(Format::Integer, register), false)
        }
    }

    /// The area of the datum.
    pub const fn area(self) -> Area {
        area(self.index)
    }
}

/// The area of an integer address.
pub const fn area(index: u16) -> Area {
    match (index >> 9) & 0x1F {
        0 => Area::Device,
        1 => Area::Visualisation,
        n => Area::Channel((n - 1) as u8),
    }
}

/// The integer address of word `offset` (0..512) of channel `channel` (1..=30):
/// 512 x (channel + 1) + offset.
pub const fn channel_index(channel: u8, offset: u16) -> Option<u16> {
    if channel < 1 || channel > 30 || offset >= AREA_WORDS {
        return None;
    }
    Some(AREA_WORDS * (channel as u16 + 1) + offset)
}

/// A tag for the datum at integer address `index` in `format`: integer and fix point tags are
/// one I16 register (fix point with one decimal), float tags two registers, high word first.
pub fn tag(
    name: impl Into<String>,
    table: Table,
    index: u16,
    format: Format,
) -> Result<Tag, AddressError> {
    let address = Address::new(format, index).encode()?;
    Ok(match format {
        Format::Integer => Tag::new(name, table, address, DataType::I16),
        Format::FixPoint1 => Tag::new(name, table, address, DataType::I16).fix_point(1),
        Format::Float => Tag::new(name, table, address, DataType::F32(ByteOrder::Abcd)),
    })
}

/// Channel 1's ti1 (001 4.2.1: address 04 98 hex, "ti1 / Kanal 1", read as 180).
pub const TI1_CHANNEL_1: u16 = 0x0498;
/// Channel 1's ti2 (001 4.2.1: the next word, read as 333).
pub const TI2_CHANNEL_1: u16 = 0x0499;
/// SetpInterface of channel 30 (001 4.2.2: address 15990 = 3E76 hex, written with 123).
pub const SETP_INTERFACE_CHANNEL_30: u16 = 15990;
/// The data 001 4.4 / 4.5 write (integer addresses 3415 and 3416, float address 9AAE hex).
pub const EXAMPLE_DATA_15: u16 = 3415;
/// See [`EXAMPLE_DATA_15`].
pub const EXAMPLE_DATA_16: u16 = 3416;
/// The first of the three words 001 4 reads with FC 04 (1004..1006 = 1066, 140, 4158).
pub const FC04_EXAMPLE: u16 = 1004;

/// The data 001's examples name, as tags.
pub fn tags() -> Vec<Tag> {
    let mut tags = Vec::new();
    for i in 0..3u16 {
        let index = FC04_EXAMPLE + i;
        tags.push(
            Tag::new(
                format!("vis_{index}"),
                Table::InputRegisters,
                index,
                DataType::I16,
            )
            .describe("visualisation data (001 4, FC 04 example)"),
        );
    }
    tags.push(
        Tag::holding("ti1_c1", TI1_CHANNEL_1, DataType::I16)
            .describe("ti1 of channel 1")
            .writable(),
    );
    tags.push(
        Tag::holding("ti2_c1", TI2_CHANNEL_1, DataType::I16)
            .describe("ti2 of channel 1")
            .writable(),
    );
    tags.push(
        Tag::holding(
            "setp_interface_c30",
            SETP_INTERFACE_CHANNEL_30,
            DataType::I16,
        )
        .describe("interface setpoint of channel 30")
        .writable(),
    );
    for index in [EXAMPLE_DATA_15, EXAMPLE_DATA_16] {
        let address = FLOAT_BASE + 2 * index;
        tags.push(
            Tag::holding(
                format!("data_{index}"),
                address,
                DataType::F32(ByteOrder::Abcd),
            )
            .describe("parameter written by 001 4.5's float example")
            .writable(),
        );
    }
    tags
}

/// Request limits from the 250-byte message buffer (001 3.1); no bit functions, no FC 23.
pub const LIMITS: RequestLimits = RequestLimits {
    read_bits: 0,
    read_registers: MAX_READ,
    write_bits: 0,
    write_registers: MAX_WRITE,
    read_write: None,
    max_adu_len: MESSAGE_BUFFER,
};

/// 001 4.1: 31000 not defined, 32000 switched off, 0x8000 out of the integer range in the
/// integer and fix point formats, 1.5E37 not defined in the float format; writes within
/// -30000..+32000 and -1.0E37..+1.0E37 ("Übertragbare Werte").
pub const SPECIAL_VALUES: SpecialValues = SpecialValues {
    words: &[
        (NOT_DEFINED, Quality::NotDefined),
        (OFF, Quality::Off),
        (OUT_OF_RANGE, Quality::OutOfRange),
    ],
    float_not_defined: Some(FLOAT_NOT_DEFINED),
    i16_write_range: Some((INT_MIN, INT_MAX)),
    f32_write_limit: Some(FLOAT_LIMIT),
};

/// The profile's entry in [`super::registry::PROFILES`].
pub const REGISTERED: Registered = Registered {
    name: "ksvario",
    source: "001 3.1",
    build: profile,
    limits: LIMITS,
    scanner: None,
};

/// The KS vario profile.
pub fn profile() -> DeviceProfile {
    DeviceProfile {
        name: "ksvario".to_owned(),
        default_address: DEFAULT_ADDRESS,
        tags: tags(),
        limits: LIMITS,
        functions: FUNCTIONS.to_vec(),
        special_values: SPECIAL_VALUES,
        keep_alive: None,
    }
}
