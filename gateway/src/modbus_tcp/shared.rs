//! What the accept loop hands to every connection of one server: the unit map, the options and
//! the counters.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::{Arc, Mutex, RwLock};

use super::options::ServerOptions;
use super::stats::ServerStats;
use super::tls::TlsServer;
use crate::unit::UnitMap;

/// The unit map the server answers from, replaceable at run time: take the write lock and swap
/// the map. Each request clones its unit's service out and drops the lock before it waits.
pub type SharedUnits = Arc<RwLock<UnitMap>>;

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
