//! The REST API (axum, JSON) under `/api/v1`, with `/healthz`, `/readyz` and the OpenAPI document
//! at `/api/v1/openapi.json`.
//!
//! ```text
//! GET    /                                               the status page ([`page`])
//! GET    /healthz                                        alive
//! GET    /readyz                                         ready (lines opened, Modbus TCP, zenoh)
//! GET    /api/v1/openapi.json                            this API, generated from the code
//! GET    /api/v1/status                                  the gateway and every line
//! GET    /api/v1/config                                  the configuration as written, with the
//!                                                        command line's overrides (ETag; TOML)
//! PUT    /api/v1/config                                  replace it: validate, persist, apply
//! POST   /api/v1/config/validate                         validate without applying
//! GET    /api/v1/config/lines/{line}                     one line's table
//! PUT    /api/v1/config/lines/{line}                     replace or add one line
//! DELETE /api/v1/config/lines/{line}                     remove one line
//! GET    /api/v1/lines                                   every line's status
//! GET    /api/v1/lines/{line}                            one line's status
//! GET    /api/v1/lines/{line}/diag                       diagnostic buffer, newest first
//! DELETE /api/v1/lines/{line}/diag                       clear it
//! GET    /api/v1/lines/{line}/telegrams                  received telegrams, oldest first
//! POST   /api/v1/lines/{line}/telegrams/{seq}/ack        acknowledge the oldest
//! POST   /api/v1/lines/{line}/send                       send a telegram
//! GET    /api/v1/lines/{line}/signals                    RS232 signals
//! GET    /api/v1/lines/{line}/frames?since=&follow=      frame monitor (JSON; SSE with follow)
//! GET    /api/v1/lines/{line}/capture?seconds=           frame monitor as pcapng
//! PUT    /api/v1/lines/{line}/signals                    set DTR / RTS
//! GET    /api/v1/tags?line=&device=                      tag values
//! GET    /api/v1/lines/{line}/devices/{device}/tags      one device's tags
//! GET    /api/v1/lines/{line}/devices/{device}/tags/{tag}  one tag
//! PUT    /api/v1/lines/{line}/devices/{device}/tags/{tag}  write it through to the device
//! ```
//!
//! [`serve`] runs the accept loop: connection places per client address and in all, with places
//! held back for `/metrics`, `/healthz` and `/readyz` ([`places`]), a header read timeout, a write
//! timeout ([`io`]), HTTPS when configured ([`tls`]), a graceful stop. SSE follows and timed
//! captures need a stream place as well (`max_streams`; 503 with Retry-After beyond).
//! Layers, outermost first: a panic becomes a 500 in the error shape; any error answer some
//! layer made without a JSON body gets one ([`error`]); the request timeout (504); the `Host`
//! and, for changes, `Origin` check ([`origin`], 403); the bearer token check for changes
//! ([`auth`]); the body limit (413). The service implements
//! [`ApiBackend`]; [`router`] turns it into an `axum::Router`.

pub mod auth;
pub mod backend;
mod body;
pub mod diff;
pub mod error;
mod handlers;
mod io;
pub mod metrics;
pub mod model;
mod openapi;
pub mod origin;
pub mod page;
pub mod places;
mod server;
pub mod tls;

use std::sync::Arc;
use std::time::Duration;

use axum::extract::{DefaultBodyLimit, Request, State};
use axum::http::{header, HeaderValue, StatusCode, Uri};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::{Extension, Router};
use tower_http::catch_panic::CatchPanicLayer;
use utoipa::OpenApi as _;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

pub use auth::{Auth, AuthMode, Token, TokenError};
pub use backend::{ApiBackend, BoxFuture};
pub use body::{etag, TOML_MEDIA_TYPE};
pub use diff::ConfigDiff;
pub use error::ApiError;
pub use server::{serve, DEFAULT_HEADER_READ_TIMEOUT, DEFAULT_MAX_CONNECTIONS};
pub use tls::HttpTls;

use crate::persist::{ConfigStore, ConfigText, KeptText};
use crate::plant::Config;

/// The prefix of the versioned API.
pub const API_PREFIX: &str = "/api/v1";

