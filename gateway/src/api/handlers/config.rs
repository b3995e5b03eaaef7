//! `/api/v1/config`: read, replace and validate the configuration, or one line of it.
//!
//! What is shown and written is the configuration as its operator wrote it ([`ConfigText`]): a
//! read answers the file's keys (no defaults), with the command line's listeners beside them
//! (`overrides`, never in the file); a change merges the client's document into the file, so a
//! value that keeps its meaning keeps its spelling and a new key is written as sent.
//!
//! A change is validated whole (the configuration's own rules, then the backend's), written to
//! the configuration file atomically, and then applied; changes run one at a time. `If-Match`
//! with the `ETag` of `GET /config` makes a change conditional on the version it was made from.
//! A change keeps running when the client goes away or the request times out: a configuration
//! is never half persisted or half applied because of the HTTP side.

// utoipa's expansion of responses with `headers(...)` names the body types by their full path.
#![allow(unused_qualifications)]

use axum::body::Bytes;
use axum::extract::{FromRequest, Request, State};
use axum::http::{header, HeaderMap, HeaderValue};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Json};
use utoipa::openapi::schema::{ArrayBuilder, ObjectBuilder, Schema, Type};
use utoipa::openapi::RefOr;
use utoipa::{PartialSchema, ToSchema};

use super::{audit, caller_of, ApiPath};
use crate::api::auth::Caller;
use crate::api::body::{self, JsonView, TOML_MEDIA_TYPE};
use crate::api::error::{ApiError, ErrorBody, Issue};
use crate::api::model::{ConfigChangeResult, ConfigOverride, ValidationResult};
use crate::api::{ApiBackend, ApiState};
use crate::audit::WriteResult;
use crate::persist::edit;
use crate::persist::ConfigText;
use crate::plant::Config;
use toml_edit::DocumentMut;

/// The configuration as JSON: the TOML file's tables and keys (see
/// `deploy/gateway.example.toml`). Also accepted and returned as TOML (`application/toml`).
pub(crate) struct ConfigDocument;

impl PartialSchema for ConfigDocument {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::Object)
            .description(Some(
                "The gateway configuration: the TOML file's tables ([gateway], [modbus_tcp], \
                 [lines.<name>] ...) as a JSON object. Keys left out take their defaults. GET \
                 answers the keys the file gives, in its order (no defaults written in), and \
                 `overrides`; a PUT changes only what it changes in meaning: a value the file \
                 already had keeps the file's spelling (0x0D stays 0x0D), new keys are written \
                 as sent, in the order sent, and a PUT of what GET answered leaves the file byte \
                 for byte. As TOML, GET answers the file's text (comments included), with the \
                 overrides as a leading comment.",
            ))
            .property(
                body::OVERRIDES_KEY,
                ArrayBuilder::new()
                    .items(ConfigOverride::schema())
                    .description(Some(
                        "Answers only: settings given on the command line (--modbus-tcp, --http, \
                         --zenoh-listen) that are in force in place of the keys named, with what \
                         runs (the port bound for port 0). Not part of the configuration: a PUT \
                         or validate body may carry it and it is left out, so the file keeps its \
                         own values.",
                    )),
            )
            .into()
    }
}
impl ToSchema for ConfigDocument {}

/// The configuration as a request body: [`ConfigDocument`] without `overrides`, which only
/// answers carry (a body that has it, as GET gave it, has it left out).
pub(crate) struct ConfigBody;

impl PartialSchema for ConfigBody {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::Object)
            .description(Some(
                "The gateway configuration: the TOML file's tables ([gateway], [modbus_tcp], \
                 [lines.<name>] ...) as a JSON object. Keys left out take their defaults. A PUT \
                 changes only what it changes in meaning: a value the file already had keeps the \
                 file's spelling (0x0D stays 0x0D), new keys are written as sent, in the order \
                 sent, and a PUT of what GET answered leaves the file byte for byte (the \
                 `overrides` a GET answered are left out).",
            ))
            .into()
    }
}
impl ToSchema for ConfigBody {}

/// One line's table `[lines.<name>]` as JSON (`port`, `protocol`, serial settings, the
/// protocol's parameters, `devices`).
pub(crate) struct LineDocument;

impl PartialSchema for LineDocument {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::Object)
            .description(Some(
                "One line's table [lines.<name>] as a JSON object: port, protocol, serial \
                 settings, the protocol's parameters and, for Modbus masters, devices. GET \
                 answers the keys the file gives, in its order; a PUT writes the keys sent, in \
                 the order sent, and keeps the file's spelling of values it does not change.",
            ))
            .into()
    }
}
impl ToSchema for LineDocument {}

/// The request body as bytes; over the limit answers 413.
pub(crate) struct ApiBytes(Bytes);

