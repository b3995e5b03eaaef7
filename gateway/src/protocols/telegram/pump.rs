//! The engine side of the telegram simulators' driver loop (the lines run on the line runtime):
//! the clock, the engine's deadline, and writing out what the engine transmits with the estimated
//! end of each transmission handed to the engine as its `handle_tx_done`.

use std::io;
use std::time::Duration;

use proto_core::serial_marks::{MarkDecoder, Piece};
use proto_core::telegram::Action;
use tokio::io::{AsyncWrite, AsyncWriteExt};

use super::engine::TelegramEngine;
pub(crate) use crate::line::driver::sleep_until_opt;
use crate::line::driver::{estimated_tx_end, Clock};

/// An engine with its clock.
#[derive(Debug)]
pub(crate) struct Pump<E> {
    /// The engine; callers feed it and poll its events directly.
    pub(crate) engine: E,
    clock: Clock,
    /// One character on the wire, for the estimated end of a transmission.
    char_time: Duration,
    /// The estimated end of the last transmission.
    tx_end: Option<tokio::time::Instant>,
    /// Undoes the tty layer's line error marks (`serial::open` sets `PARMRK`).
    marks: MarkDecoder,
}

// === impl Pump ===

impl<E: TelegramEngine> Pump<E> {
    /// `engine` on a line whose characters take `char_time` each.
    pub(crate) fn new(engine: E, char_time: Duration) -> Self {
        Self {
            engine,
            clock: Clock::start(),
            char_time,
            tx_end: None,
            marks: MarkDecoder::new(),
        }
    }

    /// Now on the engine's clock.
    pub(crate) fn now(&self) -> proto_core::time::Instant {
        self.clock.now().1
    }

    /// The engine's next deadline on tokio's clock.
    pub(crate) fn deadline(&self) -> Option<tokio::time::Instant> {
        self.engine.poll_timeout().map(|t| self.clock.to_tokio(t))
    }

    /// Hands the engine its deadline if it has passed (quinn `drive_timer`: a deadline already
    /// due is handled without waiting for the sleep future).
    pub(crate) fn handle_due(&mut self) {
        let (now, engine_now) = self.clock.now();
        if self.deadline().is_some_and(|d| d <= now) {
            self.engine.handle_timeout(engine_now);
        }
    }

    /// Hands the engine its deadline (the sleep until it fired).
    pub(crate) fn handle_timeout(&mut self) {
        let now = self.now();
        self.engine.handle_timeout(now);
    }

    /// Hands the engine bytes read from the port, timestamped as its protocol counts them
    /// ([`TelegramEngine::rx_time`]), with the tty layer's marks undone: data to `handle_rx`,
    /// a faulty character or a BREAK to `handle_line_error`, in stream order.
    pub(crate) fn handle_rx(&mut self, bytes: &[u8]) {
        let now = self.clock.to_engine(tokio::time::Instant::now());
        let tx_end = self.tx_end.map(|end| self.clock.to_engine(end));
        let at = self.engine.rx_time(now, tx_end);
        for piece in self.marks.decode(bytes) {
            match piece {
                Piece::Data(data) => self.engine.handle_rx(at, data),
                Piece::Error { error, .. } => self.engine.handle_line_error(at, error),
            }
        }
    }

    /// Drains the engine's RS232 actions (to `apply`) and transmissions (to `port`), in the
    /// engine's order: actions first, since `poll_transmit` holds bytes back while one is
    /// pending. Returns whether anything was done.
    ///
    /// # Errors
    ///
    /// A failed write: the port is lost.
    pub(crate) async fn flush<W: AsyncWrite + Unpin>(
        &mut self,
        port: &mut W,
        mut apply: impl FnMut(&mut W, Action),
    ) -> io::Result<bool> {
        let mut progress = false;
        loop {
            while let Some(action) = self.engine.poll_action() {
                apply(port, action);
                progress = true;
            }
            let Some(bytes) = self.engine.poll_transmit() else {
                return Ok(progress);
            };
            port.write_all(&bytes).await?;
            let end = estimated_tx_end(tokio::time::Instant::now(), bytes.len(), self.char_time);
            self.tx_end = Some(end);
            self.engine.handle_tx_done(self.clock.to_engine(end));
            progress = true;
        }
    }
}
