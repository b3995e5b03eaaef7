//! One job of the master: the checks the CP makes when the user program hands it a request
//! (003 7.2, events 0E 41h..0E 4Ah), and the checks of the reply (0E 51h..0E 56h, 0E 61h..0E 67h).

use super::registers32::{Request32, Response32};
use super::{Framing, MasterConfig};
use crate::event::{ids, master_exception_event, EventId};
use crate::modbus::pdu::{
    diag, ExceptionCode, ExceptionResponse, FunctionCode, Limits, PduError, Request, Response,
};

/// The largest FC 08 data field: a PDU holds at most 253 bytes (Modbus over Serial Line V1.02,
/// 2.5.1), the function code and the sub-function take 3.
const MAX_DIAGNOSTIC_DATA: usize = 250;
/// The FC 08 data field of the CP: "test_value WORD" (003 6.4.4.8).
const DIAGNOSTIC_DATA_LEN: usize = 2;
/// 32-bit read limit (003 7.2, 0E 45h: "with 32bit 1...62").
const MAX_READ_REGISTERS_32: u16 = 62;
/// 32-bit write limit (003 7.2, 0E 46h: "with 32bit 1..61").
const MAX_WRITE_REGISTERS_32: u16 = 61;

/// Why the master refused a request at submit time; each maps to the CP's event (003 7.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum JobError {
    /// The function is not one the master sends (0E 42h). The CP master knows FC 01..08, 11, 12,
    /// 15, 16 (003 6.4.3); the gateway adds FC 23 and 43/14 for the Altivar (002). FC 17 and the
    /// 32-bit function codes without "with 32-Bit Register" (or on RTU) are refused.
    #[error("function {function:#04x} is not supported by the master")]
    IllegalFunction { function: u8 },
    /// Broadcast (slave 0) with a function that is not a write (0E 43h; 003 6.4.3 "ADDR").
    #[error("broadcast not permitted with function {function:#04x}")]
    BroadcastNotPermitted { function: u8 },
    /// FC 01/02 quantity outside 1..2040 (ASCII 1..2008) (0E 44h).
    #[error("bit quantity {quantity} outside 1..={max}")]
    BitCount { quantity: u16, max: u16 },
    /// FC 03/04 (and the read part of FC 23) quantity outside 1..127 (ASCII 1..125, 32-bit
    /// 1..62) (0E 45h).
    #[error("register quantity {quantity} outside 1..={max}")]
    RegisterCount { quantity: u16, max: u16 },
    /// FC 15/16 (and the write part of FC 23) quantity outside 1..2040 / 1..127 (ASCII 1..1976 /
    /// 1..123, 32-bit 1..61) (0E 46h).
    #[error("write quantity {quantity} outside 1..={max}")]
    WriteCount { quantity: u16, max: u16 },
    /// FC 08 with fewer than the two bytes of the test value (0E 41h: "The minimum length for
    /// this function code is 6bytes").
    #[error("FC 08 data field of {len} bytes is too short")]
    DiagnosticDataTooShort { len: usize },
    /// FC 08 data longer than a PDU can carry (05 18h: "transmission length ... too large").
    #[error("FC 08 data field of {len} bytes is too long")]
    DiagnosticDataTooLong { len: usize },
    /// FC 08 sub-function the master does not send (0E 49h). The CP allows only 0000h
    /// (003 6.4.4.8); the gateway also allows the sub-functions the KS vario answers (001 4.3),
    /// except 04 "force listen-only", which is never answered.
    #[error("FC 08 sub-function {sub_function:#06x} not permitted")]
    DiagnosticCode { sub_function: u16 },
}

// === impl JobError ===

impl JobError {
    /// The event the CP reports for this refusal (003 7.2).
    pub const fn event(&self) -> EventId {
        match self {
            Self::IllegalFunction { .. } => ids::MASTER_ILLEGAL_FUNCTION,
            Self::BroadcastNotPermitted { .. } => ids::MASTER_BROADCAST_NOT_PERMITTED,
            Self::BitCount { .. } => ids::MASTER_BIT_COUNT_OUT_OF_RANGE,
            Self::RegisterCount { .. } => ids::MASTER_REGISTER_COUNT_OUT_OF_RANGE,
            Self::WriteCount { .. } => ids::MASTER_WRITE_COUNT_OUT_OF_RANGE,
            Self::DiagnosticDataTooShort { .. } => ids::MASTER_LEN_TOO_SMALL_FOR_FUNCTION,
            Self::DiagnosticDataTooLong { .. } => ids::MODBUS_SEND_LENGTH_INVALID,
            Self::DiagnosticCode { .. } => ids::MASTER_DIAGNOSTIC_CODE_INVALID,
        }
    }
}