impl<S: Send + Sync> FromRequest<S> for ApiBytes {
    type Rejection = ApiError;

    async fn from_request(req: Request, state: &S) -> Result<Self, Self::Rejection> {
        Bytes::from_request(req, state)
            .await
            .map(Self)
            .map_err(|e| body::read_error(e.status(), &e.body_text()))
    }
}

/// The whole configuration in force.
#[utoipa::path(
    get,
    path = "/config",
    tag = "config",
    responses(
        (status = 200, description = "The configuration as the file gives it, with the command line's `overrides` (the file's TOML text with `Accept: application/toml`)",
         body = ConfigDocument, headers(("ETag" = String, description = "The configuration's version"))),
    )
)]
pub(crate) async fn get_config(State(state): State<ApiState>, headers: HeaderMap) -> Response {
    let backend = state.backend();
    let config = backend.config();
    let etag = body::etag(&config);
    let text = state.document(&config);
    let overrides = backend.overrides();
    let mut response = if body::wants_toml(&headers) {
        let mut answer = overrides_comment(&overrides);
        answer.push_str(&text.text());
        ([(header::CONTENT_TYPE, TOML_MEDIA_TYPE)], answer).into_response()
    } else {
        Json(ConfigView {
            doc: &text.document(),
            overrides: &overrides,
        })
        .into_response()
    };
    set_etag(&mut response, &etag);
    response
}

/// The JSON answer of `GET /config`: the document's tables in its order, then `overrides`.
struct ConfigView<'a> {
    doc: &'a toml_edit::DocumentMut,
    overrides: &'a [ConfigOverride],
}

impl serde::Serialize for ConfigView<'_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut map = s.serialize_map(None)?;
        for (key, item) in self.doc.iter() {
            if !item.is_none() {
                map.serialize_entry(key, &JsonView(item))?;
            }
        }
        map.serialize_entry(body::OVERRIDES_KEY, self.overrides)?;
        map.end()
    }
}

/// The comment a TOML answer starts with when settings of the command line are in force.
fn overrides_comment(overrides: &[ConfigOverride]) -> String {
    if overrides.is_empty() {
        return String::new();
    }
    let mut text = format!("{}\n", body::OVERRIDES_BANNER);
    for o in overrides {
        text.push_str(&format!(
            "#   {} = {:?}   ({} {})\n",
            o.key, o.in_force, o.option, o.given
        ));
        if let Some(note) = &o.note {
            text.push_str(&format!("#     {note}\n"));
        }
    }
    text.push('\n');
    text
}

/// Replaces the whole configuration.
#[utoipa::path(
    put,
    path = "/config",
    tag = "config",
    request_body(content(
        (ConfigBody = "application/json"),
        (String = "application/toml")
    )),
    params(("If-Match" = Option<String>, Header, description = "Apply only if the configuration in force has this ETag")),
    responses(
        (status = 200, description = "Validated, persisted and applied", body = ConfigChangeResult,
         headers(("ETag" = String, description = "The new configuration's version"))),
        (status = 412, description = "If-Match does not name the configuration in force", body = ErrorBody),
        (status = 422, description = "Every problem of the configuration, each with its path", body = ErrorBody),
    )
)]
pub(crate) async fn put_config(
    State(state): State<ApiState>,
    caller: Option<Extension<Caller>>,
    headers: HeaderMap,
    ApiBytes(bytes): ApiBytes,
) -> Result<Response, ApiError> {
    let audit = Audit::new(caller, "config: replace".to_owned());
    let backend = state.backend();
    let new = body::content_format(&headers).and_then(|format| {
        body::config_document(
            format,
            &bytes,
            &|c, found| backend.config_issues(c, found),
            &backend.config(),
        )
    });
    let (new, sent) = audit.early(&state, new)?;
    change(state, &headers, audit, move |current, backend| {
        // The file is made to say what the body says; what it already said stays as written.
        let mut doc = current.document();
        edit::merge_table(doc.as_table_mut(), false, sent.doc.as_table());
        // The merged file says what the body said (read above); read again only if not.
        let new = if edit::plain_table(doc.as_table()) == sent.table {
            new
        } else {
            body::from_document(&doc, backend)?
        };
        Ok((new, doc))
    })
    .await
}

/// Validates a configuration without applying it.
#[utoipa::path(
    post,
    path = "/config/validate",
    tag = "config",
    request_body(content(
        (ConfigBody = "application/json"),
        (String = "application/toml")
    )),
    responses(
        (status = 200, description = "The configuration is valid", body = ValidationResult),
        (status = 422, description = "Every problem of the configuration, each with its path", body = ErrorBody),
    )
)]
pub(crate) async fn validate_config(
    State(state): State<ApiState>,
    headers: HeaderMap,
    ApiBytes(bytes): ApiBytes,
) -> Result<Json<ValidationResult>, ApiError> {
    let backend = state.backend();
    let config = body::config(
        body::content_format(&headers)?,
        &bytes,
        &|c, found| backend.config_issues(c, found),
        &backend.config(),
    )?;
    state.backend().validate(&config).map_err(backend_issues)?;
    Ok(Json(ValidationResult {
        valid: true,
        lines: config.lines.len(),
        devices: config.device_count(),
    }))
}

