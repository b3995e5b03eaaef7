//! Request PDUs: encoding (the master's side), decoding as a server, and the master's limits.

use super::{diag, FunctionCode, PduError, Request, MEI_READ_DEVICE_ID};
use crate::codec::{bit_byte_count, u16s_be, unpack_bits, Reader, Writer};
use crate::modbus::Table;

/// The FC 05 value that switches a coil on (003 6.4.4.5 "FF00h -> Bit = 1").
pub(crate) const COIL_ON: u16 = 0xFF00;
/// The FC 05 value that switches a coil off (003 6.4.4.5 "0000h -> Bit = 0").
pub(crate) const COIL_OFF: u16 = 0x0000;

/// The largest byte count a one-byte count field can carry; it bounds what one PDU can hold:
/// 2040 coils, 127 registers (003 6.4.4: the CP master's limits are exactly these).
pub(crate) const MAX_BYTE_COUNT: usize = 255;
/// Most coils one byte count can describe (255 x 8).
const MAX_PACKED_BITS: usize = MAX_BYTE_COUNT * 8;
/// Most registers one byte count can describe (255 / 2).
const MAX_PACKED_REGISTERS: usize = MAX_BYTE_COUNT / 2;

/// The FC 43/14 read device ID codes 01 (basic) .. 04 (one specific object) (Modbus Application
/// Protocol V1.1b3, 6.21).
const READ_DEVICE_ID_CODES: core::ops::RangeInclusive<u8> = 0x01..=0x04;

/// Quantity limits a side enforces (the lower limit is 1 everywhere).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// FC 01/02: most coils or inputs one read may ask for.
    pub read_bits: u16,
    /// FC 03/04: most registers one read may ask for.
    pub read_registers: u16,
    /// FC 15: most coils one write may carry.
    pub write_bits: u16,
    /// FC 16: most registers one write may carry.
    pub write_registers: u16,
    /// FC 23: most registers the read part may ask for.
    pub read_write_read_registers: u16,
    /// FC 23: most registers the write part may carry.
    pub read_write_write_registers: u16,
}

// === impl Limits ===

impl Limits {
    /// A server's limits: Modbus Application Protocol V1.1b3, 6.1 (2000), 6.3/6.4 (125), 6.11 (1968),
    /// 6.12 (123), 6.17 (125 read, 121 write). [`Request::decode`] enforces these.
    pub const SPEC: Self = Self {
        read_bits: 2000,
        read_registers: 125,
        write_bits: 1968,
        write_registers: 123,
        read_write_read_registers: 125,
        read_write_write_registers: 121,
    };

    /// The CP 341 Modbus master RTU (003 6.4.4.1..6.4.4.12 and events 0E 44h..0E 46h): 1..2040 bits,
    /// 1..127 registers. The CP has no FC 23; the gateway's extension keeps the specification's
    /// limits for it.
    pub const CP_MASTER_RTU: Self = Self {
        read_bits: 2040,
        read_registers: 127,
        write_bits: 2040,
        write_registers: 127,
        read_write_read_registers: 125,
        read_write_write_registers: 121,
    };

    /// The CP 341 Modbus master ASCII (003 6.4.4.1..6.4.4.12: "ASCII: 1...2008" bits read,
    /// 1..125 registers read, 1..1976 coils and 1..123 registers written).
    pub const CP_MASTER_ASCII: Self = Self {
        read_bits: 2008,
        read_registers: 125,
        write_bits: 1976,
        write_registers: 123,
        read_write_read_registers: 125,
        read_write_write_registers: 121,
    };
}

fn check_quantity(function: FunctionCode, quantity: u16, max: u16) -> Result<(), PduError> {
    if (1..=max).contains(&quantity) {
        Ok(())
    } else {
        Err(PduError::QuantityOutOfRange {
            function: function.0,
            quantity,
            min: 1,
            max,
        })
    }
}

fn check_address(function: FunctionCode, address: u16, quantity: u16) -> Result<(), PduError> {
    // Modbus Application Protocol V1.1b3, 6.x state diagrams: "Starting Address + Quantity" must
    // stay inside the 16-bit address space.
    if u32::from(address) + u32::from(quantity) <= 0x1_0000 {
        Ok(())
    } else {
        Err(PduError::AddressOutOfRange {
            function: function.0,
            address,
            quantity,
        })
    }
}

/// A length as a 16-bit quantity field (callers bound the length first).
fn quantity_of(len: usize) -> u16 {
    u16::try_from(len).unwrap_or(u16::MAX)
}

