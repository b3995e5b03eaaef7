//! The 3964(R) and ASCII partners (`gateway sim --device 3964r|ascii`): they answer every
//! telegram they receive with the same bytes (an echo) and send one telegram of their own every
//! `--every` interval (default 1 s, 0 = never).
//!
//! They run the same proto-core engines as the gateway's lines, as line engines on the same line
//! runtime (one port task, the timerfd, the estimated end of each transmission), so a pty pair
//! with a line on one end and a simulator on the other is two engines of ours talking. Defaults: the 3964(R)
//! partner has low priority (the demo line `r3964` has high, 003 6.3.3 "Priority": one partner
//! high, the other low), the ASCII partner ends its telegrams with ETX (003 6.2.1 "End character
//! 1: 3 (03h = ETX)"). Their own telegrams count up: `3964R 000001`, `ASCII 000001<ETX>`, ...

use std::time::Duration;

use proto_core::event::EventId;
use proto_core::proc3964::{Params3964, Priority, Settings3964, Variant};
use proto_core::serial_marks::LineError;
use proto_core::telegram::{
    Action, AsciiParams, AsciiSettings, ConfigError, EndCriterion, FlowControl, Interface,
    TelegramEvent, DEFAULT_END_CHAR,
};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::sync::mpsc;
use tokio::time::Instant;
use tokio_serial::SerialPort;
use tokio_util::sync::CancellationToken;

use crate::line::runtime::{
    LineCommands, LineEngine, LineLifecycle, LinePort, LineSignals, SecondPort, Stop, Unmarked,
};
use crate::line::Clock;
use crate::protocols::modbus_master::partner::spawn_line;
use crate::protocols::telegram::engine::{EngineFactory, TelegramEngine};
use crate::protocols::telegram::{engine_protocol, TelegramProtocol};
use crate::protocols::LineConfig;
use crate::serial::{self, DataBits, OpenError, PortSettings};

/// How often a simulator sends a telegram of its own by default (`--every`; 0 = never).
pub const DEFAULT_EVERY: Duration = Duration::from_secs(1);

/// Which telegram partner to simulate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TelegramDevice {
    /// A 3964R partner (low priority).
    P3964r,
    /// An ASCII partner (end character ETX).
    Ascii,
}

