//! The task of one line: opens the port, drives the engine on it, reopens with back-off.

use super::*;

/// Why the driver loop ended.
#[derive(Debug)]
pub(super) enum PortExit {
    Shutdown,
    Lost(String),
}

/// The task of one line.
pub(super) struct PortTask<E: LineEngine, O> {
    pub(super) base: LineBase,
    pub(super) shared: Arc<Shared>,
    pub(super) clock: Clock,
    pub(super) engine: E,
    /// The line's queue; `None` once closed and drained (or for a line without one).
    pub(super) commands: Option<mpsc::Receiver<E::Command>>,
    pub(super) opener: O,
    pub(super) shutdown: CancellationToken,
    /// What the line keeps of the port it reads (and writes).
    pub(super) first: Reader,
    /// The same of its second, receive-only port, if it has one.
    pub(super) second: Option<Reader>,
}

/// Which of a line's ports bytes came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Which {
    First,
    Second,
}

/// The receive side of one port of a line.
#[derive(Debug)]
pub(super) struct Reader {
    /// Undoes the tty layer's line error marks of the open port (reset on every opening).
    pub(super) marks: MarkDecoder,
    /// The open port's bytes carry no marks ([`LinePort::marks_line_errors`]): none are undone.
    pub(super) unmarked: bool,
    /// The UART's counters at the last look; `None` before the first look on this opening.
    pub(super) uart: Option<UartCounters>,
    /// The port has no UART counters (a pty): not asked again until it is reopened.
    pub(super) no_uart_counters: bool,
    /// Records the port's frames into the line's monitor (`None`: the monitor is off).
    pub(super) recorder: Option<Recorder>,
}

// === impl Reader ===

impl Reader {
    /// The port was (re)opened: nothing carries over.
    fn opened(&mut self) {
        self.marks.reset();
        self.no_uart_counters = false;
        self.uart = None;
        if let Some(recorder) = &mut self.recorder {
            recorder.opened();
        }
    }

    /// Ends the received frame in progress if its silence has passed at `now`.
    fn expire(&mut self, now: Instant) {
        if let Some(recorder) = &mut self.recorder {
            recorder.expire(now);
        }
    }

    /// When the received frame in progress ends by silence.
    fn frame_end(&self) -> Option<Instant> {
        self.recorder.as_ref().and_then(Recorder::deadline)
    }

    /// Characters lost to an overrun since the last look at the UART's counters (0 without
    /// counters; a port without them is not asked again).
    fn overruns<P: LinePort>(&mut self, port: &P, line: &str) -> u32 {
        if self.no_uart_counters {
            return 0;
        }
        match port.uart_counters() {
            Some(Ok(counters)) => self
                .uart
                .replace(counters)
                .map_or(0, |earlier| counters.lost_since(&earlier)),
            Some(Err(err)) => {
                tracing::debug!(line, %err, "no UART counters on this port");
                self.no_uart_counters = true;
                0
            }
            None => {
                self.no_uart_counters = true;
                0
            }
        }
    }
}

// === impl PortTask ===

impl<E: LineEngine, O: PortOpener> PortTask<E, O> {
    /// Opens the port, drives it until it fails, reopens with back-off; until shutdown.
    pub(super) async fn run(mut self) {
        let name = self.base.name.clone();
        let mut reopen = Backoff::clamped(self.base.reopen_min, self.base.reopen_max);
        loop {
            match self.open() {
                Ok((port, second)) => {
                    reopen.reset();
                    tracing::info!(line = %name, path = %self.base.port.path, second = self.base.second_port.as_deref(), protocol = self.base.protocol, "port open");
                    // 00 03h "parameter accepted": status, diag buffer, log, metrics.
                    self.shared.started();
                    let exit = self.drive(port, second).await;
                    self.shared.port_closed();
                    let shutting_down = matches!(exit, PortExit::Shutdown);
                    self.engine.closed(shutting_down);
                    match exit {
                        PortExit::Shutdown => break,
                        PortExit::Lost(reason) => self.port_failed(EVENT_PORT_LOST, reason),
                    }
                }
                Err(err) => self.port_failed(EVENT_PORT_SETUP, err),
            }
            let delay = reopen.next_delay();
            tracing::info!(line = %name, ?delay, "reopening the port after back-off");
            if !self.wait_closed(delay).await {
                break;
            }
        }
        if let Some(mut commands) = self.commands.take() {
            commands.close();
            while let Some(command) = commands.recv().await {
                self.engine.refuse(command, true);
            }
        }
        tracing::info!(line = %name, "line stopped");
    }

    /// Opens the line's port and its second port, if it has one: both or neither.
    fn open(&self) -> Result<(O::Port, Option<O::Port>), String> {
        let first = self.opener.open(&self.base.port)?;
        let Some(path) = &self.base.second_port else {
            return Ok((first, None));
        };
        let settings = PortSettings {
            path: path.clone(),
            ..self.base.port.clone()
        };
        let second = self
            .opener
            .open(&settings)
            .map_err(|err| format!("second port {path}: {err}"))?;
        Ok((first, Some(second)))
    }

