//! The places of the HTTP listener: who gets a connection served, and what it may ask.
//!
//! A client must not be able to shut the others out, least of all the monitoring: Prometheus
//! scrapes and health checks have to answer while the listener is under load or attack. The
//! path of a request is known only once its head is read, so the places are counted per
//! connection at accept, in two pools:
//!
//! - the **general** pool of `max_connections`, at most `max_connections_per_client` of them from
//!   one client address: these connections are served for anything;
//! - the **health** pool of [`HEALTH_PLACES`] places held back (at most
//!   [`HEALTH_PLACES_PER_CLIENT`] from one address): a connection that finds no general place (its
//!   address has all its places, or every place is taken) is served here, once, for `/metrics`,
//!   `/healthz` and `/readyz` only; anything else is answered 503 with Retry-After. Its request
//!   head must arrive within [`HEALTH_HEAD_TIMEOUT`].
//!
//! A place held by a connection that is only waiting (for its first request head, or for the next
//! one on a kept-alive connection) for at least [`EVICT_AFTER`] is given to a new connection that
//! needs it: a client that trickles its head (slowloris) or parks idle connections keeps a place
//! only until someone else needs it, while a probe that sends its head at once is never evicted.
//! A connection in the middle of a request is never evicted. When no place can be had, the
//! connection is closed at accept.
//!
//! Long-lived answers (SSE follows, timed captures) need a stream place as well
//! (`ApiState::stream_place`, `max_streams`), so streams can never take every general
//! place either.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use prometheus::IntGauge;
use tokio_util::sync::CancellationToken;

use crate::metrics::HttpRejectReason;

/// Places held back for `/metrics`, `/healthz` and `/readyz`.
pub const HEALTH_PLACES: usize = 8;
/// Health places one client address may hold at once.
pub const HEALTH_PLACES_PER_CLIENT: usize = 2;
/// Longest wait for the request head of a connection in a health place (a probe sends it at once).
pub const HEALTH_HEAD_TIMEOUT: Duration = Duration::from_secs(2);
/// A connection that has waited this long for a request head may lose its place to a new one.
pub const EVICT_AFTER: Duration = Duration::from_secs(1);

/// The paths served in a health place.
pub(crate) fn is_health_path(path: &str) -> bool {
    matches!(path, "/metrics" | "/healthz" | "/readyz")
}

/// Which pool a connection's place is in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Pool {
    General,
    /// Served once, for the health paths only; the reason it got no general place.
    Health(HttpRejectReason),
}

/// The limits of the pools.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Limits {
    pub(crate) max_connections: usize,
    pub(crate) per_client: usize,
}

/// Every open connection's place.
#[derive(Debug)]
pub(crate) struct Places {
    limits: Limits,
    inner: Mutex<Inner>,
    gauges: Option<(IntGauge, IntGauge)>,
}

#[derive(Debug, Default)]
struct Inner {
    next_id: u64,
    general: usize,
    health: usize,
    /// General and health places by client address.
    clients: HashMap<IpAddr, (usize, usize)>,
    open: HashMap<u64, Entry>,
}

#[derive(Debug)]
struct Entry {
    ip: IpAddr,
    health: bool,
    /// Requests in progress (read, answered, answer not yet written).
    busy: u32,
    /// Since when it waits for a request head (when `busy` is 0).
    waiting_since: Instant,
    evict: CancellationToken,
}

/// A connection's place, given back when dropped.
#[derive(Debug)]
pub(crate) struct Place {
    places: Arc<Places>,
    id: u64,
    pub(crate) pool: Pool,
    /// Cancelled when the place is given to another connection: close this one.
    pub(crate) evicted: CancellationToken,
}

/// What admitting a connection did.
#[derive(Debug)]
pub(crate) struct Admitted {
    pub(crate) place: Place,
    /// Connections closed to make room (each counted as `evicted`).
    pub(crate) evicted: usize,
}

// === impl Places ===

