//! Every error of the API as one JSON shape, and the one place where errors become responses.
//!
//! ```json
//! {"error": {"code": "validation_failed", "message": "3 problems in the configuration",
//!            "issues": [{"path": "lines.drive.baud", "message": "..."}]}}
//! ```
//!
//! `code` is a stable snake_case word clients can match on; `message` is for people; `issues` is
//! present only where a request had several problems (configuration validation, readiness).

use axum::extract::rejection::{PathRejection, QueryRejection};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::config::ConfigIssue;
use crate::protocols::{CommandError, QueueError};
use crate::tags::TagWriteError;
use proto_core::modbus::pdu::ExceptionCode;

/// The body of every error response.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct ErrorBody {
    pub error: ErrorDetail,
}

/// What went wrong.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct ErrorDetail {
    /// Stable, snake_case: `bad_request`, `unsupported_media_type`, `invalid_body`,
    /// `unauthorized`, `forbidden`, `not_found`, `method_not_allowed`, `conflict`,
    /// `precondition_failed`, `payload_too_large`, `validation_failed`, `device_exception`,
    /// `busy`, `not_ready`, `device_timeout`, `timeout`, `persist_failed`, `internal`.
    pub code: String,
    /// For people; may change between versions.
    pub message: String,
    /// Every problem found, each with where it is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub issues: Option<Vec<Issue>>,
}

/// One problem with its place: a config key path (`lines.drive.baud`), or a component for
/// readiness (`lines.drive`, `modbus_tcp`, `zenoh`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct Issue {
    /// Empty for a problem of the whole document (e.g. a syntax error).
    pub path: String,
    pub message: String,
}

impl From<ConfigIssue> for Issue {
    fn from(i: ConfigIssue) -> Self {
        Self {
            path: i.path,
            message: i.message,
        }
    }
}

/// An error answer: its status, its stable code and what to tell the client.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ApiError {
    status: StatusCode,
    code: &'static str,
    message: String,
    issues: Option<Vec<Issue>>,
    /// `WWW-Authenticate` (RFC 6750 3) on a 401.
    challenge: Option<&'static str>,
    /// `Retry-After` in seconds on a 503.
    retry_after: Option<u32>,
}