fn write_registers(w: &mut Writer<'_>, values: &[u16]) {
    for &value in values {
        w.u16_be(value);
    }
}

// === impl Request ===

impl Request {
    /// The request's function code.
    pub const fn function(&self) -> FunctionCode {
        match self {
            Self::ReadCoils { .. } => FunctionCode::READ_COILS,
            Self::ReadDiscreteInputs { .. } => FunctionCode::READ_DISCRETE_INPUTS,
            Self::ReadHoldingRegisters { .. } => FunctionCode::READ_HOLDING_REGISTERS,
            Self::ReadInputRegisters { .. } => FunctionCode::READ_INPUT_REGISTERS,
            Self::WriteSingleCoil { .. } => FunctionCode::WRITE_SINGLE_COIL,
            Self::WriteSingleRegister { .. } => FunctionCode::WRITE_SINGLE_REGISTER,
            Self::ReadExceptionStatus => FunctionCode::READ_EXCEPTION_STATUS,
            Self::Diagnostics { .. } => FunctionCode::DIAGNOSTICS,
            Self::GetCommEventCounter => FunctionCode::GET_COMM_EVENT_COUNTER,
            Self::GetCommEventLog => FunctionCode::GET_COMM_EVENT_LOG,
            Self::WriteMultipleCoils { .. } => FunctionCode::WRITE_MULTIPLE_COILS,
            Self::WriteMultipleRegisters { .. } => FunctionCode::WRITE_MULTIPLE_REGISTERS,
            Self::ReportServerId => FunctionCode::REPORT_SERVER_ID,
            Self::ReadWriteMultipleRegisters { .. } => FunctionCode::READ_WRITE_MULTIPLE_REGISTERS,
            Self::ReadDeviceIdentification { .. } => FunctionCode::ENCAPSULATED_INTERFACE,
        }
    }

    /// The table, first address and quantity of a read of one table (FC 01..04); `None` for
    /// every other request.
    pub const fn read_range(&self) -> Option<(Table, u16, u16)> {
        match *self {
            Self::ReadCoils { address, quantity } => Some((Table::Coils, address, quantity)),
            Self::ReadDiscreteInputs { address, quantity } => {
                Some((Table::DiscreteInputs, address, quantity))
            }
            Self::ReadHoldingRegisters { address, quantity } => {
                Some((Table::HoldingRegisters, address, quantity))
            }
            Self::ReadInputRegisters { address, quantity } => {
                Some((Table::InputRegisters, address, quantity))
            }
            _ => None,
        }
    }

    /// Whether the request may be sent as broadcast (address 0): writes only (003 6.4.3 "ADDR",
    /// event 0E 43h).
    pub const fn is_broadcastable(&self) -> bool {
        self.function().is_write()
    }

    /// Appends the request PDU (function code and data) to `out`.
    ///
    /// Encoding never fails. Value lists longer than a one-byte byte count can describe (more than
    /// 2040 coils, 127 registers) are cut to what it can, so the frame stays self-consistent;
    /// [`Request::validate`] reports such requests (and every other limit) before they are sent.
    pub fn encode(&self, out: &mut Vec<u8>) {
        let mut w = Writer::new(out);
        w.u8(self.function().0);
        match self {
            Self::ReadCoils { address, quantity }
            | Self::ReadDiscreteInputs { address, quantity }
            | Self::ReadHoldingRegisters { address, quantity }
            | Self::ReadInputRegisters { address, quantity } => {
                w.u16_be(*address).u16_be(*quantity);
            }
            Self::WriteSingleCoil { address, value } => {
                w.u16_be(*address)
                    .u16_be(if *value { COIL_ON } else { COIL_OFF });
            }
            Self::WriteSingleRegister { address, value } => {
                w.u16_be(*address).u16_be(*value);
            }
            Self::ReadExceptionStatus
            | Self::GetCommEventCounter
            | Self::GetCommEventLog
            | Self::ReportServerId => {}
            Self::Diagnostics { sub_function, data } => {
                w.u16_be(*sub_function).bytes(data);
            }
            Self::WriteMultipleCoils { address, values } => {
                let values = values.get(..MAX_PACKED_BITS).unwrap_or(values);
                w.u16_be(*address).u16_be(quantity_of(values.len()));
                w.count_u8(bit_byte_count(values.len())).bits(values);
            }
            Self::WriteMultipleRegisters { address, values } => {
                let values = values.get(..MAX_PACKED_REGISTERS).unwrap_or(values);
                w.u16_be(*address)
                    .u16_be(quantity_of(values.len()))
                    .count_u8(values.len() * 2);
                write_registers(&mut w, values);
            }
            Self::ReadWriteMultipleRegisters {
                read_address,
                read_quantity,
                write_address,
                values,
            } => {
                let values = values.get(..MAX_PACKED_REGISTERS).unwrap_or(values);
                w.u16_be(*read_address).u16_be(*read_quantity);
                w.u16_be(*write_address)
                    .u16_be(quantity_of(values.len()))
                    .count_u8(values.len() * 2);
                write_registers(&mut w, values);
            }
            Self::ReadDeviceIdentification {
                read_code,
                object_id,
            } => {
                w.u8(MEI_READ_DEVICE_ID).u8(*read_code).u8(*object_id);
            }
        }
    }

