//! What the accept loop hands to every connection of one server: the unit map, the options and
//! the counters.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::{Arc, Mutex, PoisonError};

use super::options::ServerOptions;
use super::stats::ServerStats;
use super::tls::TlsServer;
use crate::unit::SharedUnits;

/// What every connection of one server shares.
pub(crate) struct Shared {
    /// The units; replaced at run time by whoever holds the other `Arc`.
    pub(crate) units: SharedUnits,
    /// Limits and policy.
    pub(crate) options: ServerOptions,
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
    pub(crate) fn take(shared: &Shared, ip: IpAddr) -> Option<Self> {
        let ip = ip.to_canonical();
        let mut clients = shared
            .clients
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let open = clients.entry(ip).or_default();
        if shared
            .options
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
