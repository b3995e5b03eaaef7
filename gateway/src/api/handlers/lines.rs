//! `/api/v1/lines/...`: line status, the diagnostic buffer, telegrams, RS232 signals.

use axum::extract::State;
use axum::http::StatusCode;
use axum::{Extension, Json};

use super::{audit, caller_of, ApiJson, ApiPath};
use crate::api::auth::Caller;
use crate::api::error::{ApiError, ErrorBody};
use crate::api::model::{
    DiagView, LineStatusView, SendRequest, SendResult, Signals, SignalsPatch, TelegramQueue,
};
use crate::api::ApiState;
use crate::audit::WriteResult;

/// Every line's status.
#[utoipa::path(
    get,
    path = "/lines",
    tag = "lines",
    responses((status = 200, description = "Every line", body = Vec<LineStatusView>))
)]
pub(crate) async fn list_lines(State(state): State<ApiState>) -> Json<Vec<LineStatusView>> {
    Json(state.backend().gateway_status().lines)
}

/// One line's status: state, protocol, counters, last STATUS word, devices online.
#[utoipa::path(
    get,
    path = "/lines/{line}",
    tag = "lines",
    params(("line" = String, Path, description = "The line's name")),
    responses(
        (status = 200, description = "The line", body = LineStatusView),
        (status = 404, description = "No such line", body = ErrorBody),
    )
)]
pub(crate) async fn get_line(
    State(state): State<ApiState>,
    ApiPath(line): ApiPath<String>,
) -> Result<Json<LineStatusView>, ApiError> {
    state.backend().line_status(&line).map(Json)
}

/// A line's diagnostic buffer, newest first, with the catalog's texts (003 7.3).
#[utoipa::path(
    get,
    path = "/lines/{line}/diag",
    tag = "lines",
    params(("line" = String, Path, description = "The line's name")),
    responses(
        (status = 200, description = "The buffer, newest first", body = DiagView),
        (status = 404, description = "No such line", body = ErrorBody),
    )
)]
pub(crate) async fn get_diag(
    State(state): State<ApiState>,
    ApiPath(line): ApiPath<String>,
) -> Result<Json<DiagView>, ApiError> {
    let snapshot = state.backend().diag(&line)?;
    Ok(Json(DiagView::new(&line, &snapshot)))
}

/// Empties a line's diagnostic buffer.
#[utoipa::path(
    delete,
    path = "/lines/{line}/diag",
    tag = "lines",
    params(("line" = String, Path, description = "The line's name")),
    responses(
        (status = 204, description = "Emptied"),
        (status = 404, description = "No such line", body = ErrorBody),
    )
)]
pub(crate) async fn clear_diag(
    State(state): State<ApiState>,
    caller: Option<Extension<Caller>>,
    ApiPath(line): ApiPath<String>,
) -> Result<StatusCode, ApiError> {
    let result = state.backend().clear_diag(&line);
    audit(
        &state,
        &caller_of(caller),
        &format_args!("{line}/diag clear"),
        &result,
    );
    result.map(|()| StatusCode::NO_CONTENT)
}

/// Received telegrams waiting for acknowledgement, oldest first (ASCII and 3964(R) lines).
#[utoipa::path(
    get,
    path = "/lines/{line}/telegrams",
    tag = "telegrams",
    params(("line" = String, Path, description = "The line's name")),
    responses(
        (status = 200, description = "The queue, oldest first", body = TelegramQueue),
        (status = 404, description = "No such line", body = ErrorBody),
        (status = 409, description = "The line does not carry telegrams", body = ErrorBody),
    )
)]
pub(crate) async fn get_telegrams(
    State(state): State<ApiState>,
    ApiPath(line): ApiPath<String>,
) -> Result<Json<TelegramQueue>, ApiError> {
    state.backend().telegrams(&line).map(Json)
}

