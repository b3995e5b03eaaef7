//! Server limits; the write policy (read-only mode, write-enabled ranges) is the units'
//! ([`crate::unit::write_policy`]).

use std::net::IpAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, PoisonError, RwLock};
use std::time::Duration;

use ipnet::IpNet;

use crate::unit::write_policy::WritePolicy;

/// Default for [`ServerOptions::max_connections`].
pub const DEFAULT_MAX_CONNECTIONS: usize = 64;
/// Default for [`ServerOptions::idle_timeout`].
pub const DEFAULT_IDLE_TIMEOUT: Duration = Duration::from_secs(60);
/// Default for [`ServerOptions::request_timeout`].
pub const DEFAULT_REQUEST_TIMEOUT: Duration = Duration::from_secs(5);

/// Limits and policy of the Modbus TCP server.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ServerOptions {
    /// Connections served at once. A client over the cap is accepted and closed at once (counted
    /// as rejected, reason `limit`). 0 refuses every client.
    pub max_connections: usize,
    /// Connections served at once from one client address; `None`: only `max_connections`
    /// limits. A client over its cap is closed at accept like one over `max_connections`
    /// (reason `limit`), so that a flood from one host cannot take the places other hosts need.
    pub max_connections_per_client: Option<usize>,
    /// A connection that completes no request for this long is closed: silent clients, clients
    /// that never finish a frame, and clients that do not read their responses.
    pub idle_timeout: Duration,
    /// Client networks allowed to connect; empty allows all. Others are closed at accept
    /// (counted as rejected, reason `network`). IPv4-mapped IPv6 peers match IPv4 networks.
    pub allowed_networks: Vec<IpNet>,
    /// Which writes clients may make (REST and zenoh tag writes pass the same check).
    pub writes: WritePolicy,
    /// How long a unit service may take to answer; then the client gets exception 0x0B (gateway
    /// target device failed to respond).
    pub request_timeout: Duration,
}

impl Default for ServerOptions {
    fn default() -> Self {
        Self {
            max_connections: DEFAULT_MAX_CONNECTIONS,
            max_connections_per_client: None,
            idle_timeout: DEFAULT_IDLE_TIMEOUT,
            allowed_networks: Vec::new(),
            writes: WritePolicy::default(),
            request_timeout: DEFAULT_REQUEST_TIMEOUT,
        }
    }
}

// === impl ServerOptions ===

impl ServerOptions {
    /// Whether a client at `peer` may connect.
    pub fn allows_peer(&self, peer: IpAddr) -> bool {
        let peer = peer.to_canonical();
        self.allowed_networks.is_empty()
            || self.allowed_networks.iter().any(|net| net.contains(&peer))
    }
}

/// The options of a running server, replaced whole by a configuration change while it serves
/// (REST `PUT /api/v1/config`, SIGHUP): the caps and `allowed_networks` apply to the next
/// connection accepted, the write policy and `request_timeout` to the next request of every
/// connection, `idle_timeout` to the next wait of every connection. No connection is closed by
/// a change; one over a lowered cap stays until it ends.
#[derive(Debug)]
pub struct LiveOptions {
    current: RwLock<Arc<ServerOptions>>,
    /// Raised by every [`Self::set`]: a connection compares it after each request (one atomic
    /// load) and takes the options again only when it moved.
    generation: AtomicU64,
}

// === impl LiveOptions ===

impl LiveOptions {
    /// Options in force from now on, until [`Self::set`].
    pub fn new(options: ServerOptions) -> Arc<Self> {
        Arc::new(Self {
            current: RwLock::new(Arc::new(options)),
            generation: AtomicU64::new(0),
        })
    }

    /// The options in force.
    pub fn get(&self) -> Arc<ServerOptions> {
        Arc::clone(&self.current.read().unwrap_or_else(PoisonError::into_inner))
    }

    /// Puts `options` in force for what the server does next.
    pub fn set(&self, options: ServerOptions) {
        *self.current.write().unwrap_or_else(PoisonError::into_inner) = Arc::new(options);
        self.generation.fetch_add(1, Ordering::Release);
    }

    /// How often the options were replaced.
    pub fn generation(&self) -> u64 {
        self.generation.load(Ordering::Acquire)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn allowed_networks_match_mapped_ipv4() {
        let options = ServerOptions {
            allowed_networks: vec!["10.0.0.0/8".parse().expect("net")],
            ..ServerOptions::default()
        };
        assert!(options.allows_peer("10.1.2.3".parse().expect("ip")));
        assert!(options.allows_peer("::ffff:10.1.2.3".parse().expect("ip")));
        assert!(!options.allows_peer("127.0.0.1".parse().expect("ip")));
        assert!(ServerOptions::default().allows_peer("192.0.2.1".parse().expect("ip")));
    }
}
