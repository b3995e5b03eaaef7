//! Pieces every line driver loop shares: the clock conversion between tokio's monotonic clock and
//! the engines' [`proto_core::time::Instant`], optional deadlines, and the estimated end of a
//! transmission.

use std::time::Duration;

use tokio::time::Instant;

/// The line's clock: engine instants are microseconds since the line started.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Clock {
    base: Instant,
}

// === impl Clock ===

impl Clock {
    /// A clock whose origin is now.
    pub(crate) fn start() -> Self {
        Self {
            base: Instant::now(),
        }
    }

    /// The origin (tokio time).
    pub(crate) fn base(self) -> Instant {
        self.base
    }

    /// Now, on both clocks.
    pub(crate) fn now(self) -> (Instant, proto_core::time::Instant) {
        let now = Instant::now();
        (now, self.to_engine(now))
    }

    /// A tokio instant as an engine instant (the origin for instants before it).
    pub(crate) fn to_engine(self, at: Instant) -> proto_core::time::Instant {
        let micros = at.saturating_duration_since(self.base).as_micros();
        proto_core::time::Instant::from_micros(u64::try_from(micros).unwrap_or(u64::MAX))
    }

    /// An engine instant as a tokio instant.
    pub(crate) fn to_tokio(self, at: proto_core::time::Instant) -> Instant {
        self.base + Duration::from_micros(at.as_micros())
    }
}

/// When a frame of `len` bytes written at `now` has left the UART: the driver cannot see it, so it
/// estimates `len` character times and tells the engine that instant (libmodbus PR #494).
pub(crate) fn estimated_tx_end(now: Instant, len: usize, char_time: Duration) -> Instant {
    now + char_time.saturating_mul(u32::try_from(len).unwrap_or(u32::MAX))
}

/// Sleeps until `deadline`, or forever when there is none (for `select!`).
pub(crate) async fn sleep_until_opt(deadline: Option<Instant>) {
    match deadline {
        Some(deadline) => tokio::time::sleep_until(deadline).await,
        None => std::future::pending().await,
    }
}

/// Writes the [`LineEngine`](super::runtime::LineEngine) calls an adapter hands unchanged to
/// the proto-core engine in its field `$engine`: `rx` (`handle_rx`, `handle_line_error`),
/// `timeout` (`handle_timeout`, `poll_timeout`) and `tx` (`poll_transmit`).
macro_rules! engine_calls {
    ($engine:ident: rx) => {
        fn handle_rx(&mut self, now: proto_core::time::Instant, bytes: &[u8]) {
            self.$engine.handle_rx(now, bytes);
        }

        fn handle_line_error(
            &mut self,
            now: proto_core::time::Instant,
            error: proto_core::serial_marks::LineError,
        ) {
            self.$engine.handle_line_error(now, error);
        }
    };
    ($engine:ident: timeout) => {
        fn handle_timeout(&mut self, now: proto_core::time::Instant) {
            self.$engine.handle_timeout(now);
        }

        fn poll_timeout(&self) -> Option<proto_core::time::Instant> {
            self.$engine.poll_timeout()
        }
    };
    ($engine:ident: tx) => {
        fn poll_transmit(&mut self) -> Option<Vec<u8>> {
            self.$engine.poll_transmit()
        }
    };
    ($engine:ident: $($part:ident),+) => {
        $($crate::line::driver::engine_calls!($engine: $part);)+
    };
}
pub(crate) use engine_calls;

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn engine_instants_count_microseconds_since_the_line_started() {
        let clock = Clock::start();
        tokio::time::advance(Duration::from_millis(5)).await;
        let (now, engine) = clock.now();
        assert_eq!(engine, proto_core::time::Instant::from_millis(5));
        assert_eq!(clock.to_tokio(engine), now);
        assert_eq!(
            clock.to_engine(clock.base()),
            proto_core::time::Instant::ZERO
        );
        let end = estimated_tx_end(now, 8, Duration::from_micros(573));
        assert_eq!(end - now, Duration::from_micros(4584));
    }

    #[tokio::test(start_paused = true)]
    async fn no_deadline_never_fires() {
        let fired = tokio::time::timeout(Duration::from_secs(3600), sleep_until_opt(None)).await;
        assert!(fired.is_err());
        let at = Instant::now() + Duration::from_millis(10);
        sleep_until_opt(Some(at)).await;
        assert!(Instant::now() >= at);
    }
}
