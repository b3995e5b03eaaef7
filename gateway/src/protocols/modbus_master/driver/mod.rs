//! The Modbus master line: an adapter of the line runtime over a proto-core [`Master`] that polls
//! the devices on schedule, keeps the image and carries commands.
//!
//! The runtime owns the port; the adapter starts the next job when the master is idle (a due
//! write or on-demand read first, then the due polls, see `scheduler`), tells the master the
//! estimated end of each transmission, and hands its completions to the image and the status. On
//! shutdown the request in flight is finished first: the port is still read until the master is
//! idle, commands not yet started are answered "shutting down".

use std::sync::Arc;
use std::time::SystemTime;

use proto_core::event::{ids, EventId};
use proto_core::modbus::master::{
    Attempts, Framing, Master, MasterEvent, Outcome, RequestId, SubmitError,
};
use proto_core::modbus::pdu::{Request, Response};
use tokio::sync::mpsc;
use tokio::time::Instant;
use tokio_serial::SerialPort;
use tokio_util::sync::CancellationToken;

use super::command::{Command, CommandError, CommandResult, LineClient};
use super::device_unit::DeviceUnit;
use super::registers32;
use super::scanner::{ScanJob, Scanners};
use super::scheduler::{cycle_bound, Job, PollJob, ReadKey, Scheduler, Transition};
use super::transparent::{self, Forwarded, Gate, TransparentSettings};
use super::writeback::{broadcast_echo, refresh_image};
use super::{AddrRange, DeviceSettings, LineSettings};
use crate::image::{ProcessImage, Quality, Table};
use crate::line::driver::{sleep_until_opt, Clock};
use crate::line::metrics::{master_result, PollCycleKind, BROADCAST_DEVICE, UNKNOWN_DEVICE};
use crate::line::runtime::{
    self, LineBase, LineCapabilities, LineEngine, LineHandle, PortOpener, SerialOpener, Stop,
};
use crate::line::runtime::{LineCommands, LineLifecycle, LineSignals, SecondPort};
use crate::line::status::{DeviceStatus, PollCycle, Shared};
use crate::metrics::RequestResult;
use crate::unit::UnitService;

/// What is in flight on the line.
#[derive(Debug)]
enum InFlight {
    /// A poll, with the on-demand reads it covers (answered from its answer).
    Poll(PollJob, Vec<Command>),
    /// A communication scanner request (`scanner`).
    Scan(ScanJob),
    Command {
        device: Option<usize>,
        command: Command,
    },
}

// === impl InFlight ===

impl InFlight {
    /// The kind of job, for the request's DEBUG line.
    const fn kind(&self) -> &'static str {
        match self {
            Self::Poll(..) => "poll",
            Self::Scan(_) => "scan",
            Self::Command { .. } => "command",
        }
    }

    /// The master refused the job's request: a command is answered with the refusal (a poll and
    /// a scan are the caller's to postpone).
    fn refused(self, err: &SubmitError) {
        if let Self::Command { command, .. } = self {
            command.answer(Err(CommandError::Refused(err.to_string())));
        }
    }
}

/// How a job's request ended, for the completion of its kind.
struct Done<'a> {
    /// The slave it went to.
    slave: u8,
    /// The request as sent (16-bit registers).
    request: &'a Request,
    /// The answer, exception or failure.
    outcome: Outcome,
    /// The master's reply delay (end of request to the answer's first byte).
    reply_delay: Option<std::time::Duration>,
    /// When it ended.
    now: Instant,
}

/// Starts a Modbus master line: opens its port (reopening with back-off), polls `devices` into
/// `image`, and serves commands until `shutdown` is cancelled. Must be called within a tokio
/// runtime.
pub fn spawn_modbus_master_line(
    settings: LineSettings,
    devices: Vec<DeviceSettings>,
    image: ProcessImage,
    shutdown: CancellationToken,
) -> LineHandle {
    spawn_on(settings, devices, image, shutdown, SerialOpener)
}

