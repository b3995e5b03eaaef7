//! Response PDUs: encoding (the server's side) and decoding against the request (the master's side).

use super::request::{COIL_OFF, COIL_ON, MAX_BYTE_COUNT};
use super::{
    diag, ExceptionCode, ExceptionResponse, FunctionCode, PduError, Request, Response,
    MEI_READ_DEVICE_ID,
};
use crate::codec::{bit_byte_count, u16s_be, unpack_bits, CodecError, Reader, Writer};

/// FC 43/14 "more follows": FFh when further transactions are needed (Modbus Application
/// Protocol V1.1b3, 6.21), 00h when not.
const MORE_FOLLOWS: u8 = 0xFF;
/// FC 43/14 "more follows": no further transaction.
const NO_MORE_FOLLOWS: u8 = 0x00;

/// FC 12: status, event count and message count precede the event bytes in the byte count.
const EVENT_LOG_HEADER_LEN: usize = 6;

/// The prefix of `items` a one-byte count can describe when each item takes `item_len` bytes.
fn fitting<T>(items: &[T], item_len: usize) -> &[T] {
    items.get(..MAX_BYTE_COUNT / item_len).unwrap_or(items)
}

// === impl Response ===

impl Response {
    /// The response's function code.
    pub const fn function(&self) -> FunctionCode {
        match self {
            Self::ReadCoils(_) => FunctionCode::READ_COILS,
            Self::ReadDiscreteInputs(_) => FunctionCode::READ_DISCRETE_INPUTS,
            Self::ReadHoldingRegisters(_) => FunctionCode::READ_HOLDING_REGISTERS,
            Self::ReadInputRegisters(_) => FunctionCode::READ_INPUT_REGISTERS,
            Self::WriteSingleCoil { .. } => FunctionCode::WRITE_SINGLE_COIL,
            Self::WriteSingleRegister { .. } => FunctionCode::WRITE_SINGLE_REGISTER,
            Self::ReadExceptionStatus(_) => FunctionCode::READ_EXCEPTION_STATUS,
            Self::Diagnostics { .. } => FunctionCode::DIAGNOSTICS,
            Self::GetCommEventCounter { .. } => FunctionCode::GET_COMM_EVENT_COUNTER,
            Self::GetCommEventLog { .. } => FunctionCode::GET_COMM_EVENT_LOG,
            Self::WriteMultipleCoils { .. } => FunctionCode::WRITE_MULTIPLE_COILS,
            Self::WriteMultipleRegisters { .. } => FunctionCode::WRITE_MULTIPLE_REGISTERS,
            Self::ReportServerId(_) => FunctionCode::REPORT_SERVER_ID,
            Self::ReadWriteMultipleRegisters(_) => FunctionCode::READ_WRITE_MULTIPLE_REGISTERS,
            Self::ReadDeviceIdentification { .. } => FunctionCode::ENCAPSULATED_INTERFACE,
        }
    }

