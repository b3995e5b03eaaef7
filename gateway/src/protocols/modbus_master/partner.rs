//! Simulated Modbus slaves as a line engine: a [`ModbusDevice`] (one model or a [`crate::sim::bus::Bus`]
//! of several) driven by the gateway's own line runtime, so that the simulators and the lines
//! share one port task and one timing.
//!
//! Requests are framed as a slave does (003 6.4.3; Modbus over Serial Line V1.02, 2.5.1.1): the
//! function code and byte counts give the frame's length ([`rtu::expected_request_len`]), so a
//! frame ends with its last byte and two frames in one write are two requests; where the length
//! cannot be known (an unknown function, the free-length FC 08 echo), or bytes stop arriving
//! before it is complete, 3.5 character times of silence end the frame. The answer is due t3.5
//! after the request's last byte (001 3.5: "Eine Antwort wird jedoch frühestens nach 3,5 Zeichen
//! gestartet"), plus an injected delay; the runtime's timer (a timerfd) wakes the engine then.
//! Bytes kept while a frame is incomplete are bounded by [`MAX_PENDING`].

use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use proto_core::checksum::crc16_modbus;
use proto_core::event::EventId;
use proto_core::modbus::rtu::{self, CharTiming, FrameLen};
use proto_core::serial_marks::LineError;
use proto_core::time::Instant;
use tokio_serial::SerialPort;
use tokio_util::sync::CancellationToken;

use crate::line::runtime::{
    self, GivenPort, LineBase, LineCapabilities, LineCommands, LineEngine, LineHandle,
    LineLifecycle, LinePort, LineSignals, SecondPort, Stop,
};
use crate::line::{Clock, DEFAULT_REOPEN_MAX, DEFAULT_REOPEN_MIN};
use crate::serial::PortSettings;

/// A simulated Modbus RTU slave.
pub trait ModbusDevice: Send {
    /// Handles one received frame (address, PDU, CRC) and returns the frame to send back, or
    /// `None` when the device stays silent.
    fn handle_frame(&mut self, adu: &[u8]) -> Option<Vec<u8>>;

    /// Advances the device's own clock by `elapsed`: the process behind the registers moves on
    /// and time-outs run. The default does nothing.
    fn tick(&mut self, elapsed: Duration) {
        let _ = elapsed;
    }

    /// The faults injected into the device's answers (the runner applies `delay`).
    fn faults(&self) -> Faults {
        Faults::default()
    }

    /// Bytes the line picks up after the answer just sent, once the answer has ended (the runner
    /// sends them after a silence of more than t3.5, so they are a burst of their own). The
    /// default is none.
    fn after_answer(&mut self) -> Option<Vec<u8>> {
        None
    }
}

impl<D: ModbusDevice + ?Sized> ModbusDevice for Box<D> {
    fn handle_frame(&mut self, adu: &[u8]) -> Option<Vec<u8>> {
        (**self).handle_frame(adu)
    }

    fn tick(&mut self, elapsed: Duration) {
        (**self).tick(elapsed);
    }

    fn faults(&self) -> Faults {
        (**self).faults()
    }

    fn after_answer(&mut self) -> Option<Vec<u8>> {
        (**self).after_answer()
    }
}

/// A device shared with the code that started it (a test reads its registers or changes its
/// faults while it serves). The lock is held for one frame or one tick, never across an await.
impl<D: ModbusDevice> ModbusDevice for Arc<Mutex<D>> {
    fn handle_frame(&mut self, adu: &[u8]) -> Option<Vec<u8>> {
        self.lock()
            .unwrap_or_else(PoisonError::into_inner)
            .handle_frame(adu)
    }

    fn tick(&mut self, elapsed: Duration) {
        self.lock()
            .unwrap_or_else(PoisonError::into_inner)
            .tick(elapsed);
    }

    fn faults(&self) -> Faults {
        self.lock().unwrap_or_else(PoisonError::into_inner).faults()
    }

    fn after_answer(&mut self) -> Option<Vec<u8>> {
        self.lock()
            .unwrap_or_else(PoisonError::into_inner)
            .after_answer()
    }
}

/// Faults to inject for tests of the gateway's error handling. The default injects none.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Faults {
    /// Never answer (the master sees "no reply", 003 7.2 08 30h).
    pub silent: bool,
    /// Wait this long before answering, on top of the normal turnaround.
    pub delay: Duration,
    /// Send answers with a wrong CRC (003 7.2 0E 57h).
    pub bad_crc: bool,
    /// Send answers with another slave address (003 7.2 08 31h).
    pub wrong_address: bool,
}

// === impl Faults ===

