//! The REST API over real HTTP (reqwest against `axum::serve` on 127.0.0.1 port 0), with an
//! in-memory gateway behind it (`api/backend.rs`): every endpoint, the auth matrix, limits and
//! timeouts, configuration validation with every issue at once, the OpenAPI document against the
//! router, and a server killed with SIGKILL in the middle of a series of PUTs.

#[path = "api/backend.rs"]
mod backend;
#[path = "api/support.rs"]
mod support;

#[path = "api/auth_limits.rs"]
mod auth_limits;
#[path = "api/config_routes.rs"]
mod config_routes;
#[path = "api/crash.rs"]
mod crash;
#[path = "api/line_routes.rs"]
mod line_routes;
#[path = "api/openapi_doc.rs"]
mod openapi_doc;