impl Places {
    /// Places within `limits`; `gauges` (general, health) follow the open connections.
    pub(crate) fn new(limits: Limits, gauges: Option<(IntGauge, IntGauge)>) -> Arc<Self> {
        Arc::new(Self {
            limits: Limits {
                max_connections: limits.max_connections.max(1),
                per_client: limits.per_client.max(1),
            },
            inner: Mutex::default(),
            gauges,
        })
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// A place for a new connection from `ip`, or why there is none.
    pub(crate) fn admit(self: &Arc<Self>, ip: IpAddr) -> Result<Admitted, HttpRejectReason> {
        let ip = ip.to_canonical();
        let now = Instant::now();
        let mut inner = self.lock();
        let mut evicted = 0;
        let (general_mine, health_mine) = inner.clients.get(&ip).copied().unwrap_or_default();
        // A general place: a free one, or the place of a connection that only waits (the
        // address's own when it has all its places).
        let general = if general_mine >= self.limits.per_client {
            Err(HttpRejectReason::ClientLimit)
        } else if inner.general >= self.limits.max_connections {
            Err(HttpRejectReason::ConnectionLimit)
        } else {
            Ok(())
        };
        let general = general.or_else(|why| {
            let own = why == HttpRejectReason::ClientLimit;
            match inner.oldest_waiting(now, |e| !e.health && (!own || e.ip == ip)) {
                Some(id) => {
                    inner.evict(id);
                    evicted += 1;
                    Ok(())
                }
                None => Err(why),
            }
        });
        let pool = match general {
            Ok(()) => Pool::General,
            Err(why) => {
                let own = health_mine >= HEALTH_PLACES_PER_CLIENT;
                if own || inner.health >= HEALTH_PLACES {
                    let id = inner
                        .oldest_waiting(now, |e| e.health && (!own || e.ip == ip))
                        .ok_or(why)?;
                    inner.evict(id);
                    evicted += 1;
                }
                Pool::Health(why)
            }
        };
        let id = inner.next_id;
        inner.next_id += 1;
        let health = matches!(pool, Pool::Health(_));
        let evict = CancellationToken::new();
        inner.open.insert(
            id,
            Entry {
                ip,
                health,
                busy: 0,
                waiting_since: now,
                evict: evict.clone(),
            },
        );
        inner.count(ip, health, true);
        self.update_gauges(&inner);
        drop(inner);
        Ok(Admitted {
            place: Place {
                places: Arc::clone(self),
                id,
                pool,
                evicted: evict,
            },
            evicted,
        })
    }

    /// A request of connection `id` begins (its head was read).
    pub(crate) fn begin(&self, id: u64) {
        if let Some(e) = self.lock().open.get_mut(&id) {
            e.busy += 1;
        }
    }

    /// A request of connection `id` is over (its answer written or given up).
    pub(crate) fn end(&self, id: u64) {
        if let Some(e) = self.lock().open.get_mut(&id) {
            e.busy = e.busy.saturating_sub(1);
            if e.busy == 0 {
                e.waiting_since = Instant::now();
            }
        }
    }

    /// Open connections in the general and the health pool.
    #[cfg(test)]
    fn counts(&self) -> (usize, usize) {
        let inner = self.lock();
        (inner.general, inner.health)
    }

    fn release(&self, id: u64) {
        let mut inner = self.lock();
        if let Some(e) = inner.open.remove(&id) {
            inner.count(e.ip, e.health, false);
            self.update_gauges(&inner);
        }
    }

    fn update_gauges(&self, inner: &Inner) {
        if let Some((general, health)) = &self.gauges {
            general.set(i64::try_from(inner.general).unwrap_or(i64::MAX));
            health.set(i64::try_from(inner.health).unwrap_or(i64::MAX));
        }
    }
}

// === impl Inner ===

impl Inner {
    /// The connection that has waited longest for a request head, at least [`EVICT_AFTER`],
    /// among those `which` selects.
    fn oldest_waiting(&self, now: Instant, which: impl Fn(&Entry) -> bool) -> Option<u64> {
        self.open
            .iter()
            .filter(|(_, e)| {
                e.busy == 0 && now.saturating_duration_since(e.waiting_since) >= EVICT_AFTER
            })
            .filter(|(_, e)| which(e))
            .min_by_key(|(_, e)| e.waiting_since)
            .map(|(id, _)| *id)
    }

    /// Takes the place of connection `id` away (its task closes it).
    fn evict(&mut self, id: u64) {
        if let Some(e) = self.open.remove(&id) {
            e.evict.cancel();
            self.count(e.ip, e.health, false);
        }
    }

    fn count(&mut self, ip: IpAddr, health: bool, add: bool) {
        let client = self.clients.entry(ip).or_default();
        let (pool, mine) = if health {
            (&mut self.health, &mut client.1)
        } else {
            (&mut self.general, &mut client.0)
        };
        if add {
            *pool += 1;
            *mine += 1;
        } else {
            *pool = pool.saturating_sub(1);
            *mine = mine.saturating_sub(1);
        }
        if *client == (0, 0) {
            self.clients.remove(&ip);
        }
    }
}

// === impl Place ===

impl Place {
    /// Marks a request of this connection as begun until the guard is dropped.
    #[cfg(test)]
    pub(crate) fn request(&self) -> RequestGuard {
        self.places.begin(self.id);
        RequestGuard {
            places: Arc::clone(&self.places),
            id: self.id,
        }
    }

