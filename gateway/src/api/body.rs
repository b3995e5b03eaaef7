//! Request bodies, in one place: every JSON endpoint's body is read here, and a body that is not
//! what the endpoint takes is answered with what it takes (`expected a JSON object like
//! {"value": 30.5}, not the bare number 30.5`), never with a parser's own words.
//!
//! Configuration documents: JSON (the default) or TOML, read through the configuration's own
//! reader so that the API reports the same issues with the same paths as `gateway check`, and
//! kept as the client wrote them (keys in its order, TOML values in its spelling) for the file.
//! The configuration's version tag (`ETag`).

use std::hash::{Hash, Hasher};

use axum::http::{header, HeaderMap, StatusCode};

use serde::de::{DeserializeOwned, MapAccess, SeqAccess, Visitor};
use serde::{Deserialize, Serialize, Serializer};

use super::backend::ApiBackend;
use super::error::{ApiError, Issue};
use super::model::{SendRequest, SignalsPatch, TagWrite};
use crate::config::ConfigErrors;
use crate::plant::{Config, ExtraCheck};

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

/// The first line of the comment a TOML answer of `GET /config` starts with when settings given
/// on the command line are in force; a TOML body that starts with it has the comment removed.
pub(crate) const OVERRIDES_BANNER: &str =
    "# In force from the command line in place of these keys \
     (not part of the configuration: a PUT of this text leaves them out):";

/// The key of the JSON answer of `GET /config` that lists the command line's settings; a
/// configuration body may have it (it is left out).
pub(crate) const OVERRIDES_KEY: &str = "overrides";

/// A configuration document a client sent: what it says (`table`, read by the configuration's
/// reader) and how it says it (`doc`: the client's keys in its order, TOML values in its spelling,
/// written into the file where the file had nothing).
#[derive(Debug, Clone)]
pub(crate) struct BodyDocument {
    pub(crate) doc: toml_edit::DocumentMut,
    pub(crate) table: toml::Table,
}

/// A body as a document: 400 for bad syntax, 422 for a document that is not a table or holds
/// values TOML cannot (null, integers beyond 64-bit signed), each with its path. `expected`
/// names what the endpoint takes, for the message.
pub(crate) fn document(
    format: Format,
    body: &[u8],
    expected: &str,
) -> Result<BodyDocument, ApiError> {
    match format {
        Format::Json => {
            let value: OrderedJson = serde_json::from_slice(body)
                .map_err(|e| ApiError::bad_request(not_json(body, &e, expected)))?;
            let OrderedJson::Object(entries) = value else {
                return Err(ApiError::validation(vec![Issue {
                    path: String::new(),
                    message: format!("expected {expected}, not {}", value.kind()),
                }]));
            };
            let mut issues = Vec::new();
            let root = json_table(entries, "", &mut issues);
            if !issues.is_empty() {
                return Err(ApiError::validation(issues));
            }
            let doc = toml_edit::DocumentMut::from(root);
            let table = doc.to_string().parse::<toml::Table>().map_err(|e| {
                ApiError::internal(format!("the body as TOML does not read back: {e}"))
            })?;
            Ok(BodyDocument { doc, table })
        }
        Format::Toml => {
            let text = std::str::from_utf8(body).map_err(|_| {
                ApiError::bad_request(format!(
                    "the body is not UTF-8 text: send {expected} as TOML"
                ))
            })?;
            let text = without_banner(text);
            let table = text
                .parse::<toml::Table>()
                .map_err(|e| ApiError::bad_request(toml_syntax_message(text, &e)))?;
            let doc = text
                .parse::<toml_edit::DocumentMut>()
                .map_err(|e| ApiError::bad_request(format!("TOML syntax error: {e}")))?;
            Ok(BodyDocument { doc, table })
        }
    }
}

/// What a configuration body is expected to be, for messages.
pub(crate) const CONFIG_EXPECTED: &str =
    "a JSON object with the configuration's tables, like {\"gateway\": {\"name\": \"plant\"}, \
     \"lines\": {\"drive\": {\"port\": \"/dev/ttyS0\", \"protocol\": \"modbus-master-rtu\"}}}";

/// What a line's body is expected to be, for messages.
pub(crate) const LINE_EXPECTED: &str =
    "a JSON object with the line's keys, like {\"port\": \"/dev/ttyS1\", \"protocol\": \"ascii\", \
     \"end_chars\": [13, 10]}";

