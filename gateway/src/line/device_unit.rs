//! A polled device as a Modbus TCP unit (SPEC "Republishing").
//!
//! - reads of polled ranges come from the process image while the values are fresh and the device
//!   answers; a stale value or an offline device gives exception 0x0B;
//! - reads of addresses nobody polls (and ranges not read yet) go to the device on demand;
//! - writes (FC 05, 06, 15, 16, 23) and every other function go through to the device and answer
//!   with the device's answer, its exception passed through; the line updates the image of the
//!   written registers after the device confirmed the write;
//! - a full command queue gives 0x06, no answer within the deadline 0x0B.

use std::sync::Arc;

use proto_core::modbus::pdu::{ExceptionCode, Request, Response};

use super::command::LineClient;
use super::status::Shared;
use super::{AddrRange, DeviceSettings};
use crate::image::{ImageError, ProcessImage, Table};
use crate::unit::{UnitFuture, UnitService};

/// One polled device served under its unit id; cheap to clone.
#[derive(Clone, Debug)]
pub struct DeviceUnit {
    device: Arc<DeviceSettings>,
    /// Index of the device in its line's status.
    index: usize,
    shared: Arc<Shared>,
    client: LineClient,
    image: ProcessImage,
}

/// How a read is answered.
#[derive(Debug, PartialEq)]
enum ImageAnswer {
    /// From the image.
    Answer(Response),
    /// Not from the image: ask the device.
    OnDemand,
    /// The device is offline or the value stale.
    Fail(ExceptionCode),
}

// === impl DeviceUnit ===

impl DeviceUnit {
    pub(crate) fn new(
        device: Arc<DeviceSettings>,
        index: usize,
        shared: Arc<Shared>,
        client: LineClient,
        image: ProcessImage,
    ) -> Self {
        Self {
            device,
            index,
            shared,
            client,
            image,
        }
    }

    /// The device's settings.
    pub fn device(&self) -> &DeviceSettings {
        &self.device
    }

    /// The unit id it is served under.
    pub fn unit_id(&self) -> u8 {
        self.device.unit_id
    }

    fn answer_from_image(&self, request: &Request) -> ImageAnswer {
        let (table, address, quantity) = match *request {
            Request::ReadCoils { address, quantity } => (Table::Coils, address, quantity),
            Request::ReadDiscreteInputs { address, quantity } => {
                (Table::DiscreteInputs, address, quantity)
            }
            Request::ReadHoldingRegisters { address, quantity } => {
                (Table::HoldingRegisters, address, quantity)
            }
            Request::ReadInputRegisters { address, quantity } => {
                (Table::InputRegisters, address, quantity)
            }
            _ => return ImageAnswer::OnDemand,
        };
        if quantity == 0
            || !self
                .device
                .is_polled(table, AddrRange::new(address, quantity))
        {
            return ImageAnswer::OnDemand;
        }
        let unit = self.device.unit_id;
        let online = self.shared.device_online(self.index);
        let read = if table.is_bits() {
            self.image
                .read_bits(unit, table, address, quantity)
                .map(|r| {
                    let quality = r.quality;
                    let response = match table {
                        Table::Coils => Response::ReadCoils(r.values),
                        _ => Response::ReadDiscreteInputs(r.values),
                    };
                    (response, quality)
                })
        } else {
            self.image
                .read_words(unit, table, address, quantity)
                .map(|r| {
                    let quality = r.quality;
                    let response = match table {
                        Table::HoldingRegisters => Response::ReadHoldingRegisters(r.values),
                        _ => Response::ReadInputRegisters(r.values),
                    };
                    (response, quality)
                })
        };
        match read {
            Ok((response, quality)) if online && quality.is_live() => ImageAnswer::Answer(response),
            // The poll of this range was answered with an exception: let the device answer.
            Ok((_, crate::image::Quality::Rejected)) if online => ImageAnswer::OnDemand,
            Ok(_) => ImageAnswer::Fail(ExceptionCode::GatewayTargetFailedToRespond),
            // Polled but not read yet: ask the device unless it is known to be offline.
            Err(ImageError::Missing { .. } | ImageError::UnknownUnit(_)) if online => {
                ImageAnswer::OnDemand
            }
            Err(_) => ImageAnswer::Fail(ExceptionCode::GatewayTargetFailedToRespond),
        }
    }
}

impl UnitService for DeviceUnit {
    fn call(&self, request: Request) -> UnitFuture {
        match self.answer_from_image(&request) {
            ImageAnswer::Answer(response) => Box::pin(std::future::ready(Ok(response))),
            ImageAnswer::Fail(code) => Box::pin(std::future::ready(Err(code))),
            ImageAnswer::OnDemand => {
                let client = self.client.clone();
                let slave = self.device.slave;
                Box::pin(async move { client.request(slave, request).await })
            }
        }
    }
}