/// What the master was asked to do.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum Job {
    /// A request of the PDU codec.
    Standard(Request),
    /// A 32-bit register job of the ASCII master.
    Registers32(Request32),
}

/// A decoded reply that fits the job.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum Reply {
    /// The normal answer to a [`Job::Standard`].
    Standard(Response),
    /// The normal answer to a [`Job::Registers32`].
    Registers32(Response32),
    /// An exception response to the job's function.
    Exception(ExceptionCode),
}

fn check(quantity: u16, max: u16, error: fn(u16, u16) -> JobError) -> Result<(), JobError> {
    if (1..=max).contains(&quantity) {
        Ok(())
    } else {
        Err(error(quantity, max))
    }
}

fn bits(quantity: u16, max: u16) -> JobError {
    JobError::BitCount { quantity, max }
}

fn registers(quantity: u16, max: u16) -> JobError {
    JobError::RegisterCount { quantity, max }
}

fn writes(quantity: u16, max: u16) -> JobError {
    JobError::WriteCount { quantity, max }
}

fn len_u16(len: usize) -> u16 {
    u16::try_from(len).unwrap_or(u16::MAX)
}

// === impl Job ===

impl Job {
    /// The function code on the wire.
    pub(crate) fn function(&self) -> FunctionCode {
        match self {
            Self::Standard(request) => request.function(),
            Self::Registers32(request) => request.function(),
        }
    }

    /// The CP's checks of a job before it is sent (003 6.4.4, 7.2 0E 41h..0E 4Ah). The start
    /// addresses are "not checked by the driver and sent unchanged" (003 6.4.4.1..6.4.4.12).
    pub(crate) fn validate(&self, slave: u8, config: &MasterConfig) -> Result<(), JobError> {
        let limits = match config.framing {
            Framing::Rtu { .. } => Limits::CP_MASTER_RTU,
            Framing::Ascii { .. } => Limits::CP_MASTER_ASCII,
        };
        let function = self.function();
        match self {
            Self::Standard(request) => validate_standard(request, &limits)?,
            Self::Registers32(request) => {
                if !matches!(
                    config.framing,
                    Framing::Ascii {
                        registers32: true,
                        ..
                    }
                ) {
                    // Without "with 32-Bit Register" a function code with bit 6 set is just an
                    // illegal function code (003 6.4.2.2).
                    return Err(JobError::IllegalFunction {
                        function: request.job_function(),
                    });
                }
                match request {
                    Request32::ReadHoldingRegisters { quantity, .. } => {
                        check(*quantity, MAX_READ_REGISTERS_32, registers)?
                    }
                    Request32::WriteSingleRegister { .. } => {}
                    Request32::WriteMultipleRegisters { values, .. } => {
                        check(len_u16(values.len()), MAX_WRITE_REGISTERS_32, writes)?;
                    }
                }
            }
        }
        // 003 6.4.3 "ADDR": broadcast "is only permitted in conjunction with the writing function
        // codes" (0E 43h). Checked after the function and its quantities, as the CP's table lists.
        if slave == 0 && !function.is_write() {
            return Err(JobError::BroadcastNotPermitted {
                function: function.0,
            });
        }
        Ok(())
    }

    /// The request PDU.
    pub(crate) fn encode(&self) -> Vec<u8> {
        let mut pdu = Vec::new();
        match self {
            Self::Standard(request) => request.encode(&mut pdu),
            Self::Registers32(request) => request.encode(&mut pdu),
        }
        pdu
    }

