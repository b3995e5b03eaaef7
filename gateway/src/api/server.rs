//! The API's accept loop: connection places per client and in all ([`super::places`]), hyper's
//! HTTP/1 with a header read timeout and a write timeout ([`super::io`]), HTTPS when configured
//! ([`super::tls`]), and a graceful stop.
//!
//! `axum::serve` gives hyper no timer, so hyper's header read timeout never fires there: a client
//! that trickles a request head, or keeps an idle connection open, would hold a connection for
//! ever. Here the timer is set, so the time to receive a request head (including the wait for the
//! next request on a kept-alive connection) is bounded by the header read timeout; the time to
//! read the body and answer is bounded by `[http] request_timeout`, the time a client may leave
//! the answer unread by `[http] write_timeout`.
//!
//! Every refusal is counted in `gateway_http_rejected_total{reason}` and logged, at most one line
//! per reason and [`crate::log_limit::INTERVAL`] with the client's address and how many were left
//! out.

use std::convert::Infallible;
use std::future::Future;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::Ordering;
use std::time::Duration;

use axum::body::Body;
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};
use hyper::body::Incoming;
use hyper::server::conn::http1;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::server::graceful::{GracefulShutdown, Watcher};
use hyper_util::service::TowerToHyperService;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::net::{TcpListener, TcpStream};

use super::auth::PeerAddr;
use super::io::WriteTimeout;
use super::metrics::{ConnectionPool, HttpRejectReason};
use super::origin::LocalAddr;
use super::places::{
    is_health_path, Limits, Place, PlaceHandle, Places, Pool, HEALTH_HEAD_TIMEOUT,
};
use super::{router, ApiError, ApiState};

/// Connections served at once by default (`[http] max_connections`).
pub const DEFAULT_MAX_CONNECTIONS: u32 = crate::config::DEFAULT_HTTP_MAX_CONNECTIONS;
/// Longest wait for a request head, and for the next request on an idle connection.
pub const DEFAULT_HEADER_READ_TIMEOUT: Duration = crate::config::DEFAULT_HTTP_HEADER_READ_TIMEOUT;
/// Pause after a failed accept (e.g. out of file descriptors) before trying again.
const ACCEPT_BACKOFF: Duration = Duration::from_millis(100);
/// `Retry-After` of a request refused for want of a place.
const RETRY_AFTER_SECONDS: u32 = 5;

/// Serves the API on `listener` until `shutdown` completes; then stops accepting, closes idle
/// connections, lets requests in flight finish and returns when every connection has ended
/// (the caller bounds that with its grace period). The caller says how changes are guarded
/// (`Auth::log_mode`), at its start-up.
pub async fn serve(
    listener: TcpListener,
    state: ApiState,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> io::Result<()> {
    if let Ok(addr) = listener.local_addr() {
        tracing::info!(
            %addr,
            max_connections = state.max_connections,
            max_connections_per_client = state.max_connections_per_client,
            max_streams = state.max_streams,
            https = state.tls.is_some(),
            "REST API listening"
        );
    }
    let gauges = state.metrics.as_ref().map(|http| {
        (
            http.connections(ConnectionPool::General),
            http.connections(ConnectionPool::Health),
            http.connections(ConnectionPool::Monitoring),
        )
    });
    let places = Places::new(
        Limits {
            max_connections: state.max_connections,
            per_client: state.max_connections_per_client,
            monitoring: state.monitoring_networks.clone(),
        },
        gauges,
    );
    let gate = state.clone();
    let service = TowerToHyperService::new(router(state));
    let graceful = GracefulShutdown::new();
    let mut shutdown = std::pin::pin!(shutdown);
    loop {
        let (stream, peer) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(accepted) => accepted,
                Err(e) => {
                    gate.refused(HttpRejectReason::AcceptError, None, &e.to_string());
                    tokio::time::sleep(ACCEPT_BACKOFF).await;
                    continue;
                }
            },
            () = &mut shutdown => break,
        };
        if !gate.allows_peer(peer.ip()) {
            refuse(&stream);
            gate.refused(
                HttpRejectReason::Network,
                Some(peer),
                "client outside [http] allowed_networks, closed",
            );
            continue;
        }
        let admitted = match places.admit(peer.ip()) {
            Ok(admitted) => admitted,
            Err(why) => {
                let what = if why == HttpRejectReason::Backoff {
                    "no connection place left and the client address is backed off (its \
                     connections ended without a request), closed"
                } else {
                    "no connection place left (the health places are taken too), closed"
                };
                refuse(&stream);
                gate.refused(why, Some(peer), what);
                continue;
            }
        };
        for _ in 0..admitted.evicted {
            gate.count(HttpRejectReason::Evicted);
        }
        let local = stream.local_addr().ok();
        crate::task::spawn(
            "http connection",
            connection(
                stream,
                peer,
                local,
                admitted.place,
                gate.clone(),
                service.clone(),
                graceful.watcher(),
            ),
        );
    }
    drop(listener);
    tracing::info!(
        connections = graceful.count(),
        "REST API stopping: finishing requests in flight"
    );
    graceful.shutdown().await;
    Ok(())
}

