//! The Modbus PDU codec: requests, responses and exception responses, without framing.
//!
//! Sources: CP 341 manual (003) 6.4.4 and 6.4.8 for the function codes the CP uses, the Altivar
//! manual (002) for FC 23 and 43/14, the KS vario manual (001) for the FC 08 sub-functions, and the
//! Modbus Application Protocol Specification V1.1b3 where the seeds are silent.
//!
//! Every decoder of untrusted bytes returns a typed [`PduError`] and never panics, whatever the
//! quantities and byte counts claim.
//!
//! Two directions, two decoders:
//! - [`Request::decode`] is what a server (slave) runs on a request: it enforces the quantity limits
//!   of the Modbus Application Protocol V1.1b3 and reports the first violation, quantity before
//!   anything address-related (the order libmodbus uses), so that [`ExceptionCode::from`] gives the
//!   exception the server answers;
//! - [`Response::decode_for`] is what a master runs on an answer: it checks the answer against the
//!   request it sent (function code, byte count, echo fields), with one error variant for each
//!   distinction the CP 341 makes in its events 0E 50h..0E 56h (003 7.2).

mod request;
mod response;

pub use request::Limits;

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

    /// The bit an exception response sets in the function code (003 6.4.3 "Response of the
    /// slave": function code OR 80h).
    pub const EXCEPTION_BIT: u8 = 0x80;

    /// Whether the function writes (the only functions allowed as broadcast, 6.4.3 "ADDR").
    pub const fn is_write(self) -> bool {
        matches!(self.0, 0x05 | 0x06 | 0x0F | 0x10)
    }

    /// Whether the code has the exception bit set (an exception response).
    pub const fn is_exception(self) -> bool {
        self.0 & Self::EXCEPTION_BIT != 0
    }

    /// The code an exception response to this function carries (`self | 80h`).
    pub const fn to_exception(self) -> u8 {
        self.0 | Self::EXCEPTION_BIT
    }

    /// Whether the request codec ([`Request::decode`]) knows this function.
    pub const fn is_supported(self) -> bool {
        matches!(
            self.0,
            0x01..=0x08 | 0x0B | 0x0C | 0x0F | 0x10 | 0x11 | 0x17 | 0x2B
        )
    }

    /// The specification's name of a known function, `None` for others.
    pub const fn name(self) -> Option<&'static str> {
        Some(match self.0 {
            0x01 => "read coils",
            0x02 => "read discrete inputs",
            0x03 => "read holding registers",
            0x04 => "read input registers",
            0x05 => "write single coil",
            0x06 => "write single register",
            0x07 => "read exception status",
            0x08 => "diagnostics",
            0x0B => "get comm event counter",
            0x0C => "get comm event log",
            0x0F => "write multiple coils",
            0x10 => "write multiple registers",
            0x11 => "report server id",
            0x17 => "read/write multiple registers",
            0x2B => "encapsulated interface transport",
            _ => return None,
        })
    }
}

impl From<u8> for FunctionCode {
    fn from(code: u8) -> Self {
        Self(code)
    }
}

impl From<FunctionCode> for u8 {
    fn from(code: FunctionCode) -> Self {
        code.0
    }
}

impl core::fmt::Display for FunctionCode {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.name() {
            Some(name) => write!(f, "{:02X}h ({name})", self.0),
            None => write!(f, "{:02X}h", self.0),
        }
    }
}