    /// The encoded PDU as a new vector.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::new();
        self.encode(&mut out);
        out
    }

    /// Decodes a request PDU as a server does, enforcing [`Limits::SPEC`].
    ///
    /// Checks run in the order of the specification's state diagrams (and libmodbus): the function
    /// code, then the quantity, then the byte count, then the presence of the data, then the
    /// address range; the first failure is returned, and `ExceptionCode::from(&error)` is the
    /// exception to answer.
    pub fn decode(pdu: &[u8]) -> Result<Self, PduError> {
        Self::decode_with(pdu, &Limits::SPEC)
    }

    /// [`Request::decode`] with other limits (e.g. a slave serving the CP master's 127 registers).
    pub fn decode_with(pdu: &[u8], limits: &Limits) -> Result<Self, PduError> {
        let mut r = Reader::new(pdu);
        let function = FunctionCode(r.u8().map_err(|_| PduError::Empty)?);
        let r = &mut r;
        match function {
            FunctionCode::READ_COILS
            | FunctionCode::READ_DISCRETE_INPUTS
            | FunctionCode::READ_HOLDING_REGISTERS
            | FunctionCode::READ_INPUT_REGISTERS => decode_read(r, function, limits),
            FunctionCode::WRITE_SINGLE_COIL => decode_write_single_coil(r, function),
            FunctionCode::WRITE_SINGLE_REGISTER => {
                let address = r.u16_be().map_err(codec(function))?;
                let value = r.u16_be().map_err(codec(function))?;
                r.expect_end().map_err(codec(function))?;
                Ok(Self::WriteSingleRegister { address, value })
            }
            FunctionCode::READ_EXCEPTION_STATUS
            | FunctionCode::GET_COMM_EVENT_COUNTER
            | FunctionCode::GET_COMM_EVENT_LOG
            | FunctionCode::REPORT_SERVER_ID => {
                r.expect_end().map_err(codec(function))?;
                Ok(match function {
                    FunctionCode::READ_EXCEPTION_STATUS => Self::ReadExceptionStatus,
                    FunctionCode::GET_COMM_EVENT_COUNTER => Self::GetCommEventCounter,
                    FunctionCode::GET_COMM_EVENT_LOG => Self::GetCommEventLog,
                    _ => Self::ReportServerId,
                })
            }
            FunctionCode::DIAGNOSTICS => decode_diagnostics(r, function),
            FunctionCode::WRITE_MULTIPLE_COILS => decode_write_multiple_coils(r, function, limits),
            FunctionCode::WRITE_MULTIPLE_REGISTERS => {
                let address = r.u16_be().map_err(codec(function))?;
                let quantity = r.u16_be().map_err(codec(function))?;
                let byte_count = r.u8().map_err(codec(function))?;
                check_quantity(function, quantity, limits.write_registers)?;
                let values = read_registers(r, function, byte_count, quantity)?;
                r.expect_end().map_err(codec(function))?;
                check_address(function, address, quantity)?;
                Ok(Self::WriteMultipleRegisters { address, values })
            }
            FunctionCode::READ_WRITE_MULTIPLE_REGISTERS => decode_read_write(r, function, limits),
            FunctionCode::ENCAPSULATED_INTERFACE => decode_device_identification(r, function),
            FunctionCode(other) => Err(PduError::UnsupportedFunction(other)),
        }
    }

    /// Checks the request against a sender's `limits` before it is sent: quantities and value
    /// counts 1..=limit (events 0E 44h..0E 46h), FC 08 data field (two bytes unless
    /// sub-function 00), FC 43 read device ID code 1..4, and the address range.
    pub fn validate(&self, limits: &Limits) -> Result<(), PduError> {
        let function = self.function();
        match self {
            Self::ReadCoils { address, quantity }
            | Self::ReadDiscreteInputs { address, quantity } => {
                check_quantity(function, *quantity, limits.read_bits)?;
                check_address(function, *address, *quantity)
            }
            Self::ReadHoldingRegisters { address, quantity }
            | Self::ReadInputRegisters { address, quantity } => {
                check_quantity(function, *quantity, limits.read_registers)?;
                check_address(function, *address, *quantity)
            }
            Self::WriteSingleCoil { .. }
            | Self::WriteSingleRegister { .. }
            | Self::ReadExceptionStatus
            | Self::GetCommEventCounter
            | Self::GetCommEventLog
            | Self::ReportServerId => Ok(()),
            Self::Diagnostics { sub_function, data } => {
                // A PDU holds at most 253 bytes (Modbus over Serial Line V1.02, 2.5.1): function
                // code and sub-function leave 250 for the data.
                let ok = if *sub_function == diag::RETURN_QUERY_DATA {
                    data.len() <= 250
                } else {
                    data.len() == 2
                };
                if ok {
                    Ok(())
                } else {
                    Err(PduError::IllegalValue {
                        function: function.0,
                        field: "data_len",
                        value: quantity_of(data.len()),
                    })
                }
            }
            Self::WriteMultipleCoils { address, values } => {
                let quantity = quantity_of(values.len());
                check_quantity(
                    function,
                    quantity,
                    limits.write_bits.min(quantity_of(MAX_PACKED_BITS)),
                )?;
                check_address(function, *address, quantity)
            }
            Self::WriteMultipleRegisters { address, values } => {
                let quantity = quantity_of(values.len());
                check_quantity(
                    function,
                    quantity,
                    limits
                        .write_registers
                        .min(quantity_of(MAX_PACKED_REGISTERS)),
                )?;
                check_address(function, *address, quantity)
            }
            Self::ReadWriteMultipleRegisters {
                read_address,
                read_quantity,
                write_address,
                values,
            } => {
                let write_quantity = quantity_of(values.len());
                check_quantity(function, *read_quantity, limits.read_write_read_registers)?;
                let max = limits
                    .read_write_write_registers
                    .min(quantity_of(MAX_PACKED_REGISTERS));
                check_quantity(function, write_quantity, max)?;
                check_address(function, *read_address, *read_quantity)?;
                check_address(function, *write_address, write_quantity)
            }
            Self::ReadDeviceIdentification { read_code, .. } => {
                if READ_DEVICE_ID_CODES.contains(read_code) {
                    Ok(())
                } else {
                    let value = u16::from(*read_code);
                    Err(PduError::IllegalValue {
                        function: function.0,
                        field: "read_device_id_code",
                        value,
                    })
                }
            }
        }
    }
}

