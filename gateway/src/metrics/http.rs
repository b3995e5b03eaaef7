//! A minimal HTTP/1.1 responder for `/metrics` alone (the gateway answers it on its REST listener).
//!
//! One request per connection (`Connection: close`, which RFC 9112 9.6 allows a server to send):
//! `GET` or `HEAD /metrics` answers the registry in the text format 0.0.4, another method on
//! `/metrics` 405, any other path 404, a malformed or oversized request head 400 / 431. A request
//! head must arrive within [`REQUEST_TIMEOUT`]; at most [`MAX_CONNECTIONS`] are served at once and
//! further connections are closed at accept. Request bodies are not read.

use std::sync::Arc;
use std::time::Duration;

use prometheus::Registry;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Semaphore;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

use super::{encode_text, TEXT_CONTENT_TYPE};

/// Longest request head accepted (request line and headers).
const MAX_HEAD: usize = 8 * 1024;
/// Time a client has to send its request head, and to take the response.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(5);
/// Connections served at once.
const MAX_CONNECTIONS: usize = 16;
/// Pause after a failed `accept()` (e.g. out of file descriptors) before the next one.
const ACCEPT_BACKOFF: Duration = Duration::from_millis(100);
/// The path served.
const METRICS_PATH: &str = "/metrics";

/// Serves `GET /metrics` from `registry` on `listener` until `shutdown` is cancelled, then stops
/// accepting and returns once the connections in flight are answered (each bounded by
/// [`REQUEST_TIMEOUT`]).
pub async fn serve_metrics(listener: TcpListener, registry: Registry, shutdown: CancellationToken) {
    let tracker = TaskTracker::new();
    let limit = Arc::new(Semaphore::new(MAX_CONNECTIONS));
    loop {
        let accepted = tokio::select! {
            () = shutdown.cancelled() => break,
            accepted = listener.accept() => accepted,
        };
        match accepted {
            Ok((stream, peer)) => {
                let Ok(permit) = Arc::clone(&limit).try_acquire_owned() else {
                    tracing::debug!(%peer, "metrics: connection limit reached, closing");
                    continue;
                };
                let registry = registry.clone();
                let shutdown = shutdown.clone();
                tracker.spawn(async move {
                    let _permit = permit;
                    tokio::select! {
                        () = shutdown.cancelled() => {}
                        result = tokio::time::timeout(
                            REQUEST_TIMEOUT,
                            handle(stream, &registry),
                        ) => match result {
                            Ok(Ok(())) => {}
                            Ok(Err(error)) => tracing::debug!(%peer, %error, "metrics: connection failed"),
                            Err(_) => tracing::debug!(%peer, "metrics: request timed out"),
                        },
                    }
                });
            }
            Err(error) => {
                tracing::warn!(%error, "metrics: accept failed");
                tokio::select! {
                    () = shutdown.cancelled() => break,
                    () = tokio::time::sleep(ACCEPT_BACKOFF) => {}
                }
            }
        }
    }
    drop(listener);
    tracker.close();
    tracker.wait().await;
}

/// Reads one request head, answers it, and closes.
async fn handle(mut stream: TcpStream, registry: &Registry) -> std::io::Result<()> {
    let mut head = Vec::with_capacity(512);
    let mut chunk = [0_u8; 1024];
    let response = loop {
        let n = stream.read(&mut chunk).await?;
        if n == 0 {
            // The client left before a complete head: nothing to answer.
            return Ok(());
        }
        head.extend_from_slice(chunk.get(..n).unwrap_or_default());
        match parse_head(&head) {
            Ok(Some(request)) => break respond(request, registry),
            Ok(None) => {}
            Err(error) => break error.response(),
        }
    };
    stream.write_all(&response).await?;
    stream.shutdown().await
}

/// What the responder understood of a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct RequestHead<'a> {
    method: &'a str,
    /// The path without the query.
    path: &'a str,
}

/// Why a request head is refused.
#[derive(Debug, PartialEq, Eq)]
enum HeadError {
    /// Not `METHOD SP TARGET SP HTTP/1.x`, or not UTF-8.
    Malformed,
    /// Longer than [`MAX_HEAD`] without its end.
    TooLarge,
}

// === impl HeadError ===

impl HeadError {
    fn response(&self) -> Vec<u8> {
        match self {
            Self::Malformed => plain(400, "Bad Request", &[], "bad request\n"),
            Self::TooLarge => plain(
                431,
                "Request Header Fields Too Large",
                &[],
                "request head too large\n",
            ),
        }
    }
}

