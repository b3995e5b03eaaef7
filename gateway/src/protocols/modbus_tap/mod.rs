//! The listen-only Modbus RTU tap line: an adapter of the line runtime over a proto-core [`Tap`]
//! that stores what another master's traffic shows about the devices it lists.
//!
//! The line never transmits: the engine has nothing to send, so the runtime never writes to the
//! port (with RS485 the kernel's RS485 mode keeps the driver off, since nothing is sent), and it
//! takes no commands. It frames the bus by silence, pairs each request with its answer, and
//! stores the answers for listed devices into the image with quality `Good`: the values of read
//! answers (FC 01..04) and of confirmed writes (FC 05/06/15/16/23). The values turn stale as
//! polled ones do, after the image's stale factor (3) times the line's expected cycle without
//! another answer. Requests to addresses the line does not list are counted (device `unknown`), not
//! stored. Its devices are Modbus TCP units that answer reads from the image and refuse every
//! write with exception 01 (the function is not allowed on this unit: the gateway does not drive
//! this bus, and a write would need a second master on it).

use std::sync::Arc;
use std::time::{Duration, SystemTime};

use proto_core::event::{ids, EventId};
use proto_core::modbus::pdu::{ExceptionCode, Request, Response};
use proto_core::modbus::tap::{Block, Exchange, Outcome, Tap, TapConfig, TapEvent, Values};
use proto_core::monitor::{FrameKind, Framing as MonitorFraming, Role};
use proto_core::serial_marks::LineError;
use tokio::time::Instant;
use tokio_serial::SerialPort;
use tokio_util::sync::CancellationToken;

use crate::image::{ImageError, ProcessImage, Quality};
use crate::line::metrics::{LineFamilies, LineTraffic, BROADCAST_DEVICE, UNKNOWN_DEVICE};
use crate::line::runtime::{
    self, LineBase, LineCapabilities, LineEngine, LineHandle, PortOpener, SerialOpener, Stop,
};
use crate::line::runtime::{LineCommands, LineLifecycle, LineSignals, SecondPort};
use crate::line::status::{DeviceStatus, Shared};
use crate::line::{DEFAULT_REOPEN_MAX, DEFAULT_REOPEN_MIN};
use crate::metrics::RequestResult;
use crate::protocols::DeviceSettings;
use crate::serial::PortSettings;
use crate::unit::{UnitFuture, UnitService};

/// The config's `protocol` key of the line.
pub const TAP_PROTOCOL: &str = "modbus-rtu-tap";

/// Settings of one tap line.
#[derive(Clone, Debug)]
pub struct TapLineSettings {
    /// The line's name (logs, status, keys).
    pub name: String,
    /// The serial port (only read).
    pub port: PortSettings,
    /// The decoder: t1.5/t3.5, answer timeout, inter-character check.
    pub tap: TapConfig,
    /// How often the other master is expected to read a value: a stored value turns stale after
    /// the image's stale factor times this.
    pub expected_cycle: Duration,
    /// Depth of the diagnostic buffer.
    pub diag_depth: usize,
    /// First delay before reopening a failed port.
    pub reopen_min: Duration,
    /// Longest delay between reopen attempts.
    pub reopen_max: Duration,
    /// Where the line counts its events, traffic and requests (`None`: nowhere).
    pub metrics: Option<LineFamilies>,
}

// === impl TapLineSettings ===

impl TapLineSettings {
    /// A tap on `port` with the CP's RTU timing at its baud rate (003 6.4.3) and the defaults.
    pub fn new(name: impl Into<String>, port: PortSettings) -> Self {
        let mut tap = TapConfig::new(port.baud, port.bits_per_char());
        tap.timing = crate::line::rtu_timing(&port);
        Self {
            name: name.into(),
            port,
            tap,
            expected_cycle: crate::protocols::DEFAULT_EXPECTED_CYCLE,
            diag_depth: crate::line::DEFAULT_DIAG_DEPTH,
            reopen_min: DEFAULT_REOPEN_MIN,
            reopen_max: DEFAULT_REOPEN_MAX,
            metrics: None,
        }
    }
}

/// Starts a tap line: opens its port (reopening with back-off) and stores what the bus shows
/// about `devices` into `image` until `shutdown` is cancelled. Must be called within a tokio
/// runtime.
pub fn spawn_modbus_tap_line(
    settings: TapLineSettings,
    devices: Vec<DeviceSettings>,
    image: ProcessImage,
    shutdown: CancellationToken,
) -> LineHandle {
    spawn_on(settings, devices, image, shutdown, SerialOpener)
}

