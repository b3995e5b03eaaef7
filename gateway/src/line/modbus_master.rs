//! The Modbus master line task: owns the port and a [`Master`], polls the devices on schedule,
//! keeps the image, carries commands, and reopens the port with back-off when it fails.
//!
//! The driver loop (STYLE "serial/driver.rs"): start the next job when the master is idle, write
//! what the master transmits and tell it the estimated end of transmission, hand its events to the
//! image and the status, then wait for bytes, the master's deadline, the next poll, a command or
//! shutdown. On shutdown the request in flight is finished first (STYLE habit 9).

use std::sync::Arc;
use std::time::SystemTime;

use proto_core::event::{ids, EventId};
use proto_core::modbus::master::{Attempts, Master, MasterEvent, Outcome, RequestId};
use proto_core::modbus::pdu::{Request, Response};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::mpsc;
use tokio::time::Instant;
use tokio_serial::SerialStream;
use tokio_util::sync::CancellationToken;

use super::command::{Command, CommandError, CommandResult};
use super::driver::{estimated_tx_end, sleep_until_opt, Clock};
use super::line_metrics::{master_result, BROADCAST_DEVICE, UNKNOWN_DEVICE};
use super::registers32;
use super::scheduler::{Job, PollJob, Scheduler, Transition};
use super::status::Shared;
use super::writeback::{broadcast_echo, refresh_image};
use super::{DeviceSettings, LineSettings};
use crate::image::{ProcessImage, Quality, Table};
use crate::metrics::RequestResult;
use crate::serial::{self, Backoff};
use crate::timer::LineTimer;

/// The port could not be opened or set up: 003 7.2 event 02 0Fh "Interface could not be
/// parameterized" (also for RS485 mode refused by the driver).
pub const EVENT_PORT_SETUP: EventId = ids::INVALID_PARAMETERIZATION;
/// The open port failed (read or write error, end of file: the device node vanished): 003 7.2
/// event 08 0Dh "BREAK: receive line to partner is interrupted".
pub const EVENT_PORT_LOST: EventId = ids::LINE_BREAK;

/// What is in flight on the line.
#[derive(Debug)]
enum InFlight {
    Poll(PollJob),
    Command {
        device: Option<usize>,
        command: Command,
    },
}

/// Why the driver loop ended.
#[derive(Debug)]
enum PortExit {
    Shutdown,
    Lost(String),
}

/// The task of one Modbus master line.
pub(crate) struct LineTask {
    pub(crate) settings: LineSettings,
    pub(crate) devices: Vec<Arc<DeviceSettings>>,
    pub(crate) image: ProcessImage,
    pub(crate) shared: Arc<Shared>,
    pub(crate) commands: mpsc::Receiver<Command>,
    pub(crate) shutdown: CancellationToken,
    pub(crate) clock: Clock,
    pub(crate) sched: Scheduler<Command>,
    inflight: Option<(RequestId, InFlight)>,
    /// When the first frame of the request in flight was written (the poll duration's start).
    sent_at: Option<Instant>,
    commands_open: bool,
}

// === impl LineTask ===

impl LineTask {
    pub(crate) fn new(
        settings: LineSettings,
        devices: Vec<Arc<DeviceSettings>>,
        image: ProcessImage,
        shared: Arc<Shared>,
        commands: mpsc::Receiver<Command>,
        shutdown: CancellationToken,
        clock: Clock,
    ) -> Self {
        let devices = registers32::line_devices(&settings.master, devices);
        let sched = Scheduler::new(devices.iter().map(|d| &**d), clock.base());
        Self {
            settings,
            devices,
            image,
            shared,
            commands,
            shutdown,
            clock,
            sched,
            inflight: None,
            sent_at: None,
            commands_open: true,
        }
    }

    /// Opens the port, drives it until it fails, reopens with back-off; until shutdown.
    pub(crate) async fn run(mut self) {
        let mut reopen = Backoff::clamped(self.settings.reopen_min, self.settings.reopen_max);
        loop {
            match serial::open(&self.settings.port) {
                Ok(port) => {
                    reopen.reset();
                    tracing::info!(line = %self.settings.name, path = %self.settings.port.path, "port open");
                    self.shared.started();
                    let exit = self.drive(port).await;
                    self.shared.port_closed();
                    self.abandon_inflight();
                    match exit {
                        PortExit::Shutdown => break,
                        PortExit::Lost(reason) => self.port_failed(EVENT_PORT_LOST, reason),
                    }
                }
                Err(err) => self.port_failed(EVENT_PORT_SETUP, err.to_string()),
            }
            let delay = reopen.next_delay();
            tracing::info!(line = %self.settings.name, ?delay, "reopening the port after back-off");
            if !self.wait_closed(delay).await {
                break;
            }
        }
        for command in self.sched.drain_commands() {
            command.answer(Err(CommandError::ShuttingDown));
        }
        self.commands.close();
        while let Some(command) = self.commands.recv().await {
            command.answer(Err(CommandError::ShuttingDown));
        }
        tracing::info!(line = %self.settings.name, "line stopped");
    }