/// What the handlers share: the gateway, the auth policy, the config file, the limits.
#[derive(Clone)]
pub struct ApiState {
    backend: Arc<dyn ApiBackend>,
    auth: Arc<Auth>,
    store: Option<Arc<ConfigStore>>,
    body_limit: usize,
    request_timeout: Duration,
    /// Connections served at once.
    max_connections: usize,
    /// Longest wait for a request head.
    header_read_timeout: Duration,
    /// Connections served at once from one client address.
    max_connections_per_client: usize,
    /// Streams (SSE follows, timed captures) served at once, and their places.
    max_streams: usize,
    streams: Arc<tokio::sync::Semaphore>,
    /// An answer not read for this long is closed.
    write_timeout: Duration,
    /// HTTPS; `None`: plain HTTP.
    tls: Option<HttpTls>,
    /// Where refusals and connections are counted.
    metrics: Option<metrics::HttpMetrics>,
    /// Client networks accepted; empty: every client.
    allowed_networks: Vec<ipnet::IpNet>,
    /// Networks whose clients have places held back for `/metrics`, `/healthz`, `/readyz`.
    monitoring_networks: Vec<ipnet::IpNet>,
    /// The names a request's `Host` may carry besides an IP address ([`origin`]).
    host_names: Arc<origin::HostNames>,
    /// Configuration changes run one at a time.
    change_lock: Arc<tokio::sync::Mutex<()>>,
    /// Routes served beside the API on the same listener (e.g. `/metrics`), outside its
    /// OpenAPI document.
    extra: Option<Router>,
    /// The text the configuration was read from when there is no file (the demo's own).
    source_text: Option<Arc<str>>,
    /// The configuration in force as its operator wrote it, once shown or changed; it does not
    /// hold the configuration (the supervisor does), so a replaced one is freed.
    document: Arc<std::sync::Mutex<Option<KeptText>>>,
}

impl std::fmt::Debug for ApiState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ApiState")
            .field("auth", &self.auth.mode())
            .field(
                "store",
                &self.store.as_ref().map(|s| s.path().to_path_buf()),
            )
            .field("body_limit", &self.body_limit)
            .field("request_timeout", &self.request_timeout)
            .field("max_connections", &self.max_connections)
            .field(
                "max_connections_per_client",
                &self.max_connections_per_client,
            )
            .field("max_streams", &self.max_streams)
            .field("write_timeout", &self.write_timeout)
            .field("https", &self.tls.is_some())
            .finish_non_exhaustive()
    }
}

// === impl ApiState ===

impl ApiState {
    /// The API over `backend` with `auth`, the default limits and no configuration file.
    pub fn new(backend: Arc<dyn ApiBackend>, auth: Auth) -> Self {
        Self {
            backend,
            auth: Arc::new(auth),
            store: None,
            body_limit: usize::try_from(crate::config::DEFAULT_BODY_LIMIT).unwrap_or(usize::MAX),
            request_timeout: crate::config::DEFAULT_HTTP_REQUEST_TIMEOUT,
            max_connections: DEFAULT_MAX_CONNECTIONS as usize,
            header_read_timeout: DEFAULT_HEADER_READ_TIMEOUT,
            max_connections_per_client: crate::config::DEFAULT_HTTP_MAX_CONNECTIONS_PER_CLIENT
                as usize,
            max_streams: crate::config::DEFAULT_HTTP_MAX_STREAMS as usize,
            streams: Arc::new(tokio::sync::Semaphore::new(
                crate::config::DEFAULT_HTTP_MAX_STREAMS as usize,
            )),
            write_timeout: crate::config::DEFAULT_HTTP_WRITE_TIMEOUT,
            tls: None,
            metrics: None,
            allowed_networks: Vec::new(),
            monitoring_networks: Vec::new(),
            host_names: Arc::default(),
            change_lock: Arc::default(),
            extra: None,
            source_text: None,
            document: Arc::default(),
        }
    }

    /// The API as `[http]` says: the token from its file or variable, the limits; changes are
    /// written to `store` when there is one.
    pub fn from_config(
        backend: Arc<dyn ApiBackend>,
        http: &crate::config::HttpConfig,
        store: Option<ConfigStore>,
    ) -> Result<Self, TokenError> {
        let state = Self::new(backend, Auth::from_config(http)?)
            .with_limits(http.body_limit, http.request_timeout)
            .with_connections(http.max_connections, http.header_read_timeout)
            .with_client_limits(
                http.max_connections_per_client,
                http.max_streams,
                http.write_timeout,
            )
            .with_allowed_networks(http.allowed_networks.clone())
            .with_monitoring_networks(http.monitoring_networks.clone())
            .with_hosts(http.hosts.iter().map(String::as_str), http.tls.is_some());
        Ok(match store {
            Some(s) => state.with_store(s),
            None => state,
        })
    }

