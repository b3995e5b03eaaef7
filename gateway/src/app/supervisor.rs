//! The supervisor of a running gateway: its lines (each with its own cancellation token), the
//! Modbus TCP server, the zenoh bridge, and the configuration in force.
//!
//! A configuration change is applied by [`Supervisor::apply`]: [`ConfigDiff`] says what changed,
//! and only that is stopped and started again. A line whose serial or protocol settings or
//! devices changed is restarted as a whole (a line task takes its device list at start); a line
//! that did not change keeps its task, its open port, its counters and its diagnostic buffer, and
//! the Modbus TCP clients of its units keep their connections. A changed `[modbus_tcp]` limit
//! (caps, idle and request timeouts, networks, read-only, write ranges, TLS files and roles) is
//! put in force in the running servers (`modbus_tcp::LiveOptions`) for new connections and the
//! next request of open ones, which stay connected; only a changed listen address (or plain
//! Modbus TCP switched on or off) restarts a server. The zenoh session only when the gateway's name (its key
//! prefix) changed. Other sections (`[cp_memory]`, `[http]`, `[zenoh]`) take effect at the next
//! start of the process and are reported as pending. A SIGHUP re-read of the configuration file
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

use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

use super::lines::{self, slave_layout, LineDeps, RunningLine};
use super::{server_options, AppError, MetricsRegistry, Overrides, GRACE_PERIOD};
use crate::api::model::ApplyReport;
use crate::api::{ApiError, BoxFuture, ConfigDiff};
use crate::config::ConfigIssue;
use crate::cpmem::{self, SharedCpMemory};
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
        let mut lines = BTreeMap::new();
        {
            let deps = LineDeps {
                config: &config,
                image: &image,
                metrics: &exported.metrics,
                cp_memory: memory.as_ref(),
                parent: &lines_token,
                mirrored: &mirrored,
            };
            for (name, line) in &config.lines {
                match lines::start_line(name, line, &deps, None) {
                    Ok(running) => {
                        lines.insert(name.clone(), running);
                    }
                    Err(e) => {
                        lines_token.cancel();
                        return Err(e);
                    }
                }
            }
        }
        let units = Arc::new(RwLock::new(unit_map(&lines, &config, &image)));
        let addr = overrides.modbus_tcp.unwrap_or(config.modbus_tcp.listen);
        // `[modbus_tcp] enabled = false`: no plain listener (Modbus/TCP Security only).
        let listener = if config.modbus_tcp.enabled {
            Some(modbus_tcp::bind(addr).map_err(|source| AppError::Bind {
                what: "Modbus TCP",
                addr,
                source,
            })?)
        } else {
            info!("plain Modbus TCP switched off ([modbus_tcp] enabled = false)");
            None
        };
        let snapshot_options = server_options(&config.modbus_tcp);
        let snapshot = Snapshot {
            tags: Arc::new(TagDirectory::from_config(&config)),
            server: snapshot_options.clone(),
            config: Arc::new(config),
            lines,
        };
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
            tcp_options: LiveOptions::new(snapshot_options),
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
    fn spawn_tcp(&self, listener: tokio::net::TcpListener) -> Result<TcpServer, AppError> {
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
        let task = tokio::spawn(async move {
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

    /// Puts `new` in force, restarting only what changed; reports what was restarted.
    pub(crate) async fn apply(self: &Arc<Self>, new: Arc<Config>) -> Result<ApplyReport, ApiError> {
        let old = self.snapshot();
        let diff = ConfigDiff::between(&old.config, &new);
        let mut report = diff.report();
        // A line task takes its devices at start: a device change restarts its line.
        let mut restart: BTreeSet<String> = diff.lines_changed.iter().cloned().collect();
        restart.extend(diff.devices_changed.iter().map(|(line, _)| line.clone()));
        let memory = self.memory_for(&new, &old.config, &mut restart);
        report.devices_restarted.clear();
        report.lines_restarted = restart.iter().cloned().collect();

        // Stop the removed and the changed lines; their ports close before they reopen. A
        // restarted telegram line hands its waiting telegrams (confirmed to the partner) and
        // numbers to the line that replaces it.
        let mut lines = old.lines.clone();
        let mut carried: BTreeMap<String, crate::mailbox::Carried> = BTreeMap::new();
        for name in diff.lines_removed.iter().chain(&restart) {
            let Some(line) = lines.remove(name) else {
                continue;
            };
            let mailbox = line
                .handle
                .mailbox()
                .filter(|_| new.lines.contains_key(name));
            {
                let key = (name.clone(), line.port.clone());
                let mut opened = lock(&self.opened_before);
                let known = opened.contains(&key);
                opened.retain(|(line_name, _)| line_name != name);
                if new.lines.contains_key(name) && (known || line.handle.status().port_opens > 0) {
                    opened.insert(key);
                }
            }
            stop_line(name, line).await;
            if let Some(mailbox) = mailbox {
                carried.insert(name.clone(), mailbox.carry());
            }
            let kept: BTreeSet<&String> = new
                .lines
                .get(name)
                .map(|l| l.devices().map(|(d, _)| d).collect())
                .unwrap_or_default();
            if let Some(before) = old.config.lines.get(name) {
                for (device, _) in before.devices().filter(|(d, _)| !kept.contains(d)) {
                    self.exported.metrics.line().forget_device(name, device);
                }
                // A removed line, or one under another protocol: its series (labelled with the
                // old protocol) go; the new line's start from zero.
                let protocol = before.protocol.kind().as_str();
                let same_protocol = new
                    .lines
                    .get(name)
                    .is_some_and(|l| l.protocol.kind().as_str() == protocol);
                if !same_protocol {
                    self.exported.metrics.line().forget_line(name, protocol);
                }
            }
        }

        // Start the added and the changed lines.
        let mut failures = Vec::new();
        let mut started = Vec::new();
        {
            let deps = LineDeps {
                config: &new,
                image: &self.image,
                metrics: &self.exported.metrics,
                cp_memory: memory.as_ref(),
                parent: &self.lines_token,
                mirrored: &self.mirrored,
            };
            for name in diff.lines_added.iter().chain(&restart) {
                let Some(line) = new.lines.get(name) else {
                    continue;
                };
                match lines::start_line(name, line, &deps, carried.remove(name)) {
                    Ok(running) => {
                        info!(line = %name, port = %running.port, "line started");
                        lines.insert(name.clone(), running);
                        started.push(name.clone());
                    }
                    Err(e) => {
                        warn!(line = %name, error = %e, "line did not start");
                        failures.push(format!("line {name}: {e}"));
                    }
                }
            }
        }

        // A mirror no running slave line keeps any more (its unit id or address map changed, or
        // the line went) stops: the memory's changes no longer reach the image there.
        let gone: Vec<(u8, AddressMap)> = {
            let live: Vec<&(u8, AddressMap)> =
                lines.values().filter_map(|l| l.mirror.as_ref()).collect();
            let mut mirrored = lock(&self.mirrored);
            let (kept, gone) = mirrored.drain(..).partition(|key| live.contains(&key));
            *mirrored = kept;
            gone
        };
        // The memory in force (a replaced one was emptied of mirrors with the set). The mirror
        // set's lock is released first: `memory_for` takes the two in the other order.
        let current = lock(&self.cp).memory.clone();
        if let Some(memory) = current {
            for (unit, map) in &gone {
                if memory.unmirror(*unit, map) {
                    info!(
                        unit = *unit,
                        "CP memory mirror stopped: no slave line serves it"
                    );
                }
            }
        }

        // The units of every line, then the new snapshot, in one swap each.
        let map = unit_map(&lines, &new, &self.image);
        *self.units.write().unwrap_or_else(PoisonError::into_inner) = map;
        let snapshot = Arc::new(Snapshot {
            tags: Arc::new(TagDirectory::from_config(&new)),
            server: server_options(&new.modbus_tcp),
            config: new,
            lines,
        });
        *self.state.write().unwrap_or_else(PoisonError::into_inner) = Arc::clone(&snapshot);
        if let Some(follower) = self.follower.get() {
            follower.lines_started(&snapshot, &started).await;
        }

        report.servers_restarted.clear();
        if diff.modbus_tcp_changed {
            // The limits first: a server that keeps running takes them for what comes next.
            self.tcp_options.set(snapshot.server.clone());
            match self.restart_tcp().await {
                Ok(true) => report.servers_restarted.push("modbus_tcp".into()),
                Ok(false) => info!(
                    "Modbus TCP limits applied to the running server; its clients stay connected"
                ),
                Err(e) => failures.push(e),
            }
            let cfg = &self.snapshot().config.modbus_tcp;
            let mut tls = self.tls.lock().await;
            if let Err(e) = super::tls::apply(
                &mut tls,
                cfg,
                &self.units,
                &self.tcp_stats,
                &self.root,
                &self.reload,
            )
            .await
            {
                failures.push(e);
            }
        }
        let renamed = match self.follower.get() {
            Some(follower) if diff.name_changed => follower.renamed(self).await,
            _ => false,
        };
        if renamed {
            report.servers_restarted.push("zenoh".into());
        }
        if failures.is_empty() {
            Ok(report)
        } else {
            Err(ApiError::internal(format!(
                "the configuration was saved but not every part started: {}",
                failures.join("; ")
            )))
        }
    }

    /// The CP memory the slave lines of `new` serve: the running one when its layout fits,
    /// otherwise a new one, and then every slave line restarts on it.
    fn memory_for(
        &self,
        new: &Config,
        old: &Config,
        restart: &mut BTreeSet<String>,
    ) -> Option<SharedCpMemory> {
        let layout = slave_layout(new)?;
        let mut cp = lock(&self.cp);
        if let Some(memory) = cp.memory.as_ref().filter(|m| m.layout() == &layout) {
            return Some(memory.clone());
        }
        // Only an unpersisted memory gets here (validate refuses the other case).
        info!("the slave lines need another CP memory layout: a new memory, every slave line restarts");
        let memory = SharedCpMemory::new(layout);
        cp.memory = Some(memory.clone());
        lock(&self.mirrored).clear();
        for (name, line) in &new.lines {
            if line.protocol.cp_memory_slave().is_some() && old.lines.contains_key(name) {
                restart.insert(name.clone());
            }
        }
        Some(memory)
    }

    /// Restarts the Modbus TCP server when its address changed, or switches it on or off, as the
    /// configuration in force says; `Ok(true)` when it restarted (or stopped). A port 0 address
    /// keeps the port the server had. The same address keeps the server and its connections (its
    /// limits were replaced in place).
    async fn restart_tcp(&self) -> Result<bool, String> {
        let config = self.snapshot().config.modbus_tcp.clone();
        let mut slot = self.tcp.lock().await;
        let want = self.overrides.modbus_tcp.unwrap_or(config.listen);
        let old_local = slot.as_ref().map(|s| s.local);
        let addr = match old_local {
            Some(local) if want.port() == 0 && want.ip() == local.ip() => local,
            _ => want,
        };
        let bind = |addr| {
            modbus_tcp::bind(addr).map_err(|e| format!("Modbus TCP cannot listen on {addr}: {e}"))
        };
        if !config.enabled {
            if let Some(old) = slot.take() {
                old.token.cancel();
                if tokio::time::timeout(GRACE_PERIOD, old.task).await.is_err() {
                    warn!("the old Modbus TCP server did not stop within the grace period");
                }
                old.up.store(false, Ordering::Release);
                info!("plain Modbus TCP switched off");
                return Ok(true);
            }
            return Ok(false);
        }
        if slot.is_some() && Some(addr) == old_local {
            return Ok(false);
        }
        // A new address is bound before the old server stops: a failure leaves it running.
        let early = if Some(addr) == old_local {
            None
        } else {
            Some(bind(addr)?)
        };
        if let Some(old) = slot.take() {
            old.token.cancel();
            if tokio::time::timeout(GRACE_PERIOD, old.task).await.is_err() {
                warn!("the old Modbus TCP server did not stop within the grace period");
            }
            old.up.store(false, Ordering::Release);
        }
        let listener = match early {
            Some(l) => l,
            None => bind(addr)?,
        };
        let server = self.spawn_tcp(listener).map_err(|e| e.to_string())?;
        info!(local = %server.local, "Modbus TCP server restarted");
        *slot = Some(server);
        Ok(true)
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

/// Cancels a line and waits (bounded) for its task, which closes its port.
async fn stop_line(name: &str, line: RunningLine) {
    line.token.cancel();
    if tokio::time::timeout(GRACE_PERIOD, line.handle.join())
        .await
        .is_err()
    {
        warn!(line = %name, grace = ?GRACE_PERIOD, "line did not stop within the grace period");
    } else {
        info!(line = %name, "line stopped");
    }
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
    use super::check::resolved;
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

fn issue(path: &str, message: impl Into<String>) -> ConfigIssue {
    ConfigIssue {
        path: path.to_owned(),
        message: message.into(),
    }
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
