//! Configuration documents in request bodies: JSON (the default) or TOML, read through the
//! configuration's own reader so that the API reports the same issues with the same paths as
//! `gateway check`; and the configuration's version tag (`ETag`).

use std::hash::{Hash, Hasher};

use axum::http::{header, HeaderMap};

use super::backend::ApiBackend;
use super::error::{ApiError, Issue};
use crate::config::{Check, Config, ConfigErrors};

/// The media type of TOML documents.
pub const TOML_MEDIA_TYPE: &str = "application/toml";

/// The format of a configuration document.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Format {
    Json,
    Toml,
}

/// The format named by `Content-Type`: JSON when it says JSON, TOML when it says TOML,
/// 415 otherwise (a missing header counts as JSON, as most clients send JSON bodies).
pub(crate) fn content_format(headers: &HeaderMap) -> Result<Format, ApiError> {
    let Some(value) = headers.get(header::CONTENT_TYPE) else {
        return Ok(Format::Json);
    };
    let mime = value
        .to_str()
        .unwrap_or_default()
        .split(';')
        .next()
        .unwrap_or_default()
        .trim()
        .to_ascii_lowercase();
    match mime.as_str() {
        "application/json" => Ok(Format::Json),
        m if m.starts_with("application/") && m.ends_with("+json") => Ok(Format::Json),
        TOML_MEDIA_TYPE | "text/x-toml" => Ok(Format::Toml),
        other => Err(ApiError::unsupported_media_type(format!(
            "Content-Type {other:?}: send application/json or {TOML_MEDIA_TYPE}"
        ))),
    }
}

/// Whether the client asked for TOML (`Accept: application/toml`).
pub(crate) fn wants_toml(headers: &HeaderMap) -> bool {
    headers
        .get_all(header::ACCEPT)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .any(|m| m.split(';').next().unwrap_or_default().trim() == TOML_MEDIA_TYPE)
}

/// A body as a TOML table: 400 for bad syntax, 422 for a document that is not a table or holds
/// values TOML cannot (null, integers beyond 64-bit signed), each with its path.
pub(crate) fn table(format: Format, body: &[u8]) -> Result<toml::Table, ApiError> {
    match format {
        Format::Json => {
            let value: serde_json::Value = serde_json::from_slice(body)
                .map_err(|e| ApiError::bad_request(format!("the body is not JSON: {e}")))?;
            let mut issues = Vec::new();
            match json_to_toml(value, "", &mut issues) {
                Some(toml::Value::Table(t)) if issues.is_empty() => Ok(t),
                Some(_) if issues.is_empty() => Err(ApiError::validation(vec![Issue {
                    path: String::new(),
                    message: "expected a JSON object".into(),
                }])),
                _ => Err(ApiError::validation(issues)),
            }
        }
        Format::Toml => {
            let text = std::str::from_utf8(body)
                .map_err(|_| ApiError::bad_request("the body is not UTF-8"))?;
            text.parse::<toml::Table>()
                .map_err(|e| ApiError::bad_request(toml_syntax_message(text, &e)))
        }
    }
}

/// A whole configuration from a body, checked by the parser and by `check`.
pub(crate) fn config(format: Format, body: &[u8], check: Check<'_>) -> Result<Config, ApiError> {
    let table = table(format, body)?;
    Config::from_table_with(&table, check).map_err(validation)
}

/// A configuration from its table, checked by the parser and by `backend`.
pub(crate) fn from_table(
    table: &toml::Table,
    backend: &dyn ApiBackend,
) -> Result<Config, ApiError> {
    Config::from_table_with(table, &|config, found| backend.config_issues(config, found))
        .map_err(validation)
}

/// Every issue of a configuration as a 422.
pub(crate) fn validation(errors: ConfigErrors) -> ApiError {
    ApiError::validation(errors.issues.into_iter().map(Issue::from).collect())
}

/// `config` as a TOML table (the shape the reader takes).
pub(crate) fn to_table(config: &Config) -> Result<toml::Table, ApiError> {
    toml::Table::try_from(config)
        .map_err(|e| ApiError::internal(format!("cannot serialize the configuration: {e}")))
}

/// The configuration's version: a hash of its TOML text, as a strong `ETag` value.
pub fn etag(config: &Config) -> String {
    let text = toml::to_string(config).unwrap_or_default();
    // SipHash with fixed keys: the same text gives the same tag in every run of this build.
    let mut h = std::hash::DefaultHasher::new();
    text.hash(&mut h);
    format!("\"{:016x}\"", h.finish())
}

/// Whether `If-Match` (absent: anything) admits the version `current`.
pub(crate) fn if_match_admits(headers: &HeaderMap, current: &str) -> bool {
    let values: Vec<&str> = headers
        .get_all(header::IF_MATCH)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .collect();
    if values.is_empty() {
        return true;
    }
    values
        .iter()
        .flat_map(|v| v.split(','))
        .map(str::trim)
        // RFC 9110 13.1.1: strong comparison, a weak tag never matches.
        .any(|tag| tag == "*" || tag == current)
}

