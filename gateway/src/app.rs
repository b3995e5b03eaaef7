//! Wiring a config into running tasks: `gateway run` and `gateway demo`.
//!
//! [`run`] is the testable entry point (mini-redis `run(listener, shutdown)`): it builds the
//! process image, starts one task per line, registers every device under its unit id, binds the
//! Modbus TCP listener and the HTTP listener of `/metrics`, and serves until `shutdown` is
//! cancelled; then it drains within [`GRACE_PERIOD`] and says whether the stop was graceful or
//! forced.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::{Arc, RwLock};
use std::time::Duration;

use prometheus::Registry;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

use crate::config::{self, Config, ProtocolConfig};
use crate::cpmem::{self, SharedCpMemory};
use crate::image::{ImageConfig, ProcessImage};
use crate::line::telegram::{TelegramLineHandle, TelegramLineSettings};
use crate::line::{self, LineHandle, SlaveLineHandle, SlaveLineSettings};
use crate::metrics::Metrics;
use crate::modbus_tcp::{self, ServerOptions, ServerStats, SharedUnits};
use crate::unit::UnitMap;

mod build;
mod demo;
mod zenoh;

pub use demo::demo;

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
    /// Serve HTTP (`/metrics`) here; `None`: no HTTP listener.
    pub http: Option<SocketAddr>,
    /// The registry `/metrics` serves and its families, created in `main`; `None`: [`run`]
    /// creates its own.
    pub metrics: Option<MetricsRegistry>,
}

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
    /// Anything else from the operating system.
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

// === impl AppError ===

impl AppError {
    /// The process exit code (sysexits.h): 64 for configuration errors, 70 otherwise.
    pub fn exit_code(&self) -> u8 {
        match self {
            Self::Config(_) => 64,
            _ => 70,
        }
    }
}

impl From<crate::sim::SimError> for AppError {
    fn from(e: crate::sim::SimError) -> Self {
        Self::Setup(e.to_string())
    }
}

/// Logs through tracing to stderr; `RUST_LOG` selects the level (default `info`).
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .try_init();
}

/// Cancels `shutdown` on SIGINT or SIGTERM.
pub async fn cancel_on_signal(shutdown: CancellationToken) {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        let (Ok(mut term), Ok(mut int)) = (
            signal(SignalKind::terminate()),
            signal(SignalKind::interrupt()),
        ) else {
            warn!("cannot install signal handlers; stop the gateway with SIGKILL");
            return;
        };
        tokio::select! {
            _ = term.recv() => info!("SIGTERM received, stopping"),
            _ = int.recv() => info!("SIGINT received, stopping"),
            () = shutdown.cancelled() => return,
        }
    }
    #[cfg(not(unix))]
    {
        tokio::select! {
            _ = tokio::signal::ctrl_c() => info!("Ctrl-C received, stopping"),
            () = shutdown.cancelled() => return,
        }
    }
    shutdown.cancel();
}

/// The running parts of a gateway.
#[derive(Debug)]
pub struct Running {
    /// The process image shared by lines and servers.
    pub image: ProcessImage,
    /// The Modbus master lines by name.
    pub lines: BTreeMap<String, LineHandle>,
    /// The Modbus slave lines by name.
    pub slave_lines: BTreeMap<String, SlaveLineHandle>,
    /// The telegram lines (3964(R), ASCII) by name.
    pub telegram_lines: BTreeMap<String, TelegramLineHandle>,
    /// The CP memory the slave lines serve, if any line does.
    pub cp_memory: Option<SharedCpMemory>,
    /// Saves the CP memory; stopped (with a last save) after the lines and servers.
    persistence: Option<(CancellationToken, JoinHandle<()>)>,
    /// What answers each Modbus TCP unit id.
    pub units: SharedUnits,
    /// Modbus TCP server counters.
    pub tcp_stats: Arc<ServerStats>,
}

