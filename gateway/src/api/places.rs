//! The places of the HTTP listener: who gets a connection served, and what it may ask.
//!
//! A client must not be able to shut the others out, least of all the monitoring: Prometheus
//! scrapes and health checks have to answer while the listener is under load or attack, from one
//! address or from many. The path of a request is known only once its head is read, so the places
//! are counted per connection at accept, in three pools:
//!
//! - the **general** pool of `max_connections`, at most `max_connections_per_client` of them from
//!   one client address: these connections are served for anything;
//! - the **monitoring** pool of [`MONITORING_PLACES`] places (at most
//!   [`MONITORING_PLACES_PER_CLIENT`] from one address) that only clients of `[http]
//!   monitoring_networks` may take: a monitoring client that finds no free general place is
//!   served here, once, for `/metrics`, `/healthz` and `/readyz` only (others: 503), and no other
//!   client can take these places whatever it does;
//! - the **health** pool of [`HEALTH_PLACES`] places held back for everyone (at most
//!   [`HEALTH_PLACES_PER_CLIENT`] from one address): a connection that finds no general place is
//!   served here, once, for the same paths only; anything else is answered 503 with Retry-After.
//!
//! A connection in the health or monitoring pool must send its request head within
//! [`HEALTH_HEAD_TIMEOUT`].
//!
//! **Giving way.** A connection that is only waiting (for its first request head, for the next
//! one on a kept-alive connection, or for the rest of a request body) holds its place only until
//! someone else needs it:
//!
//! - one that has waited at least [`EVICT_AFTER`] gives its place to a new connection (its own
//!   address's first when that address has all its places);
//! - a client address whose connections end without a request (evicted or timed out while
//!   waiting for a head, or for a body), or that asks for more places while every place is taken
//!   and one of its connections has waited [`STALE_AFTER`] without a request, [`BACKOFF_STRIKES`] times, each within [`BACKOFF_FOR`] of
//!   the one before, is **backed off** until [`BACKOFF_FOR`] after the last such end (one stalled
//!   connection of an honest client does not do it, a slowloris's eight do at once): a new connection of an address that is not backed off takes the place of a waiting
//!   connection of a backed-off address at once, whatever its age, and a backed-off address may
//!   only take free places (or its own connections' places), never another client's;
//! - an address holding [`UNSERVED_TO_TAKE`] connections without a request takes no other
//!   address's place at once, and a new connection of an address holding fewer takes the place
//!   of one of them that has waited [`STALE_AFTER`] (of the address holding the most), so no
//!   address gathers many places before it is backed off, while the connections a browser opens
//!   at once have the time to send their requests.
//!
//! So a distributed slowloris (many addresses trickling heads or bodies and reconnecting at once)
//! backs all its addresses off within about a second of the first evictions, and a client that
//! sends its request at once (a probe, a REST client from an address that does not attack) still
//! gets a place the moment it connects. A connection in the middle of a request (its head read,
//! its body read, its answer not yet written) is never evicted. When no place can be had, the
//! connection is closed at accept.
//!
//! Bounds: the open connections are at most `max_connections` + [`HEALTH_PLACES`] +
//! [`MONITORING_PLACES`]; the addresses remembered as backed off at most [`BACKOFF_ADDRESSES`]
//! (an IPv6 client is remembered by its /64, the block one host is usually given).
//!
//! Long-lived answers (SSE follows, timed captures) need a stream place as well
//! (`ApiState::stream_place`, `max_streams`), so streams can never take every general
//! place either.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use ipnet::IpNet;
use prometheus::IntGauge;
use tokio_util::sync::CancellationToken;

use super::metrics::HttpRejectReason;