    /// Appends the response PDU (function code and data) to `out`.
    ///
    /// Encoding never fails. Payloads longer than a one-byte byte count can describe (more than
    /// 2040 coils, 127 registers, 255 bytes) are cut to what it can, so the frame stays
    /// self-consistent; a server that follows its limits never produces them.
    pub fn encode(&self, out: &mut Vec<u8>) {
        let mut w = Writer::new(out);
        w.u8(self.function().0);
        match self {
            Self::ReadCoils(bits) | Self::ReadDiscreteInputs(bits) => {
                let bits = bits.get(..MAX_BYTE_COUNT * 8).unwrap_or(bits);
                w.count_u8(bit_byte_count(bits.len())).bits(bits);
            }
            Self::ReadHoldingRegisters(values)
            | Self::ReadInputRegisters(values)
            | Self::ReadWriteMultipleRegisters(values) => {
                let values = fitting(values, 2);
                w.count_u8(values.len() * 2);
                for &value in values {
                    w.u16_be(value);
                }
            }
            Self::WriteSingleCoil { address, value } => {
                w.u16_be(*address)
                    .u16_be(if *value { COIL_ON } else { COIL_OFF });
            }
            Self::WriteSingleRegister { address, value } => {
                w.u16_be(*address).u16_be(*value);
            }
            Self::ReadExceptionStatus(status) => {
                w.u8(*status);
            }
            Self::Diagnostics { sub_function, data } => {
                w.u16_be(*sub_function).bytes(data);
            }
            Self::GetCommEventCounter {
                status,
                event_count,
            } => {
                w.u16_be(*status).u16_be(*event_count);
            }
            Self::GetCommEventLog {
                status,
                event_count,
                message_count,
                events,
            } => {
                let events = events
                    .get(..MAX_BYTE_COUNT - EVENT_LOG_HEADER_LEN)
                    .unwrap_or(events);
                w.count_u8(EVENT_LOG_HEADER_LEN + events.len());
                w.u16_be(*status)
                    .u16_be(*event_count)
                    .u16_be(*message_count)
                    .bytes(events);
            }
            Self::WriteMultipleCoils { address, quantity }
            | Self::WriteMultipleRegisters { address, quantity } => {
                w.u16_be(*address).u16_be(*quantity);
            }
            Self::ReportServerId(bytes) => {
                let bytes = fitting(bytes, 1);
                w.count_u8(bytes.len()).bytes(bytes);
            }
            Self::ReadDeviceIdentification {
                read_code,
                conformity_level,
                more_follows,
                next_object_id,
                objects,
            } => {
                let objects = fitting(objects, 1);
                w.u8(MEI_READ_DEVICE_ID)
                    .u8(*read_code)
                    .u8(*conformity_level);
                w.u8(if *more_follows {
                    MORE_FOLLOWS
                } else {
                    NO_MORE_FOLLOWS
                });
                w.u8(*next_object_id).count_u8(objects.len());
                for (id, value) in objects {
                    let value = fitting(value, 1);
                    w.u8(*id).count_u8(value.len()).bytes(value);
                }
            }
        }
    }

    /// The encoded PDU as a new vector.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::new();
        self.encode(&mut out);
        out
    }

    /// Decodes what a device answered to `request`, as a master does, and checks that it matches.
    ///
    /// - `Ok(Ok(response))`: a normal response that fits the request; coil and input states are
    ///   cut to the requested quantity;
    /// - `Ok(Err(exception))`: an exception response to the request's function (`function | 80h`);
    /// - `Err(error)`: the answer does not fit. The variants follow the CP 341's events (003 7.2):
    ///   [`PduError::FunctionMismatch`] 0E 51h, [`PduError::TooShort`] 0E 52h (fewer bytes than
    ///   the byte count or the function needs), [`PduError::TrailingData`] 0E 53h (more),
    ///   [`PduError::ByteCountTooSmall`] 0E 54h, [`PduError::ByteCountMismatch`] 0E 55h,
    ///   [`PduError::EchoMismatch`] 0E 56h; [`PduError::IllegalValue`] (a field no device may
    ///   send, e.g. FC 43 "more follows" 12h) and [`PduError::Empty`] are 0E 52h/0E 55h at the
    ///   caller's choice.
    ///
    /// Byte counts up to 255 are accepted, so the CP master's 127 registers and 2040 coils
    /// (003 6.4.4) can be read.
    pub fn decode_for(
        request: &Request,
        pdu: &[u8],
    ) -> Result<Result<Self, ExceptionResponse>, PduError> {
        let mut r = Reader::new(pdu);
        let expected = request.function();
        let got = r.u8().map_err(|_| PduError::Empty)?;
        if got == expected.to_exception() {
            return ExceptionResponse::decode_rest(expected, &mut r).map(Err);
        }
        if got != expected.0 {
            return Err(PduError::FunctionMismatch {
                expected: expected.0,
                got,
            });
        }
        decode_body(request, &mut r, expected.0).map(Ok)
    }
}