/// A whole configuration's document from a body (the command line's settings a `GET` showed
/// beside it left out), checked by the parser and by `check`.
pub(crate) fn config_document(
    format: Format,
    body: &[u8],
    check: ExtraCheck<'_>,
    in_force: &Config,
) -> Result<(Config, BodyDocument), ApiError> {
    let mut document = document(format, body, CONFIG_EXPECTED)?;
    document.doc.remove(OVERRIDES_KEY);
    document.table.remove(OVERRIDES_KEY);
    template_dirs_confined(&document.table, in_force)?;
    let config = Config::from_table_with(&document.table, check).map_err(validation)?;
    Ok((config, document))
}

/// A body's `[gateway] template_dirs` are confined before the body is read (reading it opens the
/// templates its devices name there): a directory the configuration in force does not list must
/// lie inside its `config_dirs`, where the files the gateway reads its settings from are; a
/// directory outside is refused (422) and nothing in it is opened.
fn template_dirs_confined(table: &toml::Table, in_force: &Config) -> Result<(), ApiError> {
    let Some(dirs) = table
        .get("gateway")
        .and_then(|g| g.get("template_dirs"))
        .and_then(toml::Value::as_array)
    else {
        return Ok(());
    };
    let canonical = |p: &std::path::Path| std::fs::canonicalize(p).unwrap_or_else(|_| p.into());
    let allowed: Vec<std::path::PathBuf> = in_force
        .gateway
        .config_dirs
        .iter()
        .map(|d| canonical(d))
        .collect();
    let mut issues = Vec::new();
    for (i, dir) in dirs.iter().enumerate() {
        let Some(dir) = dir.as_str().map(std::path::Path::new) else {
            continue;
        };
        if in_force.gateway.template_dirs.iter().any(|d| d == dir) {
            continue;
        }
        let resolved = canonical(&crate::plant::template_dir_resolved(dir));
        if !allowed.iter().any(|a| resolved.starts_with(a)) {
            issues.push(Issue {
                path: format!("gateway.template_dirs[{i}]"),
                message: format!(
                    "{} is outside [gateway] config_dirs {:?}: a change over the API names \
                     template directories there only",
                    dir.display(),
                    in_force.gateway.config_dirs
                ),
            });
        }
    }
    if issues.is_empty() {
        Ok(())
    } else {
        Err(ApiError::validation(issues))
    }
}

/// `text` without the comment [`OVERRIDES_BANNER`] begins.
fn without_banner(text: &str) -> &str {
    if !text.starts_with(OVERRIDES_BANNER) {
        return text;
    }
    let mut rest = text;
    while rest.starts_with('#') {
        rest = rest.split_once('\n').map_or("", |(_, after)| after);
    }
    rest
}

/// A body that could not be read: 413 over `[http] body_limit` (the rest is never read), 400
/// otherwise; `text` is axum's account.
pub(crate) fn read_error(status: StatusCode, text: &str) -> ApiError {
    if status == StatusCode::PAYLOAD_TOO_LARGE {
        ApiError::payload_too_large(
            "the request body is larger than this gateway takes ([http] body_limit): send a \
             smaller body, or raise body_limit in the configuration",
        )
    } else {
        let what = text
            .strip_prefix("Failed to buffer the request body: ")
            .unwrap_or(text);
        ApiError::bad_request(format!("cannot read the request body: {what}"))
    }
}

/// Why a body is not JSON, and what to send instead.
fn not_json(body: &[u8], e: &serde_json::Error, expected: &str) -> String {
    if body.iter().all(u8::is_ascii_whitespace) {
        return format!("the body is empty: send {expected}");
    }
    format!("the body is not JSON ({e}): send {expected}")
}

/// A whole configuration from a body, checked by the parser and by `check`.
pub(crate) fn config(
    format: Format,
    body: &[u8],
    check: ExtraCheck<'_>,
    in_force: &Config,
) -> Result<Config, ApiError> {
    config_document(format, body, check, in_force).map(|(config, _)| config)
}

/// The configuration an edited document reads as, checked by the parser and by `backend`.
pub(crate) fn from_document(
    doc: &toml_edit::DocumentMut,
    backend: &dyn ApiBackend,
) -> Result<Config, ApiError> {
    Config::from_table_with(&document_table(doc)?, &|config, found| {
        backend.config_issues(config, found)
    })
    .map_err(validation)
}

