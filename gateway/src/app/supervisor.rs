//! The supervisor of a running gateway: its lines (each with its own cancellation token), the
//! Modbus TCP server, the zenoh bridge, and the configuration in force.
//!
//! A configuration change is applied by [`Supervisor::apply`] (`apply.rs`): its [`plan::Plan`]
//! says, as data, what changed, and the supervisor's steps stop and start only that, in the
//! plan's order (the CP memory, the lines stopped, the lines started, the mirrors, the new
//! snapshot, the servers). A line whose serial or protocol settings or devices changed is
//! restarted as a whole (a line task takes its device list at start); a line that did not change
//! keeps its task, its open port, its counters and its diagnostic buffer, and the Modbus TCP
//! clients of its units keep their connections. A changed `[modbus_tcp]` limit (caps, idle and
//! request timeouts, networks, read-only, write ranges, TLS files and roles) is put in force in
//! the running servers (`modbus_tcp::LiveOptions`) for new connections and the next request of
//! open ones, which stay connected; only a changed listen address (or plain Modbus TCP switched
//! on or off) restarts a server. The zenoh session only when the gateway's name (its key prefix)
//! changed. Other sections (`[cp_memory]`, `[http]`, `[zenoh]`) take effect at the next start of
//! the process and are reported as pending. A SIGHUP re-read of the configuration file
//! (`super::reload`) applies the file the same way, one change at a time with the REST API's
//! (`change_lock`).
//!
//! Readers (the REST API, zenoh, the feeds) take a [`Snapshot`]: the configuration, the lines and
//! the tag directory in force, swapped as a whole when a change is applied.

use std::collections::{BTreeMap, BTreeSet};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError, RwLock};
use std::time::SystemTime;

use tokio::net::TcpListener;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

use super::lines::{self, slave_layout, LineDeps};

mod apply;
mod plan;
use super::{server_options, AppError, MetricsRegistry, Overrides, GRACE_PERIOD};
use crate::api::BoxFuture;
use crate::config::check::issue;
use crate::config::ConfigIssue;
use crate::cpmem::{self, SharedCpMemory};
use crate::feeds::gateway::RunningLine;
use crate::image::{ImageConfig, ProcessImage};
use crate::modbus_tcp::{self, LiveOptions, ServerOptions, ServerStats};
use crate::plant::Config;
use crate::tags::TagDirectory;
use crate::unit::{SharedUnits, UnitMap};
use crate::zenoh_bridge::BridgeStats;
use proto_core::cpmem::AddressMap;

/// What is in force: read as a whole, replaced as a whole.
#[derive(Debug)]
pub(crate) struct Snapshot {
    /// Shared with the REST API's view of it (one copy of every tag list in the process).
    pub(crate) config: Arc<Config>,
    pub(crate) lines: BTreeMap<String, RunningLine>,
    pub(crate) tags: Arc<TagDirectory>,
    /// The Modbus TCP server's options (its write checks apply to REST and zenoh writes too).
    pub(crate) server: ServerOptions,
}

// === impl Snapshot ===

impl Snapshot {
    /// `config` in force with `lines`: its tag directory and Modbus TCP server options.
    fn new(config: Arc<Config>, lines: BTreeMap<String, RunningLine>) -> Self {
        Self {
            tags: Arc::new(TagDirectory::from_config(&config)),
            server: server_options(&config.modbus_tcp),
            config,
            lines,
        }
    }
}

/// What status and readiness show of zenoh.
#[derive(Clone)]
pub(crate) struct ZenohState {
    /// The running bridge's counters; `None` while it is down.
    pub(crate) stats: Option<Arc<BridgeStats>>,
    /// `peer`, `client` or `router`.
    pub(crate) mode: &'static str,
    /// The other gateways seen on the fabric (`GET /api/v1/fleet`); `None` while it is down.
    pub(crate) fleet: Option<Arc<crate::zenoh_bridge::fleet::FleetView>>,
}