/// The rest of a normal answer of `function` to `request`, after the function code.
fn decode_body(request: &Request, r: &mut Reader<'_>, function: u8) -> Result<Response, PduError> {
    let err = |e: CodecError| PduError::from_codec(function, e);
    Ok(match request {
        Request::ReadCoils { quantity, .. } => {
            Response::ReadCoils(read_bits(r, function, *quantity)?)
        }
        Request::ReadDiscreteInputs { quantity, .. } => {
            Response::ReadDiscreteInputs(read_bits(r, function, *quantity)?)
        }
        Request::ReadHoldingRegisters { quantity, .. } => {
            Response::ReadHoldingRegisters(read_registers(r, function, *quantity)?)
        }
        Request::ReadInputRegisters { quantity, .. } => {
            Response::ReadInputRegisters(read_registers(r, function, *quantity)?)
        }
        Request::ReadWriteMultipleRegisters { read_quantity, .. } => {
            Response::ReadWriteMultipleRegisters(read_registers(r, function, *read_quantity)?)
        }
        Request::WriteSingleCoil { address, value } => {
            let sent = if *value { COIL_ON } else { COIL_OFF };
            let address = read_single_echo(r, function, *address, sent)?;
            Response::WriteSingleCoil {
                address,
                value: *value,
            }
        }
        Request::WriteSingleRegister { address, value } => {
            let address = read_single_echo(r, function, *address, *value)?;
            Response::WriteSingleRegister {
                address,
                value: *value,
            }
        }
        Request::ReadExceptionStatus => {
            let status = r.u8().map_err(err)?;
            r.expect_end().map_err(err)?;
            Response::ReadExceptionStatus(status)
        }
        Request::Diagnostics { sub_function, data } => {
            read_diagnostics(r, function, *sub_function, data)?
        }
        Request::GetCommEventCounter => {
            let status = r.u16_be().map_err(err)?;
            let event_count = r.u16_be().map_err(err)?;
            r.expect_end().map_err(err)?;
            Response::GetCommEventCounter {
                status,
                event_count,
            }
        }
        Request::GetCommEventLog => read_event_log(r, function)?,
        Request::WriteMultipleCoils { address, values } => {
            let quantity = u16::try_from(values.len().min(MAX_BYTE_COUNT * 8)).unwrap_or(u16::MAX);
            Response::WriteMultipleCoils {
                address: *address,
                quantity: read_echo(r, function, *address, quantity)?,
            }
        }
        Request::WriteMultipleRegisters { address, values } => {
            let quantity = u16::try_from(values.len().min(MAX_BYTE_COUNT / 2)).unwrap_or(u16::MAX);
            let quantity = read_echo(r, function, *address, quantity)?;
            Response::WriteMultipleRegisters {
                address: *address,
                quantity,
            }
        }
        Request::ReportServerId => {
            let byte_count = r.u8().map_err(err)?;
            let bytes = r.take(usize::from(byte_count)).map_err(err)?;
            r.expect_end().map_err(err)?;
            Response::ReportServerId(bytes.to_vec())
        }
        Request::ReadDeviceIdentification { read_code, .. } => {
            read_device_identification(r, *read_code)?
        }
    })
}

/// The address and value echo of FC 05/06 (Modbus Application Protocol V1.1b3, 6.5, 6.6: the
/// normal response is an echo of the request); returns the address.
fn read_single_echo(
    r: &mut Reader<'_>,
    function: u8,
    address: u16,
    value: u16,
) -> Result<u16, PduError> {
    let err = |e: CodecError| PduError::from_codec(function, e);
    let got_address = r.u16_be().map_err(err)?;
    let got_value = r.u16_be().map_err(err)?;
    r.expect_end().map_err(err)?;
    echo(function, "address", address, got_address)?;
    echo(function, "value", value, got_value)?;
    Ok(got_address)
}

