//! Wiring a config into running tasks: `gateway run` and `gateway demo`.
//!
//! [`run`] is the testable entry point (mini-redis `run(listener, shutdown)`): the supervisor
//! builds the process image, starts one task per line (each under its own cancellation token),
//! registers every device under its unit id and binds the Modbus TCP listener; the zenoh bridge
//! starts when configured; one HTTP listener serves the REST API, `/healthz`, `/readyz` and
//! `/metrics`. It serves until `shutdown` is cancelled; then it drains within [`GRACE_PERIOD`] and
//! says whether the stop was graceful or forced. Configuration changes over the REST API restart
//! only the lines and servers that changed (see [`supervisor`]).

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use prometheus::Registry;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

use crate::api::ApiState;
use crate::config;
use crate::modbus_tcp::ServerOptions;
use crate::persist::ConfigStore;
use crate::plant::Config;
use crate::unit::write_policy::WritePolicy;

mod build;
mod check;
mod demo;
mod fleet;
mod gateway;
mod hangup_log;
mod lines;
mod metrics;
mod reload;
mod reload_notice;
mod supervisor;
pub mod tag_csv;
mod tls;
mod zenoh;

pub use check::{
    ack_warnings, api_path_issues, check_command, check_report, ignored_keys_of, load_config,
    port_issues, run_issues, security_warnings, start_issues, unpolled_tags, Door,
};
pub use demo::{demo, demo_named};
pub use metrics::{Metrics, METRIC_NAMES};

/// sysexits.h EX_USAGE: the configuration (or the command line) is unusable.
pub const EX_USAGE: u8 = 64;
/// sysexits.h EX_SOFTWARE: the gateway stopped on an internal error.
pub const EX_SOFTWARE: u8 = 70;

/// How long a stopping gateway waits for lines to finish their transaction in flight and for
/// Modbus TCP connections to finish their request (systemd's TimeoutStopSec must be longer).
pub const GRACE_PERIOD: Duration = Duration::from_secs(10);

/// Settings given on the command line that take precedence over the config.
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    /// Listen for Modbus TCP here instead of `modbus_tcp.listen`.
    pub modbus_tcp: Option<SocketAddr>,
    /// The zenoh session listens on this endpoint only (e.g. `tcp/127.0.0.1:7447`), with
    /// multicast scouting off, instead of the config's `[zenoh]` endpoints.
    pub zenoh_listen: Option<String>,
    /// `gateway demo`: how often the simulated telegram partners send a telegram of their own.
    pub telegram_every: Option<Duration>,
    /// `gateway demo --paced`: every line on a paced link with the timing of a real cable.
    pub paced: bool,
    /// Serve HTTP (REST API, `/metrics`) here instead of `[http] listen`.
    pub http: Option<SocketAddr>,
    /// The configuration file: changes made over the REST API are saved there (atomically, the
    /// previous version kept as `<file>.prev`); `None`: changes are kept in memory only.
    pub config_file: Option<PathBuf>,
    /// The registry `/metrics` serves and its families, created in `main`; `None`: [`run`]
    /// creates its own.
    pub metrics: Option<MetricsRegistry>,
    /// `gateway demo`: the demo's own consumer acknowledges the oldest telegrams of every
    /// mailbox so that at most half of it is in use (it never overflows; clients still see
    /// recent telegrams).
    pub acknowledge_mailboxes: bool,
    /// The SIGHUP counter of [`handle_signals`]: every SIGHUP re-reads `config_file` and the TLS
    /// files; `None`: no reload on SIGHUP (a gateway run inside another program).
    pub hangups: Option<Hangups>,
    /// `gateway demo --token-file`: REST changes need the token in this file (role admin)
    /// instead of being open to anyone.
    pub api_token_file: Option<PathBuf>,
    /// `gateway run --exit-on-duplicate-name`: refuse the start (exit 64) when another zenoh
    /// session holds the gateway's name, instead of serving everything but zenoh until the name
    /// is free.
    pub exit_on_duplicate_name: bool,
}

/// The number of SIGHUPs received, raised by [`handle_signals`]; [`run`] reloads on every rise
/// (one received before it listened included).
pub type Hangups = tokio::sync::watch::Receiver<u64>;

/// The Prometheus registry of the process and the gateway's families registered in it.
#[derive(Clone, Debug)]
pub struct MetricsRegistry {
    /// What `/metrics` renders.
    pub registry: Registry,
    /// The families, cloned into every line and the Modbus TCP server.
    pub metrics: Metrics,
}

// === impl MetricsRegistry ===

