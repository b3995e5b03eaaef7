//! One surface over both telegram engines, so that one driver loop (the line task and the
//! simulators) drives either: the 3964(R) procedure and the ASCII driver share their calls
//! (`handle_*`, `poll_*`, `send`, `take_received`); only the ASCII driver has RS232 signals.
//!
//! Line errors (a parity or framing error, an overrun, a BREAK) come from the runtime, which
//! decodes the tty layer's marks, through `handle_line_error`.
//!
//! When a received byte counts as received ([`TelegramEngine::rx_time`]) is each protocol's
//! own: the ASCII driver is full duplex (003 6.2) and measures its character delay time on the
//! bytes' own arrival, the 3964(R) procedure is half duplex and takes no byte as received before
//! its own transmission has left the line.

use proto_core::event::EventId;
use proto_core::proc3964::{Params3964, Proc3964};
use proto_core::serial_marks::LineError;
use proto_core::telegram::{
    Action, AsciiDriver, AsciiParams, FlowControl, SendError, Signals, TelegramEvent, TelegramId,
};
use proto_core::time::Instant;

use crate::signals::OutputOwner;

/// What the driver loop needs from a telegram engine. The call order is the engines' own (see
/// [`Proc3964`] and [`AsciiDriver`]): after every input, drain `poll_action`, `poll_transmit`,
/// `poll_event`, then ask `poll_timeout`.
pub(crate) trait TelegramEngine: Send + 'static {
    /// The protocol's name for logs ("3964R", "ASCII").
    fn protocol(&self) -> &'static str;
    /// Queues a telegram.
    fn send(&mut self, now: Instant, telegram: Vec<u8>) -> Result<TelegramId, SendError>;
    /// Received bytes.
    fn handle_rx(&mut self, now: Instant, bytes: &[u8]);
    /// A character received with an error, characters lost to an overrun, or a BREAK.
    fn handle_line_error(&mut self, now: Instant, error: LineError);
    /// The time at which bytes read at `now` are handed to the engine, given the estimated end
    /// of our last transmission.
    fn rx_time(&self, now: Instant, tx_end: Option<Instant>) -> Instant;
    /// The CTS and DSR inputs (ignored by engines without RS232 signals).
    fn handle_signals(&mut self, now: Instant, signals: Signals);
    /// The oldest buffer from `poll_transmit` left the line at `now`.
    fn handle_tx_done(&mut self, now: Instant);
    /// A deadline of `poll_timeout` has come.
    fn handle_timeout(&mut self, now: Instant);
    /// The next RS232 output to set (never for engines without RS232 signals).
    fn poll_action(&mut self) -> Option<Action>;
    /// The next bytes to write.
    fn poll_transmit(&mut self) -> Option<Vec<u8>>;
    /// The next event.
    fn poll_event(&mut self) -> Option<TelegramEvent>;
    /// The next deadline.
    fn poll_timeout(&self) -> Option<Instant>;
    /// Removes the oldest received telegram from the engine's receive buffer.
    fn take_received(&mut self) -> Option<Vec<u8>>;
    /// Whether a received telegram waits for [`Self::confirm_received`] before the partner
    /// gets its acknowledgement (3964(R) with `hold_ack`; never for ASCII, which acknowledges
    /// nothing).
    fn awaiting_confirm(&self) -> bool;
    /// Acknowledges (`Ok`) or refuses (`Err(cause)`, 3964(R): NAK) the telegram that waits.
    fn confirm_received(&mut self, now: Instant, result: Result<(), EventId>);
    /// Whether the runtime can take a telegram now (3964(R): STX is answered with NAK while
    /// not).
    fn set_receive_ready(&mut self, ready: bool);
    /// Whether nothing is being sent, received or queued.
    fn is_idle(&self) -> bool;
    /// Whether the engine reacts to CTS and DSR (they must be watched).
    fn watches_signals(&self) -> bool;
    /// Who drives DTR and RTS on this line (000 5.4).
    fn output_owner(&self) -> OutputOwner;
}

/// The calls both engines answer with their own method of the same name.
macro_rules! inherent_calls {
    () => {
        fn send(&mut self, now: Instant, telegram: Vec<u8>) -> Result<TelegramId, SendError> {
            Self::send(self, now, telegram)
        }
        fn handle_rx(&mut self, now: Instant, bytes: &[u8]) {
            Self::handle_rx(self, now, bytes);
        }
        fn handle_line_error(&mut self, now: Instant, error: LineError) {
            Self::handle_line_error(self, now, error);
        }
        fn handle_tx_done(&mut self, now: Instant) {
            Self::handle_tx_done(self, now);
        }
        fn handle_timeout(&mut self, now: Instant) {
            Self::handle_timeout(self, now);
        }
        fn poll_transmit(&mut self) -> Option<Vec<u8>> {
            Self::poll_transmit(self)
        }
        fn poll_event(&mut self) -> Option<TelegramEvent> {
            Self::poll_event(self)
        }
        fn poll_timeout(&self) -> Option<Instant> {
            Self::poll_timeout(self)
        }
        fn take_received(&mut self) -> Option<Vec<u8>> {
            Self::take_received(self)
        }
        fn is_idle(&self) -> bool {
            Self::is_idle(self)
        }
    };
}