/// Why a simulator could not start or stopped.
#[derive(Debug, thiserror::Error)]
pub enum TelegramSimError {
    /// The port could not be opened.
    #[error(transparent)]
    Open(#[from] OpenError),
    /// The line settings give no valid protocol parameters.
    #[error("invalid protocol parameters: {0}")]
    Params(#[from] ConfigError),
}

/// The 3964R partner's parameters: the manual's defaults (003 6.3.3), low priority.
///
/// # Errors
///
/// A baud rate outside 150..115200.
pub fn partner_3964r(baud: u32) -> Result<Params3964, ConfigError> {
    Params3964::try_new(Settings3964 {
        priority: Priority::Low,
        baud,
        interface: Interface::Rs232,
        ..Settings3964::new(Variant::P3964R)
    })
}

/// The ASCII partner's parameters: end character ETX, the manual's defaults otherwise (003
/// 6.2.1), the character delay time raised to the baud rate's minimum where 4 ms is too short.
///
/// # Errors
///
/// A baud rate outside 150..115200, or data bits other than 7 or 8.
pub fn partner_ascii(baud: u32, data_bits: u8) -> Result<AsciiParams, ConfigError> {
    let settings = AsciiSettings {
        baud,
        data_bits,
        interface: Interface::Rs232,
        end: EndCriterion::EndChars {
            first: DEFAULT_END_CHAR,
            second: None,
        },
        ..AsciiSettings::default()
    };
    match AsciiParams::try_new(settings.clone()) {
        Err(ConfigError::BelowBaudMinimum { min_ms, .. }) => AsciiParams::try_new(AsciiSettings {
            zvz: Duration::from_millis(min_ms),
            ..settings
        }),
        other => other,
    }
}

/// A simulated telegram partner.
#[derive(Clone, Debug)]
pub struct TelegramSim {
    protocol: TelegramProtocol,
    every: Duration,
    echo: bool,
    limit: Option<u64>,
    char_time: Duration,
    observer: Option<mpsc::Sender<Vec<u8>>>,
}

// === impl TelegramSim ===

impl TelegramSim {
    /// A partner speaking `protocol` that echoes and sends its own telegram every second.
    pub fn new(protocol: TelegramProtocol) -> Self {
        Self {
            protocol,
            every: DEFAULT_EVERY,
            echo: true,
            limit: None,
            char_time: Duration::ZERO,
            observer: None,
        }
    }

    /// The partner of a configured telegram line, as the demo runs it: the line's own parameters
    /// with the other 3964(R) priority (003 6.3.3: one partner high, the other low), and for ASCII
    /// without RTS/CTS or the automatic V24 handling (the simulator has no RS232 signals; it
    /// would wait for CTS forever). `None` for a line of another protocol.
    ///
    /// # Errors
    ///
    /// The parameters the engine refuses (the config check catches them first).
    pub fn for_line(line: &LineConfig) -> Option<Result<Self, ConfigError>> {
        let protocol = engine_protocol(line)?.and_then(|protocol| match protocol {
            TelegramProtocol::P3964(p) => {
                let priority = match p.settings().priority {
                    Priority::High => Priority::Low,
                    Priority::Low => Priority::High,
                };
                Params3964::try_new(Settings3964 {
                    priority,
                    ..p.settings().clone()
                })
                .map(TelegramProtocol::P3964)
            }
            TelegramProtocol::Ascii(p) => {
                let flow = match p.settings().flow {
                    FlowControl::RtsCts | FlowControl::AutoV24 { .. } => FlowControl::None,
                    other => other,
                };
                AsciiParams::try_new(AsciiSettings {
                    flow,
                    ..p.settings().clone()
                })
                .map(TelegramProtocol::Ascii)
            }
        });
        Some(protocol.map(Self::new))
    }

    /// Sends its own telegram every `every` (zero: never).
    pub fn every(self, every: Duration) -> Self {
        Self { every, ..self }
    }

    /// Echoes received telegrams (on by default).
    pub fn echo(self, echo: bool) -> Self {
        Self { echo, ..self }
    }

    /// Stops sending its own telegrams after `limit` of them were accepted by its engine.
    pub fn limit(self, limit: u64) -> Self {
        Self {
            limit: Some(limit),
            ..self
        }
    }

    /// Estimates the end of its transmissions with this character time (zero by default: a pty
    /// carries bytes at once).
    pub fn char_time(self, char_time: Duration) -> Self {
        Self { char_time, ..self }
    }

    /// Hands every received telegram to `observer` too (dropped with a warning when it is full).
    pub fn observe(self, observer: mpsc::Sender<Vec<u8>>) -> Self {
        Self {
            observer: Some(observer),
            ..self
        }
    }

    /// Serves on `stream` (its bytes carry no line error marks) until `shutdown` is cancelled or
    /// the stream is lost: the partner as a line engine on the line runtime.
    pub async fn serve<S>(self, stream: S, shutdown: CancellationToken)
    where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        self.serve_on(Unmarked(stream), shutdown).await;
    }

    /// Serves on `port` until `shutdown` is cancelled or the port is lost.
    async fn serve_on<P: LinePort>(self, port: P, shutdown: CancellationToken) {
        match self.protocol.clone() {
            TelegramProtocol::P3964(params) => self.run(params, port, shutdown).await,
            TelegramProtocol::Ascii(params) => self.run(params, port, shutdown).await,
        }
    }

    /// Its own telegram number `n`: a text counting up, framed as the partner expects it.
    fn own_telegram(&self, n: u64) -> Vec<u8> {
        match &self.protocol {
            TelegramProtocol::P3964(p) => {
                let name = match p.settings().variant {
                    Variant::P3964 => "3964",
                    Variant::P3964R => "3964R",
                };
                format!("{name} {n:06}").into_bytes()
            }
            TelegramProtocol::Ascii(p) => {
                let mut data = format!("ASCII {n:06}").into_bytes();
                match p.settings().end {
                    EndCriterion::CharacterDelay => {}
                    EndCriterion::FixedLength(len) => data.resize(usize::from(len), b' '),
                    EndCriterion::EndChars { first, second } => {
                        data.push(first);
                        data.extend(second);
                    }
                }
                data
            }
        }
    }

    async fn run<F: EngineFactory, P: LinePort>(
        self,
        factory: F,
        port: P,
        shutdown: CancellationToken,
    ) {
        let engine = factory.build();
        tracing::info!(protocol = engine.protocol(), every = ?self.every, "telegram simulator serving");
        // Ends with the shutdown or the port, whichever comes first.
        let stop = shutdown.child_token();
        let char_time = self.char_time;
        let make = |clock| Partner::new(self, engine, clock, stop.clone());
        spawn_line("telegram-sim", make, port, char_time, stop.clone())
            .join()
            .await;
    }
}

/// The partner as a line engine: its 3964(R) or ASCII engine, driven by the line runtime's port
/// task (reads, writes with the estimated end of each transmission, the engine's deadlines on the
/// timerfd); its own telegrams are its wake-up.
struct Partner<E> {
    sim: TelegramSim,
    engine: E,
    clock: Clock,
    /// Its own telegrams accepted by the engine.
    own: u64,
    /// When its next own telegram is due (`None`: never).
    next_own: Option<Instant>,
    /// The estimated end of the last transmission.
    tx_end: Option<proto_core::time::Instant>,
    /// Cancelled when the port is lost: the partner ends with its port.
    on_lost: CancellationToken,
}

// === impl Partner ===

impl<E: TelegramEngine> Partner<E> {
    fn new(sim: TelegramSim, engine: E, clock: Clock, on_lost: CancellationToken) -> Self {
        let next_own = (!sim.every.is_zero()).then(|| Instant::now() + sim.every);
        Self {
            sim,
            engine,
            clock,
            own: 0,
            next_own,
            tx_end: None,
            on_lost,
        }
    }

