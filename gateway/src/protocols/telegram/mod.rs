//! Telegram lines: the ASCII driver (003 6.2) and the 3964(R) procedure (003 6.3) on a serial
//! port, their received telegrams in a [`Mailbox`], their sends from any client.
//!
//! A line ([`spawn_telegram_line`]) is the line runtime with one adapter (`task`) that drives
//! either engine. What a line offers through its [`LineHandle`]:
//! - [`LineHandle::mailbox_unit`]: the Modbus TCP mailbox ([`crate::mailbox`]);
//! - [`LineHandle::telegram_client`]: send a telegram and wait for its result (REST, zenoh);
//! - [`LineHandle::subscribe_rx`]: every received telegram with its sequence number and
//!   receive time (zenoh `<prefix>/<line>/rx`);
//! - [`LineHandle::signals`]: the RS232 signals (FC 5 V24_STAT, FC 6 V24_SET);
//! - [`LineHandle::status`], [`LineHandle::telegram_status`] and
//!   [`LineHandle::subscribe_events`]: diagnostic buffer, event counters, STATUS word, telegram
//!   counters.
//!
//! The mailbox is the CP's receive buffer, so the engine's own buffer is kept small: under
//! [`Overflow::Refuse`] the engine holds one telegram beyond the mailbox and then refuses
//! (3964(R): NAK; ASCII under XON/XOFF or RTS/CTS: XOFF / RTS off after a few more; ASCII
//! otherwise: the engine drops the telegram, 08 0Ah); under the other policies every telegram
//! is taken from the engine at once. Received bytes go to the engine one at a time and each
//! completed telegram moves to the mailbox at once, so the small engine buffer fills only while
//! the mailbox is full.

mod client;
pub(crate) mod config;
mod convert;
pub(crate) mod engine;
mod mailbox_unit;
pub mod partner;
mod tap;
mod task;

use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use proto_core::event::{ids, EventId};
use proto_core::proc3964::{Params3964, Settings3964};
use proto_core::telegram::{AsciiParams, AsciiSettings, FlowControl, MAX_TELEGRAM};
use tokio::sync::{broadcast, mpsc};
use tokio_util::sync::CancellationToken;

pub use crate::mailbox::TelegramRx;
pub(crate) use client::Command;
pub use client::{PendingSend, SendResult, SignalsClient, TelegramClient, TelegramSendError};
pub use convert::{engine_protocol, mailbox_ack, params_3964, params_ascii, TelegramConfigError};
pub use mailbox_unit::MailboxUnit;
pub use tap::{
    spawn_3964_tap_line, Proc3964TapConfig, Tap3964LineSettings, DEFAULT_TAP_MAILBOX,
    TAP_3964_PROTOCOL,
};

use crate::line::metrics::{LineFamilies, LineMetrics, LineTraffic};
use crate::line::runtime::{
    self, LineBase, LineCapabilities, LineHandle, PortOpener, SerialOpener,
};
use crate::line::status::{self, LineStatus};
use crate::line::{DEFAULT_DIAG_DEPTH, DEFAULT_REOPEN_MAX, DEFAULT_REOPEN_MIN};
use crate::mailbox::journal::JournalError;
use crate::mailbox::{Mailbox, MailboxSettings, Overflow, Restored, TelegramCounters};
use crate::serial::PortSettings;
use crate::unit::UnitService;

/// Commands (sends, signal requests) that may wait for the line task by default.
pub const DEFAULT_SEND_QUEUE: usize = 16;
/// How long a stopping line may finish the telegram it is sending or receiving by default.
pub const DEFAULT_SHUTDOWN_GRACE: Duration = Duration::from_secs(2);
/// Telegrams the ASCII driver holds beyond a full mailbox under XON/XOFF or RTS/CTS before it
/// stops the partner (XOFF, RTS off): room for what the partner sends before it reacts (our
/// choice; the manual gives no number).
const ASCII_FLOW_SLACK: u16 = 4;
/// The engine's buffer when the line takes every telegram at once (the manual's maximum).
const ENGINE_BUFFER_MAX: u16 = 250;