/// [`spawn_modbus_tap_line`] on the ports `opener` opens.
pub(crate) fn spawn_on<O: PortOpener>(
    settings: TapLineSettings,
    devices: Vec<DeviceSettings>,
    image: ProcessImage,
    shutdown: CancellationToken,
    opener: O,
) -> LineHandle {
    let devices: Vec<Arc<DeviceSettings>> = devices.into_iter().map(Arc::new).collect();
    let base = LineBase::new(
        &settings.name,
        TAP_PROTOCOL,
        &settings.port,
        settings.diag_depth,
        (settings.reopen_min, settings.reopen_max),
        settings.metrics.as_ref(),
    );
    let core = base.core(
        devices
            .iter()
            .map(|d| DeviceStatus::new(&d.name, d.slave, d.unit_id))
            .collect(),
    );
    let shared = Arc::clone(&core.shared);
    for device in &devices {
        shared.metrics().init_device(&device.name);
    }
    shared
        .metrics()
        .init_frames_discarded(&proto_core::modbus::tap::DISCARD_REASONS);
    let caps = TapCapabilities {
        shared: Arc::clone(&shared),
        devices: devices.clone(),
        image: image.clone(),
    };
    let engine = TapLine {
        tap: Tap::new(settings.tap),
        missing_in_row: vec![0; devices.len()],
        heard: vec![false; devices.len()],
        settings,
        devices,
        image,
        shared,
    };
    runtime::spawn(core, engine, None, Arc::new(caps), opener, shutdown)
}

/// What a tap line offers: its devices as read-only Modbus TCP units.
#[derive(Debug)]
struct TapCapabilities {
    shared: Arc<Shared>,
    devices: Vec<Arc<DeviceSettings>>,
    image: ProcessImage,
}

impl LineCapabilities for TapCapabilities {
    fn units(&self) -> Vec<(u8, Arc<dyn UnitService>)> {
        self.devices
            .iter()
            .enumerate()
            .map(|(index, device)| {
                let unit = TapUnit {
                    device: Arc::clone(device),
                    index,
                    shared: Arc::clone(&self.shared),
                    image: self.image.clone(),
                };
                (device.unit_id, Arc::new(unit) as Arc<dyn UnitService>)
            })
            .collect()
    }

