//! `/healthz`, `/readyz`, `/api/v1/status` and `/api/v1/openapi.json`.

use std::sync::atomic::{AtomicU8, Ordering};
use std::sync::Arc;

use axum::extract::State;
use axum::http::header;
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};

use crate::api::error::{ApiError, ErrorBody, Issue};
use crate::api::model::{GatewayStatus, Health};
use crate::api::ApiState;

/// The OpenAPI document, rendered once when the router is built.
#[derive(Clone)]
pub(crate) struct OpenApiJson(pub(crate) Arc<String>);

/// Alive: the process answers HTTP.
#[utoipa::path(
    get,
    path = "/healthz",
    tag = "health",
    responses((status = 200, description = "Alive", body = Health))
)]
pub(crate) async fn healthz() -> Json<Health> {
    Json(Health {
        status: "alive".into(),
    })
}

/// Ready: every line has opened its port once, the Modbus TCP listener and the zenoh session
/// are up.
#[utoipa::path(
    get,
    path = "/readyz",
    tag = "health",
    responses(
        (status = 200, description = "Ready", body = Health),
        (status = 503, description = "Not ready; each missing part is an issue", body = ErrorBody),
    )
)]
pub(crate) async fn readyz(State(state): State<ApiState>) -> Result<Json<Health>, ApiError> {
    let readiness = state.backend().readiness();
    let issues = readiness.issues();
    log_readiness(&issues);
    if issues.is_empty() {
        Ok(Json(Health {
            status: "ready".into(),
        }))
    } else {
        Err(ApiError::not_ready(issues))
    }
}

/// The answer `/readyz` gave last: 0 none yet, 1 ready, 2 not ready.
static LAST_READINESS: AtomicU8 = AtomicU8::new(0);

/// Logs what `/readyz` answered: at INFO when the answer changed since the last probe (with what
/// is missing), at DEBUG otherwise. A probe every few seconds from an orchestrator while a line's
/// port is missing is normal operation, not a warning: the line's own events say what is wrong.
/// The last answer is kept per process (one REST API).
fn log_readiness(issues: &[Issue]) {
    let now = if issues.is_empty() { 1 } else { 2 };
    let changed = LAST_READINESS.swap(now, Ordering::Relaxed) != now;
    let missing = || {
        issues
            .iter()
            .map(|i| format!("{}: {}", i.path, i.message))
            .collect::<Vec<_>>()
            .join("; ")
    };
    match (changed, issues.is_empty()) {
        (true, true) => tracing::info!("readyz: ready"),
        (true, false) => tracing::info!(missing = %missing(), "readyz: not ready"),
        (false, true) => tracing::debug!("readyz: ready"),
        (false, false) => tracing::debug!(missing = %missing(), "readyz: not ready"),
    }
}

/// The gateway: name, version, uptime, readiness, every line, the servers.
#[utoipa::path(
    get,
    path = "/status",
    tag = "status",
    responses((status = 200, description = "The gateway", body = GatewayStatus))
)]
pub(crate) async fn gateway_status(State(state): State<ApiState>) -> Json<GatewayStatus> {
    Json(state.backend().gateway_status())
}

/// This document (OpenAPI 3.1, generated from the handlers).
#[utoipa::path(
    get,
    path = "/openapi.json",
    tag = "meta",
    responses((status = 200, description = "The OpenAPI document", content_type = "application/json", body = Object))
)]
pub(crate) async fn openapi_json(Extension(doc): Extension<OpenApiJson>) -> Response {
    (
        [(header::CONTENT_TYPE, "application/json")],
        doc.0.as_str().to_owned(),
    )
        .into_response()
}