/// The protocol of a telegram line with its validated parameters.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TelegramProtocol {
    /// 3964 or 3964R (003 6.3).
    P3964(Params3964),
    /// ASCII telegrams (003 6.2).
    Ascii(AsciiParams),
}

// === impl TelegramProtocol ===

impl TelegramProtocol {
    /// The protocol's name ("3964R", "3964", "ASCII").
    pub fn name(&self) -> &'static str {
        match self {
            Self::P3964(p) => match p.settings().variant {
                proto_core::proc3964::Variant::P3964 => "3964",
                proto_core::proc3964::Variant::P3964R => "3964R",
            },
            Self::Ascii(_) => "ASCII",
        }
    }

    /// The longest telegram the engine sends: 3964(R) its configured maximum, ASCII 1024 bytes.
    pub fn max_len(&self) -> usize {
        match self {
            Self::P3964(p) => usize::from(p.settings().max_len),
            Self::Ascii(_) => MAX_TELEGRAM,
        }
    }
}

/// Settings of one telegram line.
#[derive(Clone, Debug)]
pub struct TelegramLineSettings {
    /// The line's name (logs, status, keys).
    pub name: String,
    /// The serial port.
    pub port: PortSettings,
    /// The protocol and its parameters. Their receive buffer settings are replaced by the
    /// mailbox's (see the module doc).
    pub protocol: TelegramProtocol,
    /// The mailbox: queue depth and overflow policy.
    pub mailbox: MailboxSettings,
    /// The longest telegram sent; longer ones are refused (05 17h). At most the protocol's.
    pub max_len: usize,
    /// Commands that may wait for the line task (a full queue is refused at once).
    pub send_queue: usize,
    /// Depth of the diagnostic buffer (the CP keeps 9).
    pub diag_depth: usize,
    /// First delay before reopening a failed port.
    pub reopen_min: Duration,
    /// Longest delay between reopen attempts.
    pub reopen_max: Duration,
    /// How long a stopping line may finish the telegram in progress.
    pub shutdown_grace: Duration,
    /// Prometheus families, if the gateway exports them.
    pub metrics: Option<LineFamilies>,
    /// The unit id under which Modbus TCP serves the mailbox (`None`: not served there).
    pub unit_id: Option<u8>,
    /// Sends allowed; when not, every client's send is refused at once
    /// ([`TelegramSendError::NotAllowed`]).
    pub sends: bool,
    /// The journal that keeps the waiting telegrams over a restart (`None`: they are lost
    /// with the process). With a journal, a 3964(R) telegram is acknowledged (final DLE) only
    /// once it is written and synced, and the driver holds no telegram beyond the mailbox.
    pub journal: Option<std::path::PathBuf>,
    /// What the line this one replaces left: its waiting telegrams and numbers are taken over
    /// (into the journal when it has another path, else into memory).
    pub carried: Option<crate::mailbox::Carried>,
}

// === impl TelegramLineSettings ===

impl TelegramLineSettings {
    /// A line on `port` speaking `protocol`, with the default mailbox and limits.
    pub fn new(name: impl Into<String>, port: PortSettings, protocol: TelegramProtocol) -> Self {
        let max_len = protocol.max_len();
        Self {
            name: name.into(),
            port,
            protocol,
            mailbox: MailboxSettings::default(),
            max_len,
            send_queue: DEFAULT_SEND_QUEUE,
            diag_depth: DEFAULT_DIAG_DEPTH,
            reopen_min: DEFAULT_REOPEN_MIN,
            reopen_max: DEFAULT_REOPEN_MAX,
            shutdown_grace: DEFAULT_SHUTDOWN_GRACE,
            metrics: None,
            unit_id: None,
            sends: true,
            journal: None,
            carried: None,
        }
    }

