//! The 3964(R) procedure and the ASCII telegram driver fed scripts of line events.
//!
//! Both engines share one driver ([`Run`]): the script's operations, the checks after each of
//! them and the run to rest at the end.
//!
//! Script operations (one byte each, `op & 7` saying which, `a = op >> 3` its argument):
//! - 0: receive the next `a + 1` bytes of the input;
//! - 1: wait `a * a` milliseconds without telling the engine (a late wake-up);
//! - 2: wait until the engine's deadline (or `a` ms when it has none), then `handle_timeout`;
//! - 3: a line error: parity, framing, overrun or BREAK by `a % 4`;
//! - 4: `send` the next `a + 1` bytes of the input as a telegram;
//! - 5: `take_received`;
//! - 6: receive one control character: STX, DLE, ETX, NAK, XON, XOFF, CR, LF by `a % 8`;
//! - 7: `a` even: `handle_tx_done` for every buffer taken from `poll_transmit` and not yet
//!   confirmed; `a` odd: the RS232 inputs CTS = bit 1, DSR = bit 2 of `a` (ASCII driver only).
//!
//! Checked throughout: after `handle_timeout(now)` the next deadline lies after `now` (a driver
//! following the deadlines does not spin); every `Sent` or `SendFailed` names a telegram that
//! `send` accepted and that was not reported before; received telegrams are within the limits.
//! At the end the run confirms every transmission at once and follows the deadlines: within
//! [`MAX_DRIVE_STEPS`] the engine must be idle with every accepted telegram reported.

use core::time::Duration;
use std::collections::BTreeSet;

use crate::proc3964::{self, frame, Params3964, Priority, Proc3964, Settings3964, Variant};
use crate::telegram::{
    AsciiDriver, AsciiParams, AsciiSettings, EndCriterion, FlowControl, Interface, LineError,
    SendError, Signals, TelegramEvent, TelegramId, MAX_TELEGRAM,
};
use crate::time::Instant;

/// The most deadlines followed after the script before calling it a livelock.
const MAX_DRIVE_STEPS: usize = 100_000;

/// The control characters of operation 6.
const CONTROLS: [u8; 8] = [
    proc3964::STX,
    proc3964::DLE,
    proc3964::ETX,
    proc3964::NAK,
    0x11, // XON
    0x13, // XOFF
    b'\r',
    b'\n',
];

/// The 3964(R) procedure: its deframer on the whole input, then one station driven by a script.
///
/// Input: byte 0 the setup (bit 0: 3964 without BCC, bit 1: low priority, bits 2..3 the telegram
/// length limit 250 / 4 / 16 / 1024, bits 4..5 the receive buffers 250 / 1 / 2 / 4, bits 6..7 the
/// send queue 16 / 1 / 2 / 4), then the script (see the module doc).
///
/// The deframer, fed the script bytes as a received telegram: once complete it stays complete,
/// and user data it accepts encodes back to exactly the bytes it consumed.
pub fn fuzz_3964(data: &[u8]) {
    run_3964(data);
}

/// What a script run reported, for the tests of the seeds.
#[derive(Debug, Default)]
pub(super) struct Report {
    /// The data of every `Received` event.
    pub(super) received: Vec<Vec<u8>>,
    /// `Sent` events.
    pub(super) sent: usize,
    /// `SendFailed` events.
    pub(super) failed: usize,
}

/// [`fuzz_3964`]; `None` when the setup is refused.
pub(super) fn run_3964(data: &[u8]) -> Option<Report> {
    let (&setup, script) = data.split_first()?;
    let mut settings = Settings3964::new(if setup & 1 == 0 {
        Variant::P3964R
    } else {
        Variant::P3964
    });
    if setup & 2 != 0 {
        settings.priority = Priority::Low;
    }
    settings.max_len = [250, 4, 16, 1024][usize::from(setup >> 2 & 3)];
    settings.receive_buffers = [250, 1, 2, 4][usize::from(setup >> 4 & 3)];
    settings.send_queue = [16, 1, 2, 4][usize::from(setup >> 6)];
    check_deframer(script, settings.variant, usize::from(settings.max_len));

    let params = Params3964::try_new(settings.clone()).ok()?;
    let max_len = usize::from(settings.max_len);
    let buffers = usize::from(settings.receive_buffers);
    let mut run = Run::new(Proc3964::new(params));
    run.script(script);
    run.finish();
    for data in &run.report.received {
        assert!(
            data.len() <= max_len,
            "3964: telegram of {} bytes",
            data.len()
        );
    }
    assert!(run.engine.received_len() <= buffers, "3964: receive buffer");
    Some(run.report)
}