    /// Accepted changes are written to `store` before they are applied.
    pub fn with_store(mut self, store: ConfigStore) -> Self {
        self.store = Some(Arc::new(store));
        self.primed()
    }

    /// The text the configuration in force was read from, for a gateway without a configuration
    /// file (the demo's embedded one): `GET /config` shows it (with what differs from it in
    /// force written in) instead of every key with its default.
    pub fn with_source_text(mut self, text: impl Into<Arc<str>>) -> Self {
        self.source_text = Some(text.into());
        self.primed()
    }

    /// Reads the configuration as written now, so that the first request finds it read.
    fn primed(self) -> Self {
        self.document(&self.backend.config());
        self
    }

    /// The largest body (bytes) and the longest time of a request.
    pub fn with_limits(mut self, body_limit: u64, request_timeout: Duration) -> Self {
        self.body_limit = usize::try_from(body_limit).unwrap_or(usize::MAX);
        self.request_timeout = request_timeout;
        self
    }

    /// The most connections served at once (at least 1) and the longest wait for a request head.
    pub fn with_connections(mut self, max_connections: u32, header_read_timeout: Duration) -> Self {
        self.max_connections = usize::try_from(max_connections.max(1)).unwrap_or(usize::MAX);
        self.header_read_timeout = header_read_timeout;
        self
    }

    /// The most connections from one client address (at least 1), the most streams at once (at
    /// least 1) and the longest time an answer may stay unread.
    pub fn with_client_limits(
        mut self,
        max_connections_per_client: u32,
        max_streams: u32,
        write_timeout: Duration,
    ) -> Self {
        self.max_connections_per_client =
            usize::try_from(max_connections_per_client.max(1)).unwrap_or(usize::MAX);
        self.max_streams = usize::try_from(max_streams.max(1))
            .unwrap_or(usize::MAX)
            .min(tokio::sync::Semaphore::MAX_PERMITS);
        self.streams = Arc::new(tokio::sync::Semaphore::new(self.max_streams));
        self.write_timeout = write_timeout;
        self
    }

    /// Serves HTTPS with `tls` instead of HTTP.
    pub fn with_tls(mut self, tls: HttpTls) -> Self {
        self.tls = Some(tls);
        self
    }

    /// Counts connections, streams and refusals in `metrics`.
    pub fn with_metrics(mut self, metrics: metrics::HttpMetrics) -> Self {
        self.metrics = Some(metrics);
        self
    }

    /// A place for a stream (an SSE follow, a timed capture), held until the returned value is
    /// dropped; 503 with Retry-After when all `max_streams` are taken.
    pub(crate) fn stream_place(
        &self,
        peer: Option<std::net::SocketAddr>,
    ) -> Result<StreamPlace, ApiError> {
        match Arc::clone(&self.streams).try_acquire_owned() {
            Ok(permit) => {
                let gauge = self.metrics.as_ref().map(|m| m.streams());
                if let Some(g) = &gauge {
                    g.inc();
                }
                Ok(StreamPlace {
                    _permit: permit,
                    gauge,
                })
            }
            Err(_) => {
                let what = format!(
                    "every stream place is taken ([http] max_streams = {})",
                    self.max_streams
                );
                self.refused(metrics::HttpRejectReason::StreamLimit, peer, &what);
                Err(ApiError::busy_for(
                    format!("{what}; try again later"),
                    STREAM_RETRY_AFTER_SECONDS,
                ))
            }
        }
    }

    /// Counts a refusal of `reason`.
    pub(crate) fn count(&self, reason: metrics::HttpRejectReason) {
        if let Some(m) = &self.metrics {
            m.rejected(reason);
        }
    }

    /// Counts a refusal of `reason` and logs it (one line per reason and interval, with the
    /// client's address and how many were left out).
    pub(crate) fn refused(
        &self,
        reason: metrics::HttpRejectReason,
        peer: Option<std::net::SocketAddr>,
        what: &str,
    ) {
        self.count(reason);
        let client = peer.map(|p| p.to_string()).unwrap_or_default();
        crate::warn_limited!(
            format!("http.refused.{}", reason.as_str()),
            reason = reason.as_str(),
            %client,
            "HTTP: {what}"
        );
    }

    /// Only clients in `networks` are served (empty: every client); others are closed at
    /// accept.
    pub fn with_allowed_networks(mut self, networks: Vec<ipnet::IpNet>) -> Self {
        self.allowed_networks = networks;
        self
    }