/// The errors that are their status, their code (the constructor's name) and a message.
macro_rules! plain_errors {
    ($($(#[doc = $doc:literal])* $name:ident = $status:ident;)+) => {$(
        $(#[doc = $doc])*
        pub fn $name(message: impl Into<String>) -> Self {
            Self::new(StatusCode::$status, stringify!($name), message)
        }
    )+};
}

// === impl ApiError ===

impl ApiError {
    fn new(status: StatusCode, code: &'static str, message: impl Into<String>) -> Self {
        Self {
            status,
            code,
            message: message.into(),
            issues: None,
            challenge: None,
            retry_after: None,
        }
    }

    plain_errors! {
        /// 400: a body that is not JSON, a path or query that does not parse.
        bad_request = BAD_REQUEST;
        /// 403: the request is understood and authenticated (or cannot be) but not allowed.
        forbidden = FORBIDDEN;
        /// 409: the request does not fit the current state (a telegram request on a line that has
        /// no telegrams, an acknowledge of a telegram that is not the oldest).
        conflict = CONFLICT;
        /// 412: `If-Match` names another version of the configuration.
        precondition_failed = PRECONDITION_FAILED;
        /// 413: the body is larger than `[http] body_limit`.
        payload_too_large = PAYLOAD_TOO_LARGE;
        /// 415: the body is not `application/json` (or TOML where TOML is accepted).
        unsupported_media_type = UNSUPPORTED_MEDIA_TYPE;
        /// 422: well-formed JSON that is not what the endpoint takes.
        invalid_body = UNPROCESSABLE_ENTITY;
        /// 504: the device did not answer within the line's reply monitoring and retries.
        device_timeout = GATEWAY_TIMEOUT;
        /// 504: the request took longer than `[http] request_timeout`.
        timeout = GATEWAY_TIMEOUT;
        /// 500: a valid configuration could not be written; nothing was applied.
        persist_failed = INTERNAL_SERVER_ERROR;
        /// 500: a defect; the message is logged and kept short for the client.
        internal = INTERNAL_SERVER_ERROR;
    }

    /// 401 without `Authorization`; `challenge` is the `WWW-Authenticate` value.
    pub fn unauthorized(message: impl Into<String>, challenge: &'static str) -> Self {
        Self {
            challenge: Some(challenge),
            ..Self::new(StatusCode::UNAUTHORIZED, "unauthorized", message)
        }
    }

    /// 404 for the `kind` (`line`, `device`, `tag`, ...) named `name`.
    pub fn not_found(kind: &str, name: &str) -> Self {
        Self::new(
            StatusCode::NOT_FOUND,
            "not_found",
            format!("no {kind} {name:?}"),
        )
    }

    /// 404 for a path no route serves.
    pub fn no_route(path: &str) -> Self {
        Self::new(
            StatusCode::NOT_FOUND,
            "not_found",
            format!("no route {path}"),
        )
    }

    /// 405.
    pub fn method_not_allowed() -> Self {
        Self::new(
            StatusCode::METHOD_NOT_ALLOWED,
            "method_not_allowed",
            "method not allowed on this path",
        )
    }

    /// 422 with every problem of a configuration.
    pub fn validation(issues: Vec<Issue>) -> Self {
        let message = match issues.len() {
            1 => "1 problem in the configuration".to_owned(),
            n => format!("{n} problems in the configuration"),
        };
        Self {
            issues: Some(issues),
            ..Self::new(
                StatusCode::UNPROCESSABLE_ENTITY,
                "validation_failed",
                message,
            )
        }
    }

    /// 502: the device answered with a Modbus exception (`code` 01h..0Bh).
    pub fn device_exception(code: u8, message: impl Into<String>) -> Self {
        let message = format!("exception {code:02X}h: {}", message.into());
        Self::new(StatusCode::BAD_GATEWAY, "device_exception", message)
    }

    /// 503: the line's queue is full or the line is restarting; try again shortly.
    pub fn busy(message: impl Into<String>) -> Self {
        Self::busy_for(message, 1)
    }

    /// 503: no place for the request now (a connection or stream limit of the listener); try
    /// again after `retry_after` seconds.
    pub fn busy_for(message: impl Into<String>, retry_after: u32) -> Self {
        Self {
            retry_after: Some(retry_after),
            ..Self::new(StatusCode::SERVICE_UNAVAILABLE, "busy", message)
        }
    }

    /// 503 from `/readyz`, each component that is not up as an issue.
    pub fn not_ready(issues: Vec<Issue>) -> Self {
        Self {
            issues: Some(issues),
            retry_after: Some(1),
            ..Self::new(StatusCode::SERVICE_UNAVAILABLE, "not_ready", "not ready")
        }
    }

    /// An error for a bare status that some layer produced without a body.
    pub fn from_status(status: StatusCode) -> Self {
        match status {
            StatusCode::NOT_FOUND => Self::new(status, "not_found", "not found"),
            StatusCode::METHOD_NOT_ALLOWED => Self::method_not_allowed(),
            StatusCode::PAYLOAD_TOO_LARGE => Self::payload_too_large("request body too large"),
            StatusCode::UNSUPPORTED_MEDIA_TYPE => {
                Self::unsupported_media_type("expected Content-Type: application/json")
            }
            StatusCode::REQUEST_TIMEOUT | StatusCode::GATEWAY_TIMEOUT => {
                Self::timeout("request timed out")
            }
            s if s.is_client_error() => Self::bad_request(reason(s)),
            s => Self::new(s, "internal", reason(s)),
        }
    }

    pub fn status(&self) -> StatusCode {
        self.status
    }

    pub fn code(&self) -> &'static str {
        self.code
    }

    pub fn message(&self) -> &str {
        &self.message
    }

    pub fn issues(&self) -> &[Issue] {
        self.issues.as_deref().unwrap_or_default()
    }

    /// The JSON body.
    pub fn body(&self) -> ErrorBody {
        ErrorBody {
            error: ErrorDetail {
                code: self.code.to_owned(),
                message: self.message.clone(),
                issues: self.issues.clone(),
            },
        }
    }
}

fn reason(status: StatusCode) -> String {
    status
        .canonical_reason()
        .unwrap_or("error")
        .to_ascii_lowercase()
}

impl std::fmt::Display for ApiError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} {}: {}",
            self.status.as_u16(),
            self.code,
            self.message
        )
    }
}

impl std::error::Error for ApiError {}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        // `/readyz` logs its own answers (INFO on a change): a 503 there is a state, not a fault.
        // Any client can ask for a 5xx (a read of a device that does not answer): rate-limited
        // per status and code, the number left out said with the next line.
        if self.status.is_server_error() && self.code != "not_ready" {
            crate::warn_limited!(
                format!("api error {} {}", self.status.as_u16(), self.code),
                status = self.status.as_u16(),
                code = self.code,
                message = %self.message,
                "api error"
            );
        }
        let mut response = (self.status, axum::Json(self.body())).into_response();
        let headers = response.headers_mut();
        if let Some(challenge) = self.challenge {
            headers.insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static(challenge),
            );
        }
        if let Some(secs) = self.retry_after {
            headers.insert(header::RETRY_AFTER, HeaderValue::from(secs));
        }
        if self.status == StatusCode::PAYLOAD_TOO_LARGE {
            // The rest of the body was never read, so the server closes the connection after this
            // answer; saying so keeps a client from sending its next request on a connection that
            // is about to close (RFC 9110 15.5.14, RFC 9112 9.6).
            headers.insert(header::CONNECTION, HeaderValue::from_static("close"));
        }
        response
    }
}