/// Feeds `bytes` to a deframer and checks it against [`frame::encode`].
fn check_deframer(bytes: &[u8], variant: Variant, max_len: usize) {
    let mut deframer = frame::Deframer::new(variant, max_len);
    let mut consumed = None;
    for (i, &byte) in bytes.iter().enumerate() {
        let progress = deframer.push(byte);
        match consumed {
            Some(_) => assert_eq!(progress, frame::Progress::Complete, "complete, then not"),
            None if progress == frame::Progress::Complete => consumed = Some(i + 1),
            None => {}
        }
    }
    match deframer.finish() {
        Ok(data) => {
            assert!(data.len() <= max_len, "deframer kept {} bytes", data.len());
            let wire = bytes.get(..consumed.unwrap_or(0)).unwrap_or_default();
            assert_eq!(frame::encode(&data, variant), wire, "deframer round trip");
        }
        Err(frame::FrameError::Incomplete) => assert!(consumed.is_none(), "complete, Incomplete"),
        Err(_) => {}
    }
}

/// The ASCII telegram driver driven by a script.
///
/// Input: byte 0 the end criterion (bits 0..1: character delay time / fixed length / end
/// character ETX / end characters CR LF; the fixed length is byte 1 + 1), bits 2..3 the flow
/// control (none / XON-XOFF / RTS-CTS / automatic V24; the last two on RS232), bit 4 seven data
/// bits, bit 5 transmission pause off, bit 6 a single receive buffer, bit 7 overwriting allowed
/// (with one buffer); byte 1 the fixed length; then the script (see the module doc).
///
/// Received telegrams: at most 1024 bytes, 7-bit clean with seven data bits, ending with the end
/// character(s) in that mode, exactly the fixed length in that mode.
pub fn fuzz_telegram(data: &[u8]) {
    run_telegram(data);
}

/// [`fuzz_telegram`]; `None` when the setup is refused.
pub(super) fn run_telegram(data: &[u8]) -> Option<Report> {
    let [setup, length, ref script @ ..] = *data else {
        return None;
    };
    let end = match setup & 3 {
        0 => EndCriterion::CharacterDelay,
        1 => EndCriterion::FixedLength(u16::from(length) + 1),
        2 => EndCriterion::EndChars {
            first: 0x03,
            second: None,
        },
        _ => EndCriterion::EndChars {
            first: b'\r',
            second: Some(b'\n'),
        },
    };
    let (flow, interface) = match setup >> 2 & 3 {
        0 => (FlowControl::None, Interface::Rs422),
        1 => (FlowControl::XON_XOFF, Interface::Rs422),
        2 => (FlowControl::RtsCts, Interface::Rs232),
        _ => (FlowControl::AUTO_V24, Interface::Rs232),
    };
    let settings = AsciiSettings {
        end,
        flow,
        interface,
        data_bits: if setup & 0x10 == 0 { 8 } else { 7 },
        send_pause: setup & 0x20 == 0,
        receive_buffers: if setup & 0x40 == 0 { 250 } else { 1 },
        prevent_overwrite: setup & 0x80 == 0,
        ..AsciiSettings::default()
    };
    let params = AsciiParams::try_new(settings).ok()?;
    let mut run = Run::new(AsciiDriver::new(params));
    run.script(script);
    run.finish();
    for data in &run.report.received {
        assert!(
            data.len() <= MAX_TELEGRAM,
            "telegram of {} bytes",
            data.len()
        );
        if setup & 0x10 != 0 {
            assert!(data.iter().all(|&b| b <= 0x7F), "8th bit with 7 data bits");
        }
        match end {
            EndCriterion::CharacterDelay => assert!(!data.is_empty(), "empty telegram"),
            EndCriterion::FixedLength(n) => assert_eq!(data.len(), usize::from(n), "fixed length"),
            EndCriterion::EndChars { first, second } => {
                let tail = [Some(first), second];
                let tail: Vec<u8> = tail.into_iter().flatten().collect();
                assert!(
                    data.ends_with(&tail),
                    "telegram {data:02x?} without its end"
                );
            }
        }
    }
    Some(run.report)
}