    /// Clients in `networks` have places held back for `/metrics`, `/healthz` and `/readyz`
    /// that no other client can take.
    pub fn with_monitoring_networks(mut self, networks: Vec<ipnet::IpNet>) -> Self {
        self.monitoring_networks = networks;
        self
    }

    /// A request's `Host` may carry `names` besides an IP address (and `localhost` on a
    /// loopback connection); `https`: the listener speaks HTTPS ([`origin`]).
    pub fn with_hosts<'a>(mut self, names: impl IntoIterator<Item = &'a str>, https: bool) -> Self {
        self.host_names = Arc::new(origin::HostNames::new(names, https));
        self
    }

    pub(crate) fn host_names(&self) -> &origin::HostNames {
        &self.host_names
    }

    /// Whether a client at `peer` may connect.
    pub(crate) fn allows_peer(&self, peer: std::net::IpAddr) -> bool {
        let peer = peer.to_canonical();
        self.allowed_networks.is_empty()
            || self.allowed_networks.iter().any(|net| net.contains(&peer))
    }

    /// Serves `routes` beside the API (same listener, same layers: limits, timeout, JSON
    /// errors; GET needs no token). The paths must not clash with the API's.
    pub fn with_routes(mut self, routes: Router) -> Self {
        self.extra = Some(routes);
        self
    }

    pub(crate) fn backend(&self) -> &Arc<dyn ApiBackend> {
        &self.backend
    }

    pub(crate) fn auth(&self) -> &Auth {
        &self.auth
    }

    pub(crate) fn store(&self) -> Option<Arc<ConfigStore>> {
        self.store.clone()
    }

    /// Runs configuration changes one at a time with whatever else holds `lock` (the SIGHUP
    /// re-read of the configuration file).
    pub fn with_change_lock(mut self, lock: Arc<tokio::sync::Mutex<()>>) -> Self {
        self.change_lock = lock;
        self
    }

    pub(crate) fn change_lock(&self) -> &tokio::sync::Mutex<()> {
        &self.change_lock
    }

    /// The configuration in force (`in_force`) as its operator wrote it: the file's text when
    /// it reads as `in_force` (a comment added by hand since is kept); else the text of the last
    /// change, or the source text, with what differs in force written in; else `in_force`
    /// written out whole.
    pub(crate) fn document(&self, in_force: &Arc<Config>) -> ConfigText {
        let mut kept = self
            .document
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let from_file = self.store.as_ref().and_then(|s| s.read_text());
        let k = kept.take();
        let same = match (&from_file, &k) {
            (Some(text), Some(k)) if k.text() == *text => k.reading_as(in_force),
            _ => None,
        };
        let current = match (same, from_file) {
            (Some(same), _) => same,
            (None, Some(text)) => ConfigText::read(text, in_force)
                .unwrap_or_else(|| self.derived(k.as_ref(), in_force)),
            (None, None) => self.derived(k.as_ref(), in_force),
        };
        *kept = Some(current.keep());
        current
    }

    /// The kept text, else the source text, following `in_force`.
    fn derived(&self, kept: Option<&KeptText>, in_force: &Arc<Config>) -> ConfigText {
        match (kept, &self.source_text) {
            (Some(k), _) => k.following(in_force),
            (None, Some(source)) => ConfigText::new(source, in_force),
            (None, None) => ConfigText::of(in_force),
        }
    }

    /// Keeps `text` as the configuration in force as written (after a change).
    pub(crate) fn set_document(&self, text: &ConfigText) {
        *self
            .document
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(text.keep());
    }
}

/// `Retry-After` of a stream refused for want of a place: streams last long.
const STREAM_RETRY_AFTER_SECONDS: u32 = 10;

/// A stream's place (see [`ApiState::stream_place`]).
#[derive(Debug)]
pub(crate) struct StreamPlace {
    _permit: tokio::sync::OwnedSemaphorePermit,
    gauge: Option<prometheus::IntGauge>,
}

impl Drop for StreamPlace {
    fn drop(&mut self) {
        if let Some(g) = &self.gauge {
            g.dec();
        }
    }
}