/// Places held back for `/metrics`, `/healthz` and `/readyz`.
pub const HEALTH_PLACES: usize = 8;
/// Health places one client address may hold at once.
pub const HEALTH_PLACES_PER_CLIENT: usize = 2;
/// Places held back for the same paths for the clients of `[http] monitoring_networks`.
pub const MONITORING_PLACES: usize = 8;
/// Monitoring places one client address may hold at once.
pub const MONITORING_PLACES_PER_CLIENT: usize = 4;
/// Longest wait for the request head of a connection in a health or monitoring place (a probe
/// sends it at once).
pub const HEALTH_HEAD_TIMEOUT: Duration = Duration::from_secs(2);
/// A connection that has waited this long for a request head may lose its place to a new one.
pub const EVICT_AFTER: Duration = Duration::from_secs(1);
/// How long a client address stays backed off after one of its connections ended without a
/// request (evicted or timed out waiting for a head or a body).
pub const BACKOFF_FOR: Duration = Duration::from_secs(30);
/// An address holding this many connections without a request may not take other addresses'
/// places at once (and its connections may be taken by an address holding fewer).
pub const UNSERVED_TO_TAKE: usize = 2;
/// A connection that has waited this long without a request counts against its address when the
/// address asks for more places while every place is taken.
pub const STALE_AFTER: Duration = Duration::from_millis(500);
/// Connections ending without a request that back an address off.
pub const BACKOFF_STRIKES: u32 = 3;
/// Most client addresses remembered as backed off (about 64 bytes each: 256 KiB at most); beyond
/// it a new address is not remembered until old ones expire (an attack from more addresses than
/// this is for the firewall).
pub const BACKOFF_ADDRESSES: usize = 4096;

/// The paths served in a health or monitoring place.
pub(crate) fn is_health_path(path: &str) -> bool {
    matches!(path, "/metrics" | "/healthz" | "/readyz")
}

/// Which pool a connection's place is in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Pool {
    General,
    /// Served once, for the health paths only; the reason it got no general place.
    Health(HttpRejectReason),
    /// As `Health`, in a place held back for `[http] monitoring_networks`.
    Monitoring(HttpRejectReason),
}

impl Pool {
    /// For a place that serves only the health paths, once: why it got no general place.
    pub(crate) fn health_only(self) -> Option<HttpRejectReason> {
        match self {
            Self::General => None,
            Self::Health(why) | Self::Monitoring(why) => Some(why),
        }
    }

