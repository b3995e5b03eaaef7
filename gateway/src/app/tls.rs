//! Modbus/TCP Security in the running gateway: the `[modbus_tcp.tls]` server next to the plain
//! one, its certificates read again on every reload notification (SIGHUP, `super::reload`), its files and roles replaced on a configuration
//! change without dropping the clients that are connected.

use std::net::SocketAddr;
use std::sync::Arc;

use tokio::sync::watch;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

use super::build::unit_write_ranges;
use super::reload_notice::Reload;
use super::{server_options, AppError};
use crate::config::{FunctionClassConfig, ModbusTcpConfig, ModbusTlsConfig};
use crate::modbus_tcp::{self, LiveOptions, RoleRights, Roles, ServerStats, TlsFiles, TlsServer};
use crate::unit::SharedUnits;

/// The running Modbus/TCP Security server.
pub(crate) struct TlsRun {
    pub(crate) server: TlsServer,
    pub(crate) local: SocketAddr,
    /// What it was started with: a change of it restarts the server; a change of the files,
    /// roles or limits only replaces them (new connections take them, open ones stay).
    listen: SocketAddr,
    options: Arc<LiveOptions>,
    token: CancellationToken,
    task: JoinHandle<()>,
}

/// The files of `cfg`.
pub(crate) fn files(cfg: &ModbusTlsConfig) -> TlsFiles {
    TlsFiles {
        cert: cfg.cert.clone(),
        key: cfg.key.clone(),
        ca: cfg.ca.clone(),
    }
}

/// The roles of `cfg`, as the server checks them.
pub(crate) fn roles(cfg: &ModbusTlsConfig) -> Roles {
    cfg.roles
        .iter()
        .map(|(name, role)| {
            let has = |class| role.functions.contains(&class);
            let rights = RoleRights {
                units: (!role.units.is_empty()).then(|| role.units.clone()),
                read: has(FunctionClassConfig::Read),
                write: has(FunctionClassConfig::Write),
                diagnostics: has(FunctionClassConfig::Diagnostics),
                write_ranges: unit_write_ranges(&role.write_ranges),
            };
            (name.clone(), rights)
        })
        .collect()
}

/// Starts the server of `cfg.tls`, if configured: binds its address, reads its files.
pub(crate) fn start(
    cfg: &ModbusTcpConfig,
    units: &SharedUnits,
    stats: &Arc<ServerStats>,
    root: &CancellationToken,
    reload: &Reload,
) -> Result<Option<TlsRun>, AppError> {
    let Some(tls) = &cfg.tls else {
        return Ok(None);
    };
    let server = TlsServer::new(files(tls), roles(tls))
        .map_err(|e| AppError::Setup(format!("Modbus/TCP Security: {e}")))?;
    let listener = modbus_tcp::bind(tls.listen).map_err(|source| AppError::Bind {
        what: "Modbus/TCP Security",
        addr: tls.listen,
        source,
    })?;
    let local = listener.local_addr()?;
    let token = root.child_token();
    let options = LiveOptions::new(server_options(cfg));
    let serve = modbus_tcp::serve_tls_live(
        listener,
        Arc::clone(units),
        Arc::clone(&options),
        server.clone(),
        token.clone(),
        Arc::clone(stats),
    );
    let task = tokio::spawn(async move {
        if let Err(e) = serve.await {
            warn!(error = %e, "Modbus/TCP Security server ended with an error");
        }
    });
    spawn_reloader("Modbus/TCP Security", reload.subscribe(), token.clone(), {
        let server = server.clone();
        move || server.reload()
    });
    info!(%local, roles = tls.roles.len(), "Modbus/TCP Security listening");
    Ok(Some(TlsRun {
        server,
        local,
        listen: tls.listen,
        options,
        token,
        task,
    }))
}

/// Applies a changed `[modbus_tcp]`: the same address keeps the server and its clients, which
/// take the new files, roles and limits (for new connections; the write policy and timeouts for
/// the next request); a new address restarts the server.
pub(crate) async fn apply(
    running: &mut Option<TlsRun>,
    cfg: &ModbusTcpConfig,
    units: &SharedUnits,
    stats: &Arc<ServerStats>,
    root: &CancellationToken,
    reload: &Reload,
) -> Result<(), String> {
    if let (Some(run), Some(tls)) = (running.as_ref(), &cfg.tls) {
        if run.listen == tls.listen {
            run.options.set(server_options(cfg));
            return run
                .server
                .replace(files(tls), roles(tls))
                .map_err(|e| format!("Modbus/TCP Security: {e}"));
        }
    }
    if let Some(old) = running.take() {
        old.stop().await;
    }
    *running = start(cfg, units, stats, root, reload).map_err(|e| e.to_string())?;
    Ok(())
}

// === impl TlsRun ===

impl TlsRun {
    /// Stops accepting and waits (bounded) for the connections to finish their request.
    pub(crate) async fn stop(self) {
        self.token.cancel();
        if tokio::time::timeout(super::GRACE_PERIOD, self.task)
            .await
            .is_err()
        {
            warn!("the Modbus/TCP Security server did not stop within the grace period");
        }
    }
}

/// Calls `reload` (which reads a server's certificate, key and CA again) on every reload
/// notification (SIGHUP) until `token` is cancelled; files that cannot be read leave the old ones
/// in use. `what` names the server in the log. Modbus/TCP Security and HTTPS each have one.
pub(crate) fn spawn_reloader<E: std::fmt::Display>(
    what: &'static str,
    mut reloads: watch::Receiver<u64>,
    token: CancellationToken,
    reload: impl Fn() -> Result<(), E> + Send + 'static,
) {
    tokio::spawn(async move {
        loop {
            tokio::select! {
                () = token.cancelled() => return,
                changed = reloads.changed() => if changed.is_err() { return },
            }
            reloads.borrow_and_update();
            // Within the SIGHUP log limits (a burst of SIGHUPs writes a bounded number of lines).
            match reload() {
                Ok(()) => {
                    if let Some(suppressed) =
                        super::hangup_log::hangup_line(&super::hangup_log::HANGUP_LOG)
                    {
                        info!(suppressed, "SIGHUP: {what} certificates read again");
                    }
                }
                Err(e) => {
                    if let Some(suppressed) =
                        super::hangup_log::hangup_line(&super::hangup_log::HANGUP_WARN_LOG)
                    {
                        warn!(error = %e, suppressed, "SIGHUP: {what} certificates not reloaded, the old ones stay");
                    }
                }
            }
        }
    });
}
