//! What the accept loop hands to every connection of one server: the unit map, the options and
//! the counters.

use std::sync::{Arc, RwLock};

use super::options::ServerOptions;
use super::stats::ServerStats;
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
}