/// A server that follows the running lines (the zenoh bridge): told when lines start after a
/// configuration change, when the gateway's name changes, and when the gateway stops.
pub(crate) trait Follower: Send + Sync + 'static {
    /// Lines `names` of `snapshot` started.
    fn lines_started<'a>(
        &'a self,
        snapshot: &'a Snapshot,
        names: &'a [String],
    ) -> BoxFuture<'a, ()>;
    /// The gateway's name changed: restarts under the new one; whether it runs again.
    fn renamed<'a>(&'a self, sup: &'a Arc<Supervisor>) -> BoxFuture<'a, bool>;
    /// The gateway stops.
    fn stop<'a>(&'a self, sup: &'a Supervisor) -> BoxFuture<'a, ()>;
}

/// The running Modbus TCP server.
struct TcpServer {
    token: CancellationToken,
    task: JoinHandle<()>,
    local: SocketAddr,
    up: Arc<AtomicBool>,
}

impl TcpServer {
    /// Stops the server, waiting (bounded) for its connections to finish their request.
    async fn stop(self) {
        self.token.cancel();
        if tokio::time::timeout(GRACE_PERIOD, self.task).await.is_err() {
            warn!("the old Modbus TCP server did not stop within the grace period");
        }
        self.up.store(false, Ordering::Release);
    }
}

/// The state of the CP memory the slave lines serve.
#[derive(Default)]
struct CpState {
    memory: Option<SharedCpMemory>,
    /// Saves the memory; stopped (with a last save) after the lines and servers.
    persistence: Option<(CancellationToken, JoinHandle<()>)>,
}

/// The running gateway.
pub(crate) struct Supervisor {
    pub(crate) started: SystemTime,
    pub(crate) image: ProcessImage,
    pub(crate) units: SharedUnits,
    pub(crate) exported: MetricsRegistry,
    pub(crate) overrides: Overrides,
    /// The process's shutdown token: the parent of the servers' tokens.
    pub(crate) root: CancellationToken,
    /// The parent of every line's token.
    lines_token: CancellationToken,
    state: RwLock<Arc<Snapshot>>,
    cp: Mutex<CpState>,
    /// The CP memory mirrors in the image, by unit id and address map.
    mirrored: Mutex<Vec<(u8, AddressMap)>>,
    tcp: tokio::sync::Mutex<Option<TcpServer>>,
    /// The Modbus/TCP Security server, when `[modbus_tcp.tls]` is set.
    tls: tokio::sync::Mutex<Option<super::tls::TlsRun>>,
    /// The address the Modbus TCP server listens on and whether it is up.
    tcp_state: Mutex<(SocketAddr, Arc<AtomicBool>)>,
    pub(crate) tcp_stats: Arc<ServerStats>,
    /// The plain Modbus TCP server's limits, replaced in place by a configuration change.
    tcp_options: Arc<LiveOptions>,
    /// What follows the lines besides the supervisor (the zenoh bridge), once it started.
    follower: std::sync::OnceLock<Arc<dyn Follower>>,
    /// What status and readiness show of zenoh; `None` when it is not configured.
    pub(crate) zenoh_state: Mutex<Option<ZenohState>>,
    /// The URL of the HTTP listener once bound (`http://host:port`), for the fleet's links.
    pub(crate) http_url: std::sync::OnceLock<String>,
    /// "Read your files again" (SIGHUP): the TLS servers subscribe.
    pub(crate) reload: super::reload_notice::Reload,
    /// Configuration changes run one at a time: the REST API's and the SIGHUP re-reads.
    pub(crate) change_lock: Arc<tokio::sync::Mutex<()>>,
    /// Lines (name, port) whose port was opened by an earlier task of the line, before a
    /// configuration change restarted it: readiness does not wait for the new task to reopen
    /// the same port.
    opened_before: Mutex<BTreeSet<(String, String)>>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

// === impl Supervisor ===

impl Supervisor {
    /// Starts every line of `config` and the Modbus TCP server (bound, serving).
    pub(crate) fn start(
        config: Config,
        overrides: Overrides,
        shutdown: &CancellationToken,
        exported: MetricsRegistry,
    ) -> Result<Arc<Self>, AppError> {
        let image = ProcessImage::new(ImageConfig::default());
        let (memory, persistence) = match open_cp_memory(&config)? {
            Some((memory, persistence)) => (Some(memory), persistence),
            None => (None, None),
        };
        let lines_token = shutdown.child_token();
        let mirrored = Mutex::new(Vec::new());
        let lines = start_every_line(&LineDeps {
            config: &config,
            image: &image,
            metrics: &exported.metrics,
            cp_memory: memory.as_ref(),
            parent: &lines_token,
            mirrored: &mirrored,
        })?;
        let units = Arc::new(RwLock::new(unit_map(&lines, &config, &image)));
        let addr = overrides.modbus_tcp.unwrap_or(config.modbus_tcp.listen);
        let listener = bind_plain(&config, addr)?;
        let snapshot = Snapshot::new(Arc::new(config), lines);
        let tcp_options = LiveOptions::new(snapshot.server.clone());
        let tcp_stats = Arc::new(ServerStats::with_metrics(
            exported.metrics.modbus_tcp().clone(),
            exported.metrics.audit().clone(),
        ));
        let reload = super::reload_notice::Reload::new();
        let tls = super::tls::start(
            &snapshot.config.modbus_tcp,
            &units,
            &tcp_stats,
            shutdown,
            &reload,
        )?;
        let sup = Arc::new(Self {
            started: SystemTime::now(),
            image,
            units,
            tcp_stats,
            exported,
            overrides,
            root: shutdown.clone(),
            lines_token,
            state: RwLock::new(Arc::new(snapshot)),
            cp: Mutex::new(CpState {
                memory,
                persistence,
            }),
            mirrored,
            tcp: tokio::sync::Mutex::new(None),
            tls: tokio::sync::Mutex::new(tls),
            tcp_state: Mutex::new((addr, Arc::new(AtomicBool::new(false)))),
            tcp_options,
            follower: std::sync::OnceLock::new(),
            zenoh_state: Mutex::new(None),
            http_url: std::sync::OnceLock::new(),
            opened_before: Mutex::new(BTreeSet::new()),
            reload,
            change_lock: Arc::default(),
        });
        if let Some(listener) = listener {
            let server = sup.spawn_tcp(listener)?;
            *sup.tcp
                .try_lock()
                .map_err(|_| AppError::Setup("Modbus TCP state busy".into()))? = Some(server);
        }
        Ok(sup)
    }