/// What [`Run`] needs of an engine: the common surface of [`Proc3964`] and [`AsciiDriver`].
trait Engine {
    fn handle_rx(&mut self, now: Instant, bytes: &[u8]);
    fn handle_timeout(&mut self, now: Instant);
    fn handle_line_error(&mut self, now: Instant, error: LineError);
    fn handle_tx_done(&mut self, now: Instant);
    fn handle_signals(&mut self, now: Instant, signals: Signals);
    fn send(&mut self, now: Instant, telegram: Vec<u8>) -> Result<TelegramId, SendError>;
    fn poll_transmit(&mut self) -> Option<Vec<u8>>;
    fn poll_timeout(&self) -> Option<Instant>;
    fn poll_event(&mut self) -> Option<TelegramEvent>;
    fn take_received(&mut self) -> Option<Vec<u8>>;
    fn is_idle(&self) -> bool;
}

impl Engine for Proc3964 {
    fn handle_rx(&mut self, now: Instant, bytes: &[u8]) {
        Self::handle_rx(self, now, bytes);
    }
    fn handle_timeout(&mut self, now: Instant) {
        Self::handle_timeout(self, now);
    }
    fn handle_line_error(&mut self, now: Instant, error: LineError) {
        Self::handle_line_error(self, now, error);
    }
    fn handle_tx_done(&mut self, now: Instant) {
        Self::handle_tx_done(self, now);
    }
    fn handle_signals(&mut self, _now: Instant, _signals: Signals) {}
    fn send(&mut self, now: Instant, telegram: Vec<u8>) -> Result<TelegramId, SendError> {
        Self::send(self, now, telegram)
    }
    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        Self::poll_transmit(self)
    }
    fn poll_timeout(&self) -> Option<Instant> {
        Self::poll_timeout(self)
    }
    fn poll_event(&mut self) -> Option<TelegramEvent> {
        Self::poll_event(self)
    }
    fn take_received(&mut self) -> Option<Vec<u8>> {
        Self::take_received(self)
    }
    fn is_idle(&self) -> bool {
        Self::is_idle(self)
    }
}

impl Engine for AsciiDriver {
    fn handle_rx(&mut self, now: Instant, bytes: &[u8]) {
        Self::handle_rx(self, now, bytes);
    }
    fn handle_timeout(&mut self, now: Instant) {
        Self::handle_timeout(self, now);
    }
    fn handle_line_error(&mut self, now: Instant, error: LineError) {
        Self::handle_line_error(self, now, error);
    }
    fn handle_tx_done(&mut self, now: Instant) {
        Self::handle_tx_done(self, now);
    }
    fn handle_signals(&mut self, now: Instant, signals: Signals) {
        Self::handle_signals(self, now, signals);
    }
    fn send(&mut self, now: Instant, telegram: Vec<u8>) -> Result<TelegramId, SendError> {
        Self::send(self, now, telegram)
    }
    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        // The RS232 outputs come first (see `poll_action`); the script does not model them.
        while self.poll_action().is_some() {}
        Self::poll_transmit(self)
    }
    fn poll_timeout(&self) -> Option<Instant> {
        Self::poll_timeout(self)
    }
    fn poll_event(&mut self) -> Option<TelegramEvent> {
        Self::poll_event(self)
    }
    fn take_received(&mut self) -> Option<Vec<u8>> {
        Self::take_received(self)
    }
    fn is_idle(&self) -> bool {
        Self::is_idle(self)
    }
}

/// An engine under test with its clock and what it reported.
struct Run<E> {
    engine: E,
    now: Instant,
    /// Buffers taken from `poll_transmit` and not yet confirmed with `handle_tx_done`.
    unconfirmed: usize,
    /// Telegrams accepted by `send` and not yet reported sent or failed.
    outstanding: BTreeSet<TelegramId>,
    /// What the engine reported.
    report: Report,
}

