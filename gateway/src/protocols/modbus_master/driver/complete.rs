//! The end of a request: its answer (or its failure) handed to the image, the device's status, the
//! waiting command or the scan, and the device's next state in the schedule.

use super::*;

impl MasterLine {
    /// Handles the end of the request in flight, counted under `function` (the request's, or
    /// 43h/46h/50h for a 32-bit register job); `reply_delay` is the master's, from the end of the
    /// request to the first byte of the answer.
    pub(super) fn complete(
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
            InFlight::Poll(poll, _) => Some(poll.device),
            InFlight::Scan(scan) => Some(scan.device),
            InFlight::Command { device, .. } => *device,
        };
        self.shared
            .metrics()
            .request(self.device_label(index, Some(slave)), function, result);
        let span = Span::of(slave, request, "");
        tracing::debug!(
            line = %self.settings.name,
            device = %self.device_label(index, Some(slave)),
            slave,
            function,
            address = span.address,
            count = span.count,
            result = %outcome_text(&outcome),
            time_ms = duration.map(|d| (d.as_secs_f64() * 10_000.0).round() / 10.0),
            "answer"
        );
        let done = Done {
            slave,
            request,
            outcome,
            reply_delay,
            now,
        };
        match job {
            InFlight::Scan(scan) => self.complete_scan(scan, done),
            InFlight::Poll(poll, riders) => self.complete_poll(poll, riders, done, duration),
            InFlight::Command { device, command } => self.complete_command(device, command, done),
        }
    }

    /// A communication scanner exchange ended: its words into the image, the device's state.
    pub(super) fn complete_scan(&mut self, scan: ScanJob, done: Done<'_>) {
        let Done {
            request,
            outcome,
            reply_delay,
            now,
            ..
        } = done;
        let answered = matches!(outcome, Outcome::Response(_) | Outcome::Exception(_));
        let exception = match &outcome {
            Outcome::Exception(code) => Some(u8::from(*code)),
            _ => None,
        };
        let response = match outcome {
            Outcome::Response(response) => Some(response),
            _ => None,
        };
        if let Some(device) = self.devices.get(scan.device).cloned() {
            if !answered {
                self.device_stat(scan.device, |d| d.polls_failed += 1);
            } else if response.is_none() {
                tracing::debug!(line = %self.settings.name, device = %device.name, ?request, "scanner request answered with an exception");
                self.device_stat(scan.device, |d| {
                    d.polls_exception += 1;
                    d.last_exception = exception.or(d.last_exception);
                });
            } else if self
                .scanners
                .done(scan, request, response.clone(), &self.image, now)
            {
                self.device_stat(scan.device, |d| {
                    d.polls_ok += 1;
                    d.last_answer = Some(SystemTime::now());
                });
                self.shared.metrics().image_updated(&device.name);
            } else {
                tracing::error!(line = %self.settings.name, device = %device.name, ?request, "scanner answer does not fit its request");
            }
            if response.is_none() {
                self.scanners.postpone(scan, now);
            }
            if answered {
                self.shared.metrics().device_up(&device.name, true);
                self.sched.heard(scan.device, reply_delay);
            }
        }
        let transition = self.sched.observe(scan.device, answered, now);
        self.apply(scan.device, answered, transition);
    }

    /// A poll ended: the reads riding on it answered, its answer into the image, the device's
    /// state; `duration` from its first frame written to its end.
    pub(super) fn complete_poll(
        &mut self,
        poll: PollJob,
        riders: Vec<Command>,
        done: Done<'_>,
        duration: Option<std::time::Duration>,
    ) {
        let Done {
            slave,
            outcome,
            reply_delay,
            now,
            ..
        } = done;
        for rider in riders {
            let answer = rider_answer(&poll, &rider.request, slave, &outcome);
            rider.answer(answer);
        }
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
                self.device_stat(poll.device, |d| {
                    d.polls_exception += 1;
                    d.last_exception = Some(u8::from(code));
                });
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
        self.publish_cycle(&poll);
        self.apply(poll.device, answered, transition);
    }

    /// A command ended: the write of a read-modify-write follows its read, anything else is
    /// answered to its client, the image refreshed after a confirmed write.
    pub(super) fn complete_command(
        &mut self,
        device: Option<usize>,
        command: Command,
        done: Done<'_>,
    ) {
        let command = match self.read_modify_write(device, command, &done) {
            Ok(()) => return,
            Err(command) => command,
        };
        let Done {
            slave,
            request,
            outcome,
            reply_delay,
            now,
        } = done;
        let result: CommandResult = match outcome {
            // The read of a read-modify-write answered, but not with one register: the
            // write is not made.
            Outcome::Response(_) if command.mask.is_some() => Err(CommandError::Refused(
                "the read of a read-modify-write did not return the register it asked for".into(),
            )),
            Outcome::Response(response) => {
                if let Some(d) = device.and_then(|d| self.devices.get(d)) {
                    refresh_image(&self.image, d.unit_id, request, &response);
                }
                Ok(Ok(proto_core::modbus::master::narrow(
                    &command.request,
                    request,
                    response,
                )))
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
            } else {
                self.device_stat(d, |s| s.commands_failed += 1);
            }
            // Only the device's own polls put it offline; a command without an answer
            // fails for its client alone.
            let transition = self.sched.command_done(d, answered, now);
            self.apply(d, answered, transition);
        } else {
            let transition = self.forwarded.done(slave, answered, reply_delay, now);
            transparent::log_transition(&self.settings.name, slave, transition);
        }
        command.answer(result);
    }

    /// The read of a read-modify-write answered with its register: the write follows at once,
    /// in the same job (sent, or refused to the client). The command back when it is not such
    /// a read.
    pub(super) fn read_modify_write(
        &mut self,
        device: Option<usize>,
        mut command: Command,
        done: &Done<'_>,
    ) -> Result<(), Command> {
        let registers32 = registers32::enabled(&self.settings.master);
        let write = match (command.mask, &done.outcome) {
            (Some(update), Outcome::Response(Response::ReadHoldingRegisters(words))) => {
                registers32::bit_update_write(update, words, registers32)
            }
            _ => None,
        };
        let Some(write) = write else {
            return Err(command);
        };
        command.mask = None;
        command.request = write.clone();
        let (slave, job) = (command.slave, InFlight::Command { device, command });
        if let Err((job, err)) = self.submit(
            done.now,
            slave,
            write,
            Attempts::default(),
            registers32,
            job,
        ) {
            job.refused(&err);
        }
        Ok(())
    }

    pub(super) fn device_stat(&self, index: usize, f: impl FnOnce(&mut DeviceStatus)) {
        self.shared.update(|s| {
            if let Some(d) = s.devices.get_mut(index) {
                f(d);
            }
        });
    }

    /// Stores a poll's answer in the image.
    pub(super) fn store_poll(&self, device: &DeviceSettings, poll: &PollJob, response: Response) {
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

    /// Applies a device's state change to the image and the status, and logs it: the device's
    /// first answer and its return after being offline at INFO, its going offline at WARN.
    pub(super) fn apply(&mut self, index: usize, answered: bool, transition: Transition) {
        if !matches!(transition, Transition::Unchanged) {
            self.scanners.unprime(index);
        }
        let Some(device) = self.devices.get(index) else {
            return;
        };
        let first = answered
            && self
                .heard
                .get_mut(index)
                .is_some_and(|h| !std::mem::replace(h, true));
        let line = &self.settings.name;
        match transition {
            Transition::Unchanged if first => {
                tracing::info!(line = %line, device = %device.name, slave = device.slave, unit_id = device.unit_id, "device answers");
            }
            Transition::Unchanged => {}
            Transition::WentOffline { retry_in } => {
                tracing::warn!(line = %line, device = %device.name, slave = device.slave, ?retry_in, "device offline");
                if let Some(since) = self.offline_since.get_mut(index) {
                    *since = Some(Instant::now());
                }
                self.image
                    .set_unit_quality(device.unit_id, Quality::CommFailure);
                self.device_stat(index, |d| d.online = false);
                self.shared.metrics().device_up(&device.name, false);
            }
            Transition::StillOffline { retry_in } => {
                tracing::debug!(line = %line, device = %device.name, ?retry_in, "device still offline");
            }
            Transition::CameBack => {
                let offline_for = self
                    .offline_since
                    .get_mut(index)
                    .and_then(Option::take)
                    .map(|since| format!("{:.1}s", since.elapsed().as_secs_f64()));
                let message = if first {
                    "device answers"
                } else {
                    "device answers again"
                };
                tracing::info!(line = %line, device = %device.name, slave = device.slave, unit_id = device.unit_id, offline_for, "{message}");
                self.device_stat(index, |d| d.online = true);
            }
        }
    }
}

