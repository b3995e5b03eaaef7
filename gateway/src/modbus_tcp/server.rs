//! The accept loop: network filter, connection caps (the server's and each client address's),
//! accept errors, shutdown; for Modbus/TCP Security the TLS handshake before the connection task.

use std::collections::HashMap;
use std::io;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::net::{TcpListener, TcpSocket, TcpStream};
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;
use tracing::{debug, error, info, warn};

use super::access::Authority;
use super::connection::{self, Places};
use super::metrics::{AcceptError, CloseReason, RejectReason, ServerStats};
use super::options::LiveOptions;
use super::shared::{ClientPlace, ServerPlace, Shared};
use super::tls::{role_of, TlsServer};
use crate::log_limit::{LogLimit, Verdict};
use crate::unit::SharedUnits;

pub use super::options::{
    ServerOptions, DEFAULT_IDLE_TIMEOUT, DEFAULT_MAX_CONNECTIONS, DEFAULT_REQUEST_TIMEOUT,
};

/// Listen backlog of [`bind`]: room for a burst of clients connecting at once (SCADA stations
/// reconnecting after a network outage). `TcpListener::bind` uses 128, and connections past a full
/// queue wait for the kernel's SYN-ACK retransmission (1 s, then doubling).
pub const DEFAULT_BACKLOG: u32 = 1024;

/// Binds a listener for [`serve`] with [`DEFAULT_BACKLOG`] and `SO_REUSEADDR` (a restart does not
/// wait for the old connections' TIME_WAIT). Must be called inside a tokio runtime.
pub fn bind(addr: SocketAddr) -> io::Result<TcpListener> {
    let socket = if addr.is_ipv4() {
        TcpSocket::new_v4()?
    } else {
        TcpSocket::new_v6()?
    };
    socket.set_reuseaddr(true)?;
    socket.bind(addr)?;
    socket.listen(DEFAULT_BACKLOG)
}

/// Pause after a failed `accept()` before the next one, so that a process out of file
/// descriptors does not spin; connections wait in the listen backlog meanwhile.
const ACCEPT_ERROR_PAUSE: Duration = Duration::from_millis(100);

/// Serves Modbus TCP on `listener` until `shutdown` is cancelled.
///
/// On cancel: stops accepting, lets every connection finish the request it is serving (bounded by
/// `request_timeout` and, for the write, `idle_timeout`), then returns `Ok(())`. Transient accept
/// errors (EMFILE, ENFILE, ECONNABORTED, ENOBUFS, ENOMEM, network errors) are logged, counted and
/// retried after a short pause; an error that means the listener itself is unusable (EBADF,
/// EINVAL, ENOTSOCK, EOPNOTSUPP, EFAULT) ends the server with that error, after the open
/// connections finished as on shutdown.
pub async fn serve(
    listener: TcpListener,
    units: SharedUnits,
    options: ServerOptions,
    shutdown: CancellationToken,
    stats: Arc<ServerStats>,
) -> io::Result<()> {
    run(
        listener,
        units,
        LiveOptions::new(options),
        None,
        shutdown,
        stats,
    )
    .await
}

/// As [`serve`], with options the caller replaces while the server runs ([`LiveOptions::set`]):
/// a changed limit applies to new connections (the caps, the networks) and to the next request or
/// wait of the open ones (write policy, request and idle timeouts), and closes none of them.
pub async fn serve_live(
    listener: TcpListener,
    units: SharedUnits,
    options: Arc<LiveOptions>,
    shutdown: CancellationToken,
    stats: Arc<ServerStats>,
) -> io::Result<()> {
    run(listener, units, options, None, shutdown, stats).await
}

/// Serves Modbus/TCP Security on `listener` until `shutdown` is cancelled: as [`serve`], with a
/// TLS handshake (client certificate required) before each connection is served, and every
/// request checked against the rights of the client certificate's role. `tls` stays shared with
/// the caller, who reloads or replaces the certificates through it while the server runs.
pub async fn serve_tls(
    listener: TcpListener,
    units: SharedUnits,
    options: ServerOptions,
    tls: TlsServer,
    shutdown: CancellationToken,
    stats: Arc<ServerStats>,
) -> io::Result<()> {
    run(
        listener,
        units,
        LiveOptions::new(options),
        Some(tls),
        shutdown,
        stats,
    )
    .await
}