    /// Registers what follows the lines (once; a second one is refused and returned).
    pub(crate) fn follow(&self, follower: Arc<dyn Follower>) -> Result<(), Arc<dyn Follower>> {
        self.follower.set(follower)
    }

    /// What is in force now.
    pub(crate) fn snapshot(&self) -> Arc<Snapshot> {
        Arc::clone(&self.state.read().unwrap_or_else(PoisonError::into_inner))
    }

    /// Whether an earlier task of line `name`, stopped by a configuration change, had opened
    /// `port` (the same path the line has now).
    pub(crate) fn opened_before(&self, name: &str, port: &str) -> bool {
        lock(&self.opened_before)
            .iter()
            .any(|(line, path)| line == name && path == port)
    }

    /// The address the Modbus TCP server listens on and whether it is up.
    pub(crate) fn tcp_listen(&self) -> (SocketAddr, bool) {
        let state = lock(&self.tcp_state);
        (state.0, state.1.load(Ordering::Acquire))
    }

    /// The address the Modbus/TCP Security server listens on, when it runs.
    pub(crate) async fn tls_local(&self) -> Option<SocketAddr> {
        self.tls.lock().await.as_ref().map(|run| run.local)
    }

    /// Whether plain Modbus TCP is as it should be for readiness: up, or switched off.
    pub(crate) fn tcp_ready(&self) -> bool {
        !self.snapshot().config.modbus_tcp.enabled || self.tcp_listen().1
    }