/// FC 08: the sub-function echoed, then its data echoed or a two-byte value.
fn read_diagnostics(
    r: &mut Reader<'_>,
    function: u8,
    sub_function: u16,
    data: &[u8],
) -> Result<Response, PduError> {
    let err = |e: CodecError| PduError::from_codec(function, e);
    let got_sub = r.u16_be().map_err(err)?;
    echo(function, "sub_function", sub_function, got_sub)?;
    let got_data = if diag::echoes_data(sub_function) {
        let got_data = r.take(data.len()).map_err(err)?;
        r.expect_end().map_err(err)?;
        if let Some((sent, got)) = data.iter().zip(got_data).find(|(sent, got)| sent != got) {
            return Err(PduError::EchoMismatch {
                function,
                field: "data",
                expected: u16::from(*sent),
                got: u16::from(*got),
            });
        }
        got_data
    } else {
        // 001 4.3.3..4.3.15: a counter or register value of two bytes.
        let got_data = r.take(2).map_err(err)?;
        r.expect_end().map_err(err)?;
        got_data
    };
    Ok(Response::Diagnostics {
        sub_function: got_sub,
        data: got_data.to_vec(),
    })
}

/// FC 12: byte count, status, event count, message count and the events.
fn read_event_log(r: &mut Reader<'_>, function: u8) -> Result<Response, PduError> {
    let err = |e: CodecError| PduError::from_codec(function, e);
    let byte_count = r.u8().map_err(err)?;
    if usize::from(byte_count) < EVENT_LOG_HEADER_LEN {
        return Err(PduError::ByteCountTooSmall {
            function,
            byte_count,
            expected: EVENT_LOG_HEADER_LEN,
        });
    }
    let body = r.take(usize::from(byte_count)).map_err(err)?;
    r.expect_end().map_err(err)?;
    let mut body = Reader::new(body);
    let status = body.u16_be().map_err(err)?;
    let event_count = body.u16_be().map_err(err)?;
    let message_count = body.u16_be().map_err(err)?;
    Ok(Response::GetCommEventLog {
        status,
        event_count,
        message_count,
        events: body.rest().to_vec(),
    })
}

/// Fails with [`PduError::EchoMismatch`] unless `got == expected`.
fn echo(function: u8, field: &'static str, expected: u16, got: u16) -> Result<(), PduError> {
    if expected == got {
        Ok(())
    } else {
        Err(PduError::EchoMismatch {
            function,
            field,
            expected,
            got,
        })
    }
}

/// The address and quantity echo of FC 15/16; returns the quantity.
fn read_echo(
    r: &mut Reader<'_>,
    function: u8,
    address: u16,
    quantity: u16,
) -> Result<u16, PduError> {
    let err = |e| PduError::from_codec(function, e);
    let got_address = r.u16_be().map_err(err)?;
    let got_quantity = r.u16_be().map_err(err)?;
    r.expect_end().map_err(err)?;
    echo(function, "address", address, got_address)?;
    echo(function, "quantity", quantity, got_quantity)?;
    Ok(got_quantity)
}

/// Checks a response byte count against what the requested quantity needs: smaller is 0E 54h,
/// larger 0E 55h (003 7.2).
fn check_byte_count(function: u8, byte_count: u8, expected: usize) -> Result<(), PduError> {
    match usize::from(byte_count).cmp(&expected) {
        core::cmp::Ordering::Less => Err(PduError::ByteCountTooSmall {
            function,
            byte_count,
            expected,
        }),
        core::cmp::Ordering::Equal => Ok(()),
        core::cmp::Ordering::Greater => Err(PduError::ByteCountMismatch {
            function,
            byte_count,
            expected,
        }),
    }
}

/// A byte count and `quantity` packed bits; the states beyond `quantity` (padding) are dropped.
fn read_bits(r: &mut Reader<'_>, function: u8, quantity: u16) -> Result<Vec<bool>, PduError> {
    let err = |e| PduError::from_codec(function, e);
    let byte_count = r.u8().map_err(err)?;
    check_byte_count(function, byte_count, bit_byte_count(usize::from(quantity)))?;
    let bytes = r.take(usize::from(byte_count)).map_err(err)?;
    r.expect_end().map_err(err)?;
    Ok(unpack_bits(bytes, usize::from(quantity)))
}

