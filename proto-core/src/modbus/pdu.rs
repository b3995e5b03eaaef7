//! The Modbus PDU codec: requests, responses and exception responses, without framing.
//!
//! Sources: CP 341 manual (003) 6.4.4 and 6.4.8 for the function codes the CP uses, the Altivar
//! manual (002) for FC 23 and 43/14, the KS vario manual (001) for the FC 08 sub-functions, and the
//! Modbus Application Protocol Specification V1.1b3 where the seeds are silent.
//!
//! Every decoder of untrusted bytes returns a typed [`PduError`] and never panics, whatever the
//! quantities and byte counts claim.

/// A function code as it appears on the wire (open: unknown codes round-trip).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct FunctionCode(pub u8);

// === impl FunctionCode ===

impl FunctionCode {
    /// 01 (0x01) Read Coils ("read coil status").
    pub const READ_COILS: Self = Self(0x01);
    /// 02 (0x02) Read Discrete Inputs ("read input status").
    pub const READ_DISCRETE_INPUTS: Self = Self(0x02);
    /// 03 (0x03) Read Holding Registers.
    pub const READ_HOLDING_REGISTERS: Self = Self(0x03);
    /// 04 (0x04) Read Input Registers.
    pub const READ_INPUT_REGISTERS: Self = Self(0x04);
    /// 05 (0x05) Write Single Coil ("force single coil").
    pub const WRITE_SINGLE_COIL: Self = Self(0x05);
    /// 06 (0x06) Write Single Register ("preset single register").
    pub const WRITE_SINGLE_REGISTER: Self = Self(0x06);
    /// 07 (0x07) Read Exception Status.
    pub const READ_EXCEPTION_STATUS: Self = Self(0x07);
    /// 08 (0x08) Diagnostics ("loop back test").
    pub const DIAGNOSTICS: Self = Self(0x08);
    /// 11 (0x0B) Get Comm Event Counter.
    pub const GET_COMM_EVENT_COUNTER: Self = Self(0x0B);
    /// 12 (0x0C) Get Comm Event Log.
    pub const GET_COMM_EVENT_LOG: Self = Self(0x0C);
    /// 15 (0x0F) Write Multiple Coils ("force multiple coils").
    pub const WRITE_MULTIPLE_COILS: Self = Self(0x0F);
    /// 16 (0x10) Write Multiple Registers ("preset multiple registers").
    pub const WRITE_MULTIPLE_REGISTERS: Self = Self(0x10);
    /// 17 (0x11) Report Server ID.
    pub const REPORT_SERVER_ID: Self = Self(0x11);
    /// 23 (0x17) Read/Write Multiple Registers.
    pub const READ_WRITE_MULTIPLE_REGISTERS: Self = Self(0x17);
    /// 43 (0x2B) Encapsulated Interface Transport (MEI type 14: Read Device Identification).
    pub const ENCAPSULATED_INTERFACE: Self = Self(0x2B);

    /// Whether the function writes (the only functions allowed as broadcast, 6.4.3 "ADDR").
    pub const fn is_write(self) -> bool {
        matches!(self.0, 0x05 | 0x06 | 0x0F | 0x10)
    }
}

/// An exception code of an exception response (6.4.3 "Error codes"; Modbus spec 7 for 08..0B).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ExceptionCode {
    /// 01 Illegal function.
    IllegalFunction,
    /// 02 Illegal data address.
    IllegalDataAddress,
    /// 03 Illegal data value.
    IllegalDataValue,
    /// 04 Server device failure ("failure in associated device").
    ServerDeviceFailure,
    /// 05 Acknowledge.
    Acknowledge,
    /// 06 Server device busy ("busy, rejected message").
    ServerDeviceBusy,
    /// 07 Negative acknowledge.
    NegativeAcknowledge,
    /// 08 Memory parity error.
    MemoryParityError,
    /// 0A Gateway path unavailable.
    GatewayPathUnavailable,
    /// 0B Gateway target device failed to respond.
    GatewayTargetFailedToRespond,
    /// Any other code, kept so that it round-trips.
    Other(u8),
}