    /// The engine's parameters with the receive buffer the mailbox needs: one telegram under
    /// [`Overflow::Refuse`] (ASCII under XON/XOFF or RTS/CTS: a few), the manual's maximum
    /// otherwise; overwriting is always prevented in the engine (the mailbox decides).
    fn engine_protocol(&self) -> TelegramProtocol {
        let refuse = self.mailbox.overflow == Overflow::Refuse;
        match &self.protocol {
            TelegramProtocol::P3964(p) => {
                let settings = Settings3964 {
                    receive_buffers: if refuse { 1 } else { ENGINE_BUFFER_MAX },
                    hold_ack: self.journal.is_some(),
                    ..p.settings().clone()
                };
                TelegramProtocol::P3964(Params3964::try_new(settings).unwrap_or_else(|_| p.clone()))
            }
            TelegramProtocol::Ascii(p) => {
                let flow = matches!(
                    p.settings().flow,
                    FlowControl::XonXoff { .. } | FlowControl::RtsCts
                );
                let settings = AsciiSettings {
                    receive_buffers: match (refuse, flow) {
                        (true, false) => 1,
                        (true, true) => ASCII_FLOW_SLACK,
                        (false, _) => ENGINE_BUFFER_MAX,
                    },
                    prevent_overwrite: true,
                    ..p.settings().clone()
                };
                TelegramProtocol::Ascii(
                    AsciiParams::try_new(settings).unwrap_or_else(|_| p.clone()),
                )
            }
        }
    }
}

/// The telegram side of a telegram line ([`LineHandle::telegram_status`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TelegramLineStatus {
    /// Port, diagnostic buffer, event counters and STATUS word, as every line reports them
    /// (`devices` empty, `commands_*` zero).
    pub line: LineStatus,
    /// "3964R", "3964" or "ASCII".
    pub protocol: &'static str,
    /// Telegrams and bytes received and sent, overflows, acknowledgements.
    pub counters: TelegramCounters,
    /// Telegrams waiting in the mailbox.
    pub waiting: usize,
    /// The mailbox's settings.
    pub mailbox: MailboxSettings,
    /// Why the data flow control cannot use the RS232 signals, if it cannot.
    pub signals_error: Option<String>,
}

/// What the line adapter and the handle share.
#[derive(Debug)]
pub(crate) struct LineShared {
    pub(crate) status: Arc<status::Shared>,
    /// Telegrams and bytes of the line (events are counted through `status`).
    pub(crate) metrics: LineMetrics,
    pub(crate) mailbox: Arc<Mailbox>,
    protocol: &'static str,
    signals_error: Mutex<Option<String>>,
    /// The send queue's client.
    client: TelegramClient,
    /// The unit id of the mailbox on Modbus TCP.
    unit_id: Option<u8>,
}
// === impl LineShared ===

impl LineShared {
    /// Records an event: diagnostic buffer, counter, STATUS word (status and mailbox register),
    /// log, subscribers; 08 0Ah also counts an overflow.
    pub(crate) fn raise(&self, id: EventId, detail: Option<String>) {
        if id == ids::NO_FREE_RECEIVE_BUFFER {
            self.mailbox.count_overflow();
        }
        self.mailbox.set_status_word(id.status_word());
        self.status.raise(id, None, detail);
    }

    /// Records why the signals cannot be used; returns whether it is new.
    pub(crate) fn set_signals_error(&self, error: String) -> bool {
        let mut slot = self
            .signals_error
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        let new = slot.as_deref() != Some(error.as_str());
        *slot = Some(error);
        new
    }
}

impl LineCapabilities for LineShared {
    fn units(&self) -> Vec<(u8, Arc<dyn UnitService>)> {
        let unit = MailboxUnit::new(Arc::clone(&self.mailbox), self.client.clone());
        self.unit_id
            .map(|id| (id, Arc::new(unit) as Arc<dyn UnitService>))
            .into_iter()
            .collect()
    }

