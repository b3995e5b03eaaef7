//! The route handlers, one module per resource, and the extractors that turn axum's rejections
//! into [`ApiError`]s.

pub(crate) mod config;
pub(crate) mod fleet;
pub(crate) mod health;
pub(crate) mod lines;
pub(crate) mod monitor;
pub(crate) mod tags;

use std::fmt::Display;

use axum::body::Bytes;
use axum::extract::{FromRequest, FromRequestParts, Path, Query, Request};
use axum::http::request::Parts;
use axum::Extension;
use serde::de::DeserializeOwned;

use super::auth::{Caller, Who};
use super::body::{self, JsonBody};
use super::error::ApiError;
use super::ApiState;
use crate::audit::WriteResult;

/// The caller the auth middleware put into the request; a request that did not pass it (none
/// does in the served router) is shown without address as unauthenticated.
pub(crate) fn caller_of(ext: Option<Extension<Caller>>) -> Caller {
    ext.map_or(
        Caller {
            addr: None,
            who: Who::Unauthenticated,
        },
        |Extension(c)| c,
    )
}

/// The audit result of an answer: accepted; refused for a 4xx (the request, the policy or a
/// precondition refused it, nothing was changed); failed for a 5xx (the device, the line or
/// the store did not take it).
pub(crate) fn outcome<T>(result: &Result<T, ApiError>) -> (WriteResult, String) {
    match result {
        Ok(_) => (WriteResult::Accepted, "ok".to_owned()),
        Err(e) if e.status().is_server_error() => (WriteResult::Failed, e.message().to_owned()),
        Err(e) => (WriteResult::Refused, e.message().to_owned()),
    }
}

/// Records a change's answer in the audit trail.
pub(crate) fn audit<T>(
    state: &ApiState,
    caller: &Caller,
    target: &dyn Display,
    result: &Result<T, ApiError>,
) {
    let (result, detail) = outcome(result);
    state.backend().audit(caller, target, result, &detail);
}

/// A JSON body, read by [`body::json`]: every refusal (415, 400, 413, 422) says what the endpoint
/// takes.
pub(crate) struct ApiJson<T>(pub(crate) T);

impl<T, S> FromRequest<S> for ApiJson<T>
where
    T: JsonBody,
    S: Send + Sync,
{
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &S) -> Result<Self, Self::Rejection> {
        body::require_json::<T>(req.headers())?;
        let bytes = Bytes::from_request(req, state)
            .await
            .map_err(|e| body::read_error(e.status(), &e.body_text()))?;
        body::json::<T>(&bytes).map(Self)
    }
}

/// Path parameters; a parameter that does not parse answers 400.
pub(crate) struct ApiPath<T>(pub(crate) T);

impl<T, S> FromRequestParts<S> for ApiPath<T>
where
    T: DeserializeOwned + Send,
    S: Send + Sync,
{
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, Self::Rejection> {
        let Path(value) = Path::<T>::from_request_parts(parts, state).await?;
        Ok(Self(value))
    }
}

/// Query parameters; unknown or malformed ones answer 400.
pub(crate) struct ApiQuery<T>(pub(crate) T);

impl<T, S> FromRequestParts<S> for ApiQuery<T>
where
    T: DeserializeOwned,
    S: Send + Sync,
{
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, Self::Rejection> {
        let Query(value) = Query::<T>::from_request_parts(parts, state).await?;
        Ok(Self(value))
    }
}

/// The tag of the bearer-token security scheme in the OpenAPI document.
pub(crate) const BEARER: &str = "bearer";