/// Runs `config` until `shutdown` is cancelled.
pub async fn run(
    config: Config,
    overrides: Overrides,
    shutdown: CancellationToken,
) -> Result<(), AppError> {
    let exported = match overrides.metrics.clone() {
        Some(exported) => exported,
        None => MetricsRegistry::new()
            .map_err(|e| AppError::Setup(format!("cannot register the metrics: {e}")))?,
    };
    let lines_token = shutdown.child_token();
    let running = start_lines(&config, &lines_token, &exported.metrics)?;

    let addr = overrides.modbus_tcp.unwrap_or(config.modbus_tcp.listen);
    let listener = modbus_tcp::bind(addr).map_err(|source| AppError::Bind {
        what: "Modbus TCP",
        addr,
        source,
    })?;
    let local = listener.local_addr()?;
    let options = server_options(&config.modbus_tcp);
    let zenoh_token = shutdown.child_token();
    let bridge = start_zenoh(&config, &overrides, &running, options.clone(), &zenoh_token).await?;

    let http_token = shutdown.child_token();
    let http = match overrides.http {
        Some(addr) => Some(serve_http(addr, exported.registry.clone(), http_token.clone()).await?),
        None => {
            info!("no HTTP listen address given (--http): /metrics is not served");
            None
        }
    };
    info!(%local, units = ?running.units.read().map(|u| u.unit_ids()).unwrap_or_default(), "Modbus TCP listening");
    // A fixed line on stdout that scripts and tests wait for; printed last, when everything
    // listens.
    println!("modbus-tcp listening on {local}");

    let server_token = shutdown.child_token();
    let server = tokio::spawn(modbus_tcp::serve(
        listener,
        Arc::clone(&running.units),
        options,
        server_token.clone(),
        Arc::clone(&running.tcp_stats),
    ));

    shutdown.cancelled().await;
    info!(grace = ?GRACE_PERIOD, "draining: lines finish their transaction in flight, connections their request");
    lines_token.cancel();
    server_token.cancel();
    zenoh_token.cancel();
    http_token.cancel();
    let drain = async {
        if let Some(bridge) = bridge {
            bridge.join().await;
        }
        for (_, line) in running.lines {
            line.join().await;
        }
        for (_, line) in running.slave_lines {
            line.join().await;
        }
        for (_, line) in running.telegram_lines {
            line.join().await;
        }
        match server.await {
            Ok(Ok(())) => {}
            Ok(Err(e)) => warn!(error = %e, "Modbus TCP server ended with an error"),
            Err(e) => warn!(error = %e, "Modbus TCP server task failed"),
        }
        if let Some(task) = http {
            if let Err(e) = task.await {
                warn!(error = %e, "HTTP server task failed");
            }
        }
        // Last: the final save sees every write the lines and the server carried out.
        if let Some((token, task)) = running.persistence {
            token.cancel();
            let _ = task.await;
        }
    };
    if tokio::time::timeout(GRACE_PERIOD, drain).await.is_ok() {
        info!("stopped gracefully");
    } else {
        warn!(grace = ?GRACE_PERIOD, "grace period over: stopping forcibly");
    }
    Ok(())
}

/// Starts the zenoh bridge when the config has a `[zenoh]` section (or the command line names an
/// endpoint), fed from the image and the lines.
async fn start_zenoh(
    config: &Config,
    overrides: &Overrides,
    running: &Running,
    server: ServerOptions,
    shutdown: &CancellationToken,
) -> Result<Option<crate::zenoh_bridge::Bridge>, AppError> {
    let cfg = match (&overrides.zenoh_listen, &config.zenoh) {
        (Some(endpoint), base) => {
            let mut cfg = crate::zenoh_bridge::ZenohConfig::loopback_peer(endpoint)
                .map_err(AppError::Setup)?;
            if let Some(base) = base {
                cfg.prefix.clone_from(&base.prefix);
            }
            cfg
        }
        (None, Some(cfg)) if cfg.enabled => cfg.clone(),
        (None, _) => {
            info!("no [zenoh] section: the gateway joins no zenoh fabric");
            return Ok(None);
        }
    };
    let tags = Arc::new(crate::tags::TagDirectory::from_config(config));
    let protocols = config
        .lines
        .iter()
        .map(|(n, l)| (n.clone(), l.protocol.kind().as_str()))
        .collect();
    let backend =
        zenoh::GatewayBackend::new(&config.gateway.name, running, tags, protocols, server);
    let listen = cfg.listen.clone().unwrap_or_default();
    let (bridge, handle) = crate::zenoh_bridge::Bridge::start(
        cfg,
        &config.gateway.name,
        Arc::new(backend.clone_for_bridge()),
        shutdown.clone(),
    )
    .await
    .map_err(|e| AppError::Setup(format!("zenoh: {e}")))?;
    zenoh::spawn_feeds(&handle, &backend, shutdown);
    let endpoints: Vec<&str> = listen
        .iter()
        .map(crate::zenoh_bridge::Endpoint::as_str)
        .collect();
    info!(prefix = %handle.prefix(), ?endpoints, "zenoh session open");
    println!("zenoh session open, prefix {}", handle.prefix());
    Ok(Some(bridge))
}

/// Binds `addr` and serves HTTP there until `shutdown`: for now `GET /metrics` from `registry`
/// ([`crate::metrics::serve_metrics`]). Prints `http listening on <addr>` on stdout once bound.
async fn serve_http(
    addr: SocketAddr,
    registry: Registry,
    shutdown: CancellationToken,
) -> Result<JoinHandle<()>, AppError> {
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|source| AppError::Bind {
            what: "HTTP",
            addr,
            source,
        })?;
    let local = listener.local_addr()?;
    info!(%local, "HTTP listening: /metrics");
    // A fixed line on stdout that scripts and tests wait for.
    println!("http listening on {local}");
    Ok(tokio::spawn(crate::metrics::serve_metrics(
        listener, registry, shutdown,
    )))
}