/// [`spawn_modbus_master_line`] on the ports `opener` opens.
fn spawn_on<O: PortOpener>(
    settings: LineSettings,
    devices: Vec<DeviceSettings>,
    image: ProcessImage,
    shutdown: CancellationToken,
    opener: O,
) -> LineHandle {
    let depth = settings.queue_depth.max(1);
    let (tx, rx) = mpsc::channel(depth);
    let devices: Vec<Arc<DeviceSettings>> = devices.into_iter().map(Arc::new).collect();
    let base = LineBase::new(
        &settings.name,
        settings.protocol(),
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
    let (shared, clock) = (Arc::clone(&core.shared), core.clock);
    for device in &devices {
        shared.metrics().init_device(&device.name);
    }
    let client = LineClient::new(tx, depth, settings.command_deadline());
    let caps = MasterCapabilities {
        client,
        shared: Arc::clone(&shared),
        devices: devices.clone(),
        image: image.clone(),
        transparent: settings.transparent.clone(),
    };
    let engine = MasterLine::new(settings, devices, image, shared, clock);
    runtime::spawn(core, engine, Some(rx), Arc::new(caps), opener, shutdown)
}

/// What a master line offers: its command queue and its devices as Modbus TCP units.
#[derive(Debug)]
struct MasterCapabilities {
    client: LineClient,
    shared: Arc<Shared>,
    devices: Vec<Arc<DeviceSettings>>,
    image: ProcessImage,
    /// Unit ids forwarded to the slave of the same address (`transparent`).
    transparent: Option<TransparentSettings>,
}

impl LineCapabilities for MasterCapabilities {
    fn units(&self) -> Vec<(u8, Arc<dyn UnitService>)> {
        self.device_units()
            .into_iter()
            .map(|(id, unit)| (id, Arc::new(unit) as Arc<dyn UnitService>))
            .collect()
    }

    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

// === impl MasterCapabilities ===

impl MasterCapabilities {
    fn device_units(&self) -> Vec<(u8, DeviceUnit)> {
        self.devices
            .iter()
            .enumerate()
            .map(|(index, device)| {
                let unit = DeviceUnit::new(
                    Arc::clone(device),
                    index,
                    Arc::clone(&self.shared),
                    self.client.clone(),
                    self.image.clone(),
                );
                (device.unit_id, unit)
            })
            .collect()
    }
}

/// What a Modbus master line adds to every line.
impl LineHandle {
    /// The command queue of a Modbus master line.
    pub fn client(&self) -> Option<LineClient> {
        self.capability::<MasterCapabilities>()
            .map(|c| c.client.clone())
    }

    /// Every device of a Modbus master line as a Modbus TCP unit, with its unit id.
    pub fn device_units(&self) -> Vec<(u8, DeviceUnit)> {
        self.capability::<MasterCapabilities>()
            .map(MasterCapabilities::device_units)
            .unwrap_or_default()
    }

    /// The unit ids a transparent Modbus master line forwards, each with its service; the unit
    /// map takes them only where no declared unit holds the id.
    pub fn transparent_units(&self) -> Vec<(u8, Arc<dyn UnitService>)> {
        self.capability::<MasterCapabilities>()
            .map(|c| transparent::units(c.transparent.as_ref(), &c.client))
            .unwrap_or_default()
    }

    /// The device named `name` of a Modbus master line as a Modbus TCP unit.
    pub fn device_unit(&self, name: &str) -> Option<DeviceUnit> {
        self.device_units()
            .into_iter()
            .map(|(_, u)| u)
            .find(|u| u.device().name == name)
    }
}

/// The adapter of one Modbus master line.
struct MasterLine {
    settings: LineSettings,
    devices: Vec<Arc<DeviceSettings>>,
    image: ProcessImage,
    shared: Arc<Shared>,
    clock: Clock,
    sched: Scheduler<Command>,
    /// The dead-device rules of the forwarded addresses (`transparent`).
    forwarded: Forwarded,
    scanners: Scanners,
    master: Master,
    inflight: Option<(RequestId, InFlight)>,
    /// When the first frame of the request in flight was written (the poll duration's start).
    sent_at: Option<Instant>,
    stopping: bool,
    /// Per device: whether it has answered since the line started (its first answer is logged).
    heard: Vec<bool>,
    /// Per device: since when it is offline (logged with its return).
    offline_since: Vec<Option<Instant>>,
}

impl LineEngine for MasterLine {
    fn opened(&mut self, _modem: Option<&mut dyn SerialPort>) {
        self.master = Master::new(self.settings.master);
        self.scanners.unprime_all();
    }

    crate::line::driver::engine_calls!(master: rx, timeout, tx);

    fn transmitted(&mut self, written: Instant, _len: usize, end: proto_core::time::Instant) {
        self.sent_at.get_or_insert(written);
        self.shared.metrics().sent_telegram();
        self.master.handle_tx_done(end);
    }

    fn handle_events(&mut self) -> bool {
        let mut completed = false;
        while let Some(event) = self.master.poll_event() {
            match event {
                // Slave 0: raised while the line was idle.
                MasterEvent::Raised { id, slave } => {
                    self.shared.raise(id, (slave != 0).then_some(slave), None);
                    if id == ids::MODBUS_BYTE_OVERFLOW {
                        self.sched.unexpected_reply(Instant::now());
                    }
                }
                MasterEvent::Completed {
                    id,
                    slave,
                    request,
                    outcome,
                } => {
                    completed = true;
                    match self.inflight.take() {
                        Some((expected, job)) if expected == id => {
                            let delay = self.master.reply_delay();
                            // A 32-bit register job counts under its own code (43h, 46h, 50h).
                            let function =
                                self.master.job_function().unwrap_or(request.function().0);
                            self.complete(job, slave, &request, function, outcome, delay);
                        }
                        other => {
                            tracing::error!(line = %self.settings.name, slave, "completion of a request not in flight");
                            self.inflight = other;
                        }
                    }
                }
                // The line never submits a bare 32-bit job (`submit_registers32`): on a line with
                // `registers32` the master completes the 16-bit request it was given.
                MasterEvent::Completed32 { slave, .. } => {
                    tracing::error!(line = %self.settings.name, slave, "completion of a 32-bit job not submitted by the line");
                }
            }
        }
        completed
    }
}

impl LineCommands for MasterLine {
    type Command = Command;

    fn start(&mut self, now: Instant) {
        if self.inflight.is_none() && self.master.is_idle() {
            self.start_next(now);
        }
    }

    fn command(&mut self, command: Command, _modem: Option<&mut dyn SerialPort>) {
        if command.is_write() {
            self.sched.push_write(command);
        } else {
            let key = self.read_key(&command);
            self.sched.push_read(command, key);
        }
    }

    fn refuse(&mut self, command: Command, shutting_down: bool) {
        command.answer(Err(if shutting_down {
            CommandError::ShuttingDown
        } else {
            CommandError::PortClosed
        }));
    }
}

impl LineLifecycle for MasterLine {
    fn stop(&mut self) -> Stop {
        self.stopping = true;
        for command in self.sched.drain_commands() {
            command.answer(Err(CommandError::ShuttingDown));
        }
        Stop {
            read: true,
            close_queue: false,
            grace: None,
        }
    }

    fn done(&self) -> bool {
        self.inflight.is_none() && self.master.is_idle()
    }

    fn closed(&mut self, shutting_down: bool) {
        self.abandon_inflight();
        for command in self.sched.drain_commands() {
            self.refuse(command, shutting_down);
        }
    }

    /// The port failed: event, status, and every device's values marked as comm failure.
    fn port_failed(&mut self, id: EventId, reason: String) {
        self.shared.raise(id, None, Some(reason));
        for device in &self.devices {
            self.image
                .set_unit_quality(device.unit_id, Quality::CommFailure);
            self.shared.metrics().device_up(&device.name, false);
        }
    }

    /// RTU: t3.5 of silence ends a frame (003 6.4.3, with the line's multiplier); ASCII: CR LF
    /// (003 6.4.2.2).
    fn monitor_framing(&self) -> proto_core::monitor::Framing {
        use proto_core::monitor::{FrameKind, Framing as MonitorFraming, Role};
        match self.settings.master.framing {
            Framing::Rtu { timing } => MonitorFraming {
                kind: FrameKind::ModbusRtu(Role::Master),
                gap: Some(timing.t3_5()),
            },
            Framing::Ascii { .. } => MonitorFraming {
                kind: FrameKind::ModbusAscii(Role::Master),
                gap: None,
            },
        }
    }
}

impl LineSignals for MasterLine {
    /// The next poll, while the line is idle.
    fn wake(&self) -> impl std::future::Future<Output = ()> + Send + '_ {
        let idle = self.inflight.is_none() && self.master.is_idle() && !self.stopping;
        let next = [self.sched.next_wake(), self.scanners.next_wake()]
            .into_iter()
            .flatten()
            .min();
        sleep_until_opt(if idle { next } else { None })
    }
}

impl SecondPort for MasterLine {}

// === impl MasterLine ===

impl MasterLine {
    fn new(
        settings: LineSettings,
        devices: Vec<Arc<DeviceSettings>>,
        image: ProcessImage,
        shared: Arc<Shared>,
        clock: Clock,
    ) -> Self {
        let devices = registers32::line_devices(&settings.master, devices);
        let sched = Scheduler::new(devices.iter().map(|d| &**d), clock.base())
            .with_commands_in_row(settings.commands_in_row);
        let scanners = Scanners::new(devices.iter().map(|d| &**d), clock.base());
        let forwarded = Forwarded::new(settings.transparent.clone());
        let master = Master::new(settings.master);
        let n = devices.len();
        let line = Self {
            settings,
            devices,
            image,
            shared,
            clock,
            sched,
            forwarded,
            scanners,
            master,
            inflight: None,
            sent_at: None,
            stopping: false,
            heard: vec![false; n],
            offline_since: vec![None; n],
        };
        line.publish_cycles();
        line
    }

    /// What an on-demand read of a configured device reads, so that a due poll covering it can
    /// answer it.
    fn read_key(&self, command: &Command) -> Option<ReadKey> {
        let device = self.sched.device_index(command.slave)?;
        let (table, address, quantity) = command.request.read_range()?;
        (quantity > 0).then_some(ReadKey {
            device,
            table,
            range: AddrRange::new(address, quantity),
        })
    }

    /// The longest one exchange can hold the line: every attempt waits the reply monitoring
    /// time after a request and a reply of the largest frame.
    fn longest_exchange(&self) -> std::time::Duration {
        let master = &self.settings.master;
        let max_chars: u32 = match master.framing {
            // 256 bytes an RTU frame, 513 characters an ASCII one (Modbus over Serial Line 2.5).
            Framing::Rtu { .. } => 256,
            Framing::Ascii { .. } => 513,
        };
        let port = &self.settings.port;
        let char_time =
            std::time::Duration::from_secs(u64::from(port.bits_per_char())) / port.baud.max(1);
        let attempt = master
            .reply_timeout
            .saturating_add(char_time.saturating_mul(2 * max_chars))
            .saturating_add(master.turnaround_delay);
        attempt.saturating_mul(u32::from(master.retries) + 1)
    }

    /// Puts the planned, bound and achieved cycles of every device into the status and the
    /// metrics.
    fn publish_cycles(&self) {
        let exchange = self.longest_exchange();
        let blocks = self.sched.blocks();
        for (index, device) in self.devices.iter().enumerate() {
            let cycles: Vec<PollCycle> = self
                .sched
                .cycles(index)
                .into_iter()
                .map(|c| PollCycle {
                    table: c.read.table,
                    start: c.read.range.start,
                    count: c.read.range.count,
                    planned: c.read.period,
                    bound: cycle_bound(
                        c.read.period,
                        blocks,
                        self.settings.commands_in_row,
                        exchange,
                    ),
                    achieved: c.last,
                    achieved_max: c.max,
                })
                .collect();
            let metrics = self.shared.metrics();
            // One series per period: the slowest block of that period.
            let mut periods: Vec<std::time::Duration> = cycles.iter().map(|c| c.planned).collect();
            periods.sort_unstable();
            periods.dedup();
            for period in periods {
                let of_period = || cycles.iter().filter(|c| c.planned == period);
                let bound = of_period().map(|c| c.bound).max().unwrap_or(period);
                metrics.poll_cycle(&device.name, period, PollCycleKind::Planned, period);
                metrics.poll_cycle(&device.name, period, PollCycleKind::Bound, bound);
                if let Some(last) = of_period().filter_map(|c| c.achieved).max() {
                    metrics.poll_cycle(&device.name, period, PollCycleKind::Achieved, last);
                }
                if let Some(max) = of_period().filter_map(|c| c.achieved_max).max() {
                    metrics.poll_cycle(&device.name, period, PollCycleKind::AchievedMax, max);
                }
            }
            self.device_stat(index, |d| d.cycles = cycles);
        }
    }

    /// Puts the cycle of one poll block into the status and the metrics after its poll.
    fn publish_cycle(&self, poll: &PollJob) {
        let Some(device) = self.devices.get(poll.device) else {
            return;
        };
        let Some(cycle) = self.sched.cycles(poll.device).get(poll.block).copied() else {
            return;
        };
        let metrics = self.shared.metrics();
        let period = cycle.read.period;
        if let Some(last) = cycle.last {
            metrics.poll_cycle(&device.name, period, PollCycleKind::Achieved, last);
        }
        self.device_stat(poll.device, |d| {
            if let Some(c) = d.cycles.get_mut(poll.block) {
                c.achieved = cycle.last;
                c.achieved_max = cycle.max;
            }
        });
        // The slowest block of the period is the series' maximum.
        let max = self
            .sched
            .cycles(poll.device)
            .iter()
            .filter(|c| c.read.period == period)
            .filter_map(|c| c.max)
            .max();
        if let Some(max) = max {
            metrics.poll_cycle(&device.name, period, PollCycleKind::AchievedMax, max);
        }
    }

    /// Hands `request` for `slave` to the master as `job`: in flight from now on success; the job
    /// and why back on refusal. `registers32`: whether the request may go as a 32-bit register
    /// job on a line with 32-bit registers (the master translates it; the scanner's words never
    /// do).
    fn submit(
        &mut self,
        now: Instant,
        slave: u8,
        request: Request,
        attempts: Attempts,
        registers32: bool,
        job: InFlight,
    ) -> Result<(), (InFlight, SubmitError)> {
        let span = Span::of(slave, &request, job.kind());
        let engine_now = self.clock.to_engine(now);
        let submitted = if registers32 {
            self.master
                .submit_with(engine_now, slave, request, attempts)
        } else {
            self.master
                .submit_plain(engine_now, slave, request, attempts)
        };
        match submitted {
            Ok(id) => {
                self.submitted(id, job, span);
                Ok(())
            }
            Err(err) => Err((job, err)),
        }
    }

    /// A job was handed to the master: in flight from now, its request logged (DEBUG).
    fn submitted(&mut self, id: RequestId, job: InFlight, span: Span) {
        tracing::debug!(
            line = %self.settings.name, slave = span.slave, function = span.function,
            address = span.address, count = span.count, job = %span.job, "request"
        );
        self.sent_at = None;
        self.inflight = Some((id, job));
    }

    /// The port closed with a request in flight: counted as an error, a command answered.
    fn abandon_inflight(&mut self) {
        self.sent_at = None;
        let Some((_, job)) = self.inflight.take() else {
            return;
        };
        let (device, slave, function) = match &job {
            InFlight::Poll(poll, _) => (Some(poll.device), None, poll.read.request().function()),
            InFlight::Scan(scan) => (Some(scan.device), None, scan.step.function()),
            InFlight::Command { device, command } => {
                (*device, Some(command.slave), command.request.function())
            }
        };
        self.shared.metrics().request(
            self.device_label(device, slave),
            function.0,
            RequestResult::Error,
        );
        match job {
            InFlight::Command { command, .. } => command.answer(Err(CommandError::PortClosed)),
            InFlight::Poll(_, riders) => {
                for rider in riders {
                    rider.answer(Err(CommandError::PortClosed));
                }
            }
            InFlight::Scan(_) => {}
        }
    }

    /// The `device` label of a request to the device at `index`, or to `slave` when no
    /// configured device has that address.
    fn device_label(&self, index: Option<usize>, slave: Option<u8>) -> &str {
        match (index.and_then(|i| self.devices.get(i)), slave) {
            (Some(device), _) => &device.name,
            (None, Some(0)) => BROADCAST_DEVICE,
            (None, _) => UNKNOWN_DEVICE,
        }
    }

    /// Submits the next job to the idle master; answers commands that cannot be sent.
    fn start_next(&mut self, now: Instant) {
        if !self.scanners.yields() && self.start_scan(now) {
            return;
        }
        self.scanners.started(false);
        while let Some(job) = self.sched.next_job(now) {
            match job {
                Job::Command(mut command) => {
                    let device = self.sched.device_index(command.slave);
                    if device.is_some_and(|d| !self.sched.accepts_commands(d, now)) {
                        let slave = command.slave;
                        command.answer(Err(CommandError::Offline(slave)));
                        continue;
                    }
                    // A forwarded address keeps the dead-device rules of its own.
                    let gate = device
                        .is_none()
                        .then(|| {
                            self.forwarded
                                .gate(command.slave, now, &self.settings.master)
                        })
                        .flatten();
                    if gate == Some(Gate::Offline) {
                        let slave = command.slave;
                        command.answer(Err(CommandError::Offline(slave)));
                        continue;
                    }
                    let registers32 = registers32::enabled(&self.settings.master);
                    if let (Some(update), true) = (command.mask, registers32) {
                        // The bit's register is half of a 32-bit register of the slave: the
                        // read-modify-write reads and writes the whole of it (003 6.4.4).
                        command.request = registers32::bit_update_read(update);
                    }
                    // An on-demand read of part of a 32-bit register reads the whole of it; the
                    // client gets what it asked for (`narrow`).
                    let request = match (registers32, command.mask) {
                        (true, None) => proto_core::modbus::master::widen_read(&command.request),
                        _ => None,
                    }
                    .unwrap_or_else(|| command.request.clone());
                    let slave = command.slave;
                    let attempts = match gate {
                        Some(Gate::Send(attempts)) => attempts,
                        _ => Attempts::default(),
                    };
                    let job = InFlight::Command { device, command };
                    match self.submit(now, slave, request, attempts, registers32, job) {
                        Ok(()) => return,
                        Err((job, err)) => job.refused(&err),
                    }
                }
                Job::Poll(poll) => {
                    let Some(device) = self.devices.get(poll.device).cloned() else {
                        continue;
                    };
                    // A probe of an offline device is one attempt with its own wait (`probe`).
                    let attempts = self.sched.poll_attempts(poll.device, &self.settings.master);
                    let request = poll.read.request();
                    let registers32 = registers32::enabled(&self.settings.master);
                    let slave = device.slave;
                    let job = InFlight::Poll(poll, Vec::new());
                    match self.submit(now, slave, request, attempts, registers32, job) {
                        Ok(()) => {
                            // The queued reads it covers ride on it, once it is sent.
                            if let Some((_, InFlight::Poll(poll, riders))) = &mut self.inflight {
                                *riders = self.sched.riders(poll);
                            }
                            return;
                        }
                        Err((job, err)) => {
                            let InFlight::Poll(poll, _) = job else {
                                continue;
                            };
                            tracing::error!(
                                line = %self.settings.name, device = %device.name, error = %err,
                                "poll refused by the master; check the device limits"
                            );
                            let range = poll.read.range;
                            self.image.set_quality(
                                device.unit_id,
                                poll.read.table,
                                range.start,
                                range.count,
                                Quality::Rejected,
                            );
                            self.sched.postpone(poll, now);
                        }
                    }
                }
            }
        }
        // Nothing else to do: the scanner need not wait for another turn.
        self.start_scan(now);
    }

    /// Submits the due communication scanner request, if any; whether one was started.
    fn start_scan(&mut self, now: Instant) -> bool {
        let sched = &self.sched;
        let Some(mut job) = self
            .scanners
            .next_job(now, |d| sched.accepts_commands(d, now))
        else {
            return false;
        };
        let Some(device) = self.devices.get(job.device) else {
            return false;
        };
        let Some(request) = self.scanners.request(&mut job, &self.image) else {
            return false;
        };
        let attempts = self.sched.poll_attempts(job.device, &self.settings.master);
        let (slave, device) = (device.slave, Arc::clone(device));
        // The scanner words are 16-bit registers: never sent as a 32-bit register job.
        match self.submit(now, slave, request, attempts, false, InFlight::Scan(job)) {
            Ok(()) => {
                self.scanners.started(true);
                true
            }
            Err((job, err)) => {
                let InFlight::Scan(job) = job else {
                    return false;
                };
                tracing::error!(
                    line = %self.settings.name, device = %device.name, error = %err,
                    "scanner request refused by the master; check the device limits"
                );
                self.scanners.postpone(job, now);
                false
            }
        }
    }
}

mod complete;
use complete::Span;

#[cfg(test)]
mod tests;