    fn port_failed(&mut self, id: EventId, reason: String) {
        self.shared.update(|s| s.port_error = Some(reason.clone()));
        self.engine.port_failed(id, reason);
    }

    /// Waits `delay` with the port closed, refusing commands at once. False on shutdown.
    async fn wait_closed(&mut self, delay: Duration) -> bool {
        let until = Instant::now() + delay;
        loop {
            tokio::select! {
                biased;
                () = self.shutdown.cancelled() => return false,
                () = tokio::time::sleep_until(until) => return true,
                command = recv(&mut self.commands) => match command {
                    Some(command) => self.engine.refuse(command, false),
                    None => self.commands = None,
                },
            }
        }
    }

    /// Hands bytes read from a port to the engine: the one place where received bytes pass
    /// from the port to the protocol. The tty layer's marks are undone here: data to the engine's
    /// `handle_rx`, a faulty character or a BREAK to its `handle_line_error`, in stream order (a
    /// read without an `FF` byte goes to the engine as it is, without a copy). Bytes of the
    /// second port go to the engine's `*_second` hooks.
    fn receive(&mut self, which: Which, bytes: &[u8]) {
        let (at, now) = self.clock.now();
        let mut data = 0;
        let reader = match which {
            Which::First => &mut self.first,
            Which::Second => match &mut self.second {
                Some(second) => second,
                None => return,
            },
        };
        let plain = reader.unmarked.then_some(Piece::Data(bytes));
        let decoded = (!reader.unmarked).then(|| reader.marks.decode(bytes));
        for piece in plain.into_iter().chain(decoded.into_iter().flatten()) {
            match piece {
                Piece::Data(bytes) => {
                    data += bytes.len();
                    if let Some(recorder) = &mut reader.recorder {
                        recorder.received(at, bytes);
                    }
                    match which {
                        Which::First => self.engine.handle_rx(now, bytes),
                        Which::Second => self.engine.handle_rx_second(now, bytes),
                    }
                }
                Piece::Error { error, .. } => {
                    if let Some(recorder) = &mut reader.recorder {
                        recorder.line_error(at, error);
                    }
                    match which {
                        Which::First => self.engine.handle_line_error(now, error),
                        Which::Second => self.engine.handle_line_error_second(now, error),
                    }
                }
            }
        }
        // A control character one port received tells the other port's framing what comes
        // next, as the gateway's own transmission would (3964(R): a DLE answers STX, so the
        // partner's telegram follows).
        let control = reader.recorder.as_mut().and_then(Recorder::take_control);
        let other = match which {
            Which::First => self.second.as_mut(),
            Which::Second => Some(&mut self.first),
        };
        if let (Some(byte), Some(other)) = (control, other) {
            if let Some(recorder) = &mut other.recorder {
                recorder.peer_sent(&[byte]);
            }
        }
        self.shared.metrics().received_bytes(data);
    }

    /// Looks at the UART's counters of a port (after a read): characters lost to an overrun
    /// since the last look go to the engine as [`LineError::Overrun`] (003 7.2, 08 0Ch), the one
    /// line error the stream's marks cannot show. A port without counters is not asked again.
    fn check_uart(&mut self, which: Which, port: &O::Port) {
        let line = self.base.name.as_str();
        let reader = match which {
            Which::First => &mut self.first,
            Which::Second => match &mut self.second {
                Some(second) => second,
                None => return,
            },
        };
        let lost = reader.overruns(port, line);
        if lost == 0 {
            return;
        }
        tracing::debug!(line, lost, "receive overrun");
        let (at, now) = self.clock.now();
        if let Some(recorder) = &mut reader.recorder {
            recorder.line_error(at, LineError::Overrun);
        }
        match which {
            Which::First => self.engine.handle_line_error(now, LineError::Overrun),
            Which::Second => self
                .engine
                .handle_line_error_second(now, LineError::Overrun),
        }
    }

    /// The port (and the second one) just opened: the monitor's readers, the UART counters' start
    /// and the engine learn of it.
    fn opened(&mut self, port: &mut O::Port, second: Option<&O::Port>) {
        self.first.opened();
        self.first.unmarked = !port.marks_line_errors();
        self.check_uart(Which::First, port); // the counters' start on this opening
        if let (Some(reader), Some(port)) = (&mut self.second, second) {
            reader.opened();
            reader.unmarked = !port.marks_line_errors();
            let _ = reader.overruns(port, &self.base.name);
        }
        self.engine.opened(port.modem());
    }

    /// Applies the engine's modem actions and writes every frame it has to send, telling it the
    /// estimated end of each transmission.
    async fn transmit(
        &mut self,
        port: &mut O::Port,
        path: &str,
        char_time: Duration,
    ) -> Result<(), PortExit> {
        loop {
            while let Some(action) = self.engine.poll_action() {
                self.engine.apply_action(action, port.modem());
            }
            let Some(frame) = self.engine.poll_transmit() else {
                return Ok(());
            };
            if let Err(err) = port.write_all(&frame).await {
                return Err(PortExit::Lost(format!("write to {path} failed: {err}")));
            }
            let written = Instant::now();
            let end = estimated_tx_end(written, frame.len(), char_time);
            if let Some(recorder) = &mut self.first.recorder {
                recorder.sent(written, end, &frame);
            }
            self.shared.metrics().sent_bytes(frame.len());
            self.engine
                .transmitted(written, frame.len(), self.clock.to_engine(end));
        }
    }

