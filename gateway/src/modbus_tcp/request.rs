//! One request, from PDU bytes to response PDU bytes: decode, policy, unit lookup, the unit's
//! answer under a timeout, encode.
//!
//! Order of the checks, each answered with the exception shown (the first that applies wins):
//!
//! 1. the PDU does not decode: `ExceptionCode::from(&PduError)` (01 unknown function, 03 bad
//!    quantity or byte count, 02 address overflow), quantity checked before address as libmodbus
//!    does;
//! 2. the unit id is not in the unit map: 0x0A (gateway path unavailable);
//! 3. read-only mode and the request changes state: 01 (illegal function);
//! 4. a table write outside the write-enabled ranges: 02 (illegal data address);
//! 5. the unit service does not answer within `request_timeout`: 0x0B (gateway target device
//!    failed to respond); otherwise the service's response or exception;
//! 6. a response that does not fit an ADU or answers another function: 04 (server device failure).

use std::sync::{Arc, PoisonError};

use proto_core::modbus::pdu::{ExceptionCode, ExceptionResponse, FunctionCode, Request, Response};
use tracing::{debug, error};

use super::mbap::MAX_PDU_LEN;
use super::options::ServerOptions;
use super::server::SharedUnits;
use super::stats::{FrameReject, RequestResult, ServerStats};
use crate::unit::{UnitResult, UnitService};

/// What every connection of one server shares.
pub(crate) struct Shared {
    /// The units; replaced at run time by whoever holds the other `Arc`.
    pub(crate) units: SharedUnits,
    /// Limits and policy.
    pub(crate) options: ServerOptions,
    /// Counters.
    pub(crate) stats: Arc<ServerStats>,
}

/// Answers the request `pdu` to `unit`, writing the response PDU (normal or exception) to `out`.
/// `Err` when there is nothing to answer (no function code): the connection closes.
pub(crate) async fn answer(
    shared: &Shared,
    unit: u8,
    pdu: &[u8],
    out: &mut Vec<u8>,
) -> Result<(), FrameReject> {
    let Some(&function) = pdu.first() else {
        return Err(FrameReject::EmptyPdu);
    };
    let result = match admit(shared, unit, pdu) {
        Ok((service, request)) => call(service.as_ref(), request, shared).await,
        Err(code) => Err(code),
    };
    out.clear();
    let result = match result {
        Ok(response) => {
            encode_response(&response, out);
            if out.len() <= MAX_PDU_LEN && out.first() == Some(&function) {
                Ok(())
            } else {
                error!(
                    unit,
                    function,
                    len = out.len(),
                    "unit service gave a response that does not fit the request"
                );
                Err(ExceptionCode::ServerDeviceFailure)
            }
        }
        Err(code) => Err(code),
    };
    if let Err(code) = result {
        debug!(unit, function, ?code, "exception response");
        out.clear();
        encode_exception(function, code, out);
    }
    let counted = result.map_or_else(RequestResult::Exception, |()| RequestResult::Ok);
    shared.stats.count_request(function, counted);
    Ok(())
}

/// Steps 1 to 4: the decoded request and the service to call, or the exception.
fn admit(
    shared: &Shared,
    unit: u8,
    pdu: &[u8],
) -> Result<(Arc<dyn UnitService>, Request), ExceptionCode> {
    let request = decode_request(pdu).map_err(|error| {
        debug!(unit, %error, "request does not decode");
        ExceptionCode::from(&error)
    })?;
    let service = {
        // A panic elsewhere while holding the lock leaves a map that is still whole: keep serving.
        let units = shared.units.read().unwrap_or_else(PoisonError::into_inner);
        units.get(unit).cloned()
    };
    let service = service.ok_or(ExceptionCode::GatewayPathUnavailable)?;
    if let Some(code) = shared.options.check_write(unit, &request) {
        return Err(code);
    }
    Ok((service, request))
}

/// Step 5: the service's answer, or 0x0B after `request_timeout`.
async fn call(service: &dyn UnitService, request: Request, shared: &Shared) -> UnitResult {
    let timeout = shared.options.request_timeout;
    tokio::time::timeout(timeout, service.call(request))
        .await
        .unwrap_or(Err(ExceptionCode::GatewayTargetFailedToRespond))
}

fn decode_request(pdu: &[u8]) -> Result<Request, proto_core::modbus::pdu::PduError> {
    Request::decode(pdu)
}

fn encode_response(response: &Response, out: &mut Vec<u8>) {
    response.encode(out);
}

fn encode_exception(function: u8, code: ExceptionCode, out: &mut Vec<u8>) {
    ExceptionResponse {
        function: FunctionCode(function),
        code,
    }
    .encode(out);
}
