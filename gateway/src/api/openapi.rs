//! The OpenAPI document, generated from the handlers' `#[utoipa::path]` attributes and the
//! models' `ToSchema` derives as the router is built ([`super::routes`]), so the document lists
//! exactly the routes the router serves.
//!
//! A modifier adds what every operation shares and the middleware guarantees: the bearer
//! security scheme and the 401 answer on every change, 403 everywhere (a foreign `Host`; on a
//! change also a foreign `Origin` and what the token's role lacks), 413/415 on every body, and
//! the timeout and internal-error answers everywhere, all in the one error shape.

use utoipa::openapi::path::{Operation, PathItem};
use utoipa::openapi::response::ResponseBuilder;
use utoipa::openapi::security::{Http, HttpAuthScheme, SecurityRequirement, SecurityScheme};
use utoipa::openapi::{ContentBuilder, OpenApi as OpenApiDoc, Ref, RefOr};
use utoipa::{Modify, OpenApi};

use super::auth::AuthMode;
use super::error::{ErrorBody, ErrorDetail, Issue};
use super::handlers::BEARER;

/// The document's fixed part; the paths come from the router.
#[derive(OpenApi)]
#[openapi(
    info(
        title = "CP 341 gateway",
        description = "Configuration, status, diagnostics, telegrams, tags and RS232 signals of the \
                       serial gateway. Changes (PUT, POST, DELETE) need `Authorization: Bearer <token>`. \
                       Every error answers `{\"error\": {\"code\", \"message\", \"issues\"?}}`."
    ),
    components(schemas(ErrorBody, ErrorDetail, Issue)),
    tags(
        (name = "config", description = "Read, replace and validate the configuration"),
        (name = "status", description = "The gateway"),
        (name = "lines", description = "Line status, diagnostic buffer, RS232 signals, frame monitor and captures"),
        (name = "telegrams", description = "Received telegrams and sending (ASCII, 3964(R))"),
        (name = "tags", description = "Device values by name"),
        (name = "health", description = "Liveness and readiness"),
        (name = "meta", description = "This document"),
    ),
    modifiers(&CommonAnswers)
)]
pub(crate) struct ApiDoc;

/// Adds the bearer scheme and the answers every operation shares.
struct CommonAnswers;

impl Modify for CommonAnswers {
    fn modify(&self, doc: &mut OpenApiDoc) {
        doc.components
            .get_or_insert_with(Default::default)
            .add_security_scheme(
                BEARER,
                SecurityScheme::Http(Http::new(HttpAuthScheme::Bearer)),
            );
    }
}

/// Completes the document once every route is in it (the derive's modifiers run before the
/// router adds its paths), for a server whose changes need the token.
pub(crate) fn finish(doc: OpenApiDoc) -> OpenApiDoc {
    finish_for(doc, AuthMode::Token)
}

/// Completes the document for a server whose changes are guarded as `mode` says, so that it
/// describes what that server answers: with tokens, changes need one (401 without it, 403 when
/// its role lacks the right); locked, every change answers 403; insecure, changes need nothing
/// and neither 401 nor 403 is answered.
pub(crate) fn finish_for(mut doc: OpenApiDoc, mode: AuthMode) -> OpenApiDoc {
    for (path, item) in doc.paths.paths.iter_mut() {
        let health = super::places::is_health_path(path);
        for (changes, op) in operations(item) {
            common_answers(op, changes, mode);
            if !health {
                op.responses
                    .responses
                    .entry("503".to_owned())
                    .or_insert_with(|| {
                        error_response(
                            "No connection place for the client now (every place of its address, \
                             [http] max_connections_per_client, or of the listener, \
                             max_connections, is taken; only /metrics, /healthz and /readyz are \
                             served then); try again after Retry-After seconds",
                        )
                    });
            }
        }
    }
    if mode == AuthMode::Insecure {
        if let Some(components) = doc.components.as_mut() {
            components.security_schemes.remove(BEARER);
        }
    }
    doc
}

fn operations(item: &mut PathItem) -> Vec<(bool, &mut Operation)> {
    let mut ops = Vec::new();
    for (changes, op) in [
        (false, &mut item.get),
        (false, &mut item.head),
        (true, &mut item.put),
        (true, &mut item.post),
        (true, &mut item.delete),
        (true, &mut item.patch),
    ] {
        if let Some(op) = op.as_mut() {
            ops.push((changes, op));
        }
    }
    ops
}

fn common_answers(op: &mut Operation, changes: bool, mode: AuthMode) {
    let has_parameters = op.parameters.as_ref().is_some_and(|p| !p.is_empty());
    let mut add = |status: &str, description: &str| {
        op.responses
            .responses
            .entry(status.to_owned())
            .or_insert_with(|| error_response(description));
    };
    if changes && mode == AuthMode::Token {
        add(
            "401",
            "No token, another scheme, or a wrong token (WWW-Authenticate says which)",
        );
    }
    // 403: a foreign Host on any request, a foreign Origin on a change (every mode, the
    // insecure one too), and what the token's mode refuses.
    let mut forbidden = vec![
        "The Host is not a name of this listener (an IP address, localhost on loopback, the \
         gateway's name, or one of [http] hosts)",
    ];
    if changes {
        forbidden.push(
            "the Origin is not the listener's own origin nor one of [http] hosts (a change from \
             another site's page)",
        );
        match mode {
            AuthMode::Token => forbidden.push(
                "the token's role does not grant the right this change needs (write, send, \
                 diagnostics or config)",
            ),
            AuthMode::Locked => forbidden.push("changes are disabled: no token is configured"),
            AuthMode::Insecure => {}
        }
    }
    add("403", &forbidden.join("; or "));
    if has_parameters {
        // A path parameter that does not parse (a sequence number that is not a number) or a
        // query parameter the operation does not know.
        add("400", "A path or query parameter is not valid");
    }
    if op.request_body.is_some() {
        add("400", "The body is not JSON (or TOML)");
        add("413", "The body is larger than [http] body_limit");
        add("415", "The body's Content-Type is not accepted");
    }
    add("500", "An internal error");
    add("504", "The request took longer than [http] request_timeout");
    if changes && mode != AuthMode::Insecure {
        op.security = Some(vec![SecurityRequirement::new(BEARER, Vec::<String>::new())]);
    }
}

fn error_response(description: &str) -> RefOr<utoipa::openapi::Response> {
    ResponseBuilder::new()
        .description(description)
        .content(
            "application/json",
            ContentBuilder::new()
                .schema(Some(Ref::from_schema_name("ErrorBody")))
                .build(),
        )
        .build()
        .into()
}
