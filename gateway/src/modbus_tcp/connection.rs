//! One client connection: frames in, responses out, strictly in order.
//!
//! Requests of one connection are served one after the other; pipelined frames wait in the
//! [`FrameReader`] and their responses leave in the order the requests came. The idle deadline
//! moves only when a request has been answered, so a client that trickles bytes without finishing
//! a frame is closed as idle as well.
//!
//! Each response is built in one buffer per connection (header room, then the PDU the unit writes)
//! and appended to the burst's answers: the responses to every complete frame a read brought (a
//! client that pipelines) leave in one write, after the last of them. A unit that has to wait (the
//! device answers) sends what is answered before it first, so no answer waits for another's device.

use std::future::{poll_fn, Future};
use std::io;
use std::net::SocketAddr;
use std::sync::Arc;
use std::task::Poll;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::time::{sleep_until, Instant};
use tokio_util::sync::CancellationToken;
use tracing::debug;

use super::access::Authority;
use super::mbap::{complete_frame, Frame, FrameReader, MbapError, HEADER_LEN, MAX_ADU_LEN};
use super::metrics::{CloseReason, FrameReject, OpenConnection};
use super::request::answer;
use super::shared::Shared;

/// Bytes asked from the socket at once.
const READ_CHUNK: usize = 1024;

/// Far enough to mean "never" for an idle timeout too large to add to the clock.
const FAR_FUTURE: std::time::Duration = std::time::Duration::from_secs(100 * 365 * 24 * 3600);

/// A byte stream a connection is served on: plain TCP, or TLS over TCP (Modbus/TCP Security).
pub(crate) trait ClientStream: AsyncRead + AsyncWrite + Unpin + Send {
    /// Writes what the stream takes at once, without waiting; `Ok(0)` when it takes nothing now.
    fn write_now(&mut self, _bytes: &[u8]) -> io::Result<usize> {
        Ok(0)
    }
}

impl ClientStream for TcpStream {
    fn write_now(&mut self, bytes: &[u8]) -> io::Result<usize> {
        match self.try_write(bytes) {
            Err(error) if error.kind() == io::ErrorKind::WouldBlock => Ok(0),
            other => other,
        }
    }
}

impl ClientStream for tokio_rustls::server::TlsStream<TcpStream> {}

/// What holds one connection's places: in the server's cap, in its client address's cap, and in
/// the open-connections gauge.
pub(crate) struct Places {
    pub(crate) _permit: super::shared::ServerPlace,
    pub(crate) _client: super::shared::ClientPlace,
    pub(crate) _open: OpenConnection,
}

/// Serves one accepted connection until the client leaves, a limit closes it, or shutdown.
/// `_places` hold the connection's places in the caps and the open-connections gauge; `authority`
/// is what its requests may do.
pub(crate) async fn run<S: ClientStream>(
    mut stream: S,
    peer: SocketAddr,
    shared: Arc<Shared>,
    shutdown: CancellationToken,
    _places: Places,
    authority: Authority,
) {
    // A token of its own: the connection asks it after every request and waits on it, which on
    // the server's token would take a lock that every connection shares.
    let shutdown = shutdown.child_token();
    let reason = serve(&mut stream, peer, &shared, &shutdown, &authority).await;
    debug!(%peer, ?reason, "connection closed");
    shared.stats.count_closed(reason);
    // Best effort: the client may be gone already.
    let _ = stream.shutdown().await;
}

async fn serve<S: ClientStream>(
    stream: &mut S,
    peer: SocketAddr,
    shared: &Shared,
    shutdown: &CancellationToken,
    authority: &Authority,
) -> CloseReason {
    // The options in force, taken again when a configuration change replaced them.
    let mut generation = shared.options.generation();
    let mut options = shared.options.get();
    let mut idle = options.idle_timeout;
    let mut reader = FrameReader::new();
    let mut chunk = [0u8; READ_CHUNK];
    // The response ADU: the header's room, then the PDU written by `answer`.
    let mut adu = Vec::with_capacity(MAX_ADU_LEN);
    // The responses of the burst not yet written, in order.
    let mut answered: Vec<u8> = Vec::with_capacity(MAX_ADU_LEN);
    let mut deadline = deadline_after(idle);
    // One timer and one shutdown waiter for the connection's life, not one per request: the
    // timer is armed for the deadline it had when armed, and when it fires early (the deadline
    // moved since) it is set again.
    let idle_timer = sleep_until(deadline);
    tokio::pin!(idle_timer);
    let cancelled = shutdown.cancelled();
    tokio::pin!(cancelled);
    loop {
        // Answer every complete frame already received, in order; a bad frame closes the
        // connection after the answers before it.
        let closing = loop {
            let frame = match next_frame(&mut reader, peer, shared) {
                Ok(Some(frame)) => frame,
                Ok(None) => break None,
                Err(reason) => break Some(reason),
            };
            if shared.options.generation() != generation {
                generation = shared.options.generation();
                options = shared.options.get();
                idle = options.idle_timeout;
            }
            let header = frame.header;
            adu.clear();
            adu.resize(HEADER_LEN, 0);
            let (unit, pdu) = (header.unit_id, frame.pdu);
            let answering = answer(shared, &options, authority, peer, unit, pdu, &mut adu);
            let result = match in_order(stream, peer, &mut answered, idle, answering).await {
                Ok(result) => result,
                Err(reason) => return reason,
            };
            if let Err(reject) = result {
                crate::warn_limited!(
                    "modbus_tcp/no_function",
                    %peer, transaction_id = header.transaction_id,
                    "frame without function code, closing the connection"
                );
                shared.stats.count_frame_rejected(reject);
                break Some(CloseReason::BadFrame);
            }
            // `answer` never gives more than `MAX_PDU_LEN` bytes.
            if !complete_frame(header, &mut adu) {
                break Some(CloseReason::BadFrame);
            }
            answered.extend_from_slice(&adu);
        };
        if !answered.is_empty() {
            if let Err(reason) = write_response(stream, peer, &answered, idle).await {
                return reason;
            }
            answered.clear();
            deadline = deadline_after(idle);
            if shutdown.is_cancelled() {
                return CloseReason::Shutdown;
            }
        }
        if let Some(reason) = closing {
            return reason;
        }
        // A request that is there is read before a shutdown is noticed: it is answered, and the
        // check after the answer closes the connection.
        let read = tokio::select! {
            biased;
            read = stream.read(&mut chunk) => read,
            () = &mut cancelled => return CloseReason::Shutdown,
            () = &mut idle_timer => {
                if idle_timer.deadline() >= deadline {
                    debug!(%peer, partial = reader.buffered(), "idle timeout");
                    return CloseReason::Idle;
                }
                idle_timer.as_mut().reset(deadline);
                continue;
            }
        };
        if let Err(reason) = received(read, &chunk, &mut reader, peer) {
            return reason;
        }
    }
}