/// The configuration an edited document reads as, checked by the parser's own rules.
pub(crate) fn from_document_unchecked(doc: &toml_edit::DocumentMut) -> Result<Config, ApiError> {
    Config::from_table(&document_table(doc)?).map_err(validation)
}

fn document_table(doc: &toml_edit::DocumentMut) -> Result<toml::Table, ApiError> {
    doc.to_string().parse().map_err(|e| {
        ApiError::internal(format!("the edited configuration does not read back: {e}"))
    })
}

/// Every issue of a configuration as a 422.
pub(crate) fn validation(errors: ConfigErrors) -> ApiError {
    ApiError::validation(errors.issues.into_iter().map(Issue::from).collect())
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

// === JSON in the client's order ===

/// A JSON value with its objects' keys in the order the client wrote them (serde_json's own
/// `Value` sorts them), so that a line added over REST is written with its keys as sent.
#[derive(Debug, Clone, PartialEq)]
enum OrderedJson {
    Null,
    Bool(bool),
    Int(i64),
    /// A whole number beyond `i64::MAX`: TOML cannot hold it.
    Big(u64),
    Float(f64),
    Str(String),
    Array(Vec<Self>),
    /// Keys in the client's order; a key given twice keeps its first place and its last value.
    Object(Vec<(String, Self)>),
}

impl OrderedJson {
    /// What the value is, for messages: `the number 30.5`, `a string`, ...
    fn kind(&self) -> String {
        match self {
            Self::Null => "null".to_owned(),
            Self::Bool(b) => format!("the bare value {b}"),
            Self::Int(i) => format!("the bare number {i}"),
            Self::Big(u) => format!("the bare number {u}"),
            Self::Float(f) => format!("the bare number {f}"),
            Self::Str(_) => "a bare string".to_owned(),
            Self::Array(_) => "an array".to_owned(),
            Self::Object(_) => "an object".to_owned(),
        }
    }
}

impl<'de> Deserialize<'de> for OrderedJson {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(OrderedJsonVisitor)
    }
}

struct OrderedJsonVisitor;

impl<'de> Visitor<'de> for OrderedJsonVisitor {
    type Value = OrderedJson;

    fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("a JSON value")
    }

    fn visit_unit<E>(self) -> Result<OrderedJson, E> {
        Ok(OrderedJson::Null)
    }

    fn visit_none<E>(self) -> Result<OrderedJson, E> {
        Ok(OrderedJson::Null)
    }

    fn visit_bool<E>(self, v: bool) -> Result<OrderedJson, E> {
        Ok(OrderedJson::Bool(v))
    }

    fn visit_i64<E>(self, v: i64) -> Result<OrderedJson, E> {
        Ok(OrderedJson::Int(v))
    }

    fn visit_u64<E>(self, v: u64) -> Result<OrderedJson, E> {
        Ok(i64::try_from(v).map_or(OrderedJson::Big(v), OrderedJson::Int))
    }

    fn visit_f64<E>(self, v: f64) -> Result<OrderedJson, E> {
        Ok(OrderedJson::Float(v))
    }

    fn visit_str<E>(self, v: &str) -> Result<OrderedJson, E> {
        Ok(OrderedJson::Str(v.to_owned()))
    }

    fn visit_string<E>(self, v: String) -> Result<OrderedJson, E> {
        Ok(OrderedJson::Str(v))
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<OrderedJson, A::Error> {
        let mut items = Vec::new();
        while let Some(item) = seq.next_element()? {
            items.push(item);
        }
        Ok(OrderedJson::Array(items))
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<OrderedJson, A::Error> {
        let mut entries: Vec<(String, OrderedJson)> = Vec::new();
        while let Some((key, value)) = map.next_entry::<String, OrderedJson>()? {
            match entries.iter_mut().find(|(k, _)| *k == key) {
                Some(slot) => slot.1 = value,
                None => entries.push((key, value)),
            }
        }
        Ok(OrderedJson::Object(entries))
    }
}

/// `path.key`, or `key` at the root.
fn child_path(path: &str, key: &str) -> String {
    if path.is_empty() {
        key.to_owned()
    } else {
        format!("{path}.{key}")
    }
}

/// A JSON object as a TOML table laid out as an operator writes one: objects as `[tables]`,
/// arrays of objects that hold tables as `[[arrays of tables]]`, other arrays (the `ranges` of a
/// poll group) inline; issues at the paths TOML cannot hold.
fn json_table(
    entries: Vec<(String, OrderedJson)>,
    path: &str,
    issues: &mut Vec<Issue>,
) -> toml_edit::Table {
    let mut table = toml_edit::Table::new();
    for (key, value) in entries {
        let at = child_path(path, &key);
        let item = match value {
            OrderedJson::Object(entries) => {
                let child = json_table(entries, &at, issues);
                Some(toml_edit::Item::Table(child))
            }
            OrderedJson::Array(items) if holds_tables(&items) => {
                let mut tables = toml_edit::ArrayOfTables::new();
                for (i, item) in items.into_iter().enumerate() {
                    if let OrderedJson::Object(entries) = item {
                        tables.push(json_table(entries, &format!("{at}[{i}]"), issues));
                    }
                }
                Some(toml_edit::Item::ArrayOfTables(tables))
            }
            other => json_value(other, &at, issues).map(toml_edit::Item::Value),
        };
        if let Some(item) = item {
            table.insert(&key, item);
        }
    }
    // A table of tables only (`[lines]`, `devices`) gets no header of its own.
    let only_tables = !table.is_empty() && table.iter().all(|(_, item)| !item.is_value());
    table.set_implicit(only_tables);
    table
}

/// Whether an array is one of objects that hold objects or arrays of them (poll groups, not
/// ranges).
fn holds_tables(items: &[OrderedJson]) -> bool {
    !items.is_empty()
        && items.iter().all(|item| match item {
            OrderedJson::Object(entries) => entries.iter().any(|(_, v)| {
                matches!(v, OrderedJson::Object(_))
                    || matches!(v, OrderedJson::Array(a) if a.iter().any(|x| matches!(x, OrderedJson::Object(_))))
            }),
            _ => false,
        })
}

/// A JSON value as an inline TOML value, or an issue at `path`.
fn json_value(value: OrderedJson, path: &str, issues: &mut Vec<Issue>) -> Option<toml_edit::Value> {
    let mut issue = |message: &str| {
        issues.push(Issue {
            path: path.to_owned(),
            message: message.to_owned(),
        });
        None
    };
    match value {
        OrderedJson::Null => {
            issue("null is not a value here: leave the key out to take its default")
        }
        OrderedJson::Bool(b) => Some(b.into()),
        OrderedJson::Int(i) => Some(i.into()),
        OrderedJson::Big(_) => issue("integer too large (at most 9223372036854775807)"),
        OrderedJson::Float(f) => Some(f.into()),
        OrderedJson::Str(s) => Some(s.into()),
        OrderedJson::Array(items) => {
            let mut array = toml_edit::Array::new();
            for (i, item) in items.into_iter().enumerate() {
                if let Some(v) = json_value(item, &format!("{path}[{i}]"), issues) {
                    array.push(v);
                }
            }
            Some(array.into())
        }
        OrderedJson::Object(entries) => {
            let mut table = toml_edit::InlineTable::new();
            for (key, item) in entries {
                let at = child_path(path, &key);
                if let Some(v) = json_value(item, &at, issues) {
                    table.insert(&key, v);
                }
            }
            Some(table.into())
        }
    }
}

// === TOML shown as JSON, in the file's order ===

/// A TOML item as JSON with the keys in the document's order (dates as strings).
pub(crate) struct JsonView<'a>(pub(crate) &'a toml_edit::Item);

impl Serialize for JsonView<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self.0 {
            toml_edit::Item::None => s.serialize_unit(),
            toml_edit::Item::Value(v) => ValueView(v).serialize(s),
            toml_edit::Item::Table(t) => TableView(t).serialize(s),
            toml_edit::Item::ArrayOfTables(tables) => {
                s.collect_seq(tables.iter().map(|t| TableView(t)))
            }
        }
    }
}

/// A table as a JSON object (see [`JsonView`]).
pub(crate) struct TableView<'a>(pub(crate) &'a dyn toml_edit::TableLike);

impl Serialize for TableView<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_map(
            self.0
                .iter()
                .filter(|(_, item)| !item.is_none())
                .map(|(k, item)| (k, JsonView(item))),
        )
    }
}

struct ValueView<'a>(&'a toml_edit::Value);

impl Serialize for ValueView<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use toml_edit::Value as V;
        match self.0 {
            V::String(v) => s.serialize_str(v.value()),
            V::Integer(v) => s.serialize_i64(*v.value()),
            V::Float(v) => s.serialize_f64(*v.value()),
            V::Boolean(v) => s.serialize_bool(*v.value()),
            V::Datetime(v) => s.collect_str(v.value()),
            V::Array(a) => s.collect_seq(a.iter().map(ValueView)),
            V::InlineTable(t) => s.collect_map(t.iter().map(|(k, v)| (k, ValueView(v)))),
        }
    }
}