    /// Frames and bytes received; the requests seen with an answer count as answered, those
    /// without as failed (the tap sends nothing).
    fn traffic(&self) -> Option<LineTraffic> {
        let mut traffic = self.shared.metrics().traffic();
        self.shared.update(|s| {
            traffic.commands_answered = s.commands_answered;
            traffic.commands_failed = s.commands_failed;
        });
        Some(traffic)
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

/// What a tap line adds to every line.
impl LineHandle {
    /// Whether the line only listens (a `modbus-rtu-tap` line): its units refuse writes.
    pub fn is_tap(&self) -> bool {
        self.capability::<TapCapabilities>().is_some()
    }
}

/// A tapped device as a Modbus TCP unit: reads from the image, no writes.
#[derive(Debug)]
struct TapUnit {
    device: Arc<DeviceSettings>,
    index: usize,
    shared: Arc<Shared>,
    image: ProcessImage,
}

// === impl TapUnit ===

impl TapUnit {
    /// The answer to `request`: a read of values the bus showed while they are fresh and the
    /// device answers; 0x0B for values not seen (yet) or stale (the tap cannot ask the device);
    /// 01 for every other function, writes above all.
    fn answer(&self, request: &Request, out: &mut Vec<u8>) -> Result<(), ExceptionCode> {
        let Some((table, address, quantity)) = request.read_range() else {
            return Err(ExceptionCode::IllegalFunction);
        };
        let online = self.shared.device_online(self.index);
        let mark = out.len();
        out.push(request.function().0);
        let read = self
            .image
            .encode_read(self.device.unit_id, table, address, quantity, out);
        let result = match read {
            Ok(quality) if online && quality.is_live() => return Ok(()),
            Err(ImageError::InvalidRange { .. }) => Err(ExceptionCode::IllegalDataAddress),
            _ => Err(ExceptionCode::GatewayTargetFailedToRespond),
        };
        out.truncate(mark);
        result
    }
}

impl UnitService for TapUnit {
    fn answer_now(
        &self,
        request: &Request,
        out: &mut Vec<u8>,
    ) -> Option<Result<(), ExceptionCode>> {
        Some(self.answer(request, out))
    }

    fn call(&self, request: Request) -> UnitFuture {
        let mut pdu = Vec::new();
        let result = self.answer(&request, &mut pdu).and_then(|()| {
            Response::decode_for(&request, &pdu)
                .ok()
                .and_then(Result::ok)
                .ok_or(ExceptionCode::ServerDeviceFailure)
        });
        Box::pin(std::future::ready(result))
    }

    fn listen_only(&self) -> bool {
        true
    }
}

/// The adapter of one tap line.
struct TapLine {
    settings: TapLineSettings,
    devices: Vec<Arc<DeviceSettings>>,
    /// Requests in a row without an answer, by device.
    missing_in_row: Vec<u32>,
    /// Whether each device has answered since the line started (its first answer is logged).
    heard: Vec<bool>,
    image: ProcessImage,
    shared: Arc<Shared>,
    tap: Tap,
}

impl LineEngine for TapLine {
    fn opened(&mut self, _modem: Option<&mut dyn SerialPort>) {
        self.tap = Tap::new(self.settings.tap);
    }

    fn handle_rx(&mut self, now: proto_core::time::Instant, bytes: &[u8]) {
        self.tap.handle_rx(now, bytes);
    }

    /// 003 7.2: a character with a parity or framing error or an overrun is 08 0Ch, a BREAK
    /// 08 0Dh; the frame it hits is discarded by the tap.
    fn handle_line_error(&mut self, now: proto_core::time::Instant, error: LineError) {
        self.shared.raise(error.event(), None, None);
        self.tap.handle_line_error(now, error);
    }

    crate::line::driver::engine_calls!(tap: timeout);

    /// Never anything: the tap only listens.
    fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        None
    }

    fn transmitted(&mut self, _written: Instant, _len: usize, _end: proto_core::time::Instant) {}

    fn handle_events(&mut self) -> bool {
        while let Some(event) = self.tap.poll_event() {
            match event {
                TapEvent::Frame { .. } => self.shared.metrics().received_telegram(),
                TapEvent::Discarded { reason, len } => {
                    tracing::debug!(line = %self.settings.name, ?reason, len, "frame discarded");
                    self.shared.metrics().frame_discarded(reason);
                }
                TapEvent::Exchange(exchange) => self.exchange(exchange),
            }
        }
        false
    }
}

impl LineCommands for TapLine {
    /// A tap takes no commands.
    type Command = ();

    fn command(&mut self, (): (), _modem: Option<&mut dyn SerialPort>) {}

    fn refuse(&mut self, (): (), _shutting_down: bool) {}
}

impl LineLifecycle for TapLine {
    /// Nothing to finish: the line stops at once.
    fn stop(&mut self) -> Stop {
        Stop::AT_ONCE
    }

    fn done(&self) -> bool {
        true
    }

    fn closed(&mut self, _shutting_down: bool) {}

    /// The port failed: event, status, and every device's values marked as comm failure.
    fn port_failed(&mut self, id: EventId, reason: String) {
        self.shared.raise(id, None, Some(reason));
        for device in &self.devices {
            self.image
                .set_unit_quality(device.unit_id, Quality::CommFailure);
            self.shared.metrics().device_up(&device.name, false);
        }
    }