/// A request PDU (function code and data, no address, no checksum).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Request {
    /// FC 01: quantity 1..2000 (the CP master: 1..2040, see [`Request::validate`]).
    ReadCoils { address: u16, quantity: u16 },
    /// FC 02.
    ReadDiscreteInputs { address: u16, quantity: u16 },
    /// FC 03: quantity 1..125 (CP: 1..127).
    ReadHoldingRegisters { address: u16, quantity: u16 },
    /// FC 04.
    ReadInputRegisters { address: u16, quantity: u16 },
    /// FC 05: on = FF00h, off = 0000h; any other value is an illegal data value.
    WriteSingleCoil { address: u16, value: bool },
    /// FC 06.
    WriteSingleRegister { address: u16, value: u16 },
    /// FC 07.
    ReadExceptionStatus,
    /// FC 08 with its sub-function and data field (bytes, as sent).
    Diagnostics { sub_function: u16, data: Vec<u8> },
    /// FC 11 (0x0B).
    GetCommEventCounter,
    /// FC 12 (0x0C).
    GetCommEventLog,
    /// FC 15 (0x0F): one bool a coil.
    WriteMultipleCoils { address: u16, values: Vec<bool> },
    /// FC 16 (0x10).
    WriteMultipleRegisters { address: u16, values: Vec<u16> },
    /// FC 17 (0x11).
    ReportServerId,
    /// FC 23 (0x17): the write is carried out before the read.
    ReadWriteMultipleRegisters { read_address: u16, read_quantity: u16, write_address: u16, values: Vec<u16> },
    /// FC 43 (0x2B) MEI type 14 (0x0E): read device identification.
    ReadDeviceIdentification { read_code: u8, object_id: u8 },
}

/// A normal (non-exception) response PDU.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Response {
    /// FC 01: the coil states, as many as the request asked for when decoded against it.
    ReadCoils(Vec<bool>),
    /// FC 02.
    ReadDiscreteInputs(Vec<bool>),
    /// FC 03.
    ReadHoldingRegisters(Vec<u16>),
    /// FC 04.
    ReadInputRegisters(Vec<u16>),
    /// FC 05: the echo.
    WriteSingleCoil { address: u16, value: bool },
    /// FC 06: the echo.
    WriteSingleRegister { address: u16, value: u16 },
    /// FC 07: the eight exception status outputs.
    ReadExceptionStatus(u8),
    /// FC 08.
    Diagnostics { sub_function: u16, data: Vec<u8> },
    /// FC 11.
    GetCommEventCounter { status: u16, event_count: u16 },
    /// FC 12.
    GetCommEventLog { status: u16, event_count: u16, message_count: u16, events: Vec<u8> },
    /// FC 15.
    WriteMultipleCoils { address: u16, quantity: u16 },
    /// FC 16.
    WriteMultipleRegisters { address: u16, quantity: u16 },
    /// FC 17: the device-specific bytes after the byte count.
    ReportServerId(Vec<u8>),
    /// FC 23.
    ReadWriteMultipleRegisters(Vec<u16>),
    /// FC 43/14.
    ReadDeviceIdentification {
        read_code: u8,
        conformity_level: u8,
        more_follows: bool,
        next_object_id: u8,
        objects: Vec<(u8, Vec<u8>)>,
    },
}

/// An exception response: the function code of the request and the exception code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ExceptionResponse {
    /// The function code of the request (without the 80h bit).
    pub function: FunctionCode,
    /// What the server answered.
    pub code: ExceptionCode,
}

/// Why a PDU could not be decoded.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PduError {
    /// The PDU is empty.
    #[error("empty PDU")]
    Empty,
    /// The bytes end before the function's fields do.
    #[error("PDU too short for function {function:#04x}: need {needed} bytes, have {have}")]
    TooShort { function: u8, needed: usize, have: usize },
    /// Bytes remain after the function's fields.
    #[error("{extra} trailing bytes after function {function:#04x}")]
    TrailingData { function: u8, extra: usize },
    /// The function code is not one this codec knows (a server answers exception 01).
    #[error("unsupported function code {0:#04x}")]
    UnsupportedFunction(u8),
    /// A byte count disagrees with the quantity or with the bytes present (exception 03).
    #[error("byte count {byte_count} does not match {expected} for function {function:#04x}")]
    ByteCountMismatch { function: u8, byte_count: u8, expected: usize },
    /// A quantity outside the function's range (exception 03).
    #[error("quantity {quantity} out of range {min}..={max} for function {function:#04x}")]
    QuantityOutOfRange { function: u8, quantity: u16, min: u16, max: u16 },
    /// A field with a value the function does not allow (exception 03), e.g. FC05 value 1234h.
    #[error("illegal value {value:#06x} in field {field} of function {function:#04x}")]
    IllegalValue { function: u8, field: &'static str, value: u16 },
}