/// Parses a request head: `Ok(None)` while its end (an empty line) has not arrived.
fn parse_head(buf: &[u8]) -> Result<Option<RequestHead<'_>>, HeadError> {
    let Some(end) = find_head_end(buf) else {
        return if buf.len() > MAX_HEAD {
            Err(HeadError::TooLarge)
        } else {
            Ok(None)
        };
    };
    if end > MAX_HEAD {
        return Err(HeadError::TooLarge);
    }
    let head = std::str::from_utf8(buf.get(..end).unwrap_or_default())
        .map_err(|_| HeadError::Malformed)?;
    let request_line = head.lines().next().ok_or(HeadError::Malformed)?;
    let mut parts = request_line.split(' ');
    let (Some(method), Some(target), Some(version), None) =
        (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return Err(HeadError::Malformed);
    };
    if method.is_empty() || !target.starts_with('/') || !version.starts_with("HTTP/1.") {
        return Err(HeadError::Malformed);
    }
    let path = target.split('?').next().unwrap_or(target);
    Ok(Some(RequestHead { method, path }))
}

/// The index of the end of the head (its blank line), `\r\n\r\n` or bare `\n\n`.
fn find_head_end(buf: &[u8]) -> Option<usize> {
    let crlf = buf
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .map(|at| at + 4);
    let lf = buf.windows(2).position(|w| w == b"\n\n").map(|at| at + 2);
    match (crlf, lf) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

fn respond(request: RequestHead<'_>, registry: &Registry) -> Vec<u8> {
    if request.path != METRICS_PATH {
        return plain(404, "Not Found", &[], "not found\n");
    }
    match request.method {
        "GET" | "HEAD" => {
            let body = encode_text(registry);
            let mut response = header(200, "OK", TEXT_CONTENT_TYPE, body.len(), &[]);
            if request.method == "GET" {
                response.extend_from_slice(body.as_bytes());
            }
            response
        }
        _ => plain(
            405,
            "Method Not Allowed",
            &[("Allow", "GET, HEAD")],
            "method not allowed\n",
        ),
    }
}

fn plain(status: u16, reason: &str, extra: &[(&str, &str)], body: &str) -> Vec<u8> {
    let mut response = header(
        status,
        reason,
        "text/plain; charset=utf-8",
        body.len(),
        extra,
    );
    response.extend_from_slice(body.as_bytes());
    response
}

fn header(
    status: u16,
    reason: &str,
    content_type: &str,
    length: usize,
    extra: &[(&str, &str)],
) -> Vec<u8> {
    let mut head = format!(
        "HTTP/1.1 {status} {reason}\r\nContent-Type: {content_type}\r\nContent-Length: {length}\r\nConnection: close\r\n"
    );
    for (name, value) in extra {
        head.push_str(name);
        head.push_str(": ");
        head.push_str(value);
        head.push_str("\r\n");
    }
    head.push_str("\r\n");
    head.into_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn head_is_parsed_once_complete() {
        assert_eq!(
            parse_head(b"GET /metrics HTTP/1.1\r\nHost: x\r\n"),
            Ok(None)
        );
        assert_eq!(
            parse_head(b"GET /metrics?x=1 HTTP/1.1\r\nHost: x\r\n\r\n"),
            Ok(Some(RequestHead {
                method: "GET",
                path: "/metrics"
            }))
        );
        assert_eq!(
            parse_head(b"HEAD /metrics HTTP/1.0\n\n"),
            Ok(Some(RequestHead {
                method: "HEAD",
                path: "/metrics"
            }))
        );
    }

    #[test]
    fn bad_heads_are_refused() {
        for bad in [
            &b"GET /metrics\r\n\r\n"[..],
            b"GET metrics HTTP/1.1\r\n\r\n",
            b"GET /metrics HTTP/2\r\n\r\n",
            b"GET  /metrics HTTP/1.1\r\n\r\n",
            b"\xff\xfe /metrics HTTP/1.1\r\n\r\n",
            b"\r\n\r\n",
        ] {
            assert_eq!(parse_head(bad), Err(HeadError::Malformed), "{bad:?}");
        }
        let long = vec![b'a'; MAX_HEAD + 1];
        assert_eq!(parse_head(&long), Err(HeadError::TooLarge));
    }

    #[test]
    fn responses_by_path_and_method() {
        let registry = Registry::new();
        let status = |raw: &[u8]| {
            let response = match parse_head(raw) {
                Ok(Some(request)) => respond(request, &registry),
                Ok(None) => panic!("incomplete"),
                Err(error) => error.response(),
            };
            String::from_utf8(response).expect("utf-8")
        };
        assert!(status(b"GET /metrics HTTP/1.1\r\n\r\n").starts_with("HTTP/1.1 200 OK\r\n"));
        assert!(status(b"GET / HTTP/1.1\r\n\r\n").starts_with("HTTP/1.1 404 "));
        let post = status(b"POST /metrics HTTP/1.1\r\n\r\n");
        assert!(post.starts_with("HTTP/1.1 405 "), "{post}");
        assert!(post.contains("\r\nAllow: GET, HEAD\r\n"));
        assert!(status(b"GET /metrics HTTP/9\r\n\r\n").starts_with("HTTP/1.1 400 "));
    }
}