    /// Now on the engine's clock.
    fn now(&self) -> proto_core::time::Instant {
        self.clock.now().1
    }
}

impl<E: TelegramEngine> LineEngine for Partner<E> {
    fn opened(&mut self, _modem: Option<&mut dyn SerialPort>) {}

    /// Received bytes, timestamped as the protocol counts them ([`TelegramEngine::rx_time`]).
    fn handle_rx(&mut self, now: proto_core::time::Instant, bytes: &[u8]) {
        let at = self.engine.rx_time(now, self.tx_end);
        self.engine.handle_rx(at, bytes);
    }

    fn handle_line_error(&mut self, now: proto_core::time::Instant, error: LineError) {
        let at = self.engine.rx_time(now, self.tx_end);
        self.engine.handle_line_error(at, error);
    }

    crate::line::driver::engine_calls!(engine: timeout, tx);

    fn transmitted(&mut self, _written: Instant, _len: usize, end: proto_core::time::Instant) {
        self.tx_end = Some(end);
        self.engine.handle_tx_done(end);
    }

    /// Echoes received telegrams and logs the rest; true when there were events (an echo is
    /// written at once).
    fn handle_events(&mut self) -> bool {
        let mut any = false;
        while let Some(event) = self.engine.poll_event() {
            any = true;
            match event {
                TelegramEvent::Received { .. } => {
                    let Some(data) = self.engine.take_received() else {
                        continue;
                    };
                    if let Some(observer) = &self.sim.observer {
                        if observer.try_send(data.clone()).is_err() {
                            tracing::warn!(
                                "simulator observer full: a received telegram not shown"
                            );
                        }
                    }
                    if self.sim.echo {
                        let now = self.now();
                        if let Err(err) = self.engine.send(now, data) {
                            tracing::warn!(%err, "echo not sent");
                        }
                    }
                }
                TelegramEvent::Sent { id } => tracing::trace!(%id, "sent"),
                TelegramEvent::SendFailed { id, event, .. } => {
                    tracing::info!(%id, %event, "simulator send failed");
                }
                TelegramEvent::Raised { id } => tracing::debug!(event = %id, "simulator event"),
            }
        }
        any
    }
}

impl<E> LineCommands for Partner<E> {
    type Command = ();

    fn command(&mut self, (): (), _modem: Option<&mut dyn SerialPort>) {}

    fn refuse(&mut self, (): (), _shutting_down: bool) {}
}

impl<E> LineLifecycle for Partner<E> {
    fn stop(&mut self) -> Stop {
        // A simulated partner stops at once, as one switched off.
        Stop::AT_ONCE
    }

    fn done(&self) -> bool {
        true
    }

    fn closed(&mut self, _shutting_down: bool) {}

    fn port_failed(&mut self, id: EventId, reason: String) {
        tracing::info!(event = %id, %reason, "telegram simulator: port closed, the partner stops");
        self.on_lost.cancel();
    }
}

impl<E: TelegramEngine> LineSignals for Partner<E> {
    /// The engine's RS232 actions are taken and dropped: the simulator has no outputs.
    fn poll_action(&mut self) -> Option<Action> {
        self.engine.poll_action()
    }

