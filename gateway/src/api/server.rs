//! The API's accept loop (the mini-redis shape): at most `max_connections` connections, each
//! served by hyper's HTTP/1 with a header read timeout, and a graceful stop.
//!
//! `axum::serve` gives hyper no timer, so hyper's header read timeout never fires there: a client
//! that trickles a request head, or keeps an idle connection open, would hold a connection for
//! ever. Here the timer is set, so the time to receive a request head (including the wait for the
//! next request on a kept-alive connection) is bounded by the header read timeout; the time to
//! read the body and answer is bounded by `[http] request_timeout`.

use std::future::Future;
use std::io;
use std::sync::Arc;
use std::time::Duration;

use hyper::server::conn::http1;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::server::graceful::GracefulShutdown;
use hyper_util::service::TowerToHyperService;
use tokio::net::TcpListener;
use tokio::sync::Semaphore;

use super::auth::PeerAddr;
use super::{router, ApiState};

/// Connections served at once by default (`[http] max_connections`); more wait in the listen
/// backlog.
pub const DEFAULT_MAX_CONNECTIONS: u32 = crate::config::DEFAULT_HTTP_MAX_CONNECTIONS;
/// Longest wait for a request head, and for the next request on an idle connection.
pub const DEFAULT_HEADER_READ_TIMEOUT: Duration = Duration::from_secs(10);
/// Pause after a failed accept (e.g. out of file descriptors) before trying again.
const ACCEPT_BACKOFF: Duration = Duration::from_millis(100);

/// Serves the API on `listener` until `shutdown` completes; then stops accepting, closes idle
/// connections, lets requests in flight finish and returns when every connection has ended
/// (the caller bounds that with its grace period). The caller says how changes are guarded
/// (`log_mode` of the API state's guard) before it announces the listener.
pub async fn serve(
    listener: TcpListener,
    state: ApiState,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> io::Result<()> {
    if let Ok(addr) = listener.local_addr() {
        tracing::info!(%addr, max_connections = state.max_connections, "REST API listening");
    }
    let header_read_timeout = state.header_read_timeout;
    let gate = state.clone();
    let limit = Arc::new(Semaphore::new(state.max_connections));
    let service = TowerToHyperService::new(router(state));
    let graceful = GracefulShutdown::new();
    let mut shutdown = std::pin::pin!(shutdown);
    loop {
        let permit = tokio::select! {
            p = limit.clone().acquire_owned() => p.map_err(io::Error::other)?,
            () = &mut shutdown => break,
        };
        let (stream, peer) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok((_, peer)) if !gate.allows_peer(peer.ip()) => {
                    tracing::debug!(%peer, "REST API client outside the allowed networks, closed");
                    continue;
                }
                Ok((stream, peer)) => (stream, peer),
                Err(e) => {
                    tracing::warn!(error = %e, "REST API accept failed");
                    tokio::time::sleep(ACCEPT_BACKOFF).await;
                    continue;
                }
            },
            () = &mut shutdown => break,
        };
        let conn = http1::Builder::new()
            .timer(TokioTimer::new())
            .header_read_timeout(header_read_timeout)
            .serve_connection(
                TokioIo::new(stream),
                WithPeer {
                    inner: service.clone(),
                    peer: PeerAddr(peer),
                },
            );
        let conn = graceful.watch(conn);
        tokio::spawn(async move {
            if let Err(e) = conn.await {
                tracing::debug!(error = %e, "REST API connection ended with an error");
            }
            drop(permit);
        });
    }
    drop(listener);
    tracing::info!(
        connections = graceful.count(),
        "REST API stopping: finishing requests in flight"
    );
    graceful.shutdown().await;
    Ok(())
}

/// A connection's service: every request gets the client's address (for the audit).
#[derive(Clone)]
struct WithPeer<S> {
    inner: S,
    peer: PeerAddr,
}

impl<S, B> hyper::service::Service<hyper::Request<B>> for WithPeer<S>
where
    S: hyper::service::Service<hyper::Request<B>>,
{
    type Response = S::Response;
    type Error = S::Error;
    type Future = S::Future;

    fn call(&self, mut req: hyper::Request<B>) -> Self::Future {
        req.extensions_mut().insert(self.peer);
        self.inner.call(req)
    }
}