/// Closes a connection refused at accept with a reset rather than a FIN: nothing was exchanged,
/// and the listener keeps no TIME_WAIT socket for it (a client reconnecting a thousand times a
/// second would otherwise leave tens of thousands of them).
fn refuse(stream: &TcpStream) {
    let _ = stream.set_zero_linger();
}

type Service = TowerToHyperService<axum::Router>;

/// Serves one connection in its place: the TLS handshake first when configured.
async fn connection(
    stream: TcpStream,
    peer: SocketAddr,
    local: Option<SocketAddr>,
    place: Place,
    state: ApiState,
    service: Service,
    watcher: Watcher,
) {
    let head_timeout = match place.pool.health_only() {
        None => state.header_read_timeout,
        Some(_) => state.header_read_timeout.min(HEALTH_HEAD_TIMEOUT),
    };
    let conn = Conn { peer, local };
    let io = WriteTimeout::new(stream, state.write_timeout);
    let fired = io.fired();
    let evicted = place.evicted.clone();
    let served = async {
        match state.tls.as_ref().map(super::tls::HttpTls::acceptor) {
            None => serve_io(io, conn, &place, &state, service, watcher, head_timeout).await,
            Some(acceptor) => match tokio::time::timeout(head_timeout, acceptor.accept(io)).await {
                Ok(Ok(tls)) => {
                    serve_io(tls, conn, &place, &state, service, watcher, head_timeout).await;
                }
                Ok(Err(e)) => state.refused(
                    HttpRejectReason::TlsHandshake,
                    Some(peer),
                    &format!("TLS handshake failed: {e}"),
                ),
                Err(_) => {
                    place.timed_out();
                    state.refused(
                        HttpRejectReason::TlsHandshake,
                        Some(peer),
                        "TLS handshake not complete within the header read timeout",
                    );
                }
            },
        }
    };
    tokio::select! {
        () = served => {}
        () = evicted.cancelled() => {
            tracing::debug!(%peer, "HTTP connection waiting for a request head closed: its place went to a new one");
        }
    }
    if fired.load(Ordering::Relaxed) {
        state.refused(
            HttpRejectReason::WriteTimeout,
            Some(peer),
            "answer not read within [http] write_timeout, connection closed",
        );
    }
    drop(place);
}

/// The addresses of a connection: the client's, and the listener's own address it reached.
#[derive(Clone, Copy, Debug)]
struct Conn {
    peer: SocketAddr,
    local: Option<SocketAddr>,
}

