//! One client connection: frames in, responses out, strictly in order.
//!
//! Requests of one connection are served one after the other; pipelined frames wait in the
//! [`FrameReader`] and their responses leave in the order the requests came. The idle deadline
//! moves only when a request has been answered, so a client that trickles bytes without finishing
//! a frame is closed as idle as well.

use std::net::SocketAddr;
use std::sync::Arc;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::sync::OwnedSemaphorePermit;
use tokio::time::{timeout_at, Instant};
use tokio_util::sync::CancellationToken;
use tracing::{debug, warn};

use super::mbap::{encode_frame, FrameReader, MbapError, MAX_ADU_LEN};
use super::request::{answer, Shared};
use super::stats::{CloseReason, FrameReject, OpenConnection};

/// Bytes asked from the socket at once.
const READ_CHUNK: usize = 1024;

/// Far enough to mean "never" for an idle timeout too large to add to the clock.
const FAR_FUTURE: std::time::Duration = std::time::Duration::from_secs(100 * 365 * 24 * 3600);

/// Serves one accepted connection until the client leaves, a limit closes it, or shutdown.
/// `_permit` and `_open` hold the connection's place in the cap and the open-connections gauge.
pub(crate) async fn run(
    mut stream: TcpStream,
    peer: SocketAddr,
    shared: Arc<Shared>,
    shutdown: CancellationToken,
    _permit: OwnedSemaphorePermit,
    _open: OpenConnection,
) {
    let reason = serve(&mut stream, peer, &shared, &shutdown).await;
    debug!(%peer, ?reason, "connection closed");
    shared.stats.count_closed(reason);
    // Best effort: the client may be gone already.
    let _ = stream.shutdown().await;
}

async fn serve(
    stream: &mut TcpStream,
    peer: SocketAddr,
    shared: &Shared,
    shutdown: &CancellationToken,
) -> CloseReason {
    let idle = shared.options.idle_timeout;
    let mut reader = FrameReader::new();
    let mut chunk = [0u8; READ_CHUNK];
    let mut pdu = Vec::with_capacity(MAX_ADU_LEN);
    let mut adu = Vec::with_capacity(MAX_ADU_LEN);
    let mut deadline = deadline_after(idle);
    loop {
        // Answer every complete frame already received, in order.
        loop {
            let frame = match reader.next_frame() {
                Ok(Some(frame)) => frame,
                Ok(None) => break,
                Err(error) => {
                    warn!(%peer, %error, "bad MBAP header, closing the connection");
                    shared.stats.count_frame_rejected(match error {
                        MbapError::ProtocolId(_) => FrameReject::ProtocolId,
                        MbapError::Length(_) => FrameReject::Length,
                    });
                    return CloseReason::BadFrame;
                }
            };
            let header = frame.header;
            if let Err(reject) = answer(shared, header.unit_id, frame.pdu, &mut pdu).await {
                warn!(%peer, transaction_id = header.transaction_id, "frame without function code, closing the connection");
                shared.stats.count_frame_rejected(reject);
                return CloseReason::BadFrame;
            }
            adu.clear();
            // `answer` never gives more than `MAX_PDU_LEN` bytes.
            if !encode_frame(header, &pdu, &mut adu) {
                return CloseReason::BadFrame;
            }
            match tokio::time::timeout(idle, stream.write_all(&adu)).await {
                Ok(Ok(())) => {}
                Ok(Err(error)) => {
                    debug!(%peer, %error, "write failed");
                    return CloseReason::Io;
                }
                Err(_) => {
                    debug!(%peer, "client does not take its responses");
                    return CloseReason::Idle;
                }
            }
            deadline = deadline_after(idle);
            if shutdown.is_cancelled() {
                return CloseReason::Shutdown;
            }
        }
        let read = tokio::select! {
            () = shutdown.cancelled() => return CloseReason::Shutdown,
            read = timeout_at(deadline, stream.read(&mut chunk)) => read,
        };
        match read {
            Ok(Ok(0)) => {
                if reader.buffered() > 0 {
                    debug!(%peer, bytes = reader.buffered(), "client closed inside a frame");
                }
                return CloseReason::Peer;
            }
            Ok(Ok(n)) => reader.extend(chunk.get(..n).unwrap_or_default()),
            Ok(Err(error)) => {
                debug!(%peer, %error, "read failed");
                return CloseReason::Io;
            }
            Err(_) => {
                debug!(%peer, partial = reader.buffered(), "idle timeout");
                return CloseReason::Idle;
            }
        }
    }
}

fn deadline_after(idle: std::time::Duration) -> Instant {
    let now = Instant::now();
    now.checked_add(idle).unwrap_or_else(|| now + FAR_FUTURE)
}