/// Every route with its OpenAPI operation.
fn routes() -> OpenApiRouter<ApiState> {
    use handlers::{config as c, health as h, lines as l, monitor as m, tags as t};
    let v1 = OpenApiRouter::new()
        .routes(routes!(h::openapi_json))
        .routes(routes!(h::gateway_status))
        .routes(routes!(handlers::fleet::get_fleet))
        .routes(routes!(c::get_config, c::put_config))
        .routes(routes!(c::validate_config))
        .routes(routes!(
            c::get_line_config,
            c::put_line_config,
            c::delete_line_config
        ))
        .routes(routes!(l::list_lines))
        .routes(routes!(l::get_line))
        .routes(routes!(l::get_diag, l::clear_diag))
        .routes(routes!(l::get_telegrams))
        .routes(routes!(l::ack_telegram))
        .routes(routes!(l::send_telegram))
        .routes(routes!(l::get_signals, l::set_signals))
        .routes(routes!(m::get_frames))
        .routes(routes!(m::get_capture))
        .routes(routes!(t::list_tags))
        .routes(routes!(t::device_tags))
        .routes(routes!(t::get_tag, t::put_tag));
    OpenApiRouter::with_openapi(openapi::ApiDoc::openapi())
        .routes(routes!(h::healthz))
        .routes(routes!(h::readyz))
        .nest(API_PREFIX, v1)
}

/// The OpenAPI document of [`router`] (e.g. to write it to a file).
pub fn openapi() -> utoipa::openapi::OpenApi {
    openapi::finish(routes().into_openapi())
}

/// The API as a router, ready for `axum::serve`.
pub fn router(state: ApiState) -> Router {
    let (routes, doc) = routes().split_for_parts();
    let doc = openapi::finish_for(doc, state.auth().mode());
    let doc_json = doc.to_json().unwrap_or_else(|e| {
        // The document is built from our own types; failing to render it is a defect.
        tracing::error!(error = %e, "cannot render the OpenAPI document");
        "{}".to_owned()
    });
    let routes = match state.extra.clone() {
        Some(extra) => routes.merge(extra.with_state::<ApiState>(())),
        None => routes,
    };
    // The status page at `/` ([`page`]), outside the OpenAPI document: it uses the API.
    let routes = routes.merge(page::routes());
    routes
        .fallback(no_route)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(Extension(handlers::health::OpenApiJson(Arc::new(doc_json))))
        .layer(DefaultBodyLimit::max(state.body_limit))
        .layer(middleware::from_fn_with_state(
            state.clone(),
            auth::require_auth,
        ))
        // Before the token is looked at: a foreign Host, or a change from a foreign Origin.
        .layer(middleware::from_fn_with_state(
            state.clone(),
            origin::require_own_origin,
        ))
        .layer(middleware::from_fn_with_state(state.clone(), timeout))
        .layer(middleware::from_fn(json_errors))
        .layer(CatchPanicLayer::custom(panic_response))
        .with_state(state)
}

async fn no_route(uri: Uri) -> ApiError {
    ApiError::no_route(uri.path())
}

async fn method_not_allowed() -> ApiError {
    ApiError::method_not_allowed()
}

/// 504 when the handler takes longer than the request timeout. Configuration changes run in
/// their own task and complete anyway.
async fn timeout(State(state): State<ApiState>, req: Request, next: Next) -> Response {
    match tokio::time::timeout(state.request_timeout, next.run(req)).await {
        Ok(response) => response,
        Err(_) => ApiError::timeout(format!(
            "no answer within {}",
            humantime::format_duration(state.request_timeout)
        ))
        .into_response(),
    }
}

/// Gives an error answer that has no JSON body (from axum or a layer) the API's error shape.
async fn json_errors(req: Request, next: Next) -> Response {
    let response = next.run(req).await;
    let status = response.status();
    let is_json = response
        .headers()
        .get(header::CONTENT_TYPE)
        .is_some_and(|v| v.as_bytes().starts_with(b"application/json"));
    if !(status.is_client_error() || status.is_server_error()) || is_json {
        return response;
    }
    let (parts, _) = response.into_parts();
    let mut fixed = ApiError::from_status(status).into_response();
    for name in [header::ALLOW, header::WWW_AUTHENTICATE, header::RETRY_AFTER] {
        if let Some(v) = parts.headers.get(&name) {
            fixed.headers_mut().insert(name, v.clone());
        }
    }
    fixed
}

fn panic_response(panic: Box<dyn std::any::Any + Send + 'static>) -> Response {
    let what = panic
        .downcast_ref::<&str>()
        .map(|s| (*s).to_owned())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_default();
    // A request that makes a handler panic can be sent again and again: rate-limited.
    crate::error_limited!("api handler panicked", panic = %what, "a request handler panicked");
    let mut r = ApiError::internal("internal error").into_response();
    r.headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    *r.status_mut() = StatusCode::INTERNAL_SERVER_ERROR;
    r
}