    /// The port closed with a request in flight: counted as an error, a command answered.
    fn abandon_inflight(&mut self) {
        self.sent_at = None;
        let Some((_, job)) = self.inflight.take() else {
            return;
        };
        let (device, slave, function) = match &job {
            InFlight::Poll(poll) => (Some(poll.device), None, poll.read.request().function()),
            InFlight::Command { device, command } => {
                (*device, Some(command.slave), command.request.function())
            }
        };
        self.shared.metrics().request(
            self.device_label(device, slave),
            function.0,
            RequestResult::Error,
        );
        if let InFlight::Command { command, .. } = job {
            command.answer(Err(CommandError::PortClosed));
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

    /// The port failed: event, status, and every device's values marked as comm failure.
    fn port_failed(&mut self, id: EventId, reason: String) {
        self.shared.update(|s| s.port_error = Some(reason.clone()));
        self.shared.raise(id, None, Some(reason));
        for device in &self.devices {
            self.image
                .set_unit_quality(device.unit_id, Quality::CommFailure);
            self.shared.metrics().device_up(&device.name, false);
        }
    }

    /// Waits `delay` with the port closed, answering commands at once. False on shutdown.
    async fn wait_closed(&mut self, delay: std::time::Duration) -> bool {
        for command in self.sched.drain_commands() {
            command.answer(Err(CommandError::PortClosed));
        }
        let until = Instant::now() + delay;
        loop {
            tokio::select! {
                biased;
                () = self.shutdown.cancelled() => return false,
                () = tokio::time::sleep_until(until) => return true,
                command = self.commands.recv(), if self.commands_open => match command {
                    Some(command) => command.answer(Err(CommandError::PortClosed)),
                    None => self.commands_open = false,
                },
            }
        }
    }

    /// The driver loop on an open port.
    async fn drive(&mut self, mut port: SerialStream) -> PortExit {
        let mut master = Master::new(self.settings.master);
        let char_time = self.settings.port.char_time();
        // The master's deadlines are fractions of a millisecond apart: the t3.5 gap before each
        // request (003 6.4.3), the end of a reply by t3.5 of silence, the turnaround after a
        // broadcast (003 6.4.2.2). tokio's millisecond timer would add 1.2 ms to each.
        let mut timer = LineTimer::new();
        let mut stopping = false;
        let mut buf = [0u8; 512];
        loop {
            let (now, engine_now) = self.clock.now();
            // A deadline already passed is handled without sleeping (quinn drive_timer).
            if master
                .poll_timeout()
                .is_some_and(|t| self.clock.to_tokio(t) <= now)
            {
                master.handle_timeout(engine_now);
            }
            if self.inflight.is_none() && master.is_idle() {
                if stopping {
                    return PortExit::Shutdown;
                }
                self.start_next(&mut master, now);
            }
            while let Some(frame) = master.poll_transmit() {
                if let Err(err) = port.write_all(&frame).await {
                    return PortExit::Lost(format!(
                        "write to {} failed: {err}",
                        self.settings.port.path
                    ));
                }
                let written = Instant::now();
                self.sent_at.get_or_insert(written);
                self.shared.metrics().sent(frame.len());
                let end = estimated_tx_end(written, frame.len(), char_time);
                master.handle_tx_done(self.clock.to_engine(end));
            }
            let mut completed = false;
            while let Some(event) = master.poll_event() {
                let (event, function32) = registers32::as_16bit(event);
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
                                let delay = master.reply_delay();
                                let function = function32.unwrap_or(request.function().0);
                                self.complete(job, slave, &request, function, outcome, delay);
                            }
                            other => {
                                tracing::error!(line = %self.settings.name, slave, "completion of a request not in flight");
                                self.inflight = other;
                            }
                        }
                    }
                    // Turned into `Completed` by `registers32::as_16bit` above.
                    MasterEvent::Completed32 { slave, .. } => {
                        tracing::error!(line = %self.settings.name, slave, "completion of a 32-bit job not converted");
                    }
                }
            }
            if completed {
                continue; // start the next job at once
            }