impl MetricsRegistry {
    /// A new registry with every family of the gateway registered in it.
    pub fn new() -> Result<Self, prometheus::Error> {
        let registry = Registry::new();
        let metrics = Metrics::register(&registry)?;
        Ok(Self { registry, metrics })
    }
}

/// Why the gateway could not start or stopped.
#[derive(Debug, thiserror::Error)]
pub enum AppError {
    /// The configuration is unusable.
    #[error("invalid configuration:\n{0}")]
    Config(#[from] config::ConfigErrors),
    /// A listener could not be bound.
    #[error("cannot listen for {what} on {addr}: {source}")]
    Bind {
        what: &'static str,
        addr: SocketAddr,
        source: std::io::Error,
    },
    /// A simulated device or a virtual line could not be set up.
    #[error("{0}")]
    Setup(String),
    /// The start was refused (a gateway of the same name is already live on the zenoh
    /// fabric): exits as a refused configuration does, since a restart cannot fix it.
    #[error("{0}")]
    Refused(String),
    /// Anything else from the operating system.
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

// === impl AppError ===

impl AppError {
    /// The process exit code (sysexits.h): 64 for configuration errors, 70 otherwise.
    pub fn exit_code(&self) -> u8 {
        match self {
            Self::Config(_) | Self::Refused(_) => EX_USAGE,
            _ => EX_SOFTWARE,
        }
    }
}

impl From<crate::sim::SimError> for AppError {
    fn from(e: crate::sim::SimError) -> Self {
        Self::Setup(e.to_string())
    }
}

/// Logs through tracing to stderr; `RUST_LOG` selects the level, else `default` (`info` for the
/// gateway and the simulators, `warn` for the commands that print an answer: `fleet`'s table
/// should not drown in zenoh's session notices).
pub fn init_logging(default: &str) {
    let filter = std::env::var(tracing_subscriber::EnvFilter::DEFAULT_ENV)
        .ok()
        .and_then(|spec| tracing_subscriber::EnvFilter::try_new(with_protocols(&spec)).ok())
        .unwrap_or_else(|| tracing_subscriber::EnvFilter::new(default));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .try_init();
}

/// `spec` with every directive for `gateway::line` given for `gateway::protocols` too: the
/// protocols' adapters log under their folder (`gateway::protocols::modbus_master::driver`), and
/// `RUST_LOG=info,gateway::line=debug` shows every transaction of the serial lines, as the README
/// says.
fn with_protocols(spec: &str) -> String {
    let mut out = spec.to_owned();
    for directive in spec.split(',').map(str::trim) {
        if let Some(rest) = directive.strip_prefix("gateway::line") {
            if rest.is_empty() || rest.starts_with(['=', '[']) {
                out.push_str(",gateway::protocols");
                out.push_str(rest);
            }
        }
    }
    out
}

/// Installs the process's signal handlers at once and handles them until `shutdown`: SIGINT and
/// SIGTERM cancel `shutdown`; SIGHUP raises the returned counter, which [`run`] answers by
/// re-reading the configuration file and the TLS files. Called first thing (within the
/// runtime), so that a SIGHUP during start is remembered rather than killing the process
/// (its default action).
pub fn handle_signals(shutdown: CancellationToken) -> Hangups {
    let (tx, rx) = tokio::sync::watch::channel(0u64);
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        let (Ok(mut term), Ok(mut int), Ok(mut hup)) = (
            signal(SignalKind::terminate()),
            signal(SignalKind::interrupt()),
            signal(SignalKind::hangup()),
        ) else {
            warn!("cannot install signal handlers; stop the gateway with SIGKILL");
            return rx;
        };
        crate::task::spawn("signals", async move {
            // SIGHUP lines are rate-limited (`hangup_log::HANGUP_LOG`); the number left out is told
            // once the window is over.
            let mut tell_at = None;
            loop {
                let tell = async {
                    match tell_at {
                        Some(at) => tokio::time::sleep_until(at).await,
                        None => std::future::pending().await,
                    }
                };
                tokio::select! {
                    _ = term.recv() => info!("SIGTERM received, stopping"),
                    _ = int.recv() => info!("SIGINT received, stopping"),
                    _ = hup.recv() => {
                        if let Some(suppressed) = hangup_log::hangup_line(&hangup_log::HANGUP_LOG) {
                            if tx.receiver_count() == 0 {
                                info!(suppressed, "SIGHUP received: nothing to reload in this command");
                            } else {
                                info!(suppressed, "SIGHUP received: reading the configuration and TLS files again");
                            }
                        }
                        tx.send_modify(|n| *n = n.wrapping_add(1));
                        tell_at = hangup_log::hangup_left_out_until().or(tell_at);
                        continue;
                    }
                    () = tell => {
                        hangup_log::tell_hangup_left_out();
                        // Never at once again: a window ends in the future or has nothing left.
                        let soon = tokio::time::Instant::now() + Duration::from_millis(50);
                        tell_at = hangup_log::hangup_left_out_until().map(|at| at.max(soon));
                        continue;
                    }
                    () = shutdown.cancelled() => return,
                }
                shutdown.cancel();
                return;
            }
        });
    }
    #[cfg(not(unix))]
    crate::task::spawn("signals", async move {
        let _tx = tx;
        tokio::select! {
            _ = tokio::signal::ctrl_c() => info!("Ctrl-C received, stopping"),
            () = shutdown.cancelled() => return,
        }
        shutdown.cancel();
    });
    rx
}

/// Runs `config` until `shutdown` is cancelled.
///
/// Starts the lines and the Modbus TCP server under a [`supervisor::Supervisor`], the zenoh
/// bridge when configured, and one HTTP listener for the REST API, `/healthz`, `/readyz` and
/// `/metrics` (`--http`, else `[http] listen`). Configuration changes over the API are written to
/// `overrides.config_file` when there is one, then applied by restarting only what changed.
pub async fn run(
    config: Config,
    overrides: Overrides,
    shutdown: CancellationToken,
) -> Result<(), AppError> {
    run_from(config, None, overrides, shutdown).await
}

/// `gateway run --config FILE`: reads the file and refuses it (exit 64, the problems on stderr)
/// when it is wrong or run would refuse it later (the API token, a line that cannot start),
/// before any port opens; then runs it until `shutdown` with the process's registry, saving
/// changes to the file. The exit code, as [`exit_code`] says.
pub async fn run_file(file: &Path, overrides: Overrides, shutdown: CancellationToken) -> u8 {
    let cfg = match load_for_run(file) {
        Ok(cfg) => cfg,
        Err(errors) => {
            eprintln!(
                "gateway: {} is not a valid config:\n{errors}",
                file.display()
            );
            return EX_USAGE;
        }
    };
    let metrics = match process_registry() {
        Ok(metrics) => metrics,
        Err(code) => return code,
    };
    let overrides = Overrides {
        config_file: Some(file.to_path_buf()),
        metrics: Some(metrics),
        ..overrides
    };
    exit_code(run(cfg, overrides, shutdown).await)
}

/// The configuration file at `path`, read and checked as `gateway run` checks it at start and at
/// each SIGHUP: the file's own rules and what run would refuse ([`run_issues`]).
pub(crate) fn load_for_run(path: &Path) -> Result<Config, config::ConfigErrors> {
    let config = load_config(path)?;
    let issues = run_issues(&config);
    if issues.is_empty() {
        Ok(config)
    } else {
        Err(config::ConfigErrors { issues })
    }
}

/// `gateway demo`: the embedded demo (named `name`, else `demo`) until `shutdown`, with the
/// process's registry. The exit code, as [`exit_code`] says.
pub async fn demo_command(
    name: Option<String>,
    overrides: Overrides,
    shutdown: CancellationToken,
) -> u8 {
    let metrics = match process_registry() {
        Ok(metrics) => metrics,
        Err(code) => return code,
    };
    let overrides = Overrides {
        metrics: Some(metrics),
        ..overrides
    };
    exit_code(demo_named(name, overrides, shutdown).await)
}

/// The registry `/metrics` serves, with every family of the gateway registered: one per process;
/// when it cannot be made, the exit code (70, said on stderr).
fn process_registry() -> Result<MetricsRegistry, u8> {
    MetricsRegistry::new().map_err(|e| {
        eprintln!("gateway: cannot register the metrics: {e}");
        EX_SOFTWARE
    })
}

/// The process's exit code for a gateway (or simulator) that stopped with `result`: 0, or the
/// error's code, the error logged and printed on stderr.
pub fn exit_code(result: Result<(), AppError>) -> u8 {
    match result {
        Ok(()) => 0,
        Err(e) => {
            // Under the binary's target, where this line has always been logged.
            tracing::error!(target: "gateway", error = %e, "gateway stopped");
            eprintln!("gateway: {e}");
            e.exit_code()
        }
    }
}

/// [`run`] for a configuration read from `source` rather than from a file (the demo's embedded
/// text): `GET /config` shows that text, with what differs in force written in.
pub(crate) async fn run_from(
    config: Config,
    source: Option<&'static str>,
    overrides: Overrides,
    shutdown: CancellationToken,
) -> Result<(), AppError> {
    let exported = match overrides.metrics.clone() {
        Some(exported) => exported,
        None => MetricsRegistry::new()
            .map_err(|e| AppError::Setup(format!("cannot register the metrics: {e}")))?,
    };
    for warning in security_warnings(&config)
        .into_iter()
        .chain(ack_warnings(&config))
    {
        warn!("{}: {}", warning.path, warning.message);
    }
    log_rest_guard(&config.http);
    let http_config = config.http.clone();
    let sup = supervisor::Supervisor::start(config, overrides.clone(), &shutdown, exported)?;
    if let Err(e) = zenoh::start(&sup).await {
        sup.stop().await;
        return Err(e);
    }
    let http_token = shutdown.child_token();
    let http = match serve_http(&sup, &http_config, &overrides, source, http_token.clone()).await {
        Ok(task) => task,
        Err(e) => {
            sup.stop().await;
            return Err(e);
        }
    };
    if let Some(hangups) = overrides.hangups.clone() {
        crate::task::spawn(
            "reload on SIGHUP",
            reload::on_hangup(Arc::clone(&sup), hangups, shutdown.child_token()),
        );
    }
    if overrides.acknowledge_mailboxes {
        crate::task::spawn(
            "demo mailbox consumer",
            demo::consume_mailboxes(Arc::clone(&sup), shutdown.child_token()),
        );
    }
    let (local, _) = sup.tcp_listen();
    info!(%local, units = ?sup.units.read().map(|u| u.unit_ids()).unwrap_or_default(), "Modbus TCP listening");
    if let Some(tls) = sup.tls_local().await {
        // The same kind of line for the Modbus/TCP Security listener, before the plain one.
        println!("modbus-tcp-tls listening on {tls}");
    }
    // A fixed line on stdout that scripts and tests wait for; printed last, when everything
    // listens.
    if sup.snapshot().config.modbus_tcp.enabled {
        println!("modbus-tcp listening on {local}");
    } else {
        println!("modbus-tcp switched off");
    }
    // What start-up freed (above all the configuration document) goes back to the system.
    crate::heap::release_free_memory();

    shutdown.cancelled().await;
    info!(grace = ?GRACE_PERIOD, "draining: lines finish their transaction in flight, connections their request");
    http_token.cancel();
    let drain = async {
        sup.stop().await;
        if let Err(e) = http.await {
            warn!(error = %e, "HTTP server task failed");
        }
    };
    if tokio::time::timeout(GRACE_PERIOD, drain).await.is_ok() {
        info!("stopped gracefully");
    } else {
        warn!(grace = ?GRACE_PERIOD, "grace period over: stopping forcibly");
    }
    Ok(())
}

/// Binds the HTTP listener and serves there until `shutdown`: the REST API with `/healthz`,
/// Says, before anything starts, that REST changes are not guarded by a token (the insecure mode
/// and the locked one, as a warning): the operator reads it first, and a script that waits for
/// the listeners' lines finds it already written. With tokens, [`serve_http`] names them once it
/// has read them (a token that cannot be read stops the start there, with its own message).
fn log_rest_guard(http: &config::HttpConfig) {
    if http.token_source().is_some() || !http.tokens.is_empty() {
        return;
    }
    if http.insecure_allow_unauthenticated_changes {
        crate::api::Auth::insecure().log_mode();
    } else {
        crate::api::Auth::locked().log_mode();
    }
}

/// `/readyz` and `/metrics` from the process's registry. Prints `http listening on <addr>` on
/// stdout once bound.
async fn serve_http(
    sup: &Arc<supervisor::Supervisor>,
    http: &config::HttpConfig,
    overrides: &Overrides,
    source: Option<&'static str>,
    shutdown: CancellationToken,
) -> Result<JoinHandle<()>, AppError> {
    let addr = overrides.http.unwrap_or(http.listen);
    let store = match &overrides.config_file {
        Some(path) => {
            info!(file = %path.display(), "configuration changes are saved to the configuration file (the previous version as .prev)");
            Some(ConfigStore::new(path.clone()))
        }
        None => {
            // The demo's documented default, not a fault: said once, at INFO.
            info!("no configuration file: configuration changes over the REST API are kept in memory only and are lost at exit");
            None
        }
    };
    let backend = Arc::new(crate::feeds::rest::RestBackend::new(Arc::clone(sup) as _));
    let state = ApiState::from_config(Arc::clone(&backend) as _, http, store)
        .map_err(|e| {
            AppError::Config(config::ConfigErrors {
                issues: vec![crate::api::auth::token_issue(http, &e)],
            })
        })?
        .with_routes(metrics_route(Arc::clone(sup)))
        // The names a request's Host may carry: [http] hosts and the gateway's name (a fleet
        // reaches its members by it, as the compose file's Prometheus scrapes cab1:8080).
        .with_hosts(
            http.hosts.iter().map(String::as_str).chain([sup
                .snapshot()
                .config
                .gateway
                .name
                .as_str()]),
            http.tls.is_some(),
        )
        .with_change_lock(Arc::clone(&sup.change_lock))
        .with_metrics(sup.exported.metrics.http().clone());
    let state = match source {
        Some(text) => state.with_source_text(text),
        None => state,
    };
    let state = match &http.tls {
        Some(cfg) => {
            let tls = crate::api::HttpTls::new(cfg).map_err(|e| {
                AppError::Config(config::ConfigErrors {
                    issues: vec![crate::api::tls::http_tls_issue(&e)],
                })
            })?;
            tls::spawn_reloader("HTTPS", sup.reload.subscribe(), shutdown.clone(), {
                let tls = tls.clone();
                move || tls.reload()
            });
            state.with_tls(tls)
        }
        None => state,
    };
    // Without a token, said at start-up already (log_rest_guard).
    if matches!(state.auth().mode(), crate::api::AuthMode::Token) {
        state.auth().log_mode();
    }
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|source| AppError::Bind {
            what: "HTTP",
            addr,
            source,
        })?;
    let local = listener.local_addr()?;
    backend.set_http_local(local);
    let scheme = if http.tls.is_some() { "https" } else { "http" };
    fleet::set_http_url(sup, scheme, local);
    info!(%local, scheme, "HTTP listening: /api/v1, /healthz, /readyz, /metrics");
    // A fixed line on stdout that scripts and tests wait for (the same with HTTPS).
    println!("http listening on {local}");
    Ok(crate::task::spawn("http server", async move {
        if let Err(e) = crate::api::serve(listener, state, shutdown.cancelled_owned()).await {
            warn!(error = %e, "HTTP server ended with an error");
        }
    }))
}