/// One line's configuration.
#[utoipa::path(
    get,
    path = "/config/lines/{line}",
    tag = "config",
    params(("line" = String, Path, description = "The line's name")),
    responses(
        (status = 200, description = "The line's table", body = LineDocument,
         headers(("ETag" = String, description = "The whole configuration's version"))),
        (status = 404, description = "No such line", body = ErrorBody),
    )
)]
pub(crate) async fn get_line_config(
    State(state): State<ApiState>,
    ApiPath(line): ApiPath<String>,
) -> Result<Response, ApiError> {
    let config = state.backend().config();
    if !config.lines.contains_key(&line) {
        return Err(ApiError::not_found("line", &line));
    }
    let doc = state.document(&config).document();
    let mut response = match doc.get("lines").and_then(|lines| lines.get(&line)) {
        Some(item) => Json(JsonView(item)).into_response(),
        None => Json(&config.lines[&line]).into_response(),
    };
    set_etag(&mut response, &body::etag(&config));
    Ok(response)
}

/// Replaces (or adds) one line; the other lines keep running untouched.
#[utoipa::path(
    put,
    path = "/config/lines/{line}",
    tag = "config",
    params(
        ("line" = String, Path, description = "The line's name"),
        ("If-Match" = Option<String>, Header, description = "Apply only if the configuration in force has this ETag"),
    ),
    request_body(content(
        (LineDocument = "application/json"),
        (String = "application/toml")
    )),
    responses(
        (status = 200, description = "Validated, persisted and applied", body = ConfigChangeResult,
         headers(("ETag" = String, description = "The new configuration's version"))),
        (status = 412, description = "If-Match does not name the configuration in force", body = ErrorBody),
        (status = 422, description = "Every problem, with paths under lines.<line>", body = ErrorBody),
    )
)]
pub(crate) async fn put_line_config(
    State(state): State<ApiState>,
    caller: Option<Extension<Caller>>,
    ApiPath(line): ApiPath<String>,
    headers: HeaderMap,
    ApiBytes(bytes): ApiBytes,
) -> Result<Response, ApiError> {
    let audit = Audit::new(caller, format!("config: replace lines.{line}"));
    let sent = body::content_format(&headers)
        .and_then(|format| body::document(format, &bytes, body::LINE_EXPECTED));
    let sent = audit.early(&state, sent)?;
    change(state, &headers, audit, move |current, backend| {
        let mut doc = current.document();
        let lines = doc
            .entry("lines")
            .or_insert_with(|| toml_edit::Item::Table(implicit_table()));
        let mut table = sent.doc.as_table().clone();
        // The body's own document is not a table of the file: its header is the file's.
        table.decor_mut().clear();
        table.set_implicit(false);
        let item = toml_edit::Item::Table(table);
        match lines.get_mut(&line) {
            Some(existing) if !existing.is_none() => edit::merge_item(existing, &item),
            _ => {
                let Some(lines) = lines.as_table_like_mut() else {
                    return Err(ApiError::conflict(
                        "the configuration file's `lines` is not a table: edit the file",
                    ));
                };
                lines.insert(&line, item);
            }
        }
        let new = body::from_document(&doc, backend)?;
        Ok((new, doc))
    })
    .await
}

/// A table that only holds tables (no header of its own).
fn implicit_table() -> toml_edit::Table {
    let mut t = toml_edit::Table::new();
    t.set_implicit(true);
    t
}

/// Removes one line and stops it.
#[utoipa::path(
    delete,
    path = "/config/lines/{line}",
    tag = "config",
    params(
        ("line" = String, Path, description = "The line's name"),
        ("If-Match" = Option<String>, Header, description = "Apply only if the configuration in force has this ETag"),
    ),
    responses(
        (status = 200, description = "Persisted and applied", body = ConfigChangeResult,
         headers(("ETag" = String, description = "The new configuration's version"))),
        (status = 404, description = "No such line", body = ErrorBody),
        (status = 412, description = "If-Match does not name the configuration in force", body = ErrorBody),
        (status = 422, description = "The configuration without the line is not valid", body = ErrorBody),
    )
)]
pub(crate) async fn delete_line_config(
    State(state): State<ApiState>,
    caller: Option<Extension<Caller>>,
    ApiPath(line): ApiPath<String>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let audit = Audit::new(caller, format!("config: remove lines.{line}"));
    change(state, &headers, audit, move |current, _| {
        if !current.config().lines.contains_key(&line) {
            return Err(ApiError::not_found("line", &line));
        }
        let mut doc = current.document();
        if let Some(lines) = doc.get_mut("lines").and_then(|l| l.as_table_like_mut()) {
            lines.remove(&line);
        }
        // Rules across lines (unit ids, ports) still hold after a removal, but run them anyway.
        let new = body::from_document_unchecked(&doc)?;
        Ok((new, doc))
    })
    .await
}