    fn apply_action(&mut self, action: Action, _modem: Option<&mut dyn SerialPort>) {
        tracing::trace!(?action, "the simulator has no RS232 outputs");
    }

    /// Its next own telegram, until the limit is reached.
    fn wake(&self) -> impl std::future::Future<Output = ()> + Send + '_ {
        let sending = self.sim.limit.is_none_or(|l| self.own < l);
        let at = self.next_own.filter(|_| sending);
        async move {
            match at {
                Some(at) => tokio::time::sleep_until(at).await,
                None => std::future::pending().await,
            }
        }
    }

    /// Sends its own telegram; the next is due `every` later (from now when this one was late).
    fn woken(&mut self, _modem: Option<&mut dyn SerialPort>) {
        let Some(at) = self.next_own else { return };
        let now = Instant::now();
        let next = at + self.sim.every;
        self.next_own = Some(if next <= now {
            now + self.sim.every
        } else {
            next
        });
        let telegram = self.sim.own_telegram(self.own + 1);
        match self.engine.send(self.clock.to_engine(now), telegram) {
            Ok(_) => self.own += 1,
            Err(err) => tracing::debug!(%err, "own telegram skipped"),
        }
    }
}

impl<E> SecondPort for Partner<E> {}

/// `gateway sim --device 3964r|ascii`: opens `port` and serves the partner until `shutdown` or
/// until the port is lost.
///
/// # Errors
///
/// The port does not open, or the line settings give no valid parameters.
pub async fn run_telegram_sim(
    device: TelegramDevice,
    port: PortSettings,
    every: Duration,
    shutdown: CancellationToken,
) -> Result<(), TelegramSimError> {
    let protocol = match device {
        TelegramDevice::P3964r => TelegramProtocol::P3964(partner_3964r(port.baud)?),
        TelegramDevice::Ascii => {
            let bits = match port.data_bits {
                DataBits::Seven => 7,
                DataBits::Eight => 8,
            };
            TelegramProtocol::Ascii(partner_ascii(port.baud, bits)?)
        }
    };
    let stream = serial::open(&port)?;
    tracing::info!(port = %port.path, baud = port.baud, ?device, "telegram simulator on its port");
    // The port marks line errors (`serial::open` sets `PARMRK`): the runtime undoes the marks.
    TelegramSim::new(protocol)
        .every(every)
        .char_time(port.char_time())
        .serve_on(stream, shutdown)
        .await;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn partners_follow_the_spec_defaults() {
        let p = partner_3964r(9600).expect("valid");
        assert_eq!(p.settings().priority, Priority::Low);
        assert_eq!(p.settings().variant, Variant::P3964R);
        let a = partner_ascii(9600, 8).expect("valid");
        assert_eq!(
            a.settings().end,
            EndCriterion::EndChars {
                first: 0x03,
                second: None
            }
        );
        // 4 ms is below the minimum at 1200 Bd (32 ms, 003 6.2.1): raised.
        let slow = partner_ascii(1200, 7).expect("valid");
        assert_eq!(slow.settings().zvz, Duration::from_millis(32));
        assert!(partner_ascii(9600, 6).is_err());
    }

    #[test]
    fn the_demo_partners_mirror_their_lines() {
        let demo = crate::plant::demo();
        let r3964 = demo.lines.get("r3964").expect("demo line");
        let sim = TelegramSim::for_line(r3964)
            .expect("telegram line")
            .expect("valid");
        let TelegramProtocol::P3964(p) = &sim.protocol else {
            panic!("3964R expected");
        };
        assert_eq!(p.settings().priority, Priority::Low, "the line is high");
        let ascii = demo.lines.get("ascii").expect("demo line");
        let sim = TelegramSim::for_line(ascii)
            .expect("telegram line")
            .expect("valid");
        assert_eq!(sim.own_telegram(1), b"ASCII 000001\x03");
        let drive = demo.lines.get("drive").expect("demo line");
        assert!(TelegramSim::for_line(drive).is_none());
    }

    #[test]
    fn own_telegrams_count_up_in_the_partners_framing() {
        let sim = TelegramSim::new(TelegramProtocol::P3964(partner_3964r(9600).unwrap()));
        assert_eq!(sim.own_telegram(7), b"3964R 000007");
        let sim = TelegramSim::new(TelegramProtocol::Ascii(partner_ascii(9600, 8).unwrap()));
        assert_eq!(sim.own_telegram(12), b"ASCII 000012\x03");
    }
}