/// A codec error of `function`'s request as the PDU error it is.
fn codec(function: FunctionCode) -> impl Fn(crate::codec::CodecError) -> PduError {
    move |e| PduError::from_codec(function.0, e)
}

/// FC 01..04: address and quantity (Modbus Application Protocol V1.1b3, 6.1..6.4).
fn decode_read(
    r: &mut Reader<'_>,
    function: FunctionCode,
    limits: &Limits,
) -> Result<Request, PduError> {
    let address = r.u16_be().map_err(codec(function))?;
    let quantity = r.u16_be().map_err(codec(function))?;
    r.expect_end().map_err(codec(function))?;
    let max = match function {
        FunctionCode::READ_COILS | FunctionCode::READ_DISCRETE_INPUTS => limits.read_bits,
        _ => limits.read_registers,
    };
    check_quantity(function, quantity, max)?;
    check_address(function, address, quantity)?;
    Ok(match function {
        FunctionCode::READ_COILS => Request::ReadCoils { address, quantity },
        FunctionCode::READ_DISCRETE_INPUTS => Request::ReadDiscreteInputs { address, quantity },
        FunctionCode::READ_HOLDING_REGISTERS => Request::ReadHoldingRegisters { address, quantity },
        _ => Request::ReadInputRegisters { address, quantity },
    })
}

/// FC 05: a coil and FF00h or 0000h (003 6.4.4.5).
fn decode_write_single_coil(
    r: &mut Reader<'_>,
    function: FunctionCode,
) -> Result<Request, PduError> {
    let address = r.u16_be().map_err(codec(function))?;
    let raw = r.u16_be().map_err(codec(function))?;
    r.expect_end().map_err(codec(function))?;
    let value = match raw {
        COIL_ON => true,
        COIL_OFF => false,
        value => {
            return Err(PduError::IllegalValue {
                function: function.0,
                field: "value",
                value,
            })
        }
    };
    Ok(Request::WriteSingleCoil { address, value })
}