impl TelegramEngine for Proc3964 {
    inherent_calls!();
    fn protocol(&self) -> &'static str {
        match self.params().settings().variant {
            proto_core::proc3964::Variant::P3964 => "3964",
            proto_core::proc3964::Variant::P3964R => "3964R",
        }
    }
    /// Half duplex: no byte before the end of our own transmission. The estimate assumes the
    /// configured baud rate; a pseudo-terminal carries the bytes at once, and the partner's
    /// answer then arrives before the estimated end. A byte that answers ours cannot precede it,
    /// and the engine takes a byte received before its DLE is out as a partner that did not wait
    /// (003 7.2, 08 02h). What is lost: a byte the partner sent, without waiting, within the few
    /// character times our own bytes take on a real line.
    fn rx_time(&self, now: Instant, tx_end: Option<Instant>) -> Instant {
        tx_end.map_or(now, |end| end.max(now))
    }
    fn handle_signals(&mut self, _now: Instant, _signals: Signals) {}
    fn poll_action(&mut self) -> Option<Action> {
        None
    }
    fn awaiting_confirm(&self) -> bool {
        Self::awaiting_confirm(self)
    }
    fn confirm_received(&mut self, now: Instant, result: Result<(), EventId>) {
        Self::confirm_received(self, now, result);
    }
    fn set_receive_ready(&mut self, ready: bool) {
        Self::set_receive_ready(self, ready);
    }
    fn watches_signals(&self) -> bool {
        false
    }
    fn output_owner(&self) -> OutputOwner {
        OutputOwner::Free
    }
}

impl TelegramEngine for AsciiDriver {
    inherent_calls!();
    fn protocol(&self) -> &'static str {
        "ASCII"
    }
    /// Full duplex (003 6.2): the receiver runs while we send, and the character delay time is
    /// measured between the received bytes' own arrivals, whatever we transmit meanwhile.
    fn rx_time(&self, now: Instant, _tx_end: Option<Instant>) -> Instant {
        now
    }
    fn handle_signals(&mut self, now: Instant, signals: Signals) {
        Self::handle_signals(self, now, signals);
    }
    fn poll_action(&mut self) -> Option<Action> {
        Self::poll_action(self)
    }
    /// A received ASCII telegram counts as received once it is in the mailbox: there is no
    /// acknowledgement to hold back (003 6.2).
    fn awaiting_confirm(&self) -> bool {
        false
    }
    fn confirm_received(&mut self, _now: Instant, _result: Result<(), EventId>) {}
    fn set_receive_ready(&mut self, _ready: bool) {}
    fn watches_signals(&self) -> bool {
        matches!(
            self.params().settings().flow,
            FlowControl::RtsCts | FlowControl::AutoV24 { .. }
        )
    }
    fn output_owner(&self) -> OutputOwner {
        match self.params().settings().flow {
            FlowControl::None | FlowControl::XonXoff { .. } => OutputOwner::Free,
            FlowControl::RtsCts => OutputOwner::RtsCts,
            FlowControl::AutoV24 { .. } => OutputOwner::AutoV24,
        }
    }
}

/// Builds a fresh engine for every opening of the port (nothing carries over a reopen).
pub(crate) trait EngineFactory: Send + Sync + 'static {
    /// The engine type.
    type Engine: TelegramEngine;
    /// A new engine.
    fn build(&self) -> Self::Engine;
    /// How the frame monitor cuts and describes the line's frames.
    fn framing(&self) -> proto_core::monitor::Framing;
}

impl EngineFactory for Params3964 {
    type Engine = Proc3964;
    fn build(&self) -> Proc3964 {
        Proc3964::new(self.clone())
    }
    /// 003 6.3: control characters and telegrams ending DLE ETX (BCC in 3964R); the character
    /// delay time ZVZ is the longest gap inside a telegram.
    fn framing(&self) -> proto_core::monitor::Framing {
        let settings = self.settings();
        proto_core::monitor::Framing {
            kind: proto_core::monitor::FrameKind::Proc3964 {
                bcc: settings.variant == proto_core::proc3964::Variant::P3964R,
            },
            gap: Some(settings.zvz),
        }
    }
}

impl EngineFactory for AsciiParams {
    type Engine = AsciiDriver;
    fn build(&self) -> AsciiDriver {
        AsciiDriver::new(self.clone())
    }
    /// 003 6.2.1: the telegram's end criterion; the character delay time ZVZ is the longest gap
    /// inside a telegram in every end mode.
    fn framing(&self) -> proto_core::monitor::Framing {
        let settings = self.settings();
        proto_core::monitor::Framing {
            kind: proto_core::monitor::FrameKind::Telegram(settings.end),
            gap: Some(settings.zvz),
        }
    }
}