impl Faults {
    /// The answer as the faults change it.
    pub fn apply(&self, answer: Option<Vec<u8>>) -> Option<Vec<u8>> {
        if self.silent {
            return None;
        }
        let mut frame = answer?;
        if self.wrong_address {
            if let Some(address) = frame.first_mut() {
                *address = address.wrapping_add(1).max(1);
            }
            reseal(&mut frame);
        }
        if self.bad_crc {
            if let Some(last) = frame.last_mut() {
                *last ^= 0xFF;
            }
        }
        Some(frame)
    }
}

/// Recomputes the CRC of a frame after its bytes changed.
fn reseal(frame: &mut Vec<u8>) {
    if frame.len() >= rtu::MIN_FRAME_LEN {
        frame.truncate(frame.len() - 2);
        let crc = crc16_modbus(frame);
        frame.extend_from_slice(&crc.to_le_bytes());
    }
}

/// How often the devices' own clock advances (the drive's ramps, its time-out).
const TICK: Duration = Duration::from_millis(100);
/// Bytes kept while a frame is incomplete: more than any RTU frame (the longest the codec takes
/// is 264 bytes); beyond that the bytes are noise and are dropped at the next silence.
const MAX_PENDING: usize = 1024;

/// A frame waiting for the time it goes out.
#[derive(Debug)]
struct Due {
    at: Instant,
    frame: Vec<u8>,
    /// An answer (after it the device may add a burst of its own); otherwise such a burst.
    answer: bool,
}

/// The devices on one simulated port, as a line engine.
pub(crate) struct DeviceEngine<D> {
    device: D,
    timing: CharTiming,
    /// The bytes of the frame being received (at most [`MAX_PENDING`] are kept), and the
    /// arrival of the last of them.
    pending: Vec<u8>,
    last_rx: Option<Instant>,
    /// Frames not yet due, earliest first.
    due: Vec<Due>,
    /// Frames due, to write.
    transmit: std::collections::VecDeque<(Vec<u8>, bool)>,
    /// The frame written last was an answer.
    answered: bool,
    /// When the devices' clock last advanced, and when it advances next (tokio time).
    last_tick: tokio::time::Instant,
    next_tick: tokio::time::Instant,
    /// Cancelled when the port is lost: the simulator ends with its port, as a device unplugged.
    on_lost: CancellationToken,
}

// === impl DeviceEngine ===

impl<D: ModbusDevice> DeviceEngine<D> {
    /// `device` on a line with `timing`; `on_lost` is cancelled when the port fails.
    pub(crate) fn new(device: D, timing: CharTiming, on_lost: CancellationToken) -> Self {
        let now = tokio::time::Instant::now();
        Self {
            device,
            timing,
            pending: Vec::new(),
            last_rx: None,
            due: Vec::new(),
            transmit: std::collections::VecDeque::new(),
            answered: false,
            last_tick: now,
            next_tick: now + TICK,
            on_lost,
        }
    }

    /// Schedules `frame` at `at`, keeping the queue in time order.
    fn schedule(&mut self, at: Instant, frame: Vec<u8>, answer: bool) {
        let index = self.due.partition_point(|d| d.at <= at);
        self.due.insert(index, Due { at, frame, answer });
    }

    /// Lets the devices handle `request`; an answer is due at `at` plus the injected delay.
    fn serve(&mut self, request: &[u8], at: Instant) {
        if let Some(reply) = self.device.handle_frame(request) {
            let at = at + self.device.faults().delay;
            self.schedule(at, reply, true);
        }
    }

    /// The silence after the frame being received: t3.5 after its last byte.
    fn silence_end(&self) -> Option<Instant> {
        self.last_rx.map(|at| at + self.timing.t3_5())
    }

    /// Ends a frame whose silence passed by `now` and serves it, then moves every frame whose
    /// time came to the transmit queue.
    fn advance(&mut self, now: Instant) {
        if let Some(end) = self.silence_end().filter(|end| *end <= now) {
            self.last_rx = None;
            let frame = std::mem::take(&mut self.pending);
            if frame.len() > MAX_PENDING {
                tracing::debug!(len = frame.len(), "simulated bus: dropping noise");
            } else if !frame.is_empty() {
                self.serve(&frame, end);
            }
        }
        let ready = self.due.partition_point(|d| d.at <= now);
        for due in self.due.drain(..ready) {
            self.transmit.push_back((due.frame, due.answer));
        }
    }

    /// Cuts and serves every frame of `pending` complete by its length, received at `now`.
    fn take_frames(&mut self, now: Instant) {
        while let FrameLen::Complete(len) = rtu::expected_request_len(&self.pending) {
            if len > self.pending.len() {
                break;
            }
            let frame: Vec<u8> = self.pending.drain(..len).collect();
            self.serve(&frame, now + self.timing.t3_5());
        }
        if self.pending.is_empty() {
            self.last_rx = None;
        }
    }
}

