//! What the line tests share: in-process ports for the runtime to open, waiting for a line to get
//! somewhere, and its event counts.

use std::collections::VecDeque;
use std::sync::{Mutex, PoisonError};
use std::time::Duration;

use proto_core::event::EventId;
use tokio::io::DuplexStream;

use super::runtime::{LineHandle, PortOpener};
use crate::serial::PortSettings;

/// Hands out one in-process port, then refuses ("no second port"); the test's end plays the
/// partner (and writes what the tty layer delivers from a UART with `INPCK | PARMRK` where the
/// test needs line errors, which a pty cannot produce).
pub(crate) struct OnePort(pub(crate) Mutex<Option<DuplexStream>>);

impl PortOpener for OnePort {
    type Port = DuplexStream;

    fn open(&self, _settings: &PortSettings) -> Result<DuplexStream, String> {
        self.0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .take()
            .ok_or_else(|| "no second port".to_owned())
    }
}

/// Hands out the ports (or refusals) of a queue in order, then refuses ("no such port").
pub(crate) struct Ports(pub(crate) Mutex<VecDeque<Result<DuplexStream, String>>>);

impl PortOpener for Ports {
    type Port = DuplexStream;

    fn open(&self, _settings: &PortSettings) -> Result<DuplexStream, String> {
        self.0
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .pop_front()
            .unwrap_or_else(|| Err("no such port".into()))
    }
}

/// Waits up to 5 s for `check`; panics naming `what` if it never holds.
pub(crate) async fn eventually(what: &str, mut check: impl FnMut() -> bool) {
    for _ in 0..500 {
        if check() {
            return;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    panic!("{what} did not happen");
}

/// How often `line` raised `id` since it started.
pub(crate) fn events(line: &LineHandle, id: EventId) -> u64 {
    line.status().event_counts.get(&id).copied().unwrap_or(0)
}