/// FC 08 sub-function codes (KS vario manual 001 4.3; Modbus Application Protocol V1.1b3, 6.8).
///
/// Sub-function 00 echoes a data field of any length; every other sub-function carries a 2-byte data
/// field in the request (00 00 for all of 001's sub-functions but 00) and in the response (the echo
/// for 01 and 0A, a counter or register value for the others; 04 is never answered).
pub mod diag {
    /// 00 Return query data: the response echoes the request's data.
    pub const RETURN_QUERY_DATA: u16 = 0x00;
    /// 01 Restart communications (ends listen-only mode; echoes 00 00).
    pub const RESTART_COMMUNICATIONS: u16 = 0x01;
    /// 02 Return diagnostic register.
    pub const RETURN_DIAGNOSTIC_REGISTER: u16 = 0x02;
    /// 04 Force listen-only mode (no response).
    pub const FORCE_LISTEN_ONLY: u16 = 0x04;
    /// 0A Clear counters and diagnostic register (echoes 00 00).
    pub const CLEAR_COUNTERS: u16 = 0x0A;
    /// 0B Return bus message count (every message seen on the bus).
    pub const BUS_MESSAGE_COUNT: u16 = 0x0B;
    /// 0C Return bus communication error count (CRC or parity errors).
    pub const BUS_COMM_ERROR_COUNT: u16 = 0x0C;
    /// 0D Return bus exception error count.
    pub const BUS_EXCEPTION_ERROR_COUNT: u16 = 0x0D;
    /// 0E Return server (slave) message count.
    pub const SERVER_MESSAGE_COUNT: u16 = 0x0E;
    /// 0F Return server no-response count.
    pub const SERVER_NO_RESPONSE_COUNT: u16 = 0x0F;
    /// 10 Return server NAK count.
    pub const SERVER_NAK_COUNT: u16 = 0x10;
    /// 11 Return server busy count.
    pub const SERVER_BUSY_COUNT: u16 = 0x11;
    /// 12 Return bus character overrun count (messages too long).
    pub const BUS_OVERRUN_COUNT: u16 = 0x12;
    /// 40 Return parity error count (KS vario, 001 4.3.13).
    pub const PARITY_ERROR_COUNT: u16 = 0x40;
    /// 41 Return framing error count (KS vario, 001 4.3.14).
    pub const FRAMING_ERROR_COUNT: u16 = 0x41;
    /// 42 Return buffer-full count (KS vario, 001 4.3.15).
    pub const BUFFER_FULL_COUNT: u16 = 0x42;

    /// Whether the KS vario manual (001 4.3) lists the sub-function.
    pub const fn is_known(sub_function: u16) -> bool {
        matches!(sub_function, 0x00 | 0x01 | 0x02 | 0x04 | 0x0A..=0x12 | 0x40..=0x42)
    }

    /// Whether a response echoes the request's data field (00 any data, 01 and 0A their 00 00).
    pub const fn echoes_data(sub_function: u16) -> bool {
        matches!(
            sub_function,
            RETURN_QUERY_DATA | RESTART_COMMUNICATIONS | CLEAR_COUNTERS
        )
    }
}

/// The MEI type of Read Device Identification (Modbus Application Protocol V1.1b3, 6.21; 002 "Identifikation").
pub const MEI_READ_DEVICE_ID: u8 = 0x0E;

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

// === impl ExceptionCode ===

impl From<u8> for ExceptionCode {
    fn from(code: u8) -> Self {
        match code {
            0x01 => Self::IllegalFunction,
            0x02 => Self::IllegalDataAddress,
            0x03 => Self::IllegalDataValue,
            0x04 => Self::ServerDeviceFailure,
            0x05 => Self::Acknowledge,
            0x06 => Self::ServerDeviceBusy,
            0x07 => Self::NegativeAcknowledge,
            0x08 => Self::MemoryParityError,
            0x0A => Self::GatewayPathUnavailable,
            0x0B => Self::GatewayTargetFailedToRespond,
            other => Self::Other(other),
        }
    }
}

impl From<ExceptionCode> for u8 {
    fn from(code: ExceptionCode) -> Self {
        match code {
            ExceptionCode::IllegalFunction => 0x01,
            ExceptionCode::IllegalDataAddress => 0x02,
            ExceptionCode::IllegalDataValue => 0x03,
            ExceptionCode::ServerDeviceFailure => 0x04,
            ExceptionCode::Acknowledge => 0x05,
            ExceptionCode::ServerDeviceBusy => 0x06,
            ExceptionCode::NegativeAcknowledge => 0x07,
            ExceptionCode::MemoryParityError => 0x08,
            ExceptionCode::GatewayPathUnavailable => 0x0A,
            ExceptionCode::GatewayTargetFailedToRespond => 0x0B,
            ExceptionCode::Other(other) => other,
        }
    }
}