/// A JSON value as TOML, or issues at the paths TOML cannot hold.
fn json_to_toml(
    value: serde_json::Value,
    path: &str,
    issues: &mut Vec<Issue>,
) -> Option<toml::Value> {
    use serde_json::Value as J;
    let mut issue = |message: &str| {
        issues.push(Issue {
            path: path.to_owned(),
            message: message.to_owned(),
        });
        None
    };
    match value {
        J::Null => issue("null is not a value here: leave the key out to take its default"),
        J::Bool(b) => Some(toml::Value::Boolean(b)),
        J::String(s) => Some(toml::Value::String(s)),
        J::Number(n) => {
            if let Some(i) = n.as_i64() {
                Some(toml::Value::Integer(i))
            } else if n.is_u64() {
                issue("integer too large")
            } else {
                n.as_f64().map(toml::Value::Float)
            }
        }
        J::Array(items) => {
            let mut out = Vec::with_capacity(items.len());
            for (i, item) in items.into_iter().enumerate() {
                if let Some(v) = json_to_toml(item, &format!("{path}[{i}]"), issues) {
                    out.push(v);
                }
            }
            Some(toml::Value::Array(out))
        }
        J::Object(map) => {
            let mut out = toml::Table::new();
            for (key, item) in map {
                let at = if path.is_empty() {
                    key.clone()
                } else {
                    format!("{path}.{key}")
                };
                if let Some(v) = json_to_toml(item, &at, issues) {
                    out.insert(key, v);
                }
            }
            Some(toml::Value::Table(out))
        }
    }
}

/// `TOML syntax error at line L, column C: <what>`.
fn toml_syntax_message(text: &str, e: &toml::de::Error) -> String {
    let what = e.message().trim().replace('\n', "; ");
    match e.span() {
        Some(span) => {
            let before = text.get(..span.start).unwrap_or(text);
            let line = before.matches('\n').count() + 1;
            let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
            format!("TOML syntax error at line {line}, column {column}: {what}")
        }
        None => format!("TOML syntax error: {what}"),
    }
}

#[cfg(test)]
mod tests {
    use axum::http::HeaderValue;

    use super::*;
    use crate::config::no_check;

    #[test]
    fn json_and_toml_give_the_same_config() {
        let demo = crate::config::demo();
        let json = serde_json::to_vec(&demo).unwrap();
        assert_eq!(config(Format::Json, &json, &no_check).unwrap(), demo);
        let toml_text = toml::to_string(&demo).unwrap();
        assert_eq!(
            config(Format::Toml, toml_text.as_bytes(), &no_check).unwrap(),
            demo
        );
        assert_eq!(
            etag(&demo),
            etag(&config(Format::Json, &json, &no_check).unwrap())
        );
    }

    #[test]
    fn values_toml_cannot_hold_are_issues_with_paths() {
        let body =
            br#"{"gateway": {"name": null}, "lines": {"a": {"x": [1, 18446744073709551615]}}}"#;
        let e = table(Format::Json, body).unwrap_err();
        assert_eq!(e.code(), "validation_failed");
        let paths: Vec<&str> = e.issues().iter().map(|i| i.path.as_str()).collect();
        assert_eq!(paths, ["gateway.name", "lines.a.x[1]"]);
        assert_eq!(
            table(Format::Json, b"[1]").unwrap_err().code(),
            "validation_failed"
        );
        assert_eq!(table(Format::Json, b"{").unwrap_err().code(), "bad_request");
        let e = table(Format::Toml, b"[gateway\nname = 1").unwrap_err();
        assert_eq!(e.code(), "bad_request");
        assert!(e.message().contains("line 1"), "{}", e.message());
    }

    #[test]
    fn content_types_and_if_match() {
        let mut h = HeaderMap::new();
        assert_eq!(content_format(&h).unwrap(), Format::Json);
        h.insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/toml; charset=utf-8"),
        );
        assert_eq!(content_format(&h).unwrap(), Format::Toml);
        h.insert(header::CONTENT_TYPE, HeaderValue::from_static("text/plain"));
        assert_eq!(
            content_format(&h).unwrap_err().code(),
            "unsupported_media_type"
        );

        assert!(if_match_admits(&h, "\"a\""));
        h.insert(header::IF_MATCH, HeaderValue::from_static("\"b\", \"a\""));
        assert!(if_match_admits(&h, "\"a\""));
        assert!(!if_match_admits(&h, "\"c\""));
        h.insert(header::IF_MATCH, HeaderValue::from_static("W/\"c\""));
        assert!(!if_match_admits(&h, "\"c\""));
        h.insert(header::IF_MATCH, HeaderValue::from_static("*"));
        assert!(if_match_admits(&h, "\"c\""));

        h.insert(
            header::ACCEPT,
            HeaderValue::from_static("text/html, application/toml;q=0.9"),
        );
        assert!(wants_toml(&h));
    }
}