    /// A handle for the connection's service (which outlives no connection but is `Clone`).
    pub(crate) fn handle(&self) -> PlaceHandle {
        PlaceHandle {
            places: Arc::clone(&self.places),
            id: self.id,
            pool: self.pool,
        }
    }
}

impl Drop for Place {
    fn drop(&mut self) {
        self.places.release(self.id);
    }
}

/// What a connection's service knows of its place.
#[derive(Clone, Debug)]
pub(crate) struct PlaceHandle {
    places: Arc<Places>,
    id: u64,
    pub(crate) pool: Pool,
}

impl PlaceHandle {
    /// Marks a request as begun until the guard is dropped.
    pub(crate) fn request(&self) -> RequestGuard {
        self.places.begin(self.id);
        RequestGuard {
            places: Arc::clone(&self.places),
            id: self.id,
        }
    }
}

/// A request in progress on a connection: its place cannot be evicted.
#[derive(Debug)]
pub(crate) struct RequestGuard {
    places: Arc<Places>,
    id: u64,
}

impl Drop for RequestGuard {
    fn drop(&mut self) {
        self.places.end(self.id);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ip(s: &str) -> IpAddr {
        s.parse().unwrap()
    }

    fn places(max_connections: usize, per_client: usize) -> Arc<Places> {
        Places::new(
            Limits {
                max_connections,
                per_client,
            },
            None,
        )
    }

    #[test]
    fn one_address_gets_its_share_then_health_places() {
        let p = places(64, 2);
        let a = ip("127.0.1.1");
        let mut held: Vec<Place> = (0..2).map(|_| p.admit(a).unwrap().place).collect();
        // Busy connections cannot be evicted.
        let _busy: Vec<RequestGuard> = held.iter().map(Place::request).collect();
        let third = p.admit(a).unwrap();
        assert_eq!(
            third.place.pool,
            Pool::Health(HttpRejectReason::ClientLimit)
        );
        held.push(third.place);
        held.push(p.admit(a).unwrap().place);
        // Two health places per address, none of them waiting long enough to give way.
        assert_eq!(p.admit(a).unwrap_err(), HttpRejectReason::ClientLimit);
        // Another address is not touched by it.
        assert_eq!(p.admit(ip("127.0.0.1")).unwrap().place.pool, Pool::General);
        assert_eq!(p.counts(), (2, 2));
        drop(held);
        assert_eq!(p.counts(), (0, 0));
    }

    #[test]
    fn every_general_place_taken_leaves_the_health_places() {
        let p = places(3, 8);
        let held: Vec<Place> = (1..=3)
            .map(|n| p.admit(ip(&format!("127.0.1.{n}"))).unwrap().place)
            .collect();
        let _busy: Vec<RequestGuard> = held.iter().map(Place::request).collect();
        let mut health = Vec::new();
        for n in 0..HEALTH_PLACES {
            let a = p.admit(ip(&format!("127.0.2.{n}"))).unwrap();
            assert_eq!(
                a.place.pool,
                Pool::Health(HttpRejectReason::ConnectionLimit)
            );
            health.push(a.place);
        }
        assert_eq!(
            p.admit(ip("127.0.0.1")).unwrap_err(),
            HttpRejectReason::ConnectionLimit
        );
    }

    #[test]
    fn a_connection_that_only_waits_gives_its_place_to_a_new_one() {
        let p = places(2, 8);
        let slow = p.admit(ip("127.0.1.1")).unwrap().place;
        let busy = p.admit(ip("127.0.1.2")).unwrap().place;
        let _request = busy.request();
        // Backdate the slow one's wait.
        p.lock().open.get_mut(&slow.id).unwrap().waiting_since -= EVICT_AFTER;
        let probe = p.admit(ip("127.0.0.1")).unwrap();
        assert_eq!(probe.place.pool, Pool::General);
        assert_eq!(probe.evicted, 1);
        assert!(slow.evicted.is_cancelled());
        assert!(!busy.evicted.is_cancelled());
        // The evicted place is not given back twice.
        drop(slow);
        assert_eq!(p.counts(), (2, 0));
        // A request that ended starts a new wait: not evictable at once.
        drop(_request);
        assert_eq!(
            p.admit(ip("127.0.0.2")).unwrap().place.pool,
            Pool::Health(HttpRejectReason::ConnectionLimit)
        );
    }
}