    /// Binds the listener's server task under its own token.
    fn spawn_tcp(&self, listener: TcpListener) -> Result<TcpServer, AppError> {
        let local = listener.local_addr()?;
        let token = self.root.child_token();
        let up = Arc::new(AtomicBool::new(true));
        let serve = modbus_tcp::serve_live(
            listener,
            Arc::clone(&self.units),
            Arc::clone(&self.tcp_options),
            token.clone(),
            Arc::clone(&self.tcp_stats),
        );
        let flag = Arc::clone(&up);
        let task = crate::task::spawn("modbus-tcp server", async move {
            match serve.await {
                Ok(()) => {}
                Err(e) => warn!(error = %e, "Modbus TCP server ended with an error"),
            }
            flag.store(false, Ordering::Release);
        });
        *lock(&self.tcp_state) = (local, Arc::clone(&up));
        Ok(TcpServer {
            token,
            task,
            local,
            up,
        })
    }

    /// The start checks of every door with the paths of the change confined
    /// ([`super::check::start_issues`]), and what needs the running system: a new Modbus TCP
    /// address can be bound, a persisted CP memory keeps its layout.
    pub(crate) fn validate(&self, new: &Config) -> Result<(), Vec<ConfigIssue>> {
        let old = self.snapshot();
        // The start checks every door runs, with the paths of the change confined.
        let mut issues = super::check::start_issues(
            new,
            super::check::Door::Api {
                in_force: &old.config,
            },
        );
        if let Err(more) = self.running_issues(new) {
            issues.extend(more);
        }
        if issues.is_empty() {
            Ok(())
        } else {
            Err(issues)
        }
    }

    /// What `new` needs from the running system: a new Modbus TCP address can be bound, a
    /// persisted CP memory keeps its layout (it takes another only at a restart).
    pub(crate) fn running_issues(&self, new: &Config) -> Result<(), Vec<ConfigIssue>> {
        let old = self.snapshot();
        let mut issues = Vec::new();
        if self.overrides.modbus_tcp.is_none()
            && new.modbus_tcp.listen != old.config.modbus_tcp.listen
        {
            if let Err(e) = std::net::TcpListener::bind(new.modbus_tcp.listen) {
                issues.push(issue(
                    "modbus_tcp.listen",
                    format!("cannot listen on {}: {e}", new.modbus_tcp.listen),
                ));
            }
        }
        issues.extend(changed_journal_issues(new, &old.config));
        let layout = slave_layout(new);
        let (current, persisted) = {
            let cp = lock(&self.cp);
            (
                cp.memory.as_ref().map(|m| m.layout().clone()),
                cp.persistence.is_some(),
            )
        };
        if let Some(layout) = &layout {
            if persisted && current.as_ref() != Some(layout) {
                issues.push(issue(
                    "cp_memory",
                    "the slave lines need another CP memory layout; a persisted CP memory \
                     (persist_file) takes a new layout only at a restart of the gateway",
                ));
            }
        }
        if issues.is_empty() {
            Ok(())
        } else {
            Err(issues)
        }
    }