    /// Shutdown asked: the engine says how it stops; with `close_queue` the commands not yet
    /// taken are refused.
    fn begin_stop(&mut self) -> Stop {
        let stop = self.engine.stop();
        if stop.close_queue {
            if let Some(mut commands) = self.commands.take() {
                commands.close();
                while let Ok(command) = commands.try_recv() {
                    self.engine.refuse(command, true);
                }
            }
        }
        stop
    }

    /// The driver loop on an open port.
    async fn drive(&mut self, mut port: O::Port, mut second: Option<O::Port>) -> PortExit {
        let path = self.base.port.path.clone();
        let second_path = self.base.second_port.clone().unwrap_or_default();
        let char_time = self.base.port.char_time();
        self.opened(&mut port, second.as_ref());
        // The engine's deadlines can be fractions of a millisecond apart (t1.5/t3.5, 003 6.4.3;
        // the turnaround after a broadcast, 003 6.4.2.2): tokio's millisecond timer would add
        // 1.2 ms to each.
        let mut timer = LineTimer::new();
        let mut stopping: Option<Stop> = None;
        let mut stop_at: Option<Instant> = None;
        let mut buf = [0u8; READ_BUF];
        let mut buf_second = [0u8; READ_BUF];
        loop {
            let (now, engine_now) = self.clock.now();
            // A deadline already passed is handled without sleeping (quinn drive_timer).
            if self
                .engine
                .poll_timeout()
                .is_some_and(|t| self.clock.to_tokio(t) <= now)
            {
                self.engine.handle_timeout(engine_now);
            }
            self.first.expire(now);
            if let Some(reader) = &mut self.second {
                reader.expire(now);
            }
            if stopping.is_none() {
                self.engine.start(now);
            }
            if let Err(exit) = self.transmit(&mut port, &path, char_time).await {
                return exit;
            }
            if self.engine.handle_events() {
                continue; // start the next job at once
            }
            if stopping.is_some() && self.engine.done() {
                return PortExit::Shutdown;
            }
            // One timer for every deadline of the line: the engine's, and the end by silence of a
            // frame the monitor is receiving (the turn of the loop closes it).
            let deadline = self.engine.poll_timeout().map(|t| self.clock.to_tokio(t));
            let wake_at = [
                deadline,
                self.first.frame_end(),
                self.second.as_ref().and_then(Reader::frame_end),
            ]
            .into_iter()
            .flatten()
            .min();
            let reading = stopping.is_none_or(|s| s.read);
            let taking = stopping.is_none();
            tokio::select! {
                biased;
                () = self.shutdown.cancelled(), if stopping.is_none() => {
                    let stop = self.begin_stop();
                    stop_at = stop.grace.map(|grace| Instant::now() + grace);
                    stopping = Some(stop);
                }
                () = sleep_until_opt(stop_at) => return PortExit::Shutdown,
                read = port.read(&mut buf), if reading => match read {
                    Ok(0) => return PortExit::Lost(format!("{path} reached end of file")),
                    Ok(n) => {
                        self.receive(Which::First, buf.get(..n).unwrap_or_default());
                        self.check_uart(Which::First, &port);
                    }
                    Err(err) => return PortExit::Lost(format!("read from {path} failed: {err}")),
                },
                read = read_opt(&mut second, &mut buf_second), if reading => match read {
                    Ok(0) => return PortExit::Lost(format!("{second_path} reached end of file")),
                    Ok(n) => {
                        self.receive(Which::Second, buf_second.get(..n).unwrap_or_default());
                        if let Some(port) = &second {
                            self.check_uart(Which::Second, port);
                        }
                    }
                    Err(err) => return PortExit::Lost(format!("read from {second_path} failed: {err}")),
                },
                () = timer.sleep_until_opt(wake_at) => {
                    if deadline.is_some() && deadline == wake_at {
                        let (_, engine_now) = self.clock.now();
                        self.engine.handle_timeout(engine_now);
                    }
                }
                () = self.engine.wake() => self.engine.woken(port.modem()),
                command = recv(&mut self.commands), if taking => match command {
                    Some(command) => self.engine.command(command, port.modem()),
                    None => self.commands = None,
                },
            }
        }
    }
}

/// Reads the port if there is one; never completes without one.
pub(super) async fn read_opt<P: LinePort>(
    port: &mut Option<P>,
    buf: &mut [u8],
) -> std::io::Result<usize> {
    match port {
        Some(port) => port.read(buf).await,
        None => std::future::pending().await,
    }
}

/// The next command of an open queue; never for a closed one.
pub(super) async fn recv<C>(commands: &mut Option<mpsc::Receiver<C>>) -> Option<C> {
    match commands {
        Some(commands) => commands.recv().await,
        None => std::future::pending().await,
    }
}