/// A path that does not fit its route (`/telegrams/abc/ack`): which part, and what belongs there.
impl From<PathRejection> for ApiError {
    fn from(r: PathRejection) -> Self {
        use axum::extract::path::ErrorKind;
        let message = match &r {
            PathRejection::FailedToDeserializePathParams(e) => match e.kind() {
                ErrorKind::ParseErrorAtKey {
                    key,
                    value,
                    expected_type,
                } => format!(
                    "{key} in the path is {value:?}: expected {}",
                    expected_kind(expected_type)
                ),
                ErrorKind::ParseErrorAtIndex {
                    value,
                    expected_type,
                    ..
                }
                | ErrorKind::ParseError {
                    value,
                    expected_type,
                } => format!(
                    "{value:?} in the path: expected {} there",
                    expected_kind(expected_type)
                ),
                ErrorKind::InvalidUtf8InPathParam { key } => {
                    format!("{key} in the path is not UTF-8 text")
                }
                _ => format!("the path does not fit this route ({})", e.body_text()),
            },
            other => format!("the path does not fit this route ({})", other.body_text()),
        };
        Self::bad_request(message)
    }
}

/// A query that does not fit its route: which parameter, and what it takes.
impl From<QueryRejection> for ApiError {
    fn from(r: QueryRejection) -> Self {
        Self::bad_request(query_message(&r.body_text()))
    }
}

/// What a Rust type named in a parser's message is, for people.
fn expected_kind(type_name: &str) -> &str {
    match type_name {
        "u8" | "u16" | "u32" | "u64" | "u128" | "usize" => "a whole number, 0 or more",
        "i8" | "i16" | "i32" | "i64" | "i128" | "isize" => "a whole number",
        "f32" | "f64" => "a number",
        "bool" => "true or false",
        "alloc::string::String" | "String" | "&str" => "text",
        other => other,
    }
}

/// axum's query message (`Failed to deserialize query string: since: invalid digit found in
/// string`) in words that say what to send (`query parameter since: expected a whole number`).
fn query_message(text: &str) -> String {
    let inner = text
        .strip_prefix("Failed to deserialize query string: ")
        .unwrap_or(text);
    let (key, what) = match inner.split_once(": ") {
        Some((key, what)) if !key.contains(' ') => (key, what),
        _ => ("", inner),
    };
    if let Some(rest) = what.strip_prefix("unknown field ") {
        let name = rest.split(',').next().unwrap_or(rest).trim_matches('`');
        return match rest.split_once(", expected ") {
            Some((_, expected)) => {
                format!("unknown query parameter {name:?}: this path takes {expected}")
            }
            None => format!("unknown query parameter {name:?}: this path takes none"),
        };
    }
    let what = match what {
        "invalid digit found in string"
        | "cannot parse integer from empty string"
        | "number too large to fit in target type"
        | "number too small to fit in target type" => "expected a whole number, 0 or more",
        "provided string was not `true` or `false`" => "expected true or false",
        other => other,
    };
    if key.is_empty() {
        format!("the query does not fit this path: {what}")
    } else {
        format!("query parameter {key}: {what}")
    }
}

/// What a device (or the gateway's own Modbus policy) answered: 504 when the target did not
/// respond (0Bh), 503 when it is busy (06h), otherwise 502 with the code.
impl From<ExceptionCode> for ApiError {
    fn from(code: ExceptionCode) -> Self {
        match code {
            ExceptionCode::GatewayTargetFailedToRespond => {
                Self::device_timeout("the device did not respond (exception 0Bh)")
            }
            ExceptionCode::ServerDeviceBusy => Self::busy("the device is busy (exception 06h)"),
            other => Self::new(
                StatusCode::BAD_GATEWAY,
                "device_exception",
                format!("the device answered exception {other}"),
            ),
        }
    }
}

/// A command on a line that got no answer.
impl From<CommandError> for ApiError {
    fn from(e: CommandError) -> Self {
        match e {
            CommandError::NoReply { .. } | CommandError::Offline(_) => {
                Self::device_timeout(e.to_string())
            }
            CommandError::PortClosed | CommandError::ShuttingDown => Self::busy(e.to_string()),
            CommandError::Refused(_) => Self::invalid_body(e.to_string()),
        }
    }
}