/// What `answering` gives; when it waits (its unit waits for a device), the answers before it
/// in `answered` leave first, so that a client's earlier requests are not held behind it.
async fn in_order<S: ClientStream, F: Future>(
    stream: &mut S,
    peer: SocketAddr,
    answered: &mut Vec<u8>,
    idle: std::time::Duration,
    answering: F,
) -> Result<F::Output, CloseReason> {
    tokio::pin!(answering);
    match poll_fn(|cx| Poll::Ready(answering.as_mut().poll(cx))).await {
        Poll::Ready(result) => Ok(result),
        Poll::Pending => {
            write_response(stream, peer, answered, idle).await?;
            answered.clear();
            Ok(answering.await)
        }
    }
}

/// The next complete frame received, `Ok(None)` when more bytes are needed; a bad header closes
/// the connection.
fn next_frame<'r>(
    reader: &'r mut FrameReader,
    peer: SocketAddr,
    shared: &Shared,
) -> Result<Option<Frame<'r>>, CloseReason> {
    reader.next_frame().map_err(|error| {
        crate::warn_limited!(
            "modbus_tcp/bad_header",
            %peer, %error, "bad MBAP header, closing the connection"
        );
        shared.stats.count_frame_rejected(match error {
            MbapError::ProtocolId(_) => FrameReject::ProtocolId,
            MbapError::Length(_) => FrameReject::Length,
        });
        CloseReason::BadFrame
    })
}

/// Hands what a read of the socket gave (into `chunk`) to the reader; `Err` when the connection
/// ends there: the client closed it, or the read failed.
fn received(
    read: io::Result<usize>,
    chunk: &[u8],
    reader: &mut FrameReader,
    peer: SocketAddr,
) -> Result<(), CloseReason> {
    match read {
        Ok(0) => {
            if reader.buffered() > 0 {
                debug!(%peer, bytes = reader.buffered(), "client closed inside a frame");
            }
            Err(CloseReason::Peer)
        }
        Ok(n) => {
            reader.extend(chunk.get(..n).unwrap_or_default());
            Ok(())
        }
        Err(error) => {
            debug!(%peer, %error, "read failed");
            Err(CloseReason::Io)
        }
    }
}

/// Writes responses (none: nothing to do): at once when the socket takes it whole (the usual case on plain TCP, no
/// timer), else the rest (and, on TLS, the flush of the record) within `idle`. `Err`: why the
/// connection closes.
async fn write_response<S: ClientStream>(
    stream: &mut S,
    peer: SocketAddr,
    adu: &[u8],
    idle: std::time::Duration,
) -> Result<(), CloseReason> {
    if adu.is_empty() {
        return Ok(());
    }
    let written = match stream.write_now(adu) {
        Ok(n) => n,
        Err(error) => {
            debug!(%peer, %error, "write failed");
            return Err(CloseReason::Io);
        }
    };
    let Some(rest) = adu.get(written..).filter(|rest| !rest.is_empty()) else {
        return Ok(());
    };
    let write = async {
        stream.write_all(rest).await?;
        stream.flush().await
    };
    match tokio::time::timeout(idle, write).await {
        Ok(Ok(())) => Ok(()),
        Ok(Err(error)) => {
            debug!(%peer, %error, "write failed");
            Err(CloseReason::Io)
        }
        Err(_) => {
            debug!(%peer, "client does not take its responses");
            Err(CloseReason::Idle)
        }
    }
}

fn deadline_after(idle: std::time::Duration) -> Instant {
    let now = Instant::now();
    now.checked_add(idle).unwrap_or_else(|| now + FAR_FUTURE)
}
