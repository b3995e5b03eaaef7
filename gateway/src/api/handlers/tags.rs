//! `/api/v1/tags` and `/api/v1/lines/{line}/devices/{device}/tags/...`: device values by name.

use axum::extract::State;
use axum::{Extension, Json};

use super::{audit, caller_of, ApiJson, ApiPath, ApiQuery};
use crate::api::auth::Caller;
use crate::api::error::{ApiError, ErrorBody};
use crate::api::model::{TagQuery, TagValue, TagWrite};
use crate::api::ApiState;

/// Every tag, or those of one line and/or device name.
#[utoipa::path(
    get,
    path = "/tags",
    tag = "tags",
    params(TagQuery),
    responses(
        (status = 200, description = "The tags' values", body = Vec<TagValue>),
        (status = 400, description = "An unknown query parameter", body = ErrorBody),
        (status = 404, description = "No such line", body = ErrorBody),
    )
)]
pub(crate) async fn list_tags(
    State(state): State<ApiState>,
    ApiQuery(q): ApiQuery<TagQuery>,
) -> Result<Json<Vec<TagValue>>, ApiError> {
    state
        .backend()
        .tags(q.line.as_deref(), q.device.as_deref())
        .map(Json)
}

/// The tags of one device.
#[utoipa::path(
    get,
    path = "/lines/{line}/devices/{device}/tags",
    tag = "tags",
    params(
        ("line" = String, Path, description = "The line's name"),
        ("device" = String, Path, description = "The device's name"),
    ),
    responses(
        (status = 200, description = "The device's tags", body = Vec<TagValue>),
        (status = 404, description = "No such line or device", body = ErrorBody),
    )
)]
pub(crate) async fn device_tags(
    State(state): State<ApiState>,
    ApiPath((line, device)): ApiPath<(String, String)>,
) -> Result<Json<Vec<TagValue>>, ApiError> {
    let backend = state.backend();
    let known = backend
        .config()
        .lines
        .get(&line)
        .map(|l| l.devices().any(|(name, _)| *name == device));
    if known.is_none() {
        return Err(ApiError::not_found("line", &line));
    }
    let tags = backend.tags(Some(&line), Some(&device))?;
    // A device of the line's table, or a tag group the gateway adds itself (the CP memory of a
    // slave line, device `memory`).
    if known == Some(false) && tags.is_empty() {
        return Err(ApiError::not_found("device", &format!("{line}/{device}")));
    }
    Ok(Json(tags))
}

/// One tag's value.
#[utoipa::path(
    get,
    path = "/lines/{line}/devices/{device}/tags/{tag}",
    tag = "tags",
    params(
        ("line" = String, Path, description = "The line's name"),
        ("device" = String, Path, description = "The device's name"),
        ("tag" = String, Path, description = "The tag's name"),
    ),
    responses(
        (status = 200, description = "The value", body = TagValue),
        (status = 404, description = "No such line, device or tag", body = ErrorBody),
        (status = 504, description = "Read on demand, and the device did not answer", body = ErrorBody),
    )
)]
pub(crate) async fn get_tag(
    State(state): State<ApiState>,
    ApiPath((line, device, tag)): ApiPath<(String, String, String)>,
) -> Result<Json<TagValue>, ApiError> {
    state.backend().tag(&line, &device, &tag).await.map(Json)
}

/// Writes one tag through to the device; answers with the value after the write.
#[utoipa::path(
    put,
    path = "/lines/{line}/devices/{device}/tags/{tag}",
    tag = "tags",
    params(
        ("line" = String, Path, description = "The line's name"),
        ("device" = String, Path, description = "The device's name"),
        ("tag" = String, Path, description = "The tag's name"),
    ),
    request_body = TagWrite,
    responses(
        (status = 200, description = "Written; the value after the write", body = TagValue),
        (status = 404, description = "No such line, device or tag", body = ErrorBody),
        (status = 409, description = "The tag is not writable", body = ErrorBody),
        (status = 422, description = "The value does not fit the tag", body = ErrorBody),
        (status = 502, description = "The device answered with an exception", body = ErrorBody),
        (status = 503, description = "The line's command queue is full", body = ErrorBody),
        (status = 504, description = "The device did not answer", body = ErrorBody),
    )
)]
pub(crate) async fn put_tag(
    State(state): State<ApiState>,
    caller: Option<Extension<Caller>>,
    ApiPath((line, device, tag)): ApiPath<(String, String, String)>,
    ApiJson(write): ApiJson<TagWrite>,
) -> Result<Json<TagValue>, ApiError> {
    let result = state
        .backend()
        .write_tag(&line, &device, &tag, write.value.clone())
        .await;
    let target = format!(
        "{line}/{device}/{tag} = {}",
        proto_core::profiles::Value::from(write.value)
    );
    audit(&state, &caller_of(caller), &target, &result);
    result.map(Json)
}
