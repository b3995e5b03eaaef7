//! The log lines of SIGHUPs, rate-limited ([`HANGUP_LOG`], [`HANGUP_WARN_LOG`]): a burst of
//! SIGHUPs writes at most [`HANGUP_BURST`] INFO and [`HANGUP_BURST`] WARN lines per
//! [`HANGUP_WINDOW`], then, once the window is over, one line with the number left out. Shared
//! by the re-read of the file (`reload`), the TLS listeners' reload (`tls`) and the signal loop.

use tracing::{info, warn};

use crate::log_limit::{LogLimit, Verdict};

/// The window of the SIGHUP log limits.
pub(crate) const HANGUP_WINDOW: std::time::Duration = std::time::Duration::from_secs(10);

/// The most lines of one level the SIGHUPs of one window write (three SIGHUPs' worth: each
/// writes "received" and what came of it).
pub(crate) const HANGUP_BURST: u32 = 6;

/// INFO lines of SIGHUPs: received, applied, nothing to apply, certificates read again.
pub(crate) static HANGUP_LOG: LogLimit = LogLimit::new(HANGUP_WINDOW, HANGUP_BURST);

/// WARN lines of SIGHUPs: a file refused, a part not started, certificates not reloaded.
pub(crate) static HANGUP_WARN_LOG: LogLimit = LogLimit::new(HANGUP_WINDOW, HANGUP_BURST);

/// Whether a SIGHUP line of `limit` is written now: `Some(n)` with the `n` left out before it.
pub(crate) fn hangup_line(limit: &LogLimit) -> Option<u64> {
    match limit.check() {
        Verdict::Log { suppressed } => Some(suppressed),
        Verdict::Suppress => None,
    }
}

/// When the SIGHUP lines left out must be told (the end of a window with lines left out).
pub(crate) fn hangup_left_out_until() -> Option<tokio::time::Instant> {
    [&HANGUP_LOG, &HANGUP_WARN_LOG]
        .iter()
        .filter_map(|limit| limit.left_out_until())
        .max()
        .map(tokio::time::Instant::from_std)
}

/// Writes one line with the number of SIGHUP lines left out in windows that are over.
pub(crate) fn tell_hangup_left_out() {
    let now = std::time::Instant::now();
    let info = HANGUP_LOG.take_left_out_at(now).unwrap_or(0);
    let warn = HANGUP_WARN_LOG.take_left_out_at(now).unwrap_or(0);
    let secs = HANGUP_WINDOW.as_secs();
    let left_out = info + warn;
    if warn > 0 {
        warn!(
            left_out, info, warn,
            "SIGHUP: {left_out} log lines about SIGHUPs left out in the last {secs} s (rate limit; every SIGHUP was handled)"
        );
    } else if info > 0 {
        info!(
            left_out, info, warn,
            "SIGHUP: {left_out} log lines about SIGHUPs left out in the last {secs} s (rate limit; every SIGHUP was handled)"
        );
    }
}