/// A command that could not be queued: back-pressure is 503, never an unbounded wait.
impl From<QueueError> for ApiError {
    fn from(e: QueueError) -> Self {
        Self::busy(e.to_string())
    }
}

/// A tag write the directory or the device refused.
impl From<TagWriteError> for ApiError {
    fn from(e: TagWriteError) -> Self {
        match e {
            TagWriteError::UnknownTag(t) => Self::not_found("tag", &t),
            TagWriteError::ReadOnly(_) => Self::conflict(e.to_string()),
            TagWriteError::Value { .. } => Self::invalid_body(e.to_string()),
            TagWriteError::Exception(code) => code.into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_json_shape_is_stable() {
        let e = ApiError::validation(vec![Issue {
            path: "lines.drive.baud".into(),
            message: "bad".into(),
        }]);
        let v = serde_json::to_value(e.body()).unwrap();
        assert_eq!(
            v,
            serde_json::json!({"error": {"code": "validation_failed",
                "message": "1 problem in the configuration",
                "issues": [{"path": "lines.drive.baud", "message": "bad"}]}})
        );
        let v = serde_json::to_value(ApiError::not_found("line", "x").body()).unwrap();
        assert_eq!(
            v,
            serde_json::json!({"error": {"code": "not_found", "message": "no line \"x\""}})
        );
    }

    #[test]
    fn bare_statuses_get_a_code() {
        for (status, code) in [
            (StatusCode::NOT_FOUND, "not_found"),
            (StatusCode::METHOD_NOT_ALLOWED, "method_not_allowed"),
            (StatusCode::PAYLOAD_TOO_LARGE, "payload_too_large"),
            (StatusCode::REQUEST_TIMEOUT, "timeout"),
            (StatusCode::IM_A_TEAPOT, "bad_request"),
            (StatusCode::BAD_GATEWAY, "internal"),
        ] {
            let e = ApiError::from_status(status);
            assert_eq!(e.code(), code, "{status}");
        }
    }

    #[test]
    fn device_answers_map_to_statuses() {
        let e = ApiError::from(ExceptionCode::IllegalDataValue);
        assert_eq!(
            (e.status(), e.code()),
            (StatusCode::BAD_GATEWAY, "device_exception")
        );
        assert_eq!(
            e.message(),
            "the device answered exception 03h (illegal data value)"
        );
        let e = ApiError::from(ExceptionCode::GatewayTargetFailedToRespond);
        assert_eq!(e.code(), "device_timeout");
        assert_eq!(
            ApiError::from(ExceptionCode::ServerDeviceBusy).code(),
            "busy"
        );
        assert_eq!(
            ApiError::from(QueueError::Full).status(),
            StatusCode::SERVICE_UNAVAILABLE
        );
        assert_eq!(
            ApiError::from(CommandError::Offline(2)).code(),
            "device_timeout"
        );
        assert_eq!(ApiError::from(CommandError::PortClosed).code(), "busy");
        assert_eq!(
            ApiError::from(TagWriteError::ReadOnly("eta".into())).code(),
            "conflict"
        );
        assert_eq!(
            ApiError::from(TagWriteError::UnknownTag("x".into())).code(),
            "not_found"
        );
        let e = ApiError::from(TagWriteError::Exception(ExceptionCode::IllegalDataAddress));
        assert_eq!(e.code(), "device_exception");
    }

    #[test]
    fn query_refusals_name_the_parameter_and_what_it_takes() {
        assert_eq!(
            query_message(
                "Failed to deserialize query string: foo: unknown field `foo`, expected `line` or `device`"
            ),
            "unknown query parameter \"foo\": this path takes `line` or `device`"
        );
        assert_eq!(
            query_message(
                "Failed to deserialize query string: since: invalid digit found in string"
            ),
            "query parameter since: expected a whole number, 0 or more"
        );
        assert_eq!(
            query_message(
                "Failed to deserialize query string: follow: provided string was not `true` or `false`"
            ),
            "query parameter follow: expected true or false"
        );
    }

    #[test]
    fn challenges_and_retry_after_become_headers() {
        let r = ApiError::unauthorized("no token", "Bearer realm=\"gateway\"").into_response();
        assert_eq!(r.status(), StatusCode::UNAUTHORIZED);
        assert_eq!(
            r.headers().get(header::WWW_AUTHENTICATE).unwrap(),
            "Bearer realm=\"gateway\""
        );
        let r = ApiError::busy("queue full").into_response();
        assert_eq!(r.headers().get(header::RETRY_AFTER).unwrap(), "1");
    }
}