/// A request as its DEBUG line shows it: slave, function, first address and count (none for a
/// function without them), and the kind of job (poll, command, scan).
#[derive(Debug, Clone, Copy)]
pub(super) struct Span {
    pub(super) slave: u8,
    pub(super) function: u8,
    pub(super) address: Option<u16>,
    pub(super) count: Option<u16>,
    pub(super) job: &'static str,
}

impl Span {
    pub(super) fn of(slave: u8, request: &Request, job: &'static str) -> Self {
        let len = |n: usize| Some(u16::try_from(n).unwrap_or(u16::MAX));
        let (address, count) = match request {
            Request::ReadCoils { address, quantity }
            | Request::ReadDiscreteInputs { address, quantity }
            | Request::ReadHoldingRegisters { address, quantity }
            | Request::ReadInputRegisters { address, quantity } => {
                (Some(*address), Some(*quantity))
            }
            Request::WriteSingleCoil { address, .. }
            | Request::WriteSingleRegister { address, .. } => (Some(*address), Some(1)),
            Request::WriteMultipleCoils { address, values } => (Some(*address), len(values.len())),
            Request::WriteMultipleRegisters { address, values } => {
                (Some(*address), len(values.len()))
            }
            Request::ReadWriteMultipleRegisters {
                read_address,
                read_quantity,
                ..
            } => (Some(*read_address), Some(*read_quantity)),
            _ => (None, None),
        };
        Self {
            slave,
            function: request.function().0,
            address,
            count,
            job,
        }
    }
}