    /// Checks a reply PDU (the frame's checksum and address already checked) against the job,
    /// raising the CP's event for what does not fit.
    pub(crate) fn check_reply(&self, pdu: &[u8]) -> Result<Reply, EventId> {
        let decoded = match self {
            Self::Standard(request) => {
                Response::decode_for(request, pdu).map(|r| r.map(Reply::Standard))
            }
            Self::Registers32(request) => {
                if pdu.first() == Some(&request.function().to_exception()) {
                    ExceptionResponse::decode(pdu).map(Err)
                } else {
                    request
                        .decode_response(pdu)
                        .map(|r| Ok(Reply::Registers32(r)))
                }
            }
        };
        match decoded {
            Ok(Ok(reply)) => Ok(reply),
            Ok(Err(exception)) => Ok(Reply::Exception(exception.code)),
            Err(error) => Err(reply_event(&error)),
        }
    }
}

/// The event for an exception code: 01..07 are 0E 61h..0E 67h (003 7.2); the manual has no event
/// for the codes the CP does not list (08, 0A, 0B and others), so they raise none and are reported
/// only as the outcome.
pub(crate) fn exception_event(code: ExceptionCode) -> Option<EventId> {
    master_exception_event(u8::from(code))
}

/// The event for a reply that does not fit its request (003 7.2 0E 51h..0E 56h).
pub(crate) fn reply_event(error: &PduError) -> EventId {
    match error {
        PduError::FunctionMismatch { .. }
        | PduError::UnsupportedFunction(_)
        | PduError::UnsupportedMeiType(_) => ids::MODBUS_WRONG_FUNCTION,
        PduError::Empty | PduError::TooShort { .. } => ids::MODBUS_BYTE_UNDERFLOW,
        PduError::TrailingData { .. } => ids::MODBUS_BYTE_OVERFLOW,
        PduError::ByteCountTooSmall { .. } => ids::MODBUS_BYTE_COUNT_TOO_SMALL,
        PduError::EchoMismatch { .. } => ids::MODBUS_ECHO_WRONG,
        // A value no device may send ("more follows" 12h) makes the byte content wrong.
        PduError::ByteCountMismatch { .. }
        | PduError::IllegalValue { .. }
        | PduError::QuantityOutOfRange { .. }
        | PduError::AddressOutOfRange { .. } => ids::MODBUS_BYTE_COUNT_WRONG,
    }
}

fn validate_standard(request: &Request, limits: &Limits) -> Result<(), JobError> {
    match request {
        Request::ReadCoils { quantity, .. } | Request::ReadDiscreteInputs { quantity, .. } => {
            check(*quantity, limits.read_bits, bits)
        }
        Request::ReadHoldingRegisters { quantity, .. }
        | Request::ReadInputRegisters { quantity, .. } => {
            check(*quantity, limits.read_registers, registers)
        }
        Request::WriteMultipleCoils { values, .. } => {
            check(len_u16(values.len()), limits.write_bits, writes)
        }
        Request::WriteMultipleRegisters { values, .. } => {
            check(len_u16(values.len()), limits.write_registers, writes)
        }
        Request::ReadWriteMultipleRegisters {
            read_quantity,
            values,
            ..
        } => {
            check(*read_quantity, limits.read_write_read_registers, registers)?;
            check(
                len_u16(values.len()),
                limits.read_write_write_registers,
                writes,
            )
        }
        Request::Diagnostics { sub_function, data } => {
            if !diag::is_known(*sub_function) || *sub_function == diag::FORCE_LISTEN_ONLY {
                return Err(JobError::DiagnosticCode {
                    sub_function: *sub_function,
                });
            }
            let max = if *sub_function == diag::RETURN_QUERY_DATA {
                MAX_DIAGNOSTIC_DATA
            } else {
                DIAGNOSTIC_DATA_LEN
            };
            if data.len() < DIAGNOSTIC_DATA_LEN {
                Err(JobError::DiagnosticDataTooShort { len: data.len() })
            } else if data.len() > max {
                Err(JobError::DiagnosticDataTooLong { len: data.len() })
            } else {
                Ok(())
            }
        }
        Request::ReportServerId => Err(JobError::IllegalFunction {
            function: request.function().0,
        }),
        Request::WriteSingleCoil { .. }
        | Request::WriteSingleRegister { .. }
        | Request::ReadExceptionStatus
        | Request::GetCommEventCounter
        | Request::GetCommEventLog
        | Request::ReadDeviceIdentification { .. } => Ok(()),
    }
}