            let master_deadline = master.poll_timeout().map(|t| self.clock.to_tokio(t));
            let idle = self.inflight.is_none() && master.is_idle() && !stopping;
            let poll_deadline = if idle { self.sched.next_wake() } else { None };
            tokio::select! {
                biased;
                () = self.shutdown.cancelled(), if !stopping => {
                    stopping = true;
                    for command in self.sched.drain_commands() {
                        command.answer(Err(CommandError::ShuttingDown));
                    }
                }
                read = port.read(&mut buf) => match read {
                    Ok(0) => return PortExit::Lost(format!("{} reached end of file", self.settings.port.path)),
                    Ok(n) => {
                        let (_, engine_now) = self.clock.now();
                        self.shared.metrics().received_bytes(n);
                        master.handle_rx(engine_now, buf.get(..n).unwrap_or_default());
                    }
                    Err(err) => return PortExit::Lost(format!("read from {} failed: {err}", self.settings.port.path)),
                },
                () = timer.sleep_until_opt(master_deadline) => {
                    let (_, engine_now) = self.clock.now();
                    master.handle_timeout(engine_now);
                }
                () = sleep_until_opt(poll_deadline) => {}
                command = self.commands.recv(), if self.commands_open && !stopping => match command {
                    Some(command) if command.is_write() => self.sched.push_write(command),
                    Some(command) => self.sched.push_read(command),
                    None => self.commands_open = false,
                },
            }
        }
    }

    /// Submits the next job to the idle master; answers commands that cannot be sent.
    fn start_next(&mut self, master: &mut Master, now: Instant) {
        let engine_now = self.clock.to_engine(now);
        while let Some(job) = self.sched.next_job(now) {
            match job {
                Job::Command(command) => {
                    let device = self.sched.device_index(command.slave);
                    if device.is_some_and(|d| !self.sched.accepts_commands(d, now)) {
                        let slave = command.slave;
                        command.answer(Err(CommandError::Offline(slave)));
                        continue;
                    }
                    let registers32 = registers32::enabled(&self.settings.master);
                    let request = command.request.clone();
                    let attempts = Attempts::default();
                    match registers32::submit(
                        master,
                        registers32,
                        engine_now,
                        command.slave,
                        request,
                        attempts,
                    ) {
                        Ok(id) => {
                            self.sent_at = None;
                            self.inflight = Some((id, InFlight::Command { device, command }));
                            return;
                        }
                        Err(err) => command.answer(Err(CommandError::Refused(err.to_string()))),
                    }
                }
                Job::Poll(poll) => {
                    let Some(device) = self.devices.get(poll.device) else {
                        continue;
                    };
                    // A probe of an offline device is one attempt with its own wait (`probe`).
                    let attempts = self.sched.poll_attempts(poll.device, &self.settings.master);
                    let request = poll.read.request();
                    let registers32 = registers32::enabled(&self.settings.master);
                    match registers32::submit(
                        master,
                        registers32,
                        engine_now,
                        device.slave,
                        request,
                        attempts,
                    ) {
                        Ok(id) => {
                            self.sent_at = None;
                            self.inflight = Some((id, InFlight::Poll(poll)));
                            return;
                        }
                        Err(err) => {
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
    }

    /// Handles the end of the request in flight, counted under `function` (the request's, or
    /// 43h/46h/50h for a 32-bit register job); `reply_delay` is the master's, from the end of the
    /// request to the first byte of the answer.
    fn complete(
        &mut self,
        job: InFlight,
        slave: u8,
        request: &Request,
        function: u8,
        outcome: Outcome,
        reply_delay: Option<std::time::Duration>,
    ) {
        let now = Instant::now();
        let duration = self
            .sent_at
            .take()
            .map(|sent| now.saturating_duration_since(sent));
        let result = master_result(&outcome);
        if matches!(outcome, Outcome::Response(_) | Outcome::Exception(_)) {
            self.shared.metrics().received_telegram();
        }
        // A garbled answer may be a late reply to a short probe that ran into this request.
        if matches!(outcome, Outcome::Failed(event) if event != ids::MODBUS_NO_REPLY) {
            self.sched.unexpected_reply(now);
        }
        let index = match &job {
            InFlight::Poll(poll) => Some(poll.device),
            InFlight::Command { device, .. } => *device,
        };
        self.shared
            .metrics()
            .request(self.device_label(index, Some(slave)), function, result);
        match job {
            InFlight::Poll(poll) => {
                let Some(device) = self.devices.get(poll.device).cloned() else {
                    return;
                };
                if let Some(duration) = duration {
                    self.shared.metrics().poll_duration(&device.name, duration);
                }
                let range = poll.read.range;
                let answered = match outcome {
                    Outcome::Response(response) => {
                        self.store_poll(&device, &poll, response);
                        self.device_stat(poll.device, |d| d.polls_ok += 1);
                        true
                    }
                    Outcome::Exception(code) => {
                        tracing::debug!(line = %self.settings.name, device = %device.name, ?code, ?range, "poll answered with an exception");
                        self.image.set_quality(
                            device.unit_id,
                            poll.read.table,
                            range.start,
                            range.count,
                            Quality::Rejected,
                        );
                        self.device_stat(poll.device, |d| d.polls_exception += 1);
                        true
                    }
                    Outcome::Broadcast => true,
                    Outcome::Failed(_) => {
                        self.device_stat(poll.device, |d| d.polls_failed += 1);
                        false
                    }
                };
                if answered {
                    self.shared.metrics().device_up(&device.name, true);
                    self.sched.heard(poll.device, reply_delay);
                }
                let transition = self.sched.poll_done(poll, answered, now);
                self.apply(poll.device, transition);
            }
            InFlight::Command { device, command } => {
                let result: CommandResult = match outcome {
                    Outcome::Response(response) => {
                        if let Some(d) = device.and_then(|d| self.devices.get(d)) {
                            refresh_image(&self.image, d.unit_id, request, &response);
                        }
                        Ok(Ok(response))
                    }
                    Outcome::Exception(code) => Ok(Err(code)),
                    Outcome::Broadcast => broadcast_echo(request)
                        .map(Ok)
                        .ok_or_else(|| CommandError::Refused("broadcast of a read".into())),
                    Outcome::Failed(event) => Err(CommandError::NoReply { slave, event }),
                };
                let answered = !matches!(result, Err(CommandError::NoReply { .. }));
                if let Some(d) = device
                    .and_then(|d| self.devices.get(d))
                    .filter(|_| answered)
                {
                    self.shared.metrics().device_up(&d.name, true);
                }
                self.shared.update(|s| {
                    if answered {
                        s.commands_answered += 1;
                    } else {
                        s.commands_failed += 1;
                    }
                });
                if let Some(d) = device {
                    if answered {
                        self.device_stat(d, |s| s.last_answer = Some(SystemTime::now()));
                        self.sched.heard(d, reply_delay);
                    }
                    let transition = self.sched.observe(d, answered, now);
                    self.apply(d, transition);
                }
                command.answer(result);
            }
        }
    }

    fn device_stat(&self, index: usize, f: impl FnOnce(&mut super::status::DeviceStatus)) {
        self.shared.update(|s| {
            if let Some(d) = s.devices.get_mut(index) {
                f(d);
            }
        });
    }

    /// Stores a poll's answer in the image.
    fn store_poll(&self, device: &DeviceSettings, poll: &PollJob, response: Response) {
        let unit = device.unit_id;
        let ReadBlockParts {
            table,
            start,
            count,
            period,
        } = ReadBlockParts::of(poll);
        self.device_stat(poll.device, |d| d.last_answer = Some(SystemTime::now()));
        match (table, response) {
            (Table::Coils, Response::ReadCoils(bits))
            | (Table::DiscreteInputs, Response::ReadDiscreteInputs(bits)) => {
                self.image.store_bits(
                    unit,
                    table,
                    start,
                    bits.get(..count).unwrap_or(&bits),
                    Some(period),
                );
                self.shared.metrics().image_updated(&device.name);
            }
            (Table::HoldingRegisters, Response::ReadHoldingRegisters(words))
            | (Table::InputRegisters, Response::ReadInputRegisters(words)) => {
                self.image.store_words(
                    unit,
                    table,
                    start,
                    words.get(..count).unwrap_or(&words),
                    Some(period),
                );
                self.shared.metrics().image_updated(&device.name);
            }
            (_, other) => {
                tracing::error!(line = %self.settings.name, device = %device.name, ?other, "poll answered with another function");
                self.image.set_quality(
                    unit,
                    table,
                    start,
                    poll.read.range.count,
                    Quality::Rejected,
                );
            }
        }
    }

    /// Applies a device's state change to the image and the status.
    fn apply(&self, index: usize, transition: Transition) {
        let Some(device) = self.devices.get(index) else {
            return;
        };
        let line = &self.settings.name;
        match transition {
            Transition::Unchanged => {}
            Transition::WentOffline { retry_in } => {
                tracing::warn!(line = %line, device = %device.name, slave = device.slave, ?retry_in, "device offline");
                self.image
                    .set_unit_quality(device.unit_id, Quality::CommFailure);
                self.device_stat(index, |d| d.online = false);
                self.shared.metrics().device_up(&device.name, false);
            }
            Transition::StillOffline { retry_in } => {
                tracing::debug!(line = %line, device = %device.name, ?retry_in, "device still offline");
            }
            Transition::CameBack => {
                tracing::info!(line = %line, device = %device.name, slave = device.slave, "device answers again");
                self.device_stat(index, |d| d.online = true);
            }
        }
    }
}

/// The parts of a poll's read block.
struct ReadBlockParts {
    table: Table,
    start: u16,
    count: usize,
    period: std::time::Duration,
}

impl ReadBlockParts {
    fn of(poll: &PollJob) -> Self {
        let read = poll.read;
        Self {
            table: read.table,
            start: read.range.start,
            count: usize::from(read.range.count),
            period: read.period,
        }
    }
}