impl<E: Engine> Run<E> {
    fn new(engine: E) -> Self {
        Self {
            engine,
            now: Instant::from_millis(1),
            unconfirmed: 0,
            outstanding: BTreeSet::new(),
            report: Report::default(),
        }
    }

    fn script(&mut self, script: &[u8]) {
        let mut ops = script.iter();
        while let Some(&op) = ops.next() {
            let arg = op >> 3;
            let now = self.now;
            match op & 7 {
                0 => {
                    let bytes: Vec<u8> = ops.by_ref().take(usize::from(arg) + 1).copied().collect();
                    self.engine.handle_rx(now, &bytes);
                }
                1 => self.now += Duration::from_millis(u64::from(arg) * u64::from(arg)),
                2 => {
                    let fallback = now + Duration::from_millis(u64::from(arg));
                    self.timeout_at(self.engine.poll_timeout().unwrap_or(fallback));
                }
                3 => {
                    let error = [
                        LineError::Parity,
                        LineError::Framing,
                        LineError::Overrun,
                        LineError::Break,
                    ][usize::from(arg % 4)];
                    self.engine.handle_line_error(now, error);
                }
                4 => {
                    let telegram: Vec<u8> =
                        ops.by_ref().take(usize::from(arg) + 1).copied().collect();
                    if let Ok(id) = self.engine.send(now, telegram) {
                        assert!(self.outstanding.insert(id), "id {id:?} given twice");
                    }
                }
                5 => {
                    let _ = self.engine.take_received();
                }
                6 => {
                    let control = CONTROLS[usize::from(arg % 8)];
                    self.engine.handle_rx(now, &[control]);
                }
                _ if arg % 2 == 0 => self.confirm_all(),
                _ => {
                    let signals = Signals {
                        cts: arg & 2 != 0,
                        dsr: arg & 4 != 0,
                    };
                    self.engine.handle_signals(now, signals);
                }
            }
            self.drain();
        }
    }

    /// Moves the clock to `at` (never back) and calls `handle_timeout`; the next deadline must
    /// lie after it.
    fn timeout_at(&mut self, at: Instant) {
        self.now = self.now.max(at);
        let now = self.now;
        self.engine.handle_timeout(now);
        self.drain();
        if let Some(deadline) = self.engine.poll_timeout() {
            assert!(deadline > now, "deadline {deadline:?} not after {now:?}");
        }
    }

    /// Confirms every transmission as done now.
    fn confirm_all(&mut self) {
        while self.unconfirmed > 0 {
            self.unconfirmed -= 1;
            let now = self.now;
            self.engine.handle_tx_done(now);
            self.drain();
        }
    }

    /// Takes the transmissions and events and checks the events.
    fn drain(&mut self) {
        while self.engine.poll_transmit().is_some() {
            self.unconfirmed += 1;
        }
        while let Some(event) = self.engine.poll_event() {
            match event {
                TelegramEvent::Sent { id } => {
                    assert!(
                        self.outstanding.remove(&id),
                        "{id:?} reported twice or never sent"
                    );
                    self.report.sent += 1;
                }
                TelegramEvent::SendFailed { id, .. } => {
                    assert!(
                        self.outstanding.remove(&id),
                        "{id:?} reported twice or never sent"
                    );
                    self.report.failed += 1;
                }
                TelegramEvent::Received { data } => self.report.received.push(data),
                TelegramEvent::Raised { .. } => {}
            }
        }
    }

    /// Confirms every transmission and follows the deadlines until the engine rests.
    fn finish(&mut self) {
        for _ in 0..MAX_DRIVE_STEPS {
            self.drain();
            self.confirm_all();
            match self.engine.poll_timeout() {
                Some(deadline) => self.timeout_at(deadline),
                None if self.unconfirmed == 0 => {
                    assert!(self.engine.is_idle(), "no deadline, but not idle");
                    assert!(
                        self.outstanding.is_empty(),
                        "telegrams never reported: {:?}",
                        self.outstanding
                    );
                    return;
                }
                None => {}
            }
        }
        panic!("still busy after {MAX_DRIVE_STEPS} steps: livelock");
    }
}