/// [`serve_tls`] with options replaced while it runs, as [`serve_live`].
pub async fn serve_tls_live(
    listener: TcpListener,
    units: SharedUnits,
    options: Arc<LiveOptions>,
    tls: TlsServer,
    shutdown: CancellationToken,
    stats: Arc<ServerStats>,
) -> io::Result<()> {
    run(listener, units, options, Some(tls), shutdown, stats).await
}

async fn run(
    listener: TcpListener,
    units: SharedUnits,
    options: Arc<LiveOptions>,
    tls: Option<TlsServer>,
    shutdown: CancellationToken,
    stats: Arc<ServerStats>,
) -> io::Result<()> {
    let shared = Arc::new(Shared {
        units,
        options,
        open: Arc::default(),
        stats,
        tls,
        clients: Arc::new(Mutex::new(HashMap::new())),
    });
    let what = if shared.tls.is_some() {
        "Modbus/TCP Security"
    } else {
        "Modbus TCP"
    };
    let tracker = TaskTracker::new();
    if let Ok(local) = listener.local_addr() {
        let options = shared.options.get();
        info!(%local, max_connections = options.max_connections,
            max_connections_per_client = options.max_connections_per_client,
            "{what} server listening");
    }
    let result = loop {
        let accepted = tokio::select! {
            biased;
            () = shutdown.cancelled() => break Ok(()),
            accepted = listener.accept() => accepted,
        };
        match accepted {
            Ok((stream, peer)) => admit(stream, peer, &shared, &tracker, &shutdown),
            Err(error) => {
                let Some(kind) = classify(&error) else {
                    error!(%error, "Modbus TCP listener failed");
                    break Err(error);
                };
                // Clients can cause it (EMFILE under a connection flood): at most one line per
                // 10 s, the rest counted in the stats.
                crate::warn_limited!("modbus tcp accept", %error, ?kind, "accept failed, retrying");
                shared.stats.count_accept_error(kind);
                tokio::select! {
                    () = shutdown.cancelled() => break Ok(()),
                    () = tokio::time::sleep(ACCEPT_ERROR_PAUSE) => {}
                }
            }
        }
    };
    drop(listener);
    tracker.close();
    tracker.wait().await;
    info!("{what} server stopped");
    result
}

/// Filters a new connection and spawns its task; a refused one is closed by dropping it.
fn admit(
    stream: TcpStream,
    peer: SocketAddr,
    shared: &Arc<Shared>,
    tracker: &TaskTracker,
    shutdown: &CancellationToken,
) {
    // The limits in force at this accept (a configuration change replaces them for the next).
    let options = shared.options.get();
    if !options.allows_peer(peer.ip()) {
        refused(shared, peer, "the client is outside allowed_networks");
        shared.stats.count_rejected(RejectReason::Network);
        return;
    }
    let Some(client) = ClientPlace::take(shared, &options, peer.ip()) else {
        refused(
            shared,
            peer,
            "the client address has max_connections_per_client open",
        );
        shared.stats.count_rejected(RejectReason::Limit);
        return;
    };
    let Some(permit) = ServerPlace::take(shared, options.max_connections) else {
        refused(shared, peer, "the server has max_connections open");
        shared.stats.count_rejected(RejectReason::Limit);
        return;
    };
    // Responses are small and each one completes a client's transaction: do not wait for more.
    if let Err(error) = stream.set_nodelay(true) {
        debug!(%peer, %error, "TCP_NODELAY not set");
    }
    let shared = Arc::clone(shared);
    let shutdown = shutdown.clone();
    let Some(tls) = shared.tls.clone() else {
        debug!(%peer, "client connected");
        let places = Places {
            _permit: permit,
            _client: client,
            _open: shared.stats.count_accepted(),
        };
        tracker.spawn(crate::task::watch(
            "modbus-tcp connection",
            connection::run(stream, peer, shared, shutdown, places, Authority::Open),
        ));
        return;
    };
    tracker.spawn(crate::task::watch("modbus-tcp tls handshake", async move {
        let handshake_timeout = options.idle_timeout.min(HANDSHAKE_TIMEOUT);
        let handshake = tokio::time::timeout(handshake_timeout, tls.acceptor().accept(stream));
        let result = tokio::select! {
            () = shutdown.cancelled() => {
                shared.stats.count_closed(CloseReason::Shutdown);
                return;
            }
            result = handshake => result,
        };
        let stream = match result {
            Ok(Ok(stream)) => stream,
            failed => {
                shared.stats.count_handshake_failed();
                if let Verdict::Log { suppressed } = HANDSHAKE_LOG.check() {
                    match failed {
                        Ok(Err(error)) => warn!(%peer, %error, suppressed, "TLS handshake failed"),
                        _ => warn!(%peer, suppressed, "TLS handshake timed out"),
                    }
                }
                return;
            }
        };
        let role = stream
            .get_ref()
            .1
            .peer_certificates()
            .and_then(<[_]>::first)
            .and_then(|certificate| role_of(certificate));
        let authority = Authority::of_role(role, &tls.roles());
        info!(%peer, role = authority.label(), "Modbus/TCP Security client connected");
        let places = Places {
            _permit: permit,
            _client: client,
            _open: shared.stats.count_accepted(),
        };
        connection::run(stream, peer, shared, shutdown, places, authority).await;
    }));
}