impl From<&PduError> for ExceptionCode {
    /// The exception a server answers to a request it could not decode; the one place this mapping
    /// lives (Modbus Application Protocol V1.1b3, 7 and the per-function state diagrams of 6):
    /// an unknown function or MEI type is 01, an address range past FFFFh is 02, every other
    /// violation (quantity, byte count, value, missing or trailing bytes) is 03.
    ///
    /// The variants only a master meets (a response that does not match its request) map to 04,
    /// which is what a gateway answers when the device behind it misbehaved.
    fn from(error: &PduError) -> Self {
        match error {
            PduError::UnsupportedFunction(_) | PduError::UnsupportedMeiType(_) => {
                Self::IllegalFunction
            }
            PduError::AddressOutOfRange { .. } => Self::IllegalDataAddress,
            PduError::Empty
            | PduError::TooShort { .. }
            | PduError::TrailingData { .. }
            | PduError::ByteCountMismatch { .. }
            | PduError::QuantityOutOfRange { .. }
            | PduError::IllegalValue { .. } => Self::IllegalDataValue,
            PduError::FunctionMismatch { .. }
            | PduError::ByteCountTooSmall { .. }
            | PduError::EchoMismatch { .. } => Self::ServerDeviceFailure,
        }
    }
}

impl From<PduError> for ExceptionCode {
    fn from(error: PduError) -> Self {
        Self::from(&error)
    }
}

impl core::fmt::Display for ExceptionCode {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let name = match self {
            Self::IllegalFunction => "illegal function",
            Self::IllegalDataAddress => "illegal data address",
            Self::IllegalDataValue => "illegal data value",
            Self::ServerDeviceFailure => "server device failure",
            Self::Acknowledge => "acknowledge",
            Self::ServerDeviceBusy => "server device busy",
            Self::NegativeAcknowledge => "negative acknowledge",
            Self::MemoryParityError => "memory parity error",
            Self::GatewayPathUnavailable => "gateway path unavailable",
            Self::GatewayTargetFailedToRespond => "gateway target device failed to respond",
            Self::Other(_) => "unknown exception",
        };
        write!(f, "{:02X}h ({name})", u8::from(*self))
    }
}