/// Who asked for a configuration change and what it was, for the audit trail.
struct Audit {
    caller: Caller,
    target: String,
}

impl Audit {
    fn new(caller: Option<Extension<Caller>>, target: String) -> Self {
        Self {
            caller: caller_of(caller),
            target,
        }
    }

    /// Audits a request refused before the change ran (a body that does not parse).
    fn early<T>(&self, state: &ApiState, result: Result<T, ApiError>) -> Result<T, ApiError> {
        if result.is_err() {
            audit(state, &self.caller, &self.target, &result);
        }
        result
    }
}

/// What a change makes of the configuration in force (as written): the new configuration and
/// the document that reads as it.
type Edit =
    Box<dyn FnOnce(&ConfigText, &dyn ApiBackend) -> Result<(Config, DocumentMut), ApiError> + Send>;

/// Runs a change to completion in its own task: lock, `If-Match`, edit, validate, persist,
/// apply, audit. The task goes on if the request is dropped (timeout, client gone).
async fn change<F>(
    state: ApiState,
    headers: &HeaderMap,
    who: Audit,
    edit: F,
) -> Result<Response, ApiError>
where
    F: FnOnce(&ConfigText, &dyn ApiBackend) -> Result<(Config, DocumentMut), ApiError>
        + Send
        + 'static,
{
    let if_match = headers.clone();
    let edit: Edit = Box::new(edit);
    let task = crate::task::spawn("rest config change", async move {
        let result = change_in_task(&state, &if_match, edit).await;
        match &result {
            Ok(r) => state.backend().audit(
                &who.caller,
                &who.target,
                WriteResult::Accepted,
                &format_args!("etag {}", r.etag),
            ),
            Err(_) => audit(&state, &who.caller, &who.target, &result),
        }
        result
    });
    let result = task.await;
    // What the change read and merged (whole documents) goes back to the system.
    crate::heap::release_free_memory();
    let result =
        result.map_err(|e| ApiError::internal(format!("the change task failed: {e}")))??;
    let mut response = Json(&result).into_response();
    set_etag(&mut response, &result.etag);
    Ok(response)
}

/// The steps of [`change`] in its task.
async fn change_in_task(
    state: &ApiState,
    if_match: &HeaderMap,
    edit: Edit,
) -> Result<ConfigChangeResult, ApiError> {
    let _one_at_a_time = state.change_lock().lock().await;
    let backend = state.backend();
    let current = backend.config();
    if !body::if_match_admits(if_match, &body::etag(&current)) {
        return Err(ApiError::precondition_failed(
            "the configuration changed since it was read (If-Match)",
        ));
    }
    let written = state.document(&current);
    let (new, doc) = edit(&written, backend.as_ref())?;
    backend.validate(&new).map_err(backend_issues)?;
    let etag = body::etag(&new);
    let persisted = state.store().is_some();
    if new == *current {
        // Nothing that means anything changed: the file stays byte for byte.
        return Ok(ConfigChangeResult {
            etag,
            persisted,
            applied: Default::default(),
        });
    }
    let new = std::sync::Arc::new(new);
    let text = ConfigText::edited(&doc, std::sync::Arc::clone(&new));
    if let Some(store) = state.store() {
        let to_save = text.text();
        tokio::task::spawn_blocking(move || store.save_atomic(&to_save))
            .await
            .map_err(|e| ApiError::internal(format!("the save task failed: {e}")))?
            .map_err(|e| {
                ApiError::persist_failed(format!(
                    "the configuration is valid but was not saved, so it was not applied: {e}; \
                     check that the gateway may write the file and its directory"
                ))
            })?;
        tracing::info!(file = %state.store().map(|s| s.path().display().to_string()).unwrap_or_default(), %etag, "configuration saved");
    }
    state.set_document(&text);
    let applied = backend.apply(new).await?;
    tracing::info!(%etag, ?applied, "configuration applied");
    Ok(ConfigChangeResult {
        etag,
        persisted,
        applied,
    })
}

fn backend_issues(issues: Vec<crate::config::ConfigIssue>) -> ApiError {
    ApiError::validation(issues.into_iter().map(Issue::from).collect())
}

fn set_etag(response: &mut Response, etag: &str) {
    if let Ok(v) = HeaderValue::from_str(etag) {
        response.headers_mut().insert(header::ETAG, v);
    }
}
