//! One decoded request served from the CP memory (manual 003 6.4.8).

use crate::cpmem::{AccessError, AddressMap, BitTable, CpMemory, RegisterTable, Written};
use crate::event::EventId;
use crate::modbus::pdu::{diag, ExceptionCode, Request, Response};

/// Why a request was refused: the exception answered and the 7.2 event the CP reports, if any.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Refusal {
    /// The exception code of the answer.
    pub(crate) code: ExceptionCode,
    /// The catalog event (0E 38h, 0E 39h) the refusal raises.
    pub(crate) event: Option<EventId>,
}

impl From<AccessError> for Refusal {
    fn from(error: AccessError) -> Self {
        Self {
            code: ExceptionCode::from(&error),
            event: error.event(),
        }
    }
}

// The exception a refused access answers: the mapping of 003 6.4.6 "Error codes" as the Modbus
// Application Protocol V1.1b3 (6.x state diagrams) gives it (see `AccessError`). It lives on the
// Modbus side so that the CP memory does not depend on the Modbus PDU types.
impl From<AccessError> for ExceptionCode {
    fn from(error: AccessError) -> Self {
        Self::from(&error)
    }
}

impl From<&AccessError> for ExceptionCode {
    fn from(error: &AccessError) -> Self {
        match error {
            AccessError::IllegalQuantity { .. } => Self::IllegalDataValue,
            AccessError::NotMapped { .. }
            | AccessError::CrossesArea { .. }
            | AccessError::Misaligned { .. }
            | AccessError::ReadOnly { .. }
            | AccessError::CrossesDb { .. }
            | AccessError::WriteNotEnabled { .. }
            | AccessError::BeyondAreaEnd { .. }
            | AccessError::DbMissingOrShort { .. } => Self::IllegalDataAddress,
        }
    }
}

/// A function the slave driver does not support: exception 01 (003 6.4.6 "FUNC": only the listed
/// function codes are supported; Modbus Application Protocol V1.1b3, 7: "Illegal function").
const UNSUPPORTED: Refusal = Refusal {
    code: ExceptionCode::IllegalFunction,
    event: None,
};

/// Carries out `request` on `mem`: the normal response and what was written, or the refusal.
///
/// Served: FC 01, 02, 03, 04, 05, 06, 08 (diagnostic code 0000h only, 6.4.8.7), 15, 16 (6.4.6).
/// FC 08 with another diagnostic code answers exception 01 (the seeds are silent; the Modbus
/// Application Protocol V1.1b3, 6.8 answers an unsupported sub-function with 01).
pub(crate) fn serve(
    map: &AddressMap,
    mem: &mut CpMemory,
    request: &Request,
) -> Result<(Response, Option<Written>), Refusal> {
    let response = match request {
        Request::ReadCoils { address, quantity } => {
            Response::ReadCoils(mem.read_bits(map, BitTable::Coils, *address, *quantity)?)
        }
        Request::ReadDiscreteInputs { address, quantity } => Response::ReadDiscreteInputs(
            mem.read_bits(map, BitTable::Inputs, *address, *quantity)?,
        ),
        Request::ReadHoldingRegisters { address, quantity } => Response::ReadHoldingRegisters(
            mem.read_registers(map, RegisterTable::Holding, *address, *quantity)?,
        ),
        Request::ReadInputRegisters { address, quantity } => Response::ReadInputRegisters(
            mem.read_registers(map, RegisterTable::Input, *address, *quantity)?,
        ),
        Request::WriteSingleCoil { address, value } => {
            let written = mem.write_bits(map, *address, &[*value])?;
            return Ok((
                Response::WriteSingleCoil {
                    address: *address,
                    value: *value,
                },
                Some(written),
            ));
        }
        Request::WriteSingleRegister { address, value } => {
            let written = mem.write_registers(map, *address, &[*value])?;
            return Ok((
                Response::WriteSingleRegister {
                    address: *address,
                    value: *value,
                },
                Some(written),
            ));
        }
        Request::WriteMultipleCoils { address, values } => {
            let written = mem.write_bits(map, *address, values)?;
            let quantity = u16::try_from(values.len()).unwrap_or(u16::MAX);
            return Ok((
                Response::WriteMultipleCoils {
                    address: *address,
                    quantity,
                },
                Some(written),
            ));
        }
        Request::WriteMultipleRegisters { address, values } => {
            let written = mem.write_registers(map, *address, values)?;
            let quantity = u16::try_from(values.len()).unwrap_or(u16::MAX);
            return Ok((
                Response::WriteMultipleRegisters {
                    address: *address,
                    quantity,
                },
                Some(written),
            ));
        }
        // 6.4.8.7: "The received message is independently returned to the master by the driver."
        Request::Diagnostics { sub_function, data } if *sub_function == diag::RETURN_QUERY_DATA => {
            Response::Diagnostics {
                sub_function: *sub_function,
                data: data.clone(),
            }
        }
        _ => return Err(UNSUPPORTED),
    };
    Ok((response, None))
}