    fn kind(self) -> Kind {
        match self {
            Self::General => Kind::General,
            Self::Health(_) => Kind::Health,
            Self::Monitoring(_) => Kind::Monitoring,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    General,
    Health,
    Monitoring,
}

/// The limits of the pools.
#[derive(Clone, Debug, Default)]
pub(crate) struct Limits {
    pub(crate) max_connections: usize,
    pub(crate) per_client: usize,
    /// `[http] monitoring_networks`.
    pub(crate) monitoring: Vec<IpNet>,
}

/// The gauges of the open connections by pool (general, health, monitoring).
pub(crate) type Gauges = (IntGauge, IntGauge, IntGauge);

/// Every open connection's place.
#[derive(Debug)]
pub(crate) struct Places {
    limits: Limits,
    inner: Mutex<Inner>,
    gauges: Option<Gauges>,
}

#[derive(Debug, Default)]
struct Inner {
    next_id: u64,
    /// Open connections by pool: general, health, monitoring.
    open_by: [usize; 3],
    /// Places by client address and pool.
    clients: HashMap<IpAddr, [usize; 3]>,
    open: HashMap<u64, Entry>,
    /// How many connections of an address (an IPv6 one by its /64) ended without a request, and
    /// when the last did; at most [`BACKOFF_ADDRESSES`] addresses.
    backoff: HashMap<IpAddr, (u32, Instant)>,
    /// The last time expired entries were swept out of `backoff` (at most once a second).
    swept: Option<Instant>,
}

#[derive(Debug)]
struct Entry {
    ip: IpAddr,
    kind: Kind,
    /// Requests in progress (read, answered, answer not yet written).
    busy: u32,
    /// Requests whose head was read on this connection.
    served: u32,
    /// The request in progress is still waiting for (the rest of) its body.
    reading_body: bool,
    /// Since when it waits for a request head (when `busy` is 0) or for its body.
    waiting_since: Instant,
    evict: CancellationToken,
}

impl Entry {
    /// Waiting (for a head, or for a body) for at least `at_least`.
    fn waiting(&self, now: Instant, at_least: Duration) -> bool {
        (self.busy == 0 || self.reading_body)
            && now.saturating_duration_since(self.waiting_since) >= at_least
    }

    /// It has not sent a whole request yet (no head, or a body still coming).
    fn unserved(&self) -> bool {
        self.served == 0 || self.reading_body
    }
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

/// The key under which an address is backed off: an IPv4 address itself, an IPv6 one by its /64.
fn backoff_key(ip: IpAddr) -> IpAddr {
    match ip {
        IpAddr::V4(_) => ip,
        IpAddr::V6(v6) => {
            let bits = u128::from(v6) & !((1u128 << 64) - 1);
            IpAddr::V6(bits.into())
        }
    }
}

// === impl Places ===

impl Places {
    /// Places within `limits`; `gauges` (general, health, monitoring) follow the open connections.
    pub(crate) fn new(limits: Limits, gauges: Option<Gauges>) -> Arc<Self> {
        Arc::new(Self {
            limits: Limits {
                max_connections: limits.max_connections.max(1),
                per_client: limits.per_client.max(1),
                monitoring: limits.monitoring,
            },
            inner: Mutex::default(),
            gauges,
        })
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    fn is_monitoring(&self, ip: IpAddr) -> bool {
        self.limits.monitoring.iter().any(|net| net.contains(&ip))
    }

    /// A place for a new connection from `ip`, or why there is none.
    pub(crate) fn admit(self: &Arc<Self>, ip: IpAddr) -> Result<Admitted, HttpRejectReason> {
        let ip = ip.to_canonical();
        let now = Instant::now();
        let mut inner = self.lock();
        let mine = inner.clients.get(&ip).copied().unwrap_or_default();
        let general_free = if mine[0] >= self.limits.per_client {
            Err(HttpRejectReason::ClientLimit)
        } else if inner.open_by[0] >= self.limits.max_connections {
            Err(HttpRejectReason::ConnectionLimit)
        } else {
            Ok(())
        };
        // An address that asks for another place while every place is taken and one of its own
        // connections has waited [`STALE_AFTER`] without sending a request is holding a place it
        // does not use: counted as a connection ended without a request.
        if general_free.is_err()
            && inner
                .oldest_waiting(now, STALE_AFTER, |e| e.ip == ip && e.unserved())
                .is_some()
        {
            inner.back_off(ip, now);
        }
        let backed_off = inner.backed_off(ip, now);
        let (pool, evicted) = match general_free {
            Ok(()) => (Pool::General, 0),
            Err(why) => self.place_when_full(&mut inner, now, ip, why, mine, backed_off)?,
        };
        let place = self.open(&mut inner, now, ip, pool);
        drop(inner);
        Ok(Admitted { place, evicted })
    }

    /// A place for `ip` when no general place is free to it (`why`): a monitoring place for an
    /// address of `monitoring_networks`, else a general place taken from another connection,
    /// else a health place; with the number of connections evicted to make room.
    fn place_when_full(
        &self,
        inner: &mut Inner,
        now: Instant,
        ip: IpAddr,
        why: HttpRejectReason,
        [_, health_mine, monitoring_mine]: [usize; 3],
        backed_off: bool,
    ) -> Result<(Pool, usize), HttpRejectReason> {
        let monitoring = self.is_monitoring(ip).then(|| {
            inner.take(
                now,
                Kind::Monitoring,
                ip,
                monitoring_mine >= MONITORING_PLACES_PER_CLIENT,
                MONITORING_PLACES,
                false,
            )
        });
        if let Some(Some(n)) = monitoring {
            return Ok((Pool::Monitoring(why), n));
        }
        if let Some(n) = inner.take(
            now,
            Kind::General,
            ip,
            why == HttpRejectReason::ClientLimit,
            self.limits.max_connections,
            backed_off,
        ) {
            Ok((Pool::General, n))
        } else if let Some(n) = inner.take(
            now,
            Kind::Health,
            ip,
            health_mine >= HEALTH_PLACES_PER_CLIENT,
            HEALTH_PLACES,
            backed_off,
        ) {
            Ok((Pool::Health(why), n))
        } else if backed_off {
            Err(HttpRejectReason::Backoff)
        } else {
            Err(why)
        }
    }

    /// Opens connection place `pool` for `ip`: counted, and the gauges follow.
    fn open(self: &Arc<Self>, inner: &mut Inner, now: Instant, ip: IpAddr, pool: Pool) -> Place {
        let id = inner.next_id;
        inner.next_id += 1;
        let kind = pool.kind();
        let evict = CancellationToken::new();
        inner.open.insert(
            id,
            Entry {
                ip,
                kind,
                busy: 0,
                served: 0,
                reading_body: false,
                waiting_since: now,
                evict: evict.clone(),
            },
        );
        inner.count(ip, kind, true);
        self.update_gauges(inner);
        Place {
            places: Arc::clone(self),
            id,
            pool,
            evicted: evict,
        }
    }

    /// A request of connection `id` begins (its head was read); `with_body`: its body is still
    /// to be read.
    pub(crate) fn begin(&self, id: u64, with_body: bool) {
        if let Some(e) = self.lock().open.get_mut(&id) {
            e.busy += 1;
            e.served = e.served.saturating_add(1);
            if with_body {
                e.reading_body = true;
                e.waiting_since = Instant::now();
            }
        }
    }

    /// The body of connection `id`'s request has been read (or given up).
    pub(crate) fn body_read(&self, id: u64) {
        if let Some(e) = self.lock().open.get_mut(&id) {
            e.reading_body = false;
        }
    }

    /// A request of connection `id` is over (its answer written or given up).
    pub(crate) fn end(&self, id: u64) {
        if let Some(e) = self.lock().open.get_mut(&id) {
            e.busy = e.busy.saturating_sub(1);
            if e.busy == 0 {
                e.reading_body = false;
                e.waiting_since = Instant::now();
            }
        }
    }

    /// Connection `id` timed out waiting (for a head, a TLS handshake or a body): its address is
    /// backed off when it had not sent a whole request.
    pub(crate) fn timed_out(&self, id: u64) {
        let mut inner = self.lock();
        if let Some(ip) = inner.open.get(&id).filter(|e| e.unserved()).map(|e| e.ip) {
            inner.back_off(ip, Instant::now());
        }
    }

    /// Whether `ip` is backed off now.
    #[cfg(test)]
    fn is_backed_off(&self, ip: IpAddr) -> bool {
        self.lock().backed_off(ip, Instant::now())
    }

    /// Open connections in the general, health and monitoring pools.
    #[cfg(test)]
    fn counts(&self) -> [usize; 3] {
        self.lock().open_by
    }

    fn release(&self, id: u64) {
        let mut inner = self.lock();
        if let Some(e) = inner.open.remove(&id) {
            inner.count(e.ip, e.kind, false);
            self.update_gauges(&inner);
        }
    }

    fn update_gauges(&self, inner: &Inner) {
        if let Some((general, health, monitoring)) = &self.gauges {
            for (gauge, n) in [general, health, monitoring].into_iter().zip(inner.open_by) {
                gauge.set(i64::try_from(n).unwrap_or(i64::MAX));
            }
        }
    }
}

// === impl Inner ===

impl Inner {
    /// A place of `kind` (of which there are `places`) for a new connection from `ip`: a free one
    /// unless `at_own_cap` (its address has all its places of that kind); else the place of a
    /// waiting connection: its own address's (waited [`EVICT_AFTER`]) when `at_own_cap` or
    /// `backed_off`; else, while the address itself holds fewer than [`UNSERVED_TO_TAKE`]
    /// connections without a request, at once a backed-off address's, or one that waited
    /// [`STALE_AFTER`] of an address holding [`UNSERVED_TO_TAKE`] or more connections without a
    /// request (the one holding the most); else one that waited [`EVICT_AFTER`]. `Some(n)`: a place, having evicted `n`.
    fn take(
        &mut self,
        now: Instant,
        kind: Kind,
        ip: IpAddr,
        at_own_cap: bool,
        places: usize,
        backed_off: bool,
    ) -> Option<usize> {
        let slot = kind as usize;
        if !at_own_cap && self.open_by[slot] < places {
            return Some(0);
        }
        let own_only = at_own_cap || backed_off;
        let victim = if own_only {
            self.oldest_waiting(now, EVICT_AFTER, |e| e.kind == kind && e.ip == ip)
        } else {
            let unserved = self.unserved_by_address();
            let holds = |a: &IpAddr| unserved.get(a).copied().unwrap_or(0);
            let may_take = holds(&ip) < UNSERVED_TO_TAKE;
            let backed = may_take
                .then(|| {
                    self.oldest_waiting(now, Duration::ZERO, |e| {
                        e.kind == kind && e.ip != ip && self.backed_off(e.ip, now)
                    })
                })
                .flatten();
            let hoarder = || {
                may_take
                    .then(|| {
                        self.open
                            .iter()
                            .filter(|(_, e)| {
                                e.kind == kind
                                    && e.ip != ip
                                    && e.unserved()
                                    && e.waiting(now, STALE_AFTER)
                                    && holds(&e.ip) >= UNSERVED_TO_TAKE
                            })
                            .max_by_key(|(_, e)| (holds(&e.ip), std::cmp::Reverse(e.waiting_since)))
                            .map(|(id, _)| *id)
                    })
                    .flatten()
            };
            backed
                .or_else(hoarder)
                .or_else(|| self.oldest_waiting(now, EVICT_AFTER, |e| e.kind == kind))
        }?;
        self.evict(victim, now);
        Some(1)
    }

    /// Connections without a request yet (no head, or a body still coming), by address.
    fn unserved_by_address(&self) -> HashMap<IpAddr, usize> {
        let mut by = HashMap::new();
        for e in self.open.values().filter(|e| e.unserved()) {
            *by.entry(e.ip).or_insert(0) += 1;
        }
        by
    }

    /// The connection that has waited longest, at least `at_least`, among those `which` selects.
    fn oldest_waiting(
        &self,
        now: Instant,
        at_least: Duration,
        which: impl Fn(&Entry) -> bool,
    ) -> Option<u64> {
        self.open
            .iter()
            .filter(|(_, e)| e.waiting(now, at_least) && which(e))
            .min_by_key(|(_, e)| e.waiting_since)
            .map(|(id, _)| *id)
    }

    /// Takes the place of connection `id` away (its task closes it); its address is backed off
    /// when it had not sent a whole request.
    fn evict(&mut self, id: u64, now: Instant) {
        if let Some(e) = self.open.remove(&id) {
            e.evict.cancel();
            self.count(e.ip, e.kind, false);
            if e.unserved() {
                self.back_off(e.ip, now);
            }
        }
    }

    fn backed_off(&self, ip: IpAddr, now: Instant) -> bool {
        self.backoff
            .get(&backoff_key(ip))
            .is_some_and(|(n, since)| {
                *n >= BACKOFF_STRIKES && now.saturating_duration_since(*since) < BACKOFF_FOR
            })
    }

    /// Counts a connection of `ip` that ended without a request at `now` (not remembered when
    /// [`BACKOFF_ADDRESSES`] other addresses are, none of them expired).
    fn back_off(&mut self, ip: IpAddr, now: Instant) {
        let key = backoff_key(ip);
        if self.backoff.len() >= BACKOFF_ADDRESSES && !self.backoff.contains_key(&key) {
            let due = self
                .swept
                .is_none_or(|t| now.saturating_duration_since(t) >= Duration::from_secs(1));
            if !due {
                return;
            }
            self.swept = Some(now);
            self.backoff
                .retain(|_, (_, since)| now.saturating_duration_since(*since) < BACKOFF_FOR);
            if self.backoff.len() >= BACKOFF_ADDRESSES {
                return;
            }
        }
        let (n, since) = self.backoff.entry(key).or_insert((0, now));
        if now.saturating_duration_since(*since) >= BACKOFF_FOR {
            *n = 0;
        }
        *n = n.saturating_add(1);
        *since = now;
    }

    fn count(&mut self, ip: IpAddr, kind: Kind, add: bool) {
        let slot = kind as usize;
        let client = self.clients.entry(ip).or_default();
        if add {
            self.open_by[slot] += 1;
            client[slot] += 1;
        } else {
            self.open_by[slot] = self.open_by[slot].saturating_sub(1);
            client[slot] = client[slot].saturating_sub(1);
        }
        if *client == [0; 3] {
            self.clients.remove(&ip);
        }
    }
}

// === impl Place ===

impl Place {
    /// Marks a request of this connection as begun until the guard is dropped.
    #[cfg(test)]
    pub(crate) fn request(&self) -> RequestGuard {
        self.handle().request(false)
    }

    /// A handle for the connection's service (which outlives no connection but is `Clone`).
    pub(crate) fn handle(&self) -> PlaceHandle {
        PlaceHandle {
            places: Arc::clone(&self.places),
            id: self.id,
            pool: self.pool,
        }
    }

    /// The connection timed out waiting for a request head (or its TLS handshake).
    pub(crate) fn timed_out(&self) {
        self.places.timed_out(self.id);
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
    /// Marks a request as begun until the guard is dropped; `with_body`: its body is still to
    /// be read (until [`BodyGuard`] is dropped the connection counts as waiting).
    pub(crate) fn request(&self, with_body: bool) -> RequestGuard {
        self.places.begin(self.id, with_body);
        RequestGuard {
            places: Arc::clone(&self.places),
            id: self.id,
        }
    }

    /// Marks the request's body as being read until the guard is dropped.
    pub(crate) fn body(&self) -> BodyGuard {
        BodyGuard {
            places: Arc::clone(&self.places),
            id: self.id,
        }
    }
}

/// A request in progress on a connection: its place cannot be evicted (but while its body is
/// being read, see [`BodyGuard`]).
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

/// A request body still being read: the connection counts as waiting until it is dropped.
#[derive(Debug)]
pub(crate) struct BodyGuard {
    places: Arc<Places>,
    id: u64,
}

impl Drop for BodyGuard {
    fn drop(&mut self) {
        self.places.body_read(self.id);
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
                monitoring: Vec::new(),
            },
            None,
        )
    }

    /// Counts `n` connections of `ip` that ended without a request.
    fn strike(p: &Places, ip: IpAddr, n: u32) {
        let now = Instant::now();
        for _ in 0..n {
            p.lock().back_off(ip, now);
        }
    }

    /// Backdates connection `place`'s wait by `by`.
    fn backdate(p: &Places, place: &Place, by: Duration) {
        if let Some(e) = p.lock().open.get_mut(&place.id) {
            e.waiting_since -= by;
        }
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
        assert_eq!(p.counts(), [2, 2, 0]);
        drop(held);
        assert_eq!(p.counts(), [0; 3]);
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
        backdate(&p, &slow, EVICT_AFTER);
        let probe = p.admit(ip("127.0.0.1")).unwrap();
        assert_eq!(probe.place.pool, Pool::General);
        assert_eq!(probe.evicted, 1);
        assert!(slow.evicted.is_cancelled());
        assert!(!busy.evicted.is_cancelled());
        // The evicted place is not given back twice.
        drop(slow);
        assert_eq!(p.counts(), [2, 0, 0]);
        // A request that ended starts a new wait: not evictable at once.
        drop(_request);
        assert_eq!(
            p.admit(ip("127.0.0.2")).unwrap().place.pool,
            Pool::Health(HttpRejectReason::ConnectionLimit)
        );
    }

    #[test]
    fn an_address_whose_connections_end_without_a_request_is_backed_off() {
        let p = places(4, 8);
        // Four waiting connections of four attackers fill the pool.
        let attackers: Vec<IpAddr> = (1..=4).map(|n| ip(&format!("127.0.60.{n}"))).collect();
        let mut held: Vec<Place> = attackers
            .iter()
            .map(|a| p.admit(*a).unwrap().place)
            .collect();
        for (place, a) in held.iter().zip(&attackers) {
            backdate(&p, place, EVICT_AFTER);
            // Two of their connections ended without a request before.
            strike(&p, *a, BACKOFF_STRIKES - 1);
            assert!(!p.is_backed_off(*a));
        }
        // Another attacker's connection takes the oldest waiting place: that address, which had
        // sent no request on it, is backed off.
        let third = ip("127.0.60.9");
        let a = p.admit(third).unwrap();
        assert_eq!((a.place.pool, a.evicted), (Pool::General, 1));
        let victim = held.iter().position(|h| h.evicted.is_cancelled()).unwrap();
        let victim_ip = attackers[victim];
        assert!(p.is_backed_off(victim_ip));
        assert!(!p.is_backed_off(third));
        held.push(a.place);
        // The backed-off address may not take another's place, even one waiting for long: it
        // gets a health place while there is one, then nothing.
        for place in &held {
            backdate(&p, place, EVICT_AFTER);
        }
        let mut health = Vec::new();
        for _ in 0..HEALTH_PLACES_PER_CLIENT {
            let h = p.admit(victim_ip).unwrap();
            assert_eq!(h.evicted, 0);
            assert_eq!(
                h.place.pool,
                Pool::Health(HttpRejectReason::ConnectionLimit)
            );
            health.push(h.place);
        }
        assert_eq!(p.admit(victim_ip).unwrap_err(), HttpRejectReason::Backoff);
        // A fresh address takes a backed-off address's waiting place at once, whatever its age.
        let fresh = p.admit(ip("127.0.4.1")).unwrap();
        let in_health = fresh.place.pool;
        assert_eq!(fresh.evicted, 1, "{in_health:?}");
        assert_eq!(in_health, Pool::General);
        assert!(health.iter().all(|h| !h.evicted.is_cancelled()));
    }

    #[test]
    fn a_fresh_address_takes_the_place_of_a_backed_off_one_at_once() {
        let p = places(2, 8);
        let a = ip("127.0.60.1");
        let first = p.admit(a).unwrap().place;
        let second = p.admit(a).unwrap().place;
        // One connection that timed out does not back an address off; three do.
        first.timed_out();
        assert!(!p.is_backed_off(a));
        first.timed_out();
        first.timed_out();
        assert!(p.is_backed_off(a));
        // Both just connected (no wait at all): a fresh address still gets a general place.
        let fresh = p.admit(ip("127.0.4.1")).unwrap();
        assert_eq!((fresh.place.pool, fresh.evicted), (Pool::General, 1));
        assert!(first.evicted.is_cancelled() || second.evicted.is_cancelled());
        // A kept-alive connection that served a request and then timed out waiting for the next
        // one does not back its address off.
        let q = places(4, 8);
        let kept = q.admit(ip("127.0.0.9")).unwrap().place;
        drop(kept.handle().request(false));
        kept.timed_out();
        assert!(!q.is_backed_off(ip("127.0.0.9")));
        // A connection in the middle of a request is never taken.
        let busy = [&first, &second]
            .into_iter()
            .find(|h| !h.evicted.is_cancelled())
            .unwrap();
        let _request = busy.request();
        let next = p.admit(ip("127.0.4.2")).unwrap();
        assert_eq!(
            next.place.pool,
            Pool::Health(HttpRejectReason::ConnectionLimit)
        );
    }

    #[test]
    fn a_request_whose_body_is_still_coming_counts_as_waiting() {
        let p = places(1, 8);
        let slow = p.admit(ip("127.0.61.1")).unwrap().place;
        strike(&p, ip("127.0.61.1"), BACKOFF_STRIKES - 1);
        let handle = slow.handle();
        let _request = handle.request(true);
        let body = handle.body();
        backdate(&p, &slow, EVICT_AFTER);
        let next = p.admit(ip("127.0.4.1")).unwrap();
        assert_eq!((next.place.pool, next.evicted), (Pool::General, 1));
        assert!(slow.evicted.is_cancelled());
        assert!(p.is_backed_off(ip("127.0.61.1")));
        // Once the body is read, the request is busy: not taken.
        let _r = next.place.handle().request(true);
        drop(next.place.handle().body());
        backdate(&p, &next.place, EVICT_AFTER);
        let third = p.admit(ip("127.0.4.2")).unwrap();
        assert!(matches!(third.place.pool, Pool::Health(_)));
        drop(body);
    }

    #[test]
    fn monitoring_networks_have_places_no_one_else_can_take() {
        let p = Places::new(
            Limits {
                max_connections: 1,
                per_client: 8,
                monitoring: vec!["127.0.0.0/30".parse().unwrap()],
            },
            None,
        );
        let busy = p.admit(ip("127.0.70.1")).unwrap().place;
        let _r = busy.request();
        // Every health place taken by busy connections of other addresses.
        let mut others = Vec::new();
        for n in 0..HEALTH_PLACES {
            let h = p.admit(ip(&format!("127.0.71.{n}"))).unwrap().place;
            others.push((h.handle().request(false), h));
        }
        assert_eq!(
            p.admit(ip("127.0.72.1")).unwrap_err(),
            HttpRejectReason::ConnectionLimit
        );
        // A monitoring client still gets its places, up to its own share.
        let mut mine = Vec::new();
        for _ in 0..MONITORING_PLACES_PER_CLIENT {
            let m = p.admit(ip("127.0.0.1")).unwrap();
            assert_eq!(
                m.place.pool,
                Pool::Monitoring(HttpRejectReason::ConnectionLimit)
            );
            assert_eq!(
                m.place.pool.health_only(),
                Some(HttpRejectReason::ConnectionLimit)
            );
            mine.push(m.place);
        }
        assert_eq!(p.counts(), [1, HEALTH_PLACES, MONITORING_PLACES_PER_CLIENT]);
        // Another monitoring address has its own.
        assert!(matches!(
            p.admit(ip("127.0.0.2")).unwrap().place.pool,
            Pool::Monitoring(_)
        ));
    }

    #[test]
    fn the_backed_off_addresses_remembered_are_bounded() {
        let p = places(1, 1);
        let now = Instant::now();
        let mut inner = p.lock();
        for n in 0..BACKOFF_ADDRESSES + 100 {
            let [a, b] = u16::try_from(n).unwrap().to_be_bytes();
            inner.back_off(IpAddr::from([10, 1, a, b]), now);
        }
        assert_eq!(inner.backoff.len(), BACKOFF_ADDRESSES);
        // IPv6 by /64: one entry for a whole block.
        inner.backoff.clear();
        for n in 0..100u16 {
            inner.back_off(IpAddr::from([0x2001, 0xdb8, 0, 1, 0, 0, 0, n]), now);
        }
        assert_eq!(inner.backoff.len(), 1);
        assert!(inner.backed_off(IpAddr::from([0x2001, 0xdb8, 0, 1, 9, 9, 9, 9]), now));
        assert!(!inner.backed_off(IpAddr::from([0x2001, 0xdb8, 0, 2, 0, 0, 0, 1]), now));
        // Expired entries make room.
        let later = now + BACKOFF_FOR;
        assert!(!inner.backed_off(IpAddr::from([0x2001, 0xdb8, 0, 1, 0, 0, 0, 1]), later));
    }

    #[test]
    fn an_address_holding_unused_connections_gives_way_and_is_backed_off_when_it_asks_for_more() {
        let p = places(3, 8);
        let hoarder = ip("127.0.62.1");
        let held: Vec<Place> = (0..3).map(|_| p.admit(hoarder).unwrap().place).collect();
        // Just opened (a browser's connections opened at once): not taken.
        let early = p.admit(ip("127.0.4.9")).unwrap();
        assert_eq!(early.evicted, 0);
        assert!(matches!(early.place.pool, Pool::Health(_)));
        drop(early);
        // Half a second unused, and the hoarder holds two or more connections without a request
        // (none has waited the second): a fresh address takes one of them, and another one again.
        for place in &held {
            backdate(&p, place, STALE_AFTER);
        }
        let fresh = p.admit(ip("127.0.4.1")).unwrap();
        assert_eq!((fresh.place.pool, fresh.evicted), (Pool::General, 1));
        let other = ip("127.0.4.2");
        let second = p.admit(other).unwrap();
        assert_eq!((second.place.pool, second.evicted), (Pool::General, 1));
        // Now nobody holds two: a third new connection finds nothing to take.
        let third = p.admit(other).unwrap();
        assert_eq!(
            (third.place.pool, third.evicted),
            (Pool::Health(HttpRejectReason::ConnectionLimit), 0)
        );
        // The hoarder lost two connections without a request; asking for another place while
        // its last one has waited unused counts a third time: backed off.
        assert!(!p.is_backed_off(hoarder));
        let _more = p.admit(hoarder);
        assert!(p.is_backed_off(hoarder));
    }
}
