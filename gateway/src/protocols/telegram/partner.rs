//! The 3964(R) and ASCII partners (`gateway sim --device 3964r|ascii`): they answer every
//! telegram they receive with the same bytes (an echo) and send one telegram of their own every
//! `--every` interval (default 1 s, 0 = never).
//!
//! They run the same proto-core engines as the gateway's lines, so a pty pair with a line on one
//! end and a simulator on the other is two engines of ours talking. Defaults: the 3964(R)
//! partner has low priority (the demo line `r3964` has high, 003 6.3.3 "Priority": one partner
//! high, the other low), the ASCII partner ends its telegrams with ETX (003 6.2.1 "End character
//! 1: 3 (03h = ETX)"). Their own telegrams count up: `3964R 000001`, `ASCII 000001<ETX>`, ...

use std::io;
use std::time::Duration;

use proto_core::proc3964::{Params3964, Priority, Settings3964, Variant};
use proto_core::telegram::{
    AsciiParams, AsciiSettings, ConfigError, EndCriterion, FlowControl, Interface, TelegramEvent,
    DEFAULT_END_CHAR,
};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite};
use tokio::sync::mpsc;
use tokio::time::{Instant, MissedTickBehavior};
use tokio_util::sync::CancellationToken;

use crate::protocols::telegram::engine::{EngineFactory, TelegramEngine};
use crate::protocols::telegram::pump::{sleep_until_opt, Pump};
use crate::protocols::telegram::{engine_protocol, TelegramProtocol};
use crate::protocols::LineConfig;
use crate::serial::{self, DataBits, OpenError, PortSettings};

/// How often a simulator sends a telegram of its own by default (`--every`; 0 = never).
pub const DEFAULT_EVERY: Duration = Duration::from_secs(1);
/// Pause before reading again after the port failed (a pty whose other end is being reopened
/// reads EIO meanwhile).
const READ_RETRY: Duration = Duration::from_millis(100);

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
    /// Writing the port failed.
    #[error("serial I/O failed: {0}")]
    Io(#[from] io::Error),
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

    /// Serves on `stream` until `shutdown` is cancelled.
    ///
    /// # Errors
    ///
    /// A failed write (the port is gone).
    pub async fn serve<S>(
        self,
        stream: S,
        shutdown: CancellationToken,
    ) -> Result<(), TelegramSimError>
    where
        S: AsyncRead + AsyncWrite + Unpin,
    {
        match self.protocol.clone() {
            TelegramProtocol::P3964(params) => self.run(params, stream, shutdown).await,
            TelegramProtocol::Ascii(params) => self.run(params, stream, shutdown).await,
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

    async fn run<F, S>(
        self,
        factory: F,
        mut stream: S,
        shutdown: CancellationToken,
    ) -> Result<(), TelegramSimError>
    where
        F: EngineFactory,
        S: AsyncRead + AsyncWrite + Unpin,
    {
        let mut pump = Pump::new(factory.build(), self.char_time);
        let mut ticker = (!self.every.is_zero()).then(|| {
            let mut t = tokio::time::interval_at(Instant::now() + self.every, self.every);
            t.set_missed_tick_behavior(MissedTickBehavior::Delay);
            t
        });
        let mut own: u64 = 0;
        let mut read_failing = false;
        let mut retry_at: Option<Instant> = None;
        let mut buf = [0u8; 1024];
        tracing::info!(protocol = pump.engine.protocol(), every = ?self.every, "telegram simulator serving");
        loop {
            pump.handle_due();
            loop {
                let wrote = pump
                    .flush(&mut stream, |_, action| {
                        tracing::trace!(?action, "the simulator has no RS232 outputs");
                    })
                    .await?;
                let events = self.handle_events(&mut pump);
                if !(wrote || events) {
                    break;
                }
            }
            let sending = ticker.is_some() && self.limit.is_none_or(|l| own < l);
            tokio::select! {
                biased;
                () = shutdown.cancelled() => return Ok(()),
                read = stream.read(&mut buf), if retry_at.is_none() => match read {
                    Ok(0) => return Ok(()),
                    Ok(n) => {
                        read_failing = false;
                        pump.handle_rx(buf.get(..n).unwrap_or_default());
                    }
                    Err(err) => {
                        if !read_failing {
                            tracing::warn!(%err, "simulator read failed; retrying");
                        }
                        read_failing = true;
                        retry_at = Some(Instant::now() + READ_RETRY);
                    }
                },
                () = sleep_until_opt(retry_at) => retry_at = None,
                () = sleep_until_opt(pump.deadline()) => pump.handle_timeout(),
                _ = async { ticker.as_mut()?.tick().await; Some(()) }, if sending => {
                    let telegram = self.own_telegram(own + 1);
                    let now = pump.now();
                    match pump.engine.send(now, telegram) {
                        Ok(_) => own += 1,
                        Err(err) => tracing::debug!(%err, "own telegram skipped"),
                    }
                }
            }
        }
    }

    /// Echoes received telegrams and logs the rest; returns whether there were events.
    fn handle_events<E: TelegramEngine>(&self, pump: &mut Pump<E>) -> bool {
        let mut any = false;
        while let Some(event) = pump.engine.poll_event() {
            any = true;
            match event {
                TelegramEvent::Received { .. } => {
                    let Some(data) = pump.engine.take_received() else {
                        continue;
                    };
                    if let Some(observer) = &self.observer {
                        if observer.try_send(data.clone()).is_err() {
                            tracing::warn!(
                                "simulator observer full: a received telegram not shown"
                            );
                        }
                    }
                    if self.echo {
                        let now = pump.now();
                        if let Err(err) = pump.engine.send(now, data) {
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

/// Serves a 3964(R) partner on `stream`: echo, and its own telegram every `every` (zero: never).
///
/// # Errors
///
/// A failed write.
pub async fn serve_3964r<S>(
    stream: S,
    params: Params3964,
    every: Duration,
    shutdown: CancellationToken,
) -> Result<(), TelegramSimError>
where
    S: AsyncRead + AsyncWrite + Unpin,
{
    TelegramSim::new(TelegramProtocol::P3964(params))
        .every(every)
        .serve(stream, shutdown)
        .await
}

/// Serves an ASCII partner on `stream`: echo, and its own telegram every `every` (zero: never).
///
/// # Errors
///
/// A failed write.
pub async fn serve_ascii<S>(
    stream: S,
    params: AsciiParams,
    every: Duration,
    shutdown: CancellationToken,
) -> Result<(), TelegramSimError>
where
    S: AsyncRead + AsyncWrite + Unpin,
{
    TelegramSim::new(TelegramProtocol::Ascii(params))
        .every(every)
        .serve(stream, shutdown)
        .await
}

/// `gateway sim --device 3964r|ascii`: opens `port` and serves the partner until `shutdown`.
///
/// # Errors
///
/// The port does not open, the line settings give no valid parameters, or a write fails.
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
    TelegramSim::new(protocol)
        .every(every)
        .char_time(port.char_time())
        .serve(stream, shutdown)
        .await
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
