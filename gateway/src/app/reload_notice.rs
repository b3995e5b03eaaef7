//! The notification that tells every holder of files to read them again (a SIGHUP, after the
//! configuration file was handled: [`super::reload`]). A leaf: the TLS servers and the supervisor
//! hold it without knowing who sends it.

use std::sync::Arc;

use tokio::sync::watch;

/// "Read your files again", one notification for every part of the running gateway that holds
/// files (TLS certificates and keys). A holder subscribes and reloads on every change of the
/// counter it sees; a reload it missed while busy is seen once (the counter moved).
#[derive(Clone, Debug)]
pub(crate) struct Reload {
    tx: Arc<watch::Sender<u64>>,
}

// === impl Reload ===

impl Reload {
    pub(crate) fn new() -> Self {
        Self {
            tx: Arc::new(watch::Sender::new(0)),
        }
    }

    /// A receiver that sees every reload from now on (`changed().await`).
    pub(crate) fn subscribe(&self) -> watch::Receiver<u64> {
        self.tx.subscribe()
    }

    /// Tells every subscriber to read its files again.
    pub(crate) fn notify(&self) {
        self.tx.send_modify(|n| *n = n.wrapping_add(1));
    }
}

impl Default for Reload {
    fn default() -> Self {
        Self::new()
    }
}
