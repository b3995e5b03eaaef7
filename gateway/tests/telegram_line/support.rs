//! What the telegram line tests share: pty pairs, line settings, simulators on the other end, a
//! Modbus TCP server on 127.0.0.1 port 0 serving the mailbox, waiting helpers.

use std::net::SocketAddr;
use std::sync::{Arc, RwLock};
use std::time::Duration;

use gateway::line::LineHandle;
use gateway::mailbox::{MailboxSettings, Overflow};
use gateway::modbus_tcp::{bind, serve, ServerOptions, ServerStats};
use gateway::protocols::telegram::partner::{partner_3964r, partner_ascii, TelegramSim};
use gateway::protocols::telegram::{spawn_telegram_line, TelegramLineSettings, TelegramProtocol};
use gateway::serial::PortSettings;
use gateway::unit::{SharedUnits, UnitMap};
use proto_core::event::EventId;
use proto_core::proc3964::{Params3964, Priority, Settings3964};
use proto_core::telegram::{AsciiParams, AsciiSettings, EndCriterion};
use tokio::sync::mpsc;
use tokio_modbus::client::Context;
use tokio_modbus::prelude::*;
use tokio_serial::{SerialPort, SerialStream};
use tokio_util::sync::CancellationToken;

/// The unit id the tests serve the mailbox under.
pub(crate) const UNIT: u8 = 100;

pub(crate) fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

/// A pty pair: the partner's end, the line's path, and the line end's first handle, kept open
/// (never read) so that the partner's end does not see a hang-up before the line opens the path.
pub(crate) fn pty() -> (SerialStream, String, SerialStream) {
    let (partner, line_end) = SerialStream::pair().expect("pty pair");
    let path = line_end.name().expect("pty path");
    (partner, path, line_end)
}

/// The gateway's 3964R parameters as in the demo: the manual's defaults, high priority.
pub(crate) fn gateway_3964r() -> Params3964 {
    Params3964::try_new(Settings3964 {
        priority: Priority::High,
        ..Settings3964::default()
    })
    .expect("valid")
}

/// The gateway's ASCII parameters as in the demo: end character ETX.
pub(crate) fn gateway_ascii() -> AsciiParams {
    AsciiParams::try_new(AsciiSettings {
        end: EndCriterion::EndChars {
            first: 0x03,
            second: None,
        },
        ..AsciiSettings::default()
    })
    .expect("valid")
}

pub(crate) fn settings(
    name: &str,
    path: &str,
    protocol: TelegramProtocol,
    mailbox: MailboxSettings,
) -> TelegramLineSettings {
    let mut settings = TelegramLineSettings::new(name, PortSettings::new(path, 9600), protocol);
    settings.mailbox = mailbox;
    settings.reopen_min = ms(50);
    settings.reopen_max = ms(200);
    settings
}

pub(crate) fn mailbox(queue_depth: usize, overflow: Overflow) -> MailboxSettings {
    MailboxSettings {
        queue_depth,
        overflow,
        ..MailboxSettings::default()
    }
}

/// The partner of the same protocol as the gateway's line (3964R low priority, ASCII ETX).
pub(crate) fn partner(protocol: &TelegramProtocol) -> TelegramSim {
    match protocol {
        TelegramProtocol::P3964(_) => {
            TelegramSim::new(TelegramProtocol::P3964(partner_3964r(9600).expect("valid")))
        }
        TelegramProtocol::Ascii(_) => TelegramSim::new(TelegramProtocol::Ascii(
            partner_ascii(9600, 8).expect("valid"),
        )),
    }
}

/// A line on one end of a pty pair and a simulated partner on the other, with what the partner
/// receives.
pub(crate) struct Pair {
    pub(crate) line: LineHandle,
    pub(crate) partner_rx: mpsc::Receiver<Vec<u8>>,
    pub(crate) shutdown: CancellationToken,
    _keep: SerialStream,
}

/// Starts `settings`' line against `sim` (which gets an observer) on a fresh pty pair.
pub(crate) fn start_pair(
    name: &str,
    protocol: TelegramProtocol,
    mailbox: MailboxSettings,
    sim: TelegramSim,
) -> Pair {
    let (partner_end, path, keep) = pty();
    let shutdown = CancellationToken::new();
    let (tx, partner_rx) = mpsc::channel(4096);
    tokio::spawn(sim.observe(tx).serve(partner_end, shutdown.clone()));
    let line = spawn_telegram_line(settings(name, &path, protocol, mailbox), shutdown.clone());
    Pair {
        line,
        partner_rx,
        shutdown,
        _keep: keep,
    }
}

impl Pair {
    /// Stops the line and the partner; the line must stop within its grace period.
    pub(crate) async fn stop(self) {
        self.shutdown.cancel();
        tokio::time::timeout(Duration::from_secs(5), self.line.join())
            .await
            .expect("the line stops");
    }

    /// The next telegram the partner received.
    pub(crate) async fn partner_received(&mut self) -> Vec<u8> {
        tokio::time::timeout(Duration::from_secs(10), self.partner_rx.recv())
            .await
            .expect("the partner receives in time")
            .expect("the partner runs")
    }
}

/// Waits up to 10 s for `check` to hold.
pub(crate) async fn eventually(what: &str, mut check: impl FnMut() -> bool) {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    while !check() {
        assert!(
            tokio::time::Instant::now() < deadline,
            "timed out waiting for {what}"
        );
        tokio::time::sleep(ms(5)).await;
    }
}

pub(crate) fn event_count(line: &LineHandle, id: EventId) -> u64 {
    line.telegram_status()
        .expect("a telegram line")
        .line
        .event_counts
        .get(&id)
        .copied()
        .unwrap_or(0)
}

/// A Modbus TCP server on 127.0.0.1 port 0 serving `line`'s mailbox under [`UNIT`].
pub(crate) struct Server {
    pub(crate) addr: SocketAddr,
    shutdown: CancellationToken,
}

impl Server {
    pub(crate) fn start(line: &LineHandle) -> Self {
        let listener = bind(([127, 0, 0, 1], 0).into()).expect("bind");
        let addr = listener.local_addr().expect("local addr");
        let mut map = UnitMap::new();
        map.insert(
            UNIT,
            Arc::new(line.mailbox_unit().expect("a telegram line")),
        );
        let units: SharedUnits = Arc::new(RwLock::new(map));
        let shutdown = CancellationToken::new();
        tokio::spawn(serve(
            listener,
            units,
            ServerOptions::default(),
            shutdown.clone(),
            Arc::new(ServerStats::new()),
        ));
        Self { addr, shutdown }
    }

    pub(crate) async fn client(&self) -> Context {
        tcp::connect_slave(self.addr, Slave(UNIT))
            .await
            .expect("connect")
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.shutdown.cancel();
    }
}

/// Reads holding registers; the test fails on a transport error or an exception.
pub(crate) async fn read(client: &mut Context, address: u16, quantity: u16) -> Vec<u16> {
    client
        .read_holding_registers(address, quantity)
        .await
        .expect("transport")
        .expect("no exception")
}

/// Bytes as registers, two a register, high byte first.
pub(crate) fn words(bytes: &[u8]) -> Vec<u16> {
    bytes
        .chunks(2)
        .map(|c| u16::from_be_bytes([c[0], c.get(1).copied().unwrap_or(0)]))
        .collect()
}

/// Registers as `len` bytes.
pub(crate) fn bytes(words: &[u16], len: usize) -> Vec<u8> {
    words
        .iter()
        .flat_map(|w| w.to_be_bytes())
        .take(len)
        .collect()
}
