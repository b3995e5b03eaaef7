//! The write timeout of an HTTP connection: a response whose bytes the client does not take for
//! `[http] write_timeout` ends the connection.
//!
//! hyper has a timeout for reading a request head, none for writing: a client that asks for a
//! large answer (or follows a stream) and never reads would hold its connection, the answer's
//! buffers and, for a stream, a stream place for as long as it likes. [`WriteTimeout`] sits
//! between the socket and hyper (and under TLS): a write or flush that stays pending for the
//! timeout fails with `TimedOut`, hyper ends the connection and the socket is closed. Any
//! progress restarts the clock, so a slow client that reads is served to the end.

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::time::{Instant, Sleep};

/// A socket whose writes fail after `timeout` without progress.
#[derive(Debug)]
pub(crate) struct WriteTimeout<T> {
    inner: T,
    timeout: Duration,
    sleep: Pin<Box<Sleep>>,
    /// Whether `sleep` runs for a write that is pending.
    armed: bool,
    /// Set when the timeout ended a write (the connection's task tells why it ended).
    fired: Arc<AtomicBool>,
}

// === impl WriteTimeout ===

impl<T> WriteTimeout<T> {
    pub(crate) fn new(inner: T, timeout: Duration) -> Self {
        Self {
            inner,
            timeout,
            sleep: Box::pin(tokio::time::sleep(timeout)),
            armed: false,
            fired: Arc::default(),
        }
    }

    /// Set once a write timed out.
    pub(crate) fn fired(&self) -> Arc<AtomicBool> {
        Arc::clone(&self.fired)
    }

    /// A write is pending: starts the clock if it is not running; the error once it ran out.
    fn pending<R>(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<R>> {
        if !self.armed {
            self.armed = true;
            self.sleep.as_mut().reset(Instant::now() + self.timeout);
        }
        if self.sleep.as_mut().poll(cx).is_ready() {
            self.fired.store(true, Ordering::Relaxed);
            return Poll::Ready(Err(io::Error::new(
                io::ErrorKind::TimedOut,
                "the client did not read the answer within the write timeout",
            )));
        }
        Poll::Pending
    }

    /// What the inner write, flush or shutdown gave: progress stops the clock, pending runs it.
    fn watch<R>(
        &mut self,
        cx: &mut Context<'_>,
        polled: Poll<io::Result<R>>,
    ) -> Poll<io::Result<R>> {
        if polled.is_pending() {
            return self.pending(cx);
        }
        self.armed = false;
        polled
    }
}

impl<T: AsyncRead + Unpin> AsyncRead for WriteTimeout<T> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_read(cx, buf)
    }
}

impl<T: AsyncWrite + Unpin> AsyncWrite for WriteTimeout<T> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let polled = Pin::new(&mut self.inner).poll_write(cx, buf);
        self.watch(cx, polled)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let polled = Pin::new(&mut self.inner).poll_write_vectored(cx, bufs);
        self.watch(cx, polled)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let polled = Pin::new(&mut self.inner).poll_flush(cx);
        self.watch(cx, polled)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let polled = Pin::new(&mut self.inner).poll_shutdown(cx);
        self.watch(cx, polled)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::AsyncWriteExt;

    #[tokio::test(start_paused = true)]
    async fn a_write_without_progress_fails_after_the_timeout() {
        // A pipe of 64 bytes nobody reads: the first write fills it, the next one waits.
        let (a, _b) = tokio::io::duplex(64);
        let mut w = WriteTimeout::new(a, Duration::from_secs(10));
        let fired = w.fired();
        w.write_all(&[0; 64]).await.unwrap();
        let started = Instant::now();
        let e = w.write_all(&[0; 64]).await.unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::TimedOut);
        assert_eq!(started.elapsed(), Duration::from_secs(10));
        assert!(fired.load(Ordering::Relaxed));
    }

    #[tokio::test(start_paused = true)]
    async fn progress_restarts_the_clock() {
        use tokio::io::AsyncReadExt;
        let (a, mut b) = tokio::io::duplex(64);
        let mut w = WriteTimeout::new(a, Duration::from_secs(10));
        let reader = tokio::spawn(async move {
            // Reads 64 bytes every 6 s: slower than the writer, faster than the timeout.
            let mut buf = [0; 64];
            for _ in 0..5 {
                tokio::time::sleep(Duration::from_secs(6)).await;
                b.read_exact(&mut buf).await.unwrap();
            }
            b
        });
        for _ in 0..5 {
            w.write_all(&[0; 64]).await.unwrap();
        }
        assert!(!w.fired().load(Ordering::Relaxed));
        drop(reader.await.unwrap());
    }
}
