//! Modbus/TCP Security in the running gateway: the `[modbus_tcp.tls]` server next to the plain
//! one, its certificates read again on every reload notification (SIGHUP, `super::reload`), its files and roles replaced on a configuration
//! change without dropping the clients that are connected.

use std::net::SocketAddr;
use std::path::Path;
use std::sync::Arc;

use tokio::sync::watch;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

use super::build::unit_write_ranges;
use super::reload_notice::Reload;
use super::{server_options, AppError};
use crate::api::tls::tls_issue;
use crate::config::check::Check;
use crate::config::{ConfigIssue, Cx, FunctionClassConfig, ModbusTcpConfig, ModbusTlsConfig};
use crate::modbus_tcp::{self, LiveOptions, RoleRights, Roles, ServerStats, TlsFiles, TlsServer};
use crate::plant::check::{ApiChange, Start};
use crate::plant::Config;
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
    let task = crate::task::spawn("modbus-tcp security server", async move {
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
    crate::task::spawn("tls reloader", async move {
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

/// Modbus/TCP Security's files: at start read and made into TLS settings as `run` makes them
/// (certificate chain, private key matching it, client CA: a missing, unreadable or unusable
/// file is an issue at its key, with the path); through the REST API each confined to
/// `[gateway] config_dirs`.
pub(crate) struct ModbusTlsFiles;

/// The keys of the Modbus/TCP Security files.
const TLS_KEYS: [&str; 3] = [
    "modbus_tcp.tls.cert",
    "modbus_tcp.tls.key",
    "modbus_tcp.tls.ca",
];

impl Check<Start<'_>> for ModbusTlsFiles {
    fn check(&self, start: &Start<'_>, cx: &mut Cx) {
        if !TLS_KEYS.iter().any(|k| start.refused(k)) {
            cx.issues.extend(tls_issues(start.config));
        }
    }
}

impl Check<ApiChange<'_>> for ModbusTlsFiles {
    fn check(&self, change: &ApiChange<'_>, cx: &mut Cx) {
        let new = change.new.modbus_tcp.tls.as_ref();
        let old = change.in_force.modbus_tcp.tls.as_ref();
        let files: [fn(&ModbusTlsConfig) -> &Path; 3] = [|t| &t.cert, |t| &t.key, |t| &t.ca];
        for (key, file) in TLS_KEYS.iter().zip(files) {
            change.config_file(cx, key, new.map(file), old.map(file));
        }
    }
}

/// Modbus/TCP Security's files read and made into TLS settings as `run` makes them at start.
fn tls_issues(config: &Config) -> Vec<ConfigIssue> {
    let Some(tls) = config.modbus_tcp.tls.as_ref() else {
        return Vec::new();
    };
    match TlsServer::new(files(tls), roles(tls)) {
        Ok(_) => Vec::new(),
        Err(e) => vec![tls_issue(
            &e,
            "Modbus/TCP Security",
            "modbus_tcp.tls",
            TLS_KEYS,
        )],
    }
}

#[cfg(test)]
mod tests {
    use super::super::check::run_issues;
    use super::*;

    #[test]
    fn modbus_tcp_security_files_are_loaded_as_run_loads_them() {
        let dir = tempfile::tempdir().unwrap();
        let ca_key = rcgen::KeyPair::generate().unwrap();
        let mut ca_params = rcgen::CertificateParams::new(Vec::<String>::new()).unwrap();
        ca_params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
        let ca = ca_params.self_signed(&ca_key).unwrap();
        let key = rcgen::KeyPair::generate().unwrap();
        let cert = rcgen::CertificateParams::new(vec!["localhost".to_owned()])
            .unwrap()
            .self_signed(&key)
            .unwrap();
        let path = |name: &str| dir.path().join(name);
        std::fs::write(path("ca.crt"), ca.pem()).unwrap();
        std::fs::write(path("server.crt"), cert.pem()).unwrap();
        std::fs::write(path("server.key"), key.serialize_pem()).unwrap();
        std::fs::write(path("empty.crt"), "").unwrap();
        let config = |cert: &str, key: &str, ca: &str| {
            crate::plant::parse(&format!(
                "[modbus_tcp.tls]\ncert = \"{}\"\nkey = \"{}\"\nca = \"{}\"\n",
                path(cert).display(),
                path(key).display(),
                path(ca).display()
            ))
            .expect("parses")
        };
        assert_eq!(
            tls_issues(&config("server.crt", "server.key", "ca.crt")),
            Vec::<ConfigIssue>::new()
        );
        for (c, k, a, at, file) in [
            (
                "absent.crt",
                "server.key",
                "ca.crt",
                "modbus_tcp.tls.cert",
                "absent.crt",
            ),
            (
                "server.crt",
                "absent.key",
                "ca.crt",
                "modbus_tcp.tls.key",
                "absent.key",
            ),
            (
                "server.crt",
                "server.key",
                "absent.crt",
                "modbus_tcp.tls.ca",
                "absent.crt",
            ),
            (
                "server.crt",
                "server.key",
                "empty.crt",
                "modbus_tcp.tls.ca",
                "empty.crt",
            ),
        ] {
            let issues = tls_issues(&config(c, k, a));
            assert_eq!(issues.len(), 1, "{issues:?}");
            assert_eq!(issues[0].path, at);
            assert!(issues[0].message.contains(file), "{}", issues[0].message);
        }
        // run refuses the same before a port opens.
        let issues = run_issues(&config("server.crt", "absent.key", "ca.crt"));
        assert!(
            issues.iter().any(|i| i.path == "modbus_tcp.tls.key"),
            "{issues:?}"
        );
    }
}
