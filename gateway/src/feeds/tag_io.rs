//! Reading and writing tags through the units, shared by REST and zenoh.
//!
//! A write takes the same path and the same checks as a Modbus TCP write: the tag is encoded by
//! its profile, the server's read-only mode and write ranges are applied, and the request goes to
//! the device's unit service, which answers with the device's answer. A read of a tag that is not
//! in the image (nobody polls it) asks the unit, which reads it from the device on demand.

use std::sync::{Arc, PoisonError};
use std::time::SystemTime;

use proto_core::modbus::pdu::{ExceptionCode, Request, Response};
use proto_core::modbus::Table;
use proto_core::profiles::Value;

use crate::tags::{TagDirectory, TagEntry, TagReading, TagWriteError, TagWriteOp};
use crate::unit::write_policy::WritePolicy;
use crate::unit::{SharedUnits, UnitFuture, UnitService};

/// Why a tag write was not sent to the device.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub(crate) enum WriteRefused {
    /// The directory or the profile refused (unknown tag, read-only tag, value out of range).
    #[error(transparent)]
    Tag(#[from] TagWriteError),
    /// `[modbus_tcp] read_only`: every write is refused (Modbus TCP answers exception 01).
    #[error(
        "the gateway is read-only ([modbus_tcp] read_only): Modbus TCP would answer exception 01"
    )]
    ReadOnlyGateway,
    /// Outside `[modbus_tcp] write_ranges`.
    #[error("tag {tag} is outside [modbus_tcp] write_ranges: Modbus TCP would answer exception {code:?}")]
    OutsideRanges { tag: String, code: ExceptionCode },
    /// No unit answers the tag's unit id.
    #[error("unit {0} is not served")]
    NotServed(u8),
    /// The device is on a listen-only tap line: the gateway does not drive its bus.
    #[error(
        "{line}/{device} is on a listen-only tap line: the gateway only listens to another \
         master's traffic and never writes to the device (Modbus TCP answers exception 01)"
    )]
    ListenOnly { line: String, device: String },
}

/// A checked write, ready to send.
pub(crate) struct PreparedWrite {
    pub(crate) service: Arc<dyn UnitService>,
    pub(crate) op: TagWriteOp,
    pub(crate) entry: TagEntry,
}

// === impl PreparedWrite ===

impl PreparedWrite {
    /// Sends the write to the device's unit: one request, or for a bit tag one
    /// read-modify-write job of the line.
    pub(crate) fn send(self) -> UnitFuture {
        match self.op {
            TagWriteOp::Request(request) => self.service.call(request),
            TagWriteOp::Bit(update) => self.service.mask_write(update),
        }
    }
}

/// The unit service of `unit`.
pub(crate) fn service(units: &SharedUnits, unit: u8) -> Option<Arc<dyn UnitService>> {
    units
        .read()
        .unwrap_or_else(PoisonError::into_inner)
        .get(unit)
        .cloned()
}

/// The checked request of a write of `value` (engineering units) to `line/device/tag` of the
/// directory `tags`, under the Modbus TCP server's write `policy`.
pub(crate) fn prepare_write(
    tags: &TagDirectory,
    policy: &WritePolicy,
    units: &SharedUnits,
    line: &str,
    device: &str,
    tag: &str,
    value: &Value,
) -> Result<PreparedWrite, WriteRefused> {
    let entry = tags
        .find(line, device, tag)
        .ok_or_else(|| TagWriteError::UnknownTag(format!("{line}/{device}/{tag}")))?;
    let op = TagDirectory::write_op(entry, value)?;
    if policy.read_only {
        return Err(WriteRefused::ReadOnlyGateway);
    }
    if let Some(code) = policy.check_write(entry.unit_id(), &op.policy_request()) {
        return Err(WriteRefused::OutsideRanges {
            tag: format!("{line}/{device}/{}", entry.name()),
            code,
        });
    }
    let service =
        service(units, entry.unit_id()).ok_or(WriteRefused::NotServed(entry.unit_id()))?;
    if service.listen_only() {
        return Err(WriteRefused::ListenOnly {
            line: entry.line().to_owned(),
            device: entry.device().to_owned(),
        });
    }
    Ok(PreparedWrite {
        service,
        op,
        entry: entry.clone(),
    })
}

/// The request that reads the tag's registers or bits.
pub(crate) fn read_request(entry: &TagEntry) -> Request {
    let address = entry.address();
    let quantity = entry.words();
    match entry.table() {
        Table::Coils => Request::ReadCoils { address, quantity },
        Table::DiscreteInputs => Request::ReadDiscreteInputs { address, quantity },
        Table::InputRegisters => Request::ReadInputRegisters { address, quantity },
        Table::HoldingRegisters => Request::ReadHoldingRegisters { address, quantity },
    }
}

/// The tag's value from the device's answer to [`read_request`]; `None` for an answer of
/// another shape.
pub(crate) fn reading_from(entry: &TagEntry, response: &Response) -> Option<TagReading> {
    let words: Vec<u16> = match response {
        Response::ReadCoils(bits) | Response::ReadDiscreteInputs(bits) => {
            bits.iter().map(|&b| u16::from(b)).collect()
        }
        Response::ReadHoldingRegisters(w) | Response::ReadInputRegisters(w) => w.clone(),
        _ => return None,
    };
    let want = usize::from(entry.words());
    let words = words.get(..want)?;
    let (value, quality) = entry.decode(words);
    Some(TagReading {
        value,
        unit: entry.unit().to_owned(),
        quality: quality.as_str(),
        timestamp: SystemTime::now(),
    })
}
