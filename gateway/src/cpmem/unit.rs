//! The CP memory as a Modbus TCP unit: the same address conversion (003 6.4.8) and the same
//! answers as the serial slave, so a SCADA client and the HMI on the serial line see one memory.
//!
//! Served: FC 01, 02, 03, 04, 05, 06, 15, 16 and FC 08 sub-function 0000h (return query data,
//! 003 6.4.8.7); anything else is exception 01, as the serial slave answers (003 6.4.6 "FUNC").
//! Refusals map to exceptions in one place, proto-core's `From<&AccessError> for ExceptionCode`:
//! a quantity out of range is 03, an address the conversion or the memory cannot serve, or a
//! write outside the limits, is 02.

use std::future::ready;
use std::sync::Arc;

use proto_core::cpmem::{AccessError, AddressMap, BitTable, RegisterTable};
use proto_core::modbus::pdu::{diag, ExceptionCode, Request, Response};

use super::SharedCpMemory;
use crate::unit::{UnitFuture, UnitResult, UnitService};

/// The CP memory served under a Modbus TCP unit id through an address map; cheap to clone.
#[derive(Clone, Debug)]
pub struct CpMemoryUnit {
    memory: SharedCpMemory,
    map: Arc<AddressMap>,
}

// === impl CpMemoryUnit ===

impl CpMemoryUnit {
    /// `memory` as `map` converts it (the map of the serial slave line that shares the memory).
    pub fn new(memory: SharedCpMemory, map: AddressMap) -> Self {
        Self {
            memory,
            map: Arc::new(map),
        }
    }

    /// The memory served.
    pub fn memory(&self) -> &SharedCpMemory {
        &self.memory
    }

    /// The address map.
    pub fn map(&self) -> &AddressMap {
        &self.map
    }

    /// Answers one request at once (the memory is local: nothing to wait for).
    pub fn answer(&self, request: &Request) -> UnitResult {
        let (memory, map) = (&self.memory, &*self.map);
        let refused = |error: AccessError| {
            tracing::debug!(%error, "CP memory request refused");
            ExceptionCode::from(&error)
        };
        let response = match request {
            Request::ReadCoils { address, quantity } => Response::ReadCoils(
                memory
                    .read_bits(map, BitTable::Coils, *address, *quantity)
                    .map_err(refused)?,
            ),
            Request::ReadDiscreteInputs { address, quantity } => Response::ReadDiscreteInputs(
                memory
                    .read_bits(map, BitTable::Inputs, *address, *quantity)
                    .map_err(refused)?,
            ),
            Request::ReadHoldingRegisters { address, quantity } => Response::ReadHoldingRegisters(
                memory
                    .read_registers(map, RegisterTable::Holding, *address, *quantity)
                    .map_err(refused)?,
            ),
            Request::ReadInputRegisters { address, quantity } => Response::ReadInputRegisters(
                memory
                    .read_registers(map, RegisterTable::Input, *address, *quantity)
                    .map_err(refused)?,
            ),
            Request::WriteSingleCoil { address, value } => {
                memory
                    .write_bits(map, *address, &[*value])
                    .map_err(refused)?;
                Response::WriteSingleCoil {
                    address: *address,
                    value: *value,
                }
            }
            Request::WriteSingleRegister { address, value } => {
                memory
                    .write_registers(map, *address, &[*value])
                    .map_err(refused)?;
                Response::WriteSingleRegister {
                    address: *address,
                    value: *value,
                }
            }
            Request::WriteMultipleCoils { address, values } => {
                memory.write_bits(map, *address, values).map_err(refused)?;
                Response::WriteMultipleCoils {
                    address: *address,
                    quantity: u16::try_from(values.len()).unwrap_or(u16::MAX),
                }
            }
            Request::WriteMultipleRegisters { address, values } => {
                memory
                    .write_registers(map, *address, values)
                    .map_err(refused)?;
                Response::WriteMultipleRegisters {
                    address: *address,
                    quantity: u16::try_from(values.len()).unwrap_or(u16::MAX),
                }
            }
            // 003 6.4.8.7: "The received message is independently returned to the master".
            Request::Diagnostics { sub_function, data }
                if *sub_function == diag::RETURN_QUERY_DATA =>
            {
                Response::Diagnostics {
                    sub_function: *sub_function,
                    data: data.clone(),
                }
            }
            _ => return Err(ExceptionCode::IllegalFunction),
        };
        Ok(response)
    }
}

impl UnitService for CpMemoryUnit {
    fn call(&self, request: Request) -> UnitFuture {
        Box::pin(ready(self.answer(&request)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proto_core::cpmem::{MemoryLayout, WriteLimits};

    #[test]
    fn refusals_are_the_serial_slaves_exceptions() {
        let unit = CpMemoryUnit::new(
            SharedCpMemory::new(MemoryLayout::default()),
            AddressMap::manual_example(),
        );
        let cases = [
            // Nothing is write-enabled in the manual's example.
            (
                Request::WriteSingleRegister {
                    address: 0,
                    value: 1,
                },
                ExceptionCode::IllegalDataAddress,
            ),
            // 128 registers: above the CP's 127.
            (
                Request::ReadHoldingRegisters {
                    address: 0,
                    quantity: 128,
                },
                ExceptionCode::IllegalDataValue,
            ),
            // DB 802 does not exist.
            (
                Request::ReadHoldingRegisters {
                    address: 1024,
                    quantity: 1,
                },
                ExceptionCode::IllegalDataAddress,
            ),
            // Timers are read-only.
            (
                Request::WriteSingleCoil {
                    address: 2048,
                    value: true,
                },
                ExceptionCode::IllegalDataAddress,
            ),
            (Request::ReportServerId, ExceptionCode::IllegalFunction),
        ];
        for (request, code) in cases {
            assert_eq!(unit.answer(&request), Err(code), "{request:?}");
        }
        let echo = Request::Diagnostics {
            sub_function: diag::RETURN_QUERY_DATA,
            data: vec![0xA5, 0x37],
        };
        assert_eq!(
            unit.answer(&echo),
            Ok(Response::Diagnostics {
                sub_function: 0,
                data: vec![0xA5, 0x37]
            })
        );
    }

    #[test]
    fn writes_land_in_the_shared_memory() {
        let memory = SharedCpMemory::new(MemoryLayout::default());
        let map = AddressMap::manual_example()
            .with_limits(WriteLimits {
                outputs: Some((100, 101)),
                ..WriteLimits::NONE
            })
            .expect("valid");
        let unit = CpMemoryUnit::new(memory.clone(), map);
        let request = Request::WriteMultipleCoils {
            address: 1024 + 3,
            values: vec![true, true],
        };
        assert!(unit.answer(&request).is_ok());
        assert_eq!(memory.read(|m| m.q()[100]), 0b0001_1000);
    }
}