/// Log lines about refused connections (network filter, connection caps): the first few of a
/// window with the client's address, then one with the number left out; a scan or a reconnecting
/// flood writes a few lines, `gateway_modbus_tcp_connections_rejected_total` counts every one.
static REFUSED_LOG: LogLimit = LogLimit::new(Duration::from_secs(10), 5);

/// Logs a connection closed at accept, within [`REFUSED_LOG`]'s limit.
fn refused(shared: &Shared, peer: SocketAddr, reason: &str) {
    if let Verdict::Log { suppressed } = REFUSED_LOG.check() {
        let what = if shared.tls.is_some() {
            "Modbus/TCP Security"
        } else {
            "Modbus TCP"
        };
        warn!(%peer, reason, suppressed, "{what} connection refused");
    }
}

/// The longest a TLS handshake may take (bounded by `idle_timeout` as well): a client that
/// connects and says nothing holds its places no longer than this.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// Log lines about failed handshakes: a scan or a flood writes a few lines, not one per attempt.
static HANDSHAKE_LOG: LogLimit = LogLimit::new(Duration::from_secs(10), 10);

/// The counter of a transient accept error, or `None` when the listener is unusable.
fn classify(error: &io::Error) -> Option<AcceptError> {
    if error.kind() == io::ErrorKind::ConnectionAborted {
        return Some(AcceptError::ConnectionAborted);
    }
    match error.raw_os_error() {
        Some(libc::EMFILE) => Some(AcceptError::ProcessFdLimit),
        Some(libc::ENFILE) => Some(AcceptError::SystemFdLimit),
        Some(libc::ECONNABORTED) => Some(AcceptError::ConnectionAborted),
        Some(libc::EBADF | libc::EINVAL | libc::ENOTSOCK | libc::EOPNOTSUPP | libc::EFAULT) => None,
        _ => Some(AcceptError::Other),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fd_exhaustion_and_aborts_are_transient() {
        let of = |code| classify(&io::Error::from_raw_os_error(code));
        assert_eq!(of(libc::EMFILE), Some(AcceptError::ProcessFdLimit));
        assert_eq!(of(libc::ENFILE), Some(AcceptError::SystemFdLimit));
        assert_eq!(of(libc::ECONNABORTED), Some(AcceptError::ConnectionAborted));
        assert_eq!(of(libc::ENOBUFS), Some(AcceptError::Other));
        assert_eq!(of(libc::EPROTO), Some(AcceptError::Other));
        assert_eq!(of(libc::EBADF), None);
        assert_eq!(of(libc::EINVAL), None);
    }
}