    /// The monitor cuts the bus traffic as the tap does (t3.5 of silence, 003 6.4.3) and tells
    /// requests from answers by their shape.
    fn monitor_framing(&self) -> MonitorFraming {
        MonitorFraming {
            kind: FrameKind::ModbusRtu(Role::Listener),
            gap: Some(self.settings.tap.timing.t3_5()),
        }
    }
}

impl LineSignals for TapLine {}

impl SecondPort for TapLine {}

// === impl TapLine ===

impl TapLine {
    /// A request seen on the bus with its answer (or without).
    fn exchange(&mut self, exchange: Exchange) {
        let Exchange {
            address,
            request,
            outcome,
        } = exchange;
        let function = request.function().0;
        let metrics = self.shared.metrics();
        if address == 0 {
            metrics.request(BROADCAST_DEVICE, function, RequestResult::Ok);
            return;
        }
        let result = match &outcome {
            Outcome::Answered(_) => RequestResult::Ok,
            Outcome::Exception(code) => RequestResult::Exception(*code),
            Outcome::Missing => RequestResult::Timeout,
            Outcome::Invalid(_) | Outcome::Broadcast => RequestResult::Error,
        };
        let answered = matches!(outcome, Outcome::Answered(_) | Outcome::Exception(_));
        self.shared.update(|s| {
            if answered {
                s.commands_answered += 1;
            } else {
                s.commands_failed += 1;
            }
        });
        let Some(index) = self.devices.iter().position(|d| d.slave == address) else {
            // Not listed: counted, not stored.
            metrics.request(UNKNOWN_DEVICE, function, result);
            return;
        };
        let Some(device) = self.devices.get(index).cloned() else {
            return;
        };
        metrics.request(&device.name, function, result);
        let unit = device.unit_id;
        match outcome {
            Outcome::Answered(blocks) => {
                let period = Some(self.settings.expected_cycle);
                for Block {
                    table,
                    start,
                    values,
                } in blocks
                {
                    match values {
                        Values::Bits(bits) => {
                            self.image.store_bits(unit, table, start, &bits, period);
                        }
                        Values::Words(words) => {
                            self.image.store_words(unit, table, start, &words, period);
                        }
                    }
                }
                metrics.image_updated(&device.name);
                self.heard(index, |d| d.polls_ok += 1);
            }
            Outcome::Exception(code) => {
                if let Some((table, start, count)) = request.read_range() {
                    tracing::debug!(line = %self.settings.name, device = %device.name, ?code, start, count, "read answered with an exception");
                    self.image
                        .set_quality(unit, table, start, count, Quality::Rejected);
                }
                self.heard(index, |d| {
                    d.polls_exception += 1;
                    d.last_exception = Some(u8::from(code));
                });
            }
            Outcome::Invalid(err) => {
                tracing::debug!(line = %self.settings.name, device = %device.name, %err, "answer does not fit its request");
                self.device_stat(index, |d| d.polls_failed += 1);
            }
            Outcome::Missing | Outcome::Broadcast => self.missing(index, &device),
        }
    }

    /// The device answered: online again, its counters.
    fn heard(&mut self, index: usize, count: impl FnOnce(&mut DeviceStatus)) {
        if let Some(n) = self.missing_in_row.get_mut(index) {
            *n = 0;
        }
        let was_online = self.shared.device_online(index);
        self.device_stat(index, |d| {
            count(d);
            d.online = true;
            d.last_answer = Some(SystemTime::now());
        });
        if let Some(device) = self.devices.get(index) {
            self.shared.metrics().device_up(&device.name, true);
            let first = self
                .heard
                .get_mut(index)
                .is_some_and(|h| !std::mem::replace(h, true));
            if first {
                tracing::info!(line = %self.settings.name, device = %device.name, slave = device.slave, unit_id = device.unit_id, "device answers");
            } else if !was_online {
                tracing::info!(line = %self.settings.name, device = %device.name, slave = device.slave, unit_id = device.unit_id, "device answers again");
            }
        }
    }

    /// A request to the device got no answer: after the device's `offline_after` in a row it is
    /// offline and its values comm failures.
    fn missing(&mut self, index: usize, device: &DeviceSettings) {
        self.device_stat(index, |d| d.polls_failed += 1);
        let Some(n) = self.missing_in_row.get_mut(index) else {
            return;
        };
        *n = n.saturating_add(1);
        if *n == device.offline_after.max(1) {
            tracing::warn!(line = %self.settings.name, device = %device.name, slave = device.slave, "device offline: its requests go unanswered");
            self.shared
                .raise(ids::MODBUS_NO_REPLY, Some(device.slave), None);
            self.image
                .set_unit_quality(device.unit_id, Quality::CommFailure);
            self.device_stat(index, |d| d.online = false);
            self.shared.metrics().device_up(&device.name, false);
        }
    }

    fn device_stat(&self, index: usize, f: impl FnOnce(&mut DeviceStatus)) {
        self.shared.update(|s| {
            if let Some(d) = s.devices.get_mut(index) {
                f(d);
            }
        });
    }
}

mod build;
pub(crate) mod config;
#[cfg(test)]
mod tests;
