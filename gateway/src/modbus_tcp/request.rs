//! One request, from PDU bytes to response PDU bytes: decode, policy, unit lookup, the unit's
//! answer under a timeout, encode.
//!
//! Order of the checks, each answered with the exception shown (the first that applies wins):
//!
//! 1. the PDU does not decode: `ExceptionCode::from(&PduError)` (01 unknown function, 03 bad
//!    quantity or byte count, 02 address overflow), quantity checked before address as libmodbus
//!    does;
//! 2. on a Modbus/TCP Security connection, the request is not authorized for the client
//!    certificate's role: 01 (illegal function; see [`super::access`]), counted by role and logged
//!    at a limited rate;
//! 3. the unit id is not in the unit map: 0x0A (gateway path unavailable);
//! 4. read-only mode and the request changes state: 01 (illegal function);
//! 5. a table write outside the write-enabled ranges: 02 (illegal data address);
//! 6. the unit service does not answer within `request_timeout`: 0x0B (gateway target device
//!    failed to respond); otherwise the service's response or exception. A unit that can answer
//!    at once ([`UnitService::answer_now`], a read from the process image) writes its response
//!    straight into the connection's buffer, and a future ready at its first poll arms no timer;
//!    the answers are the same;
//! 7. a response that does not fit an ADU or answers another function: 04 (server device failure).

use std::future::poll_fn;
use std::net::SocketAddr;
use std::sync::{Arc, PoisonError};
use std::task::Poll;
use std::time::Duration;

use proto_core::modbus::pdu::{ExceptionCode, ExceptionResponse, FunctionCode, Request, Response};
use tracing::{debug, warn};

use super::access::Authority;
use super::mbap::MAX_PDU_LEN;
use super::metrics::{FrameReject, RequestResult};
use super::options::ServerOptions;
use super::shared::Shared;
use crate::audit::{WritePath, WriteResult};
use crate::log_limit::{LogLimit, Verdict};
use crate::unit::{UnitResult, UnitService};

/// Log lines about requests refused by role: a client repeating a refused request cannot flood
/// the log.
static REFUSAL_LOG: LogLimit = LogLimit::new(Duration::from_secs(10), 10);

/// Answers the request `pdu` to `unit`, appending the response PDU (normal or exception) to `out`
/// after what it holds already (the connection keeps room for the MBAP header there).
/// `Err` when there is nothing to answer (no function code): the connection closes.
pub(crate) async fn answer(
    shared: &Shared,
    options: &ServerOptions,
    authority: &Authority,
    peer: SocketAddr,
    unit: u8,
    pdu: &[u8],
    out: &mut Vec<u8>,
) -> Result<(), FrameReject> {
    let Some(&function) = pdu.first() else {
        return Err(FrameReject::EmptyPdu);
    };
    let mark = out.len();
    let mut refused = false;
    let result = match admit(shared, options, authority, peer, unit, pdu, out) {
        Admitted::Answered(result) => result,
        Admitted::Refused(code) => {
            refused = true;
            Err(code)
        }
        Admitted::Call(service, request) => match call(service.as_ref(), request, options).await {
            Ok(response) => {
                encode_response(&response, out);
                Ok(())
            }
            Err(code) => Err(code),
        },
    };
    let result = result.and_then(|()| {
        let response = out.get(mark..).unwrap_or_default();
        if response.len() <= MAX_PDU_LEN && response.first() == Some(&function) {
            Ok(())
        } else {
            // A forwarded slave's answer passes through here: rate-limited, one line per unit.
            crate::error_limited!(
                format!("unit {unit} response does not fit"),
                unit,
                function,
                len = response.len(),
                "unit service gave a response that does not fit the request"
            );
            Err(ExceptionCode::ServerDeviceFailure)
        }
    });
    if let Err(code) = result {
        debug!(unit, function, ?code, "exception response");
        out.truncate(mark);
        encode_exception(function, code, out);
    }
    let counted = result.map_or_else(RequestResult::Exception, |()| RequestResult::Ok);
    shared.stats.count_request(function, counted);
    if changes_state(pdu) {
        audit_write(shared, authority, peer, unit, pdu, result, refused);
    }
    Ok(())
}

/// Whether the request PDU changes state: FC 05, 06, 15, 16, 23, and the FC 08 sub-functions
/// that change the device (Modbus Application Protocol V1.1b3, 6.8.1: all but 00 return query
/// data, 02 return diagnostic register and 0B..12 return counters).
fn changes_state(pdu: &[u8]) -> bool {
    match pdu {
        [0x05 | 0x06 | 0x0F | 0x10 | 0x17, ..] => true,
        [0x08, hi, lo, ..] => !matches!(u16::from_be_bytes([*hi, *lo]), 0x00 | 0x02 | 0x0B..=0x12),
        _ => false,
    }
}