    /// Stops everything: lines finish their transaction in flight, connections their request;
    /// the CP memory is saved last.
    pub(crate) async fn stop(&self) {
        self.lines_token.cancel();
        let tcp = self.tcp.lock().await.take();
        if let Some(server) = &tcp {
            server.token.cancel();
        }
        let tls = self.tls.lock().await.take();
        if let Some(follower) = self.follower.get() {
            follower.stop(self).await;
        }
        if let Some(tls) = tls {
            tls.stop().await;
        }
        for (_, line) in self.snapshot().lines.clone() {
            line.handle.join().await;
        }
        if let Some(server) = tcp {
            let _ = server.task.await;
        }
        let persistence = lock(&self.cp).persistence.take();
        if let Some((token, task)) = persistence {
            token.cancel();
            let _ = task.await;
        }
    }
}

/// Starts every line of `deps.config`; a line that cannot start cancels those started (under
/// `deps.parent`) and stops the start.
fn start_every_line(deps: &LineDeps<'_>) -> Result<BTreeMap<String, RunningLine>, AppError> {
    let mut lines = BTreeMap::new();
    for (name, line) in &deps.config.lines {
        match lines::start_line(name, line, deps, None) {
            Ok(running) => {
                lines.insert(name.clone(), running);
            }
            Err(e) => {
                deps.parent.cancel();
                return Err(e);
            }
        }
    }
    Ok(lines)
}

/// The plain Modbus TCP listener bound to `addr`; none with `[modbus_tcp] enabled = false`
/// (Modbus/TCP Security only).
fn bind_plain(config: &Config, addr: SocketAddr) -> Result<Option<TcpListener>, AppError> {
    if !config.modbus_tcp.enabled {
        info!("plain Modbus TCP switched off ([modbus_tcp] enabled = false)");
        return Ok(None);
    }
    modbus_tcp::bind(addr)
        .map(Some)
        .map_err(|source| AppError::Bind {
            what: "Modbus TCP",
            addr,
            source,
        })
}

/// The unit map of `lines`, with the diagnostic unit when `config` sets one (the validation
/// keeps its unit id apart from the lines'), and the transparent lines' forwarded unit ids that
/// remain free.
fn unit_map(
    lines: &BTreeMap<String, RunningLine>,
    config: &Config,
    image: &ProcessImage,
) -> UnitMap {
    let mut map = UnitMap::new();
    for line in lines.values() {
        for (unit, service) in &line.units {
            map.insert(*unit, Arc::clone(service));
        }
    }
    if let Some(unit) = config.modbus_tcp.diagnostic_unit {
        let handles = lines.values().map(|l| l.handle.clone()).collect();
        map.insert(
            unit,
            Arc::new(modbus_tcp::DiagnosticUnit::new(handles, image.clone())),
        );
    }
    // Transparent forwarding takes only the unit ids nobody else holds: a declared unit wins.
    for line in lines.values() {
        for (unit, service) in line.handle.transparent_units() {
            if map.get(unit).is_none() {
                map.insert(unit, service);
            }
        }
    }
    map
}

/// What a running gateway refuses of a line's changed `journal` path (REST changes and SIGHUP
/// re-reads): the line's waiting telegrams are carried into the new journal, so it must not be
/// the journal of another line in force (two numberings would mix) and must hold no telegrams
/// of an earlier use. A line the change adds restores its journal as a start does.
fn changed_journal_issues(new: &Config, in_force: &Config) -> Vec<ConfigIssue> {
    use crate::config::check::resolved;
    let mut issues = Vec::new();
    for (name, line) in &new.lines {
        let (Some(path), Some(before)) = (line.journal(), in_force.lines.get(name)) else {
            continue;
        };
        let here = resolved(path);
        if before.journal().is_some_and(|b| resolved(b) == here) {
            continue;
        }
        let key = format!("lines.{name}.journal");
        let other = in_force
            .lines
            .iter()
            .find(|(n, l)| *n != name && l.journal().is_some_and(|j| resolved(j) == here));
        if let Some((other, _)) = other {
            issues.push(issue(
                &key,
                format!(
                    "{} is the journal of line {other} in force: a change does not move a \
                     journal from one line to another (their sequence numbers would mix)",
                    path.display()
                ),
            ));
        } else if let Ok(probe) = crate::mailbox::journal::probe(path) {
            if probe.waiting > 0 {
                issues.push(issue(
                    &key,
                    format!(
                        "{} holds {} telegrams of an earlier use (numbers up to {}): the line's \
                         waiting telegrams are carried into its new journal, which must hold \
                         none; name another file, or move this one away on the host",
                        path.display(),
                        probe.waiting,
                        probe.last_seq
                    ),
                ));
            }
        }
    }
    issues
}

type Persistence = Option<(CancellationToken, JoinHandle<()>)>;

/// The CP memory of the slave lines, loaded from its file when it is persisted; `None` when no
/// line serves it.
fn open_cp_memory(config: &Config) -> Result<Option<(SharedCpMemory, Persistence)>, AppError> {
    let Some(layout) = slave_layout(config) else {
        return Ok(None);
    };
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