/// Acknowledges the oldest queued telegram, which must have sequence number `seq`.
#[utoipa::path(
    post,
    path = "/lines/{line}/telegrams/{seq}/ack",
    tag = "telegrams",
    params(
        ("line" = String, Path, description = "The line's name"),
        ("seq" = u32, Path, description = "The telegram's sequence number"),
    ),
    responses(
        (status = 204, description = "Acknowledged and removed from the queue"),
        (status = 404, description = "No such line or no queued telegram with this number", body = ErrorBody),
        (status = 409, description = "Not the oldest telegram, or a line without telegrams", body = ErrorBody),
    )
)]
pub(crate) async fn ack_telegram(
    State(state): State<ApiState>,
    caller: Option<Extension<Caller>>,
    ApiPath((line, seq)): ApiPath<(String, u32)>,
) -> Result<StatusCode, ApiError> {
    let result = state.backend().ack_telegram(&line, seq);
    audit(
        &state,
        &caller_of(caller),
        &format_args!("{line}/telegrams/{seq} ack"),
        &result,
    );
    result.map(|()| StatusCode::NO_CONTENT)
}

/// Sends a telegram and waits for the outcome (DONE / ERROR / STATUS as FB 8 P_SND_RK).
#[utoipa::path(
    post,
    path = "/lines/{line}/send",
    tag = "telegrams",
    params(("line" = String, Path, description = "The line's name")),
    request_body = SendRequest,
    responses(
        (status = 200, description = "Sent (`done`), or ended with the event in `status_word`", body = SendResult),
        (status = 404, description = "No such line", body = ErrorBody),
        (status = 409, description = "The line does not send telegrams, or its write policy does not allow sends (sends = false)", body = ErrorBody),
        (status = 422, description = "Neither or both of hex and text, bad hex, or too long", body = ErrorBody),
        (status = 503, description = "The line's send queue is full", body = ErrorBody),
        (status = 504, description = "The partner did not answer", body = ErrorBody),
    )
)]
pub(crate) async fn send_telegram(
    State(state): State<ApiState>,
    caller: Option<Extension<Caller>>,
    ApiPath(line): ApiPath<String>,
    ApiJson(request): ApiJson<SendRequest>,
) -> Result<Json<SendResult>, ApiError> {
    let caller = caller_of(caller);
    let data = request.bytes();
    let target = format!("{line}/tx ({} bytes)", data.as_ref().map_or(0, Vec::len));
    let result = match data {
        Ok(data) => state.backend().send_telegram(&line, data).await,
        Err(e) => Err(e),
    };
    match &result {
        // Sent, but the partner or the line ended it with an event.
        Ok(sent) if !sent.done => state.backend().audit(
            &caller,
            &target,
            WriteResult::Failed,
            &format_args!("status word {:04X}h", sent.status_word),
        ),
        _ => audit(&state, &caller, &target, &result),
    }
    result.map(Json)
}

/// The RS232 signals of a line (000 5.4).
#[utoipa::path(
    get,
    path = "/lines/{line}/signals",
    tag = "lines",
    params(("line" = String, Path, description = "The line's name")),
    responses(
        (status = 200, description = "The signals", body = Signals),
        (status = 404, description = "No such line", body = ErrorBody),
        (status = 409, description = "The line has no RS232 signals", body = ErrorBody),
    )
)]
pub(crate) async fn get_signals(
    State(state): State<ApiState>,
    ApiPath(line): ApiPath<String>,
) -> Result<Json<Signals>, ApiError> {
    state.backend().signals(&line).await.map(Json)
}

/// Sets DTR and/or RTS; answers with the signals after the change.
#[utoipa::path(
    put,
    path = "/lines/{line}/signals",
    tag = "lines",
    params(("line" = String, Path, description = "The line's name")),
    request_body = SignalsPatch,
    responses(
        (status = 200, description = "The signals after the change", body = Signals),
        (status = 404, description = "No such line", body = ErrorBody),
        (status = 409, description = "The line has no RS232 signals, or its protocol drives them", body = ErrorBody),
        (status = 422, description = "An input signal or an unknown key", body = ErrorBody),
    )
)]
pub(crate) async fn set_signals(
    State(state): State<ApiState>,
    caller: Option<Extension<Caller>>,
    ApiPath(line): ApiPath<String>,
    ApiJson(patch): ApiJson<SignalsPatch>,
) -> Result<Json<Signals>, ApiError> {
    let result = state.backend().set_signals(&line, patch).await;
    let target = format!(
        "{line}/signals DTR={} RTS={}",
        on_off(patch.dtr),
        on_off(patch.rts)
    );
    audit(&state, &caller_of(caller), &target, &result);
    result.map(Json)
}

/// A signal's requested state for the audit.
fn on_off(v: Option<bool>) -> &'static str {
    match v {
        Some(true) => "on",
        Some(false) => "off",
        None => "unchanged",
    }
}