/// The result of a master transaction for its DEBUG line: `ok`, the exception, or the event of
/// the failure (003 7.2: 08 30h no reply, 0E 5xh a reply that could not be used).
pub(super) fn outcome_text(outcome: &Outcome) -> String {
    match outcome {
        Outcome::Response(_) => "ok".to_owned(),
        Outcome::Broadcast => "broadcast sent".to_owned(),
        Outcome::Exception(code) => format!("exception {code}"),
        Outcome::Failed(id) if *id == ids::MODBUS_NO_REPLY => format!("no reply ({id})"),
        Outcome::Failed(id) => format!("failed ({id})"),
    }
}

/// The answer to an on-demand read that rode on `poll`: its part of the poll's answer, the
/// poll's exception, or the poll's failure.
pub(super) fn rider_answer(
    poll: &PollJob,
    request: &Request,
    slave: u8,
    outcome: &Outcome,
) -> CommandResult {
    let response = match outcome {
        Outcome::Response(response) => response,
        Outcome::Exception(code) => return Ok(Err(*code)),
        Outcome::Failed(event) => {
            return Err(CommandError::NoReply {
                slave,
                event: *event,
            })
        }
        Outcome::Broadcast => {
            return Err(CommandError::Refused("broadcast of a read".into()));
        }
    };
    let part = request.read_range().and_then(|(_, address, quantity)| {
        let from = usize::from(address.checked_sub(poll.read.range.start)?);
        let to = from.checked_add(usize::from(quantity))?;
        Some(match response {
            Response::ReadCoils(bits) => Response::ReadCoils(bits.get(from..to)?.to_vec()),
            Response::ReadDiscreteInputs(bits) => {
                Response::ReadDiscreteInputs(bits.get(from..to)?.to_vec())
            }
            Response::ReadHoldingRegisters(words) => {
                Response::ReadHoldingRegisters(words.get(from..to)?.to_vec())
            }
            Response::ReadInputRegisters(words) => {
                Response::ReadInputRegisters(words.get(from..to)?.to_vec())
            }
            _ => return None,
        })
    });
    part.map(Ok)
        .ok_or_else(|| CommandError::Refused("the poll's answer does not cover the read".into()))
}

/// The parts of a poll's read block.
pub(super) struct ReadBlockParts {
    table: Table,
    start: u16,
    count: usize,
    period: std::time::Duration,
}

impl ReadBlockParts {
    pub(super) fn of(poll: &PollJob) -> Self {
        let read = poll.read;
        Self {
            table: read.table,
            start: read.range.start,
            count: usize::from(read.range.count),
            period: read.period,
        }
    }
}