async fn serve_io<I>(
    io: I,
    conn: Conn,
    place: &Place,
    state: &ApiState,
    service: Service,
    watcher: Watcher,
    head_timeout: Duration,
) where
    I: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    let peer = conn.peer;
    let served = http1::Builder::new()
        .timer(TokioTimer::new())
        .header_read_timeout(head_timeout)
        // A health place serves one request.
        .keep_alive(place.pool == Pool::General)
        .serve_connection(
            TokioIo::new(io),
            ConnService {
                inner: service,
                peer: PeerAddr(peer),
                local: conn.local.map(LocalAddr),
                place: place.handle(),
                state: state.clone(),
            },
        );
    match watcher.watch(served).await {
        Ok(()) => {}
        Err(e) if e.is_timeout() => {
            place.timed_out();
            state.refused(
                HttpRejectReason::HeaderTimeout,
                Some(peer),
                "request head not complete within the header read timeout, connection closed",
            );
        }
        Err(e) => tracing::debug!(%peer, error = %e, "REST API connection ended with an error"),
    }
}

/// A connection's service: every request gets the client's address (for the audit) and marks
/// the connection busy until its answer is written; a health place answers only the health paths.
#[derive(Clone)]
struct ConnService {
    inner: Service,
    peer: PeerAddr,
    local: Option<LocalAddr>,
    place: PlaceHandle,
    state: ApiState,
}

impl hyper::service::Service<hyper::Request<Incoming>> for ConnService {
    type Response = Response;
    type Error = Infallible;
    type Future = Pin<Box<dyn Future<Output = Result<Response, Infallible>> + Send>>;

    fn call(&self, req: hyper::Request<Incoming>) -> Self::Future {
        if let Some(why) = self.place.pool.health_only() {
            if !is_health_path(req.uri().path()) {
                let what = match why {
                    HttpRejectReason::ClientLimit => {
                        "every connection place of the client address is taken ([http] max_connections_per_client)"
                    }
                    _ => "every connection place is taken ([http] max_connections)",
                };
                self.state.refused(why, Some(self.peer.0), what);
                let mut response =
                    ApiError::busy_for(format!("{what}; try again later"), RETRY_AFTER_SECONDS)
                        .into_response();
                response
                    .headers_mut()
                    .insert(header::CONNECTION, HeaderValue::from_static("close"));
                return Box::pin(async move { Ok(response) });
            }
        }
        // A body still to come keeps the connection "waiting" (its place may be given to another
        // connection after a while, see `places`) until it has been read or given up.
        let with_body = !http_body::Body::is_end_stream(req.body());
        let guard = self.place.request(with_body);
        let body_guard = with_body.then(|| self.place.body());
        let mut req = req.map(|body| {
            Body::new(Tracked {
                body,
                guard: body_guard,
            })
        });
        req.extensions_mut().insert(self.peer);
        if let Some(local) = self.local {
            req.extensions_mut().insert(local);
        }
        let call = hyper::service::Service::call(&self.inner, req);
        Box::pin(async move {
            let response = call.await?;
            // The connection stays busy until the answer's body is written (or given up).
            Ok(response.map(|body| {
                Body::new(Guarded {
                    body,
                    _guard: guard,
                })
            }))
        })
    }
}

/// A request body that marks the connection as waiting for it until it has been read whole,
/// has failed, or is dropped.
struct Tracked {
    body: Incoming,
    guard: Option<super::places::BodyGuard>,
}

impl http_body::Body for Tracked {
    type Data = axum::body::Bytes;
    type Error = hyper::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Option<Result<http_body::Frame<Self::Data>, Self::Error>>> {
        let polled = Pin::new(&mut self.body).poll_frame(cx);
        let done = match &polled {
            std::task::Poll::Ready(None | Some(Err(_))) => true,
            std::task::Poll::Ready(Some(Ok(_))) => self.body.is_end_stream(),
            std::task::Poll::Pending => false,
        };
        if done {
            self.guard = None;
        }
        polled
    }

    fn is_end_stream(&self) -> bool {
        self.body.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.body.size_hint()
    }
}

/// A response body that holds its connection's request guard until it is dropped.
struct Guarded {
    body: Body,
    _guard: super::places::RequestGuard,
}

impl http_body::Body for Guarded {
    type Data = axum::body::Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Option<Result<http_body::Frame<Self::Data>, Self::Error>>> {
        Pin::new(&mut self.body).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.body.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.body.size_hint()
    }
}