/// Starts every line of `config` and registers its devices, memory and mailboxes as Modbus TCP
/// units; every line counts into `metrics`.
fn start_lines(
    config: &Config,
    shutdown: &CancellationToken,
    metrics: &Metrics,
) -> Result<Running, AppError> {
    let image = ProcessImage::new(ImageConfig::default());
    let mut units = UnitMap::new();
    let mut lines = BTreeMap::new();
    let mut slave_lines = BTreeMap::new();
    let mut telegram_lines = BTreeMap::new();
    let (cp_memory, persistence) = match open_cp_memory(config)? {
        Some((memory, persistence)) => (Some(memory), persistence),
        None => (None, None),
    };
    for (name, line) in &config.lines {
        match &line.protocol {
            ProtocolConfig::ModbusMasterRtu(_) | ProtocolConfig::ModbusMasterAscii(_) => {
                let Some((mut settings, devices)) = build::master_line(name, line, config) else {
                    continue;
                };
                settings.metrics = Some(metrics.clone());
                let handle = line::spawn_modbus_master_line(
                    settings,
                    devices,
                    image.clone(),
                    shutdown.child_token(),
                );
                for (unit, device) in handle.device_units() {
                    units.insert(unit, Arc::new(device));
                }
                lines.insert(name.clone(), handle);
            }
            ProtocolConfig::ModbusSlaveRtu(cfg) => {
                let memory = cp_memory.clone().ok_or_else(|| {
                    AppError::Setup(format!("line {name}: no CP memory was set up"))
                })?;
                let params =
                    cpmem::config::slave_params(cfg, memory.layout()).map_err(|issues| {
                        let text: Vec<String> =
                            issues.iter().map(|i| format!("lines.{name}.{i}")).collect();
                        AppError::Setup(text.join("\n"))
                    })?;
                let mut settings = SlaveLineSettings::new(
                    name.clone(),
                    build::port_settings(&line.serial),
                    params,
                );
                settings.diag_depth = usize::from(config.gateway.diag_buffer_depth);
                settings.metrics = Some(metrics.clone());
                let handle =
                    line::spawn_modbus_slave_line(settings, memory.clone(), shutdown.child_token());
                if let Some(unit) = cfg.unit_id {
                    units.insert(unit, Arc::new(handle.unit()));
                    memory.mirror_to(image.clone(), unit, handle.map().clone());
                }
                slave_lines.insert(name.clone(), handle);
            }
            ProtocolConfig::Proc3964(_) | ProtocolConfig::Ascii(_) => {
                let port = build::port_settings(&line.serial);
                let mut settings = TelegramLineSettings::from_config(name, line, port)
                    .map_err(|e| AppError::Setup(format!("line {name}: {e}")))?;
                settings.diag_depth = usize::from(config.gateway.diag_buffer_depth);
                settings.metrics = Some(metrics.clone());
                let handle = line::telegram::spawn_telegram_line(settings, shutdown.child_token());
                if let Some(unit) = line.unit_id() {
                    units.insert(unit, Arc::new(handle.mailbox_unit()));
                }
                telegram_lines.insert(name.clone(), handle);
            }
        }
    }
    Ok(Running {
        image,
        lines,
        slave_lines,
        telegram_lines,
        cp_memory,
        persistence,
        units: Arc::new(RwLock::new(units)),
        tcp_stats: Arc::new(ServerStats::with_metrics(metrics.clone())),
    })
}

type Persistence = Option<(CancellationToken, JoinHandle<()>)>;

/// The CP memory of the slave lines, loaded from its file when it is persisted; `None` when no
/// line serves it.
fn open_cp_memory(config: &Config) -> Result<Option<(SharedCpMemory, Persistence)>, AppError> {
    let slaves: Vec<_> = config
        .lines
        .values()
        .filter_map(|l| match &l.protocol {
            ProtocolConfig::ModbusSlaveRtu(cfg) => Some(cfg),
            _ => None,
        })
        .collect();
    if slaves.is_empty() {
        return Ok(None);
    }
    let blocks: Vec<(u16, u16)> = config
        .cp_memory
        .data_blocks
        .iter()
        .map(|b| (b.db, b.words))
        .collect();
    let layout =
        cpmem::config::memory_layout(slaves, (!blocks.is_empty()).then_some(blocks.as_slice()));
    let Some(path) = &config.cp_memory.persist_file else {
        return Ok(Some((SharedCpMemory::new(layout), None)));
    };
    let (memory, report) = SharedCpMemory::open(layout, path)
        .map_err(|e| AppError::Setup(format!("CP memory file {}: {e}", path.display())))?;
    info!(file = %path.display(), ?report, "CP memory loaded");
    let token = CancellationToken::new();
    let settings = cpmem::PersistSettings {
        path: path.clone(),
        interval: config.cp_memory.save_interval,
    };
    let task = cpmem::spawn_persistence(memory.clone(), settings, token.clone());
    Ok(Some((memory, Some((token, task)))))
}

/// The Modbus TCP server options of the config.
fn server_options(cfg: &config::ModbusTcpConfig) -> ServerOptions {
    ServerOptions {
        max_connections: usize::try_from(cfg.max_connections).unwrap_or(usize::MAX),
        idle_timeout: cfg.idle_timeout,
        allowed_networks: cfg.allowed_networks.clone(),
        read_only: cfg.read_only,
        write_ranges: build::write_ranges(cfg),
        request_timeout: cfg.request_timeout,
    }
}