    /// The mailbox counts since this line started, exactly: telegrams and their bytes, sends
    /// done and failed.
    fn traffic(&self) -> Option<LineTraffic> {
        let c = self.mailbox.counters();
        Some(LineTraffic {
            frames_sent: c.sent,
            frames_received: c.received,
            bytes_sent: c.sent_bytes,
            bytes_received: c.received_bytes,
            commands_answered: c.sent,
            commands_failed: c.send_failed,
        })
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

/// What a telegram line adds to every line.
impl LineHandle {
    /// Sends telegrams on a telegram line.
    pub fn telegram_client(&self) -> Option<TelegramClient> {
        self.capability::<LineShared>().map(|t| t.client.clone())
    }

    /// The RS232 signals of a telegram line.
    pub fn signals(&self) -> Option<SignalsClient> {
        self.capability::<LineShared>().map(|t| t.client.signals())
    }

    /// The mailbox of a telegram line (received telegrams, acknowledgements, counters).
    pub fn mailbox(&self) -> Option<Arc<Mailbox>> {
        self.capability::<LineShared>()
            .map(|t| Arc::clone(&t.mailbox))
    }

    /// The mailbox of a telegram line as a Modbus TCP unit.
    pub fn mailbox_unit(&self) -> Option<MailboxUnit> {
        self.capability::<LineShared>()
            .map(|t| MailboxUnit::new(Arc::clone(&t.mailbox), t.client.clone()))
    }

    /// Every telegram a telegram line receives, with its sequence number and receive time
    /// (bounded; a lagging receiver is told how many it missed).
    pub fn subscribe_rx(&self) -> Option<broadcast::Receiver<TelegramRx>> {
        self.capability::<LineShared>()
            .map(|t| t.mailbox.subscribe())
    }

    /// Protocol, mailbox and telegram counters of a telegram line.
    pub fn telegram_status(&self) -> Option<TelegramLineStatus> {
        self.capability::<LineShared>().map(LineShared::status)
    }
}

// === impl LineShared ===

impl LineShared {
    fn status(&self) -> TelegramLineStatus {
        let mailbox = &self.mailbox;
        TelegramLineStatus {
            line: self.status.snapshot(),
            protocol: self.protocol,
            counters: mailbox.counters(),
            waiting: mailbox.len(),
            mailbox: mailbox.settings(),
            signals_error: self
                .signals_error
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .clone(),
        }
    }
}

/// Starts a telegram line: opens its port (reopening with back-off), receives into its mailbox
/// and sends for its clients until `shutdown` is cancelled. Must be called within a tokio
/// runtime. A journal that cannot be opened is logged and raised (04 07h), and the line runs
/// without it; [`try_spawn_telegram_line`] refuses to start instead.
pub fn spawn_telegram_line(
    settings: TelegramLineSettings,
    shutdown: CancellationToken,
) -> LineHandle {
    match open_mailbox(&settings) {
        Ok(opened) => spawn_on(settings, shutdown, SerialOpener, opened),
        Err(e) => {
            tracing::error!(line = %settings.name, error = %e, "mailbox journal not opened; the line runs without it");
            let mailbox = Mailbox::new(&settings.name, settings.mailbox, settings.max_len);
            let settings = TelegramLineSettings {
                journal: None,
                ..settings
            };
            let line = spawn_on(settings, shutdown, SerialOpener, (mailbox, None));
            if let Some(shared) = line.capability::<LineShared>() {
                shared.raise(ids::CPU_TRANSFER_ERROR, Some(e.to_string()));
            }
            line
        }
    }
}

/// [`spawn_telegram_line`] that fails when the line's journal cannot be opened.
///
/// # Errors
///
/// The journal cannot be read, created or written.
pub fn try_spawn_telegram_line(
    settings: TelegramLineSettings,
    shutdown: CancellationToken,
) -> Result<LineHandle, JournalError> {
    let opened = open_mailbox(&settings)?;
    Ok(spawn_on(settings, shutdown, SerialOpener, opened))
}

/// The mailbox of a line, with what its journal held.
type OpenedMailbox = (Arc<Mailbox>, Option<Restored>);

/// The line's mailbox: from its journal when it has one; with what a replaced line carried
/// when the journal's path changed (or there is none): written into the new journal first
/// (synced), then the old journal emptied of them, so they wait in one file only.
fn open_mailbox(settings: &TelegramLineSettings) -> Result<OpenedMailbox, JournalError> {
    let carried = settings
        .carried
        .clone()
        .filter(|c| !same_journal(c.journal.as_deref(), settings.journal.as_deref()));
    let (name, mailbox, max_len) = (&settings.name, settings.mailbox, settings.max_len);
    if let (Some(c), Some(path)) = (&carried, &settings.journal) {
        crate::mailbox::journal::take_over(path, c.last_seq, c.last_acked, &c.telegrams)?;
    }
    let opened = match (&settings.journal, &carried) {
        (Some(path), _) => {
            let (mailbox, restored) = Mailbox::with_journal(name, mailbox, max_len, path)?;
            (mailbox, Some(restored))
        }
        (None, Some(c)) => (
            Mailbox::with_carried(name, mailbox, max_len, c.clone()),
            None,
        ),
        (None, None) => (Mailbox::new(name, mailbox, max_len), None),
    };
    let Some(carried) = carried else {
        return Ok(opened);
    };
    let (last_seq, last_acked) = (carried.last_seq, carried.last_acked);
    let place = |journal: Option<&std::path::Path>| {
        journal.map_or_else(|| "memory".to_owned(), |p| p.display().to_string())
    };
    let waiting = carried.telegrams.len();
    // A line without a journal before and after, with nothing waiting, has nothing to say.
    if waiting > 0 || carried.journal.is_some() || settings.journal.is_some() {
        tracing::info!(
            line = %settings.name,
            waiting,
            last_seq,
            from = %place(carried.journal.as_deref()),
            to = %place(settings.journal.as_deref()),
            "waiting telegrams carried over to the restarted line with their numbers"
        );
    }
    if let Some(old) = &carried.journal {
        if let Err(e) = crate::mailbox::journal::clear(old, last_seq, last_acked) {
            tracing::error!(line = %settings.name, error = %e, "the old journal was not emptied: its telegrams wait in the new one too; do not name it again before removing it");
        }
    }
    Ok(opened)
}

/// Whether two journal settings name the same file (links and `..` followed when both exist).
fn same_journal(a: Option<&std::path::Path>, b: Option<&std::path::Path>) -> bool {
    match (a, b) {
        (None, None) => false,
        (Some(a), Some(b)) => {
            a == b
                || matches!(
                    (std::fs::canonicalize(a), std::fs::canonicalize(b)),
                    (Ok(x), Ok(y)) if x == y
                )
        }
        _ => false,
    }
}

/// [`spawn_telegram_line`] on the ports `opener` opens.
fn spawn_on<O: PortOpener>(
    settings: TelegramLineSettings,
    shutdown: CancellationToken,
    opener: O,
    (mailbox, restored): OpenedMailbox,
) -> LineHandle {
    let settings = TelegramLineSettings {
        max_len: settings.max_len.min(settings.protocol.max_len()),
        send_queue: settings.send_queue.max(1),
        ..settings
    };
    let name: Arc<str> = Arc::from(settings.name.as_str());
    let (tx, rx) = mpsc::channel(settings.send_queue);
    let protocol = match settings.protocol {
        TelegramProtocol::P3964(_) => "3964r",
        TelegramProtocol::Ascii(_) => "ascii",
    };
    let base = LineBase::new(
        &settings.name,
        protocol,
        &settings.port,
        settings.diag_depth,
        (settings.reopen_min, settings.reopen_max),
        settings.metrics.as_ref(),
    );
    let core = base.core(Vec::new());
    let shared = Arc::new(LineShared {
        metrics: core.shared.metrics().clone(),
        status: Arc::clone(&core.shared),
        mailbox,
        protocol: settings.protocol.name(),
        signals_error: Mutex::new(None),
        client: TelegramClient::new(Arc::clone(&name), tx, settings.send_queue)
            .with_sends(settings.sends),
        unit_id: settings.unit_id,
    });
    report_restored(&shared, &settings, restored.as_ref());
    match settings.engine_protocol() {
        TelegramProtocol::P3964(params) => {
            start(core, settings, params, shared, rx, shutdown, opener)
        }
        TelegramProtocol::Ascii(params) => {
            start(core, settings, params, shared, rx, shutdown, opener)
        }
    }
}

/// Logs what the journal gave back at start, and raises its loss: 05 01h "Current request
/// aborted by a CP restart" names the telegrams a restart took (the damaged tail of the
/// journal). Without a journal the start says that a stop will lose what waits.
fn report_restored(
    shared: &LineShared,
    settings: &TelegramLineSettings,
    restored: Option<&Restored>,
) {
    let line = settings.name.as_str();
    let Some(restored) = restored else {
        tracing::info!(line, "no journal: telegrams waiting at a stop or crash are lost (set `journal` to keep them)");
        return;
    };
    let path = settings
        .journal
        .as_deref()
        .map(|p| p.display().to_string())
        .unwrap_or_default();
    tracing::info!(
        line,
        journal = %path,
        waiting = restored.telegrams,
        last_seq = restored.last_seq,
        "mailbox restored from its journal"
    );
    if let Some(loss) = &restored.loss {
        let detail = format!(
            "journal {path}: {} bytes from offset {} unreadable ({}) and cut off; telegrams \
             recorded there are lost, numbering goes on after {}",
            loss.bytes, loss.offset, loss.reason, restored.last_seq
        );
        tracing::error!(line, "{detail}");
        shared.raise(ids::REQUEST_ABORTED_BY_RESTART, Some(detail));
    }
}

/// The runtime with the telegram adapter over the engines `factory` builds.
fn start<F: engine::EngineFactory, O: PortOpener>(
    core: runtime::LineCore,
    settings: TelegramLineSettings,
    factory: F,
    shared: Arc<LineShared>,
    commands: mpsc::Receiver<Command>,
    shutdown: CancellationToken,
    opener: O,
) -> LineHandle {
    let clock = core.clock;
    let caps = Arc::clone(&shared);
    let engine = task::TelegramLine::new(settings, factory, shared, clock);
    runtime::spawn(core, engine, Some(commands), caps, opener, shutdown)
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use proto_core::event::ids;
    use proto_core::proc3964::{Params3964, Priority, Settings3964};
    use proto_core::serial_marks::{encode, Received};
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    use super::*;
    use crate::line::testing::{events, eventually, OnePort};

    #[tokio::test]
    async fn a_3964r_line_reports_a_faulty_character_and_a_break_in_idle_at_once() {
        let (port, mut partner) = tokio::io::duplex(256);
        let params = Params3964::try_new(Settings3964 {
            priority: Priority::High,
            ..Settings3964::default()
        })
        .expect("params");
        let settings = TelegramLineSettings::new(
            "r3964",
            PortSettings::new("/dev/in-process", 9600),
            TelegramProtocol::P3964(params),
        );
        let shutdown = CancellationToken::new();
        let mailbox = open_mailbox(&settings).expect("mailbox");
        let line = spawn_on(
            settings,
            shutdown.clone(),
            OnePort(Mutex::new(Some(port))),
            mailbox,
        );
        eventually("the port open", || line.status().port_open).await;

        // 003 7.2 08 0Ch: a faulty character in idle is reported immediately; like any character
        // other than STX in idle it is answered with NAK (6.3.1 "Passive operation").
        let mut marks = Vec::new();
        encode([Received::Faulty(0x02)], &mut marks);
        partner.write_all(&marks).await.expect("write");
        let mut nak = [0u8; 1];
        partner.read_exact(&mut nak).await.expect("NAK");
        assert_eq!(nak, [0x15]);
        eventually("08 0Ch", || events(&line, ids::CHARACTER_ERROR) == 1).await;

        // 08 0Dh: a BREAK in idle is reported, nothing is sent.
        marks.clear();
        encode([Received::Break], &mut marks);
        partner.write_all(&marks).await.expect("write");
        eventually("08 0Dh", || events(&line, ids::LINE_BREAK) == 1).await;
        let mut byte = [0u8; 1];
        let read = tokio::time::timeout(Duration::from_millis(100), partner.read(&mut byte)).await;
        assert!(read.is_err(), "sent after a BREAK: {read:?}");
        assert_eq!(
            line.status().diagnostics.first().map(|e| e.id),
            Some(ids::LINE_BREAK)
        );
        shutdown.cancel();
        line.join().await;
    }
}