/// `GET /metrics`: the registry in the Prometheus text format, and the process values when
/// `[http] tag_metrics` is on (read from the configuration in force at each scrape).
fn metrics_route(sup: Arc<supervisor::Supervisor>) -> axum::Router {
    use axum::http::header;
    use axum::response::IntoResponse;
    let tag_values = Arc::new(crate::tags::TagValues::new());
    axum::Router::new().route(
        "/metrics",
        axum::routing::get(move || {
            let (sup, tag_values) = (Arc::clone(&sup), Arc::clone(&tag_values));
            async move {
                let mut text = crate::metrics::encode_text(&sup.exported.registry);
                let snapshot = sup.snapshot();
                tag_values.render(&mut text, &snapshot.config.http, &snapshot.tags, &sup.image);
                (
                    [(header::CONTENT_TYPE, crate::metrics::TEXT_CONTENT_TYPE)],
                    text,
                )
                    .into_response()
            }
        }),
    )
}

/// The Modbus TCP server options of the config.
fn server_options(cfg: &config::ModbusTcpConfig) -> ServerOptions {
    ServerOptions {
        max_connections: usize::try_from(cfg.max_connections).unwrap_or(usize::MAX),
        max_connections_per_client: Some(
            usize::try_from(cfg.max_connections_per_client).unwrap_or(usize::MAX),
        ),
        idle_timeout: cfg.idle_timeout,
        allowed_networks: cfg.allowed_networks.clone(),
        writes: WritePolicy {
            read_only: cfg.read_only,
            write_ranges: build::write_ranges(cfg),
        },
        request_timeout: cfg.request_timeout,
    }
}

#[cfg(test)]
mod tests {
    use super::with_protocols;

    #[test]
    fn a_filter_for_the_lines_covers_the_protocols_adapters() {
        assert_eq!(
            with_protocols("info,gateway::line=debug"),
            "info,gateway::line=debug,gateway::protocols=debug"
        );
        assert_eq!(
            with_protocols("gateway::line"),
            "gateway::line,gateway::protocols"
        );
        // Other targets, and a module under line/, are left as they are.
        assert_eq!(
            with_protocols("warn,gateway::line::status=debug,gateway::linex=trace"),
            "warn,gateway::line::status=debug,gateway::linex=trace"
        );
        let filter = tracing_subscriber::EnvFilter::try_new(with_protocols("gateway::line=debug"));
        assert!(filter.is_ok(), "{filter:?}");
    }
}