/// The audit record of a write: who (client IP address, without the port: the audit log's limit
/// counts per source, and a client that reconnects is the same source; and role), what (unit,
/// function, first address), how it ended.
fn audit_write(
    shared: &Shared,
    authority: &Authority,
    peer: SocketAddr,
    unit: u8,
    pdu: &[u8],
    result: Result<(), ExceptionCode>,
    refused: bool,
) {
    let path = match authority {
        Authority::Open => WritePath::ModbusTcp,
        Authority::Role { .. } => WritePath::ModbusTls,
    };
    let outcome = match result {
        Ok(()) => WriteResult::Accepted,
        Err(_) if refused => WriteResult::Refused,
        Err(_) => WriteResult::Failed,
    };
    let function = pdu.first().copied().unwrap_or(0);
    let address = match pdu {
        [_, hi, lo, ..] => u16::from_be_bytes([*hi, *lo]),
        _ => 0,
    };
    let detail = match result {
        Ok(()) => String::from("ok"),
        Err(code) => format!("exception {:02X}", u8::from(code)),
    };
    crate::audit::record(
        shared.stats.audit(),
        path,
        &format_args!("{} role={}", peer.ip(), authority.label()),
        &format_args!("unit {unit} function {function:02X} address {address}"),
        outcome,
        &detail,
    );
}

/// How steps 1 to 5 ended.
enum Admitted {
    /// An exception of steps 1 to 5, or the unit's answer given at once (appended to `out`).
    Answered(Result<(), ExceptionCode>),
    /// Refused by the role (step 2) or the write policy (steps 4, 5).
    Refused(ExceptionCode),
    /// The unit answers in its own time: step 6.
    Call(Arc<dyn UnitService>, Request),
}

/// Steps 1 to 5, then the unit's answer when it can give it at once ([`UnitService::answer_now`],
/// under the read lock of the unit map: no clone of the service, no future, no timer).
fn admit(
    shared: &Shared,
    options: &ServerOptions,
    authority: &Authority,
    peer: SocketAddr,
    unit: u8,
    pdu: &[u8],
    out: &mut Vec<u8>,
) -> Admitted {
    let request = match decode_request(pdu) {
        Ok(request) => request,
        Err(error) => {
            debug!(unit, %error, "request does not decode");
            return Admitted::Answered(Err(ExceptionCode::from(&error)));
        }
    };
    // MODBUS/TCP Security, "Authorization": a request the role is not authorized for is answered
    // with exception code 01 (Illegal Function).
    if let Err(refusal) = authority.check(unit, &request) {
        let role = authority.label();
        shared.stats.count_refused(role);
        if let Verdict::Log { suppressed } = REFUSAL_LOG.check() {
            warn!(%peer, role, unit, function = pdu.first().copied().unwrap_or(0), ?refusal,
                suppressed, "request refused by role");
        }
        return Admitted::Refused(ExceptionCode::IllegalFunction);
    }
    // A panic elsewhere while holding the lock leaves a map that is still whole: keep serving.
    let units = shared.units.read().unwrap_or_else(PoisonError::into_inner);
    let Some(service) = units.get(unit) else {
        return Admitted::Answered(Err(ExceptionCode::GatewayPathUnavailable));
    };
    if let Some(code) = options
        .writes
        .check_write(unit, &request)
        .or_else(|| service.refuses(&request))
    {
        return Admitted::Refused(code);
    }
    match service.answer_now(&request, out) {
        Some(result) => Admitted::Answered(result),
        None => Admitted::Call(Arc::clone(service), request),
    }
}

/// Step 6: the service's answer, or 0x0B after `request_timeout`. A future that is ready at its
/// first poll is taken without arming the timer.
async fn call(service: &dyn UnitService, request: Request, options: &ServerOptions) -> UnitResult {
    let mut future = service.call(request);
    if let Poll::Ready(result) = poll_fn(|cx| Poll::Ready(future.as_mut().poll(cx))).await {
        return result;
    }
    tokio::time::timeout(options.request_timeout, future)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_and_device_control_change_state() {
        for pdu in [
            &[0x05, 0, 1, 0xFF, 0][..],
            &[0x06, 0, 1, 0, 1],
            &[0x0F, 0, 1],
            &[0x10, 0, 1],
            &[0x17, 0, 1],
            &[0x08, 0, 0x01, 0, 0],
            &[0x08, 0, 0x04, 0, 0],
        ] {
            assert!(changes_state(pdu), "{pdu:02X?}");
        }
        for pdu in [
            &[0x03, 0, 1, 0, 1][..],
            &[0x08, 0, 0x00, 0x12, 0x34],
            &[0x08, 0, 0x0B, 0, 0],
            &[0x08, 0],
            &[],
        ] {
            assert!(!changes_state(pdu), "{pdu:02X?}");
        }
    }
}
