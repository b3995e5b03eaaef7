//! SIGHUP: the configuration file read again and applied, the TLS files read again.
//!
//! The process installs its signal handlers first thing (`handle_signals`, before the
//! configuration is read or anything slow starts), so a SIGHUP during start never kills it: it
//! is remembered and handled once the gateway runs. Then every SIGHUP:
//!
//! 1. re-reads `--config` and runs the checks `gateway check` runs on it (the file's rules and
//!    [`super::check::start_issues`]) with those that need the running system (a new Modbus TCP
//!    address can be bound, a persisted CP memory keeps its layout); a refused file is not
//!    applied, the running configuration stays, and a warning says why, every problem with its
//!    path;
//! 2. applies an accepted file as a REST replace does ([`Supervisor::apply`]: only the lines and
//!    servers that changed restart), one change at a time with the REST API's changes;
//! 3. tells every holder of files to read them again through [`Reload`] (Modbus/TCP Security's
//!    certificate, key and CA; any TLS listener subscribes the same way), whatever step 1 found:
//!    a renewed certificate is taken even when an unrelated part of the file is refused.
//!
//! `gateway demo` has no file: a SIGHUP says so and only step 3 runs.
//!
//! The log lines of SIGHUPs are rate-limited (`hangup_log`). Every SIGHUP is still handled
//! (SIGHUPs that arrive while one is handled are taken together: the file is read once more
//! after them, so its last change is the one applied).

use std::path::Path;
use std::sync::Arc;

use tokio::sync::watch;
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

use super::hangup_log::{hangup_line, HANGUP_LOG, HANGUP_WARN_LOG};
use super::supervisor::Supervisor;

use crate::config::ConfigIssue;

/// Handles every SIGHUP counted by `hangups` (the counter [`super::handle_signals`] raises)
/// until `shutdown`; a SIGHUP that arrived before this started is handled at once.
pub(crate) async fn on_hangup(
    sup: Arc<Supervisor>,
    mut hangups: watch::Receiver<u64>,
    shutdown: CancellationToken,
) {
    loop {
        tokio::select! {
            () = shutdown.cancelled() => return,
            changed = hangups.changed() => if changed.is_err() { return },
        }
        hangups.borrow_and_update();
        reload(&sup).await;
    }
}

/// One SIGHUP: the file (if any) checked and applied, then the files' holders told.
pub(crate) async fn reload(sup: &Arc<Supervisor>) {
    match sup.overrides.config_file.clone() {
        Some(path) => reload_file(sup, &path).await,
        None => {
            if let Some(suppressed) = hangup_line(&HANGUP_LOG) {
                info!(
                    suppressed,
                    "SIGHUP: no configuration file to re-read (the demo's configuration is built \
                     in); the running configuration stays"
                );
            }
        }
    }
    // What the re-read freed (the file's text, the configuration replaced) goes back.
    crate::heap::release_free_memory();
    sup.reload.notify();
}

/// Reads, checks and applies the configuration file at `path`.
async fn reload_file(sup: &Arc<Supervisor>, path: &Path) {
    let file = path.to_owned();
    let checked = tokio::task::spawn_blocking(move || super::load_for_run(&file)).await;
    let config = match checked {
        Ok(Ok(config)) => config,
        Ok(Err(errors)) => return refused(path, &errors.issues),
        Err(e) => {
            if let Some(suppressed) = hangup_line(&HANGUP_WARN_LOG) {
                warn!(file = %path.display(), error = %e, suppressed, "SIGHUP: the configuration file was not checked; the running configuration stays");
            }
            return;
        }
    };
    // One change at a time, with the REST API's.
    let _one_at_a_time = sup.change_lock.lock().await;
    if let Err(issues) = sup.running_issues(&config) {
        return refused(path, &issues);
    }
    if config == *sup.snapshot().config {
        if let Some(suppressed) = hangup_line(&HANGUP_LOG) {
            info!(file = %path.display(), suppressed, "SIGHUP: the configuration file is the configuration in force; nothing to apply");
        }
        return;
    }
    match sup.apply(Arc::new(config)).await {
        Ok(report) => {
            if let Some(suppressed) = hangup_line(&HANGUP_LOG) {
                info!(
                    file = %path.display(),
                    lines_started = ?report.lines_started,
                    lines_stopped = ?report.lines_stopped,
                    lines_restarted = ?report.lines_restarted,
                    servers_restarted = ?report.servers_restarted,
                    pending_restart = ?report.pending_restart,
                    suppressed,
                    "SIGHUP: configuration file applied (only what changed restarted)"
                );
            }
        }
        Err(e) => {
            if let Some(suppressed) = hangup_line(&HANGUP_WARN_LOG) {
                warn!(file = %path.display(), error = %e, suppressed, "SIGHUP: configuration file applied, but not every part started");
            }
        }
    }
}

/// The warning for a refused file: every problem with its path, on one line.
fn refused(path: &Path, issues: &[ConfigIssue]) {
    let Some(suppressed) = hangup_line(&HANGUP_WARN_LOG) else {
        return;
    };
    let problems: Vec<String> = issues.iter().map(ToString::to_string).collect();
    warn!(
        suppressed,
        file = %path.display(),
        problems = %problems.join("; "),
        "SIGHUP: configuration file refused by the checks of `gateway check`, not applied; the running configuration stays"
    );
}