/// FC 08: a sub-function and its data.
fn decode_diagnostics(r: &mut Reader<'_>, function: FunctionCode) -> Result<Request, PduError> {
    let sub_function = r.u16_be().map_err(codec(function))?;
    // 001 4.3.1: sub-function 00 echoes the data field, whatever it holds; every
    // other sub-function of 001 4.3 carries exactly two bytes (00 00).
    let data = if sub_function == diag::RETURN_QUERY_DATA {
        r.rest()
    } else {
        let data = r.take(2).map_err(codec(function))?;
        r.expect_end().map_err(codec(function))?;
        data
    };
    Ok(Request::Diagnostics {
        sub_function,
        data: data.to_vec(),
    })
}

/// FC 15: address, quantity, byte count and the packed coils.
fn decode_write_multiple_coils(
    r: &mut Reader<'_>,
    function: FunctionCode,
    limits: &Limits,
) -> Result<Request, PduError> {
    let address = r.u16_be().map_err(codec(function))?;
    let quantity = r.u16_be().map_err(codec(function))?;
    let byte_count = r.u8().map_err(codec(function))?;
    check_quantity(function, quantity, limits.write_bits)?;
    let expected = bit_byte_count(usize::from(quantity));
    if usize::from(byte_count) != expected {
        return Err(PduError::ByteCountMismatch {
            function: function.0,
            byte_count,
            expected,
        });
    }
    let packed = r.take(expected).map_err(codec(function))?;
    r.expect_end().map_err(codec(function))?;
    check_address(function, address, quantity)?;
    Ok(Request::WriteMultipleCoils {
        address,
        values: unpack_bits(packed, usize::from(quantity)),
    })
}

/// FC 23: the read range, the write range and the values written.
fn decode_read_write(
    r: &mut Reader<'_>,
    function: FunctionCode,
    limits: &Limits,
) -> Result<Request, PduError> {
    let read_address = r.u16_be().map_err(codec(function))?;
    let read_quantity = r.u16_be().map_err(codec(function))?;
    let write_address = r.u16_be().map_err(codec(function))?;
    let write_quantity = r.u16_be().map_err(codec(function))?;
    let byte_count = r.u8().map_err(codec(function))?;
    check_quantity(function, read_quantity, limits.read_write_read_registers)?;
    check_quantity(function, write_quantity, limits.read_write_write_registers)?;
    let values = read_registers(r, function, byte_count, write_quantity)?;
    r.expect_end().map_err(codec(function))?;
    check_address(function, read_address, read_quantity)?;
    check_address(function, write_address, write_quantity)?;
    Ok(Request::ReadWriteMultipleRegisters {
        read_address,
        read_quantity,
        write_address,
        values,
    })
}

/// FC 43/14: read device ID code and object id (Modbus Application Protocol V1.1b3, 6.21).
fn decode_device_identification(
    r: &mut Reader<'_>,
    function: FunctionCode,
) -> Result<Request, PduError> {
    let mei_type = r.u8().map_err(codec(function))?;
    if mei_type != MEI_READ_DEVICE_ID {
        return Err(PduError::UnsupportedMeiType(mei_type));
    }
    let read_code = r.u8().map_err(codec(function))?;
    let object_id = r.u8().map_err(codec(function))?;
    r.expect_end().map_err(codec(function))?;
    if !READ_DEVICE_ID_CODES.contains(&read_code) {
        let value = u16::from(read_code);
        return Err(PduError::IllegalValue {
            function: function.0,
            field: "read_device_id_code",
            value,
        });
    }
    Ok(Request::ReadDeviceIdentification {
        read_code,
        object_id,
    })
}

/// Reads `quantity` registers after a `byte_count` that must be exactly `2 * quantity` (a
/// request's byte count: any difference is [`PduError::ByteCountMismatch`]).
fn read_registers(
    r: &mut Reader<'_>,
    function: FunctionCode,
    byte_count: u8,
    quantity: u16,
) -> Result<Vec<u16>, PduError> {
    let expected = usize::from(quantity) * 2;
    if usize::from(byte_count) != expected {
        return Err(PduError::ByteCountMismatch {
            function: function.0,
            byte_count,
            expected,
        });
    }
    let bytes = r
        .take(expected)
        .map_err(|e| PduError::from_codec(function.0, e))?;
    Ok(u16s_be(bytes))
}

#[cfg(test)]
mod tests;
