//! The HTTP listener's metric families: `gateway_http_connections{pool}`,
//! `gateway_http_streams` and `gateway_http_rejected_total{reason}`, with their labels.

use prometheus::{IntCounterVec, IntGauge, IntGaugeVec, Opts, Registry};

use crate::metrics::labels::label_enum;

label_enum! {
    /// Why the HTTP listener refused or cut a connection or a request
    /// (`gateway_http_rejected_total{reason}`).
    pub enum HttpRejectReason {
        /// The client is outside `[http] allowed_networks`: closed at accept.
        Network = "network",
        /// The client address had `max_connections_per_client` connections: a request other than
        /// `/metrics`, `/healthz`, `/readyz` answered 503, or the connection closed at accept when
        /// the places held back for those were taken too.
        ClientLimit = "client_limit",
        /// Every one of `max_connections` was taken: as `client_limit`.
        ConnectionLimit = "connection_limit",
        /// Every one of `max_streams` was taken: an SSE follow or a timed capture answered 503.
        StreamLimit = "stream_limit",
        /// A response the client did not read within `write_timeout`: the connection was closed.
        WriteTimeout = "write_timeout",
        /// A request head (or the next one on a kept-alive connection) that did not arrive within
        /// the header read timeout: the connection was closed.
        HeaderTimeout = "header_timeout",
        /// A connection waiting for a request head, closed to give its place to a new one.
        Evicted = "evicted",
        /// A TLS handshake that failed or did not complete in time.
        TlsHandshake = "tls_handshake",
        /// `accept()` failed (out of file descriptors, connection aborted, ...).
        AcceptError = "accept_error",
        /// Every place was taken and the client address is backed off (its connections recently
        /// ended without a request: evicted or timed out waiting for a head or a body), so it may
        /// not take another client's place: closed at accept.
        Backoff = "backoff",
        /// A change (a method other than GET, HEAD, OPTIONS) whose `Origin` is not the listener's
        /// own origin: 403.
        Origin = "origin",
        /// A request whose `Host` is not one of the listener's names nor in `[http] hosts`: 403.
        Host = "host",
    }
}

label_enum! {
    /// Which places of the listener a connection holds (`gateway_http_connections{pool}`).
    pub enum ConnectionPool {
        /// The `max_connections` places every request may use.
        General = "general",
        /// The places held back for `/metrics`, `/healthz` and `/readyz`.
        Health = "health",
        /// The places held back for the same paths for clients of `[http] monitoring_networks`.
        Monitoring = "monitoring",
    }
}

/// The Prometheus families of the HTTP listener. Clones share the same series.
#[derive(Clone, Debug)]
pub struct HttpMetrics {
    /// `gateway_http_connections{pool}`: HTTP connections open now.
    connections: IntGaugeVec,
    /// `gateway_http_streams`: SSE follows and timed captures being served now.
    streams: IntGauge,
    /// `gateway_http_rejected_total{reason}`: HTTP connections and requests refused or cut.
    rejected: IntCounterVec,
}

// === impl HttpMetrics ===

impl HttpMetrics {
    /// The names of the families.
    pub const NAMES: [&'static str; 3] = [
        "gateway_http_connections",
        "gateway_http_streams",
        "gateway_http_rejected_total",
    ];

    /// Registers the families in `registry`, with every pool's and reason's series at 0.
    pub fn register(registry: &Registry) -> Result<Self, prometheus::Error> {
        let [connections, streams, rejected] = Self::NAMES;
        let metrics = Self {
            connections: IntGaugeVec::new(
                Opts::new(
                    connections,
                    "HTTP connections open now, by pool (general; health: the places held back \
                     for /metrics, /healthz and /readyz; monitoring: those held back for the \
                     clients of [http] monitoring_networks).",
                ),
                &["pool"],
            )?,
            streams: IntGauge::new(
                streams,
                "HTTP streams (SSE follows, timed captures) being served now.",
            )?,
            rejected: IntCounterVec::new(
                Opts::new(
                    rejected,
                    "HTTP connections and requests refused or cut, by reason.",
                ),
                &["reason"],
            )?,
        };
        registry.register(Box::new(metrics.connections.clone()))?;
        registry.register(Box::new(metrics.streams.clone()))?;
        registry.register(Box::new(metrics.rejected.clone()))?;
        for reason in HttpRejectReason::ALL {
            metrics.rejected.with_label_values(&[reason.as_str()]);
        }
        for pool in ConnectionPool::ALL {
            metrics.connections.with_label_values(&[pool.as_str()]);
        }
        Ok(metrics)
    }

    /// The gauge of open HTTP connections of `pool`.
    pub fn connections(&self, pool: ConnectionPool) -> IntGauge {
        self.connections.with_label_values(&[pool.as_str()])
    }

    /// The gauge of HTTP streams being served.
    pub fn streams(&self) -> IntGauge {
        self.streams.clone()
    }

    /// Counts one HTTP connection or request refused or cut for `reason`.
    pub fn rejected(&self, reason: HttpRejectReason) {
        self.rejected.with_label_values(&[reason.as_str()]).inc();
    }
}