impl<D: ModbusDevice + 'static> LineEngine for DeviceEngine<D> {
    fn opened(&mut self, _modem: Option<&mut dyn SerialPort>) {
        self.pending.clear();
        self.last_rx = None;
        self.due.clear();
        self.transmit.clear();
    }

    fn handle_rx(&mut self, now: Instant, bytes: &[u8]) {
        self.advance(now);
        let room = (MAX_PENDING + 1).saturating_sub(self.pending.len());
        self.pending
            .extend_from_slice(bytes.get(..room.min(bytes.len())).unwrap_or_default());
        self.last_rx = Some(now);
        self.take_frames(now);
    }

    fn handle_line_error(&mut self, now: Instant, _error: LineError) {
        // A faulty character spoils the request it belongs to (003 6.4.6): no answer.
        self.advance(now);
        self.pending.clear();
        self.pending.resize(MAX_PENDING + 1, 0); // dropped at the silence, unanswered
        self.last_rx = Some(now);
    }

    fn handle_timeout(&mut self, now: Instant) {
        self.advance(now);
    }

    fn poll_timeout(&self) -> Option<Instant> {
        let first = self.due.first().map(|d| d.at);
        [self.silence_end(), first].into_iter().flatten().min()
    }

    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        let (frame, answer) = self.transmit.pop_front()?;
        self.answered = answer;
        Some(frame)
    }

    fn transmitted(&mut self, _written: tokio::time::Instant, _len: usize, end: Instant) {
        if std::mem::take(&mut self.answered) {
            if let Some(burst) = self.device.after_answer() {
                // After the answer has left the wire and more than t3.5 of silence: a burst of
                // its own, which reaches the master while it awaits nothing.
                self.schedule(end + self.timing.t3_5() * 2, burst, false);
            }
        }
    }

    fn handle_events(&mut self) -> bool {
        false
    }
}

impl<D> LineCommands for DeviceEngine<D> {
    type Command = ();

    fn command(&mut self, (): (), _modem: Option<&mut dyn SerialPort>) {}

    fn refuse(&mut self, (): (), _shutting_down: bool) {}
}

impl<D> LineLifecycle for DeviceEngine<D> {
    fn stop(&mut self) -> Stop {
        // A simulated device stops at once, as one switched off.
        Stop::AT_ONCE
    }

    fn done(&self) -> bool {
        true
    }

    fn closed(&mut self, _shutting_down: bool) {
        self.pending.clear();
        self.last_rx = None;
        self.due.clear();
        self.transmit.clear();
    }

    fn port_failed(&mut self, id: EventId, reason: String) {
        tracing::info!(event = %id, %reason, "simulated bus: port closed, the devices stop");
        self.on_lost.cancel();
    }
}

impl<D: ModbusDevice> LineSignals for DeviceEngine<D> {
    fn wake(&self) -> impl std::future::Future<Output = ()> + Send + '_ {
        tokio::time::sleep_until(self.next_tick)
    }

    fn woken(&mut self, _modem: Option<&mut dyn SerialPort>) {
        let now = tokio::time::Instant::now();
        self.device
            .tick(now.saturating_duration_since(self.last_tick));
        self.last_tick = now;
        self.next_tick = now + TICK;
    }
}

impl<D> SecondPort for DeviceEngine<D> {}

/// Starts the engine `make` builds on the line's clock on `port` (a stream its caller opened) on
/// the line runtime, as line `name` whose characters take `char_time`, until `shutdown` is
/// cancelled. Without a monitor, metrics or commands: a simulator has only the port task of a
/// line.
pub(crate) fn spawn_line<E, P>(
    name: &str,
    make: impl FnOnce(Clock) -> E,
    port: P,
    char_time: Duration,
    shutdown: CancellationToken,
) -> LineHandle
where
    E: LineEngine,
    P: LinePort,
{
    let mut settings = PortSettings::new(name, 1);
    // The baud rate whose character time is `char_time` with the settings' bits (the runtime
    // estimates the end of each transmission from it).
    let nanos = char_time.as_nanos().max(1);
    let bits = u128::from(settings.bits_per_char()) * 1_000_000_000;
    settings.baud = u32::try_from(bits / nanos).unwrap_or(u32::MAX).max(1);
    settings.monitor_frames = 0;
    let reopen = (DEFAULT_REOPEN_MIN, DEFAULT_REOPEN_MAX);
    let base = LineBase::new(name, "simulator", &settings, 1, reopen, None);
    let caps = Arc::new(NoCapabilities);
    let core = base.core(Vec::new());
    let engine = make(core.clock);
    runtime::spawn(core, engine, None, caps, GivenPort::new(port), shutdown)
}

/// A simulator offers nothing beyond its port task.
#[derive(Debug)]
struct NoCapabilities;

impl LineCapabilities for NoCapabilities {
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}