/// A byte count and `quantity` registers.
fn read_registers(r: &mut Reader<'_>, function: u8, quantity: u16) -> Result<Vec<u16>, PduError> {
    let err = |e| PduError::from_codec(function, e);
    let byte_count = r.u8().map_err(err)?;
    check_byte_count(function, byte_count, usize::from(quantity) * 2)?;
    let bytes = r.take(usize::from(byte_count)).map_err(err)?;
    r.expect_end().map_err(err)?;
    Ok(u16s_be(bytes))
}

/// FC 43/14 after the function code (Modbus Application Protocol V1.1b3, 6.21; 002 "Identifikation").
fn read_device_identification(r: &mut Reader<'_>, read_code: u8) -> Result<Response, PduError> {
    let function = FunctionCode::ENCAPSULATED_INTERFACE.0;
    let err = |e| PduError::from_codec(function, e);
    let mei_type = r.u8().map_err(err)?;
    echo(
        function,
        "mei_type",
        u16::from(MEI_READ_DEVICE_ID),
        u16::from(mei_type),
    )?;
    let got_code = r.u8().map_err(err)?;
    echo(
        function,
        "read_device_id_code",
        u16::from(read_code),
        u16::from(got_code),
    )?;
    let conformity_level = r.u8().map_err(err)?;
    let more_follows = match r.u8().map_err(err)? {
        MORE_FOLLOWS => true,
        NO_MORE_FOLLOWS => false,
        other => {
            return Err(PduError::IllegalValue {
                function,
                field: "more_follows",
                value: u16::from(other),
            })
        }
    };
    let next_object_id = r.u8().map_err(err)?;
    let count = r.u8().map_err(err)?;
    let mut objects = Vec::with_capacity(usize::from(count));
    for _ in 0..count {
        let id = r.u8().map_err(err)?;
        let len = r.u8().map_err(err)?;
        objects.push((id, r.take(usize::from(len)).map_err(err)?.to_vec()));
    }
    r.expect_end().map_err(err)?;
    Ok(Response::ReadDeviceIdentification {
        read_code: got_code,
        conformity_level,
        more_follows,
        next_object_id,
        objects,
    })
}

// === impl ExceptionResponse (decoding) ===

impl ExceptionResponse {
    /// Decodes an exception response PDU on its own (`function | 80h`, exception code).
    pub fn decode(pdu: &[u8]) -> Result<Self, PduError> {
        let mut r = Reader::new(pdu);
        let code = r.u8().map_err(|_| PduError::Empty)?;
        if !FunctionCode(code).is_exception() {
            return Err(PduError::FunctionMismatch {
                expected: code | FunctionCode::EXCEPTION_BIT,
                got: code,
            });
        }
        Self::decode_rest(FunctionCode(code & !FunctionCode::EXCEPTION_BIT), &mut r)
    }

    /// The exception code after the function code. The Altivar answers FC 43 errors with the MEI
    /// type before the code (002 "Negative Antwort für die Identifizierungsfunktion": `AB 0E code`);
    /// that form is accepted as well as the specification's `AB code`.
    fn decode_rest(function: FunctionCode, r: &mut Reader<'_>) -> Result<Self, PduError> {
        let err = |e| PduError::from_codec(function.to_exception(), e);
        if function == FunctionCode::ENCAPSULATED_INTERFACE
            && r.remaining() == 2
            && r.peek_u8() == Some(MEI_READ_DEVICE_ID)
        {
            r.u8().map_err(err)?;
        }
        let code = r.u8().map_err(err)?;
        r.expect_end().map_err(err)?;
        Ok(Self {
            function,
            code: ExceptionCode::from(code),
        })
    }
}

#[cfg(test)]
mod tests;
