//! What the accept loop hands to every connection of one server: the unit map, the options and
//! the counters.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use super::metrics::ServerStats;
use super::options::{LiveOptions, ServerOptions};
use super::tls::TlsServer;
use crate::unit::SharedUnits;

/// What every connection of one server shares.
pub(crate) struct Shared {
    /// The units; replaced at run time by whoever holds the other `Arc`.
    pub(crate) units: SharedUnits,
    /// Limits and policy, replaced while the server runs.
    pub(crate) options: Arc<LiveOptions>,
    /// Connections open (for `max_connections`, read at each accept).
    pub(crate) open: Arc<AtomicUsize>,
    /// Counters.
    pub(crate) stats: Arc<ServerStats>,
    /// The TLS settings and roles of a Modbus/TCP Security server; `None` for plain Modbus TCP.
    pub(crate) tls: Option<TlsServer>,
    /// Connections open per client address (canonical form), for the per-client cap.
    pub(crate) clients: Arc<Mutex<HashMap<IpAddr, usize>>>,
}

/// One connection's place in its client address's cap; given back when dropped.
pub(crate) struct ClientPlace {
    clients: Arc<Mutex<HashMap<IpAddr, usize>>>,
    ip: IpAddr,
}

// === impl ClientPlace ===

impl ClientPlace {
    /// A place for a connection from `ip`, or `None` when the address has its
    /// `max_connections_per_client` open.
    pub(crate) fn take(shared: &Shared, options: &ServerOptions, ip: IpAddr) -> Option<Self> {
        let ip = ip.to_canonical();
        let mut clients = shared
            .clients
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let open = clients.entry(ip).or_default();
        if options
            .max_connections_per_client
            .is_some_and(|cap| *open >= cap)
        {
            if *open == 0 {
                clients.remove(&ip);
            }
            return None;
        }
        *open += 1;
        Some(Self {
            clients: Arc::clone(&shared.clients),
            ip,
        })
    }
}

impl Drop for ClientPlace {
    fn drop(&mut self) {
        let mut clients = self.clients.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(open) = clients.get_mut(&self.ip) {
            *open = open.saturating_sub(1);
            if *open == 0 {
                clients.remove(&self.ip);
            }
        }
    }
}

/// One connection's place in the server's `max_connections`; given back when dropped. A cap
/// lowered below the connections open closes none of them: new ones wait until enough left.
pub(crate) struct ServerPlace {
    open: Arc<AtomicUsize>,
}

// === impl ServerPlace ===

impl ServerPlace {
    /// A place, or `None` when `max_connections` are open.
    pub(crate) fn take(shared: &Shared, max_connections: usize) -> Option<Self> {
        shared
            .open
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |open| {
                (open < max_connections).then_some(open + 1)
            })
            .ok()?;
        Some(Self {
            open: Arc::clone(&shared.open),
        })
    }
}

impl Drop for ServerPlace {
    fn drop(&mut self) {
        self.open.fetch_sub(1, Ordering::AcqRel);
    }
}