// === typed JSON bodies ===

/// The JSON body of an endpoint that takes one object, with an example of it for the messages
/// of a body that is refused.
pub(crate) trait JsonBody: DeserializeOwned {
    /// A body the endpoint takes.
    const EXAMPLE: &'static str;
}

impl JsonBody for TagWrite {
    const EXAMPLE: &'static str = r#"{"value": 30.5}"#;
}

impl JsonBody for SendRequest {
    const EXAMPLE: &'static str = r#"{"text": "HELLO"} or {"hex": "02 41 42 03"}"#;
}

impl JsonBody for SignalsPatch {
    const EXAMPLE: &'static str = r#"{"dtr": true, "rts": false}"#;
}

/// Whether `Content-Type` says JSON.
pub(crate) fn says_json(headers: &HeaderMap) -> bool {
    headers.contains_key(header::CONTENT_TYPE)
        && matches!(content_format(headers), Ok(Format::Json))
}

/// 415 unless `Content-Type` says JSON.
pub(crate) fn require_json<T: JsonBody>(headers: &HeaderMap) -> Result<(), ApiError> {
    if says_json(headers) {
        Ok(())
    } else {
        Err(ApiError::unsupported_media_type(format!(
            "expected Content-Type: application/json and a JSON object like {}",
            T::EXAMPLE
        )))
    }
}

/// The body as `T`: 400 when it is not JSON, 422 when it is JSON but not `T`; every message
/// names what the endpoint takes (`expected a JSON object like {"value": 30.5}, not the bare
/// number 30.5`) and, for a key, where it is.
pub(crate) fn json<T: JsonBody>(body: &[u8]) -> Result<T, ApiError> {
    let expected = format!("a JSON object like {}", T::EXAMPLE);
    let value: serde_json::Value = serde_json::from_slice(body)
        .map_err(|e| ApiError::bad_request(not_json(body, &e, &expected)))?;
    if !value.is_object() {
        let kind = match &value {
            serde_json::Value::Null => "null".to_owned(),
            serde_json::Value::Bool(b) => format!("the bare value {b}"),
            serde_json::Value::Number(n) => format!("the bare number {n}"),
            serde_json::Value::String(_) => "a bare string".to_owned(),
            serde_json::Value::Array(_) => "an array".to_owned(),
            serde_json::Value::Object(_) => "an object".to_owned(),
        };
        return Err(ApiError::invalid_body(format!(
            "expected {expected}, not {kind}"
        )));
    }
    serde_path_to_error::deserialize(value).map_err(|e| {
        let path = e.path().to_string();
        let what = readable_serde(&e.inner().to_string());
        let at = if path == "." {
            String::new()
        } else {
            format!("{path}: ")
        };
        ApiError::invalid_body(format!("{at}{what}; expected {expected}"))
    })
}