/// A request PDU (function code and data, no address, no checksum).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Request {
    /// FC 01: quantity 1..2000 (the CP master: 1..2040, see [`Request::validate`] and [`Limits`]).
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
    ReadWriteMultipleRegisters {
        read_address: u16,
        read_quantity: u16,
        write_address: u16,
        values: Vec<u16>,
    },
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
    GetCommEventLog {
        status: u16,
        event_count: u16,
        message_count: u16,
        events: Vec<u8>,
    },
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
    TooShort {
        function: u8,
        needed: usize,
        have: usize,
    },
    /// Bytes remain after the function's fields.
    #[error("{extra} trailing bytes after function {function:#04x}")]
    TrailingData { function: u8, extra: usize },
    /// The function code is not one this codec knows (a server answers exception 01).
    #[error("unsupported function code {0:#04x}")]
    UnsupportedFunction(u8),
    /// A byte count disagrees with the quantity or with the bytes present (exception 03).
    #[error("byte count {byte_count} does not match {expected} for function {function:#04x}")]
    ByteCountMismatch {
        function: u8,
        byte_count: u8,
        expected: usize,
    },
    /// A quantity outside the function's range (exception 03).
    #[error("quantity {quantity} out of range {min}..={max} for function {function:#04x}")]
    QuantityOutOfRange {
        function: u8,
        quantity: u16,
        min: u16,
        max: u16,
    },
    /// A field with a value the function does not allow (exception 03), e.g. FC05 value 1234h.
    #[error("illegal value {value:#06x} in field {field} of function {function:#04x}")]
    IllegalValue {
        function: u8,
        field: &'static str,
        value: u16,
    },
    /// FC 43 with an MEI type other than 0Eh (exception 01, as the Altivar answers, 002
    /// "Negative Antwort für die Identifizierungsfunktion").
    #[error("unsupported MEI type {0:#04x} of function 0x2b")]
    UnsupportedMeiType(u8),
    /// Start address plus quantity runs past FFFFh (exception 02); checked after the quantity.
    #[error("address {address:#06x} + quantity {quantity} runs past 0xffff for function {function:#04x}")]
    AddressOutOfRange {
        function: u8,
        address: u16,
        quantity: u16,
    },
    /// Response only: the answer carries another function code than the request (003 7.2, 0E 51h),
    /// also an exception response to another function.
    #[error("response function {got:#04x} does not match request function {expected:#04x}")]
    FunctionMismatch { expected: u8, got: u8 },
    /// Response only: the byte count is smaller than the requested quantity needs (003 7.2, 0E 54h
    /// "byte counter too small"); a byte count that is otherwise wrong is
    /// [`PduError::ByteCountMismatch`] (0E 55h).
    #[error("byte count {byte_count} too small: function {function:#04x} needs {expected}")]
    ByteCountTooSmall {
        function: u8,
        byte_count: u8,
        expected: usize,
    },
    /// Response only: an echoed field differs from the request (003 7.2, 0E 56h "echo wrong").
    /// For the FC 08 data field, `expected` and `got` are the first differing bytes.
    #[error(
        "echo of {field} wrong for function {function:#04x}: sent {expected:#06x}, got {got:#06x}"
    )]
    EchoMismatch {
        function: u8,
        field: &'static str,
        expected: u16,
        got: u16,
    },
}

// === impl PduError ===

impl PduError {
    /// Turns a cursor error into the PDU error of `function`.
    pub(crate) fn from_codec(function: u8, error: crate::codec::CodecError) -> Self {
        match error {
            crate::codec::CodecError::TooShort { needed, have } => Self::TooShort {
                function,
                needed,
                have,
            },
            crate::codec::CodecError::TrailingData { extra } => {
                Self::TrailingData { function, extra }
            }
        }
    }

    /// The function code the error is about, if the bytes got that far.
    pub const fn function(&self) -> Option<u8> {
        match *self {
            Self::Empty => None,
            Self::UnsupportedMeiType(_) => Some(FunctionCode::ENCAPSULATED_INTERFACE.0),
            Self::UnsupportedFunction(function)
            | Self::TooShort { function, .. }
            | Self::TrailingData { function, .. }
            | Self::ByteCountMismatch { function, .. }
            | Self::QuantityOutOfRange { function, .. }
            | Self::IllegalValue { function, .. }
            | Self::AddressOutOfRange { function, .. }
            | Self::ByteCountTooSmall { function, .. }
            | Self::EchoMismatch { function, .. } => Some(function),
            Self::FunctionMismatch { got, .. } => Some(got),
        }
    }
}

// === impl ExceptionResponse ===

impl ExceptionResponse {
    /// An exception response to `function`.
    pub const fn new(function: FunctionCode, code: ExceptionCode) -> Self {
        Self { function, code }
    }

    /// Appends the exception PDU: `function | 80h`, exception code (003 6.4.3).
    pub fn encode(&self, out: &mut Vec<u8>) {
        out.push(self.function.to_exception());
        out.push(u8::from(self.code));
    }

    /// The exception a server answers to a request it could not decode: `function` is the
    /// request's first byte (0 for an empty PDU).
    pub fn for_error(function: u8, error: &PduError) -> Self {
        Self {
            function: FunctionCode(function & !FunctionCode::EXCEPTION_BIT),
            code: ExceptionCode::from(error),
        }
    }
}

#[cfg(test)]
mod tests;