/// A serde message without the Rust type names a client cannot act on.
fn readable_serde(message: &str) -> String {
    if message.contains("untagged enum ScalarValue") {
        return "not a number, true/false or a string".to_owned();
    }
    message
        .replace("struct ", "")
        .replace("a sequence", "an array")
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
    use crate::plant::no_check;

    #[test]
    fn json_and_toml_give_the_same_config() {
        let demo = crate::plant::demo();
        let json = serde_json::to_vec(&demo).unwrap();
        assert_eq!(
            config(Format::Json, &json, &no_check, &Config::default()).unwrap(),
            demo
        );
        let toml_text = toml::to_string(&demo).unwrap();
        assert_eq!(
            config(
                Format::Toml,
                toml_text.as_bytes(),
                &no_check,
                &Config::default()
            )
            .unwrap(),
            demo
        );
        assert_eq!(
            etag(&demo),
            etag(&config(Format::Json, &json, &no_check, &Config::default()).unwrap())
        );
    }

    fn table(format: Format, body: &[u8]) -> Result<toml::Table, ApiError> {
        document(format, body, "a test document").map(|d| d.table)
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
    fn a_json_body_becomes_toml_in_the_clients_order_laid_out_as_an_operator_writes_it() {
        let body = br#"{"port": "/dev/ttyS1", "protocol": "modbus-master-rtu", "baud": 9600,
            "devices": {"drive": {"profile": "altivar71", "address": 2,
              "poll": [{"name": "status", "period": "1s",
                        "ranges": [{"table": "holding", "start": 3201, "count": 9}]}]}}}"#;
        let d = document(Format::Json, body, "x").unwrap();
        assert_eq!(
            d.doc.to_string(),
            "port = \"/dev/ttyS1\"\nprotocol = \"modbus-master-rtu\"\nbaud = 9600\n\n\
             [devices.drive]\nprofile = \"altivar71\"\naddress = 2\n\n\
             [[devices.drive.poll]]\nname = \"status\"\nperiod = \"1s\"\n\
             ranges = [{ table = \"holding\", start = 3201, count = 9 }]\n"
        );
        assert_eq!(
            d.table["devices"]["drive"]["poll"][0]["ranges"][0]["count"].as_integer(),
            Some(9)
        );
        // A key given twice keeps its place and takes its last value.
        let d = document(Format::Json, br#"{"b": 1, "a": 2, "b": 3}"#, "x").unwrap();
        assert_eq!(d.doc.to_string(), "b = 3\na = 2\n");
    }

    #[test]
    fn bodies_that_are_not_what_an_endpoint_takes_say_what_it_takes() {
        let e = json::<TagWrite>(b"30.5").unwrap_err();
        assert_eq!((e.status().as_u16(), e.code()), (422, "invalid_body"));
        assert_eq!(
            e.message(),
            r#"expected a JSON object like {"value": 30.5}, not the bare number 30.5"#
        );
        let e = json::<TagWrite>(b"{\"value\": 30.5").unwrap_err();
        assert_eq!(e.code(), "bad_request");
        assert!(
            e.message().starts_with("the body is not JSON ("),
            "{}",
            e.message()
        );
        assert!(e
            .message()
            .ends_with(r#"send a JSON object like {"value": 30.5}"#));
        let e = json::<TagWrite>(b"").unwrap_err();
        assert_eq!(
            e.message(),
            r#"the body is empty: send a JSON object like {"value": 30.5}"#
        );
        let e = json::<TagWrite>(br#"{"value": [1]}"#).unwrap_err();
        assert_eq!(
            e.message(),
            r#"value: not a number, true/false or a string; expected a JSON object like {"value": 30.5}"#
        );
        let e = json::<SignalsPatch>(br#"{"dtr": "on"}"#).unwrap_err();
        assert!(
            e.message()
                .starts_with("dtr: invalid type: string \"on\", expected a boolean"),
            "{}",
            e.message()
        );
        let e = json::<SendRequest>(br#"["02 03"]"#).unwrap_err();
        assert!(e.message().ends_with("not an array"), "{}", e.message());
        for message in [
            json::<TagWrite>(b"30.5").unwrap_err().message().to_owned(),
            json::<SendRequest>(b"true")
                .unwrap_err()
                .message()
                .to_owned(),
            json::<SignalsPatch>(b"{\"x\": 1}")
                .unwrap_err()
                .message()
                .to_owned(),
        ] {
            assert!(
                !message.contains("struct") && !message.contains("Failed to"),
                "{message}"
            );
        }
        // A configuration body that is not an object says what a configuration looks like.
        let e = config(Format::Json, b"30.5", &no_check, &Config::default()).unwrap_err();
        assert!(
            e.issues()[0]
                .message
                .starts_with("expected a JSON object with the configuration's tables"),
            "{e}"
        );
        assert!(
            e.issues()[0].message.ends_with("not the bare number 30.5"),
            "{e}"
        );
    }

    #[test]
    fn the_overrides_a_get_showed_are_left_out_of_a_config_body() {
        let demo = crate::plant::demo();
        let mut json = serde_json::to_value(&demo).unwrap();
        json["overrides"] = serde_json::json!([{"key": "http.listen", "in_force": "127.0.0.1:1"}]);
        let body = serde_json::to_vec(&json).unwrap();
        assert_eq!(
            config(Format::Json, &body, &no_check, &Config::default()).unwrap(),
            demo
        );
        let text = format!(
            "{OVERRIDES_BANNER}\n#   http.listen = \"127.0.0.1:1\"   (--http 127.0.0.1:0)\n\n{}",
            toml::to_string(&demo).unwrap()
        );
        let (read, doc) =
            config_document(Format::Toml, text.as_bytes(), &no_check, &Config::default()).unwrap();
        assert_eq!(read, demo);
        assert!(!doc.doc.to_string().contains("--http"), "{}", doc.doc);
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
