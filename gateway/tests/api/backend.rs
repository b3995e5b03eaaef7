//! An in-memory gateway behind the API: it holds a configuration, applies changes by restarting
//! only what [`ConfigDiff`] names, keeps per-line counters, a diagnostic buffer, a telegram queue
//! and RS232 signals, and tag values with ranges. Tests drive it from the outside (events,
//! received telegrams, readiness) and read it back over HTTP.

use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, SystemTime};

use gateway::api::auth::Caller;
use gateway::api::model::{
    ApplyReport, DeviceStatusView, DiagRecord, DiagSnapshot, EventCount, EventView, GatewayStatus,
    LineCounters, LineState, LineStatusView, ModbusTcpStatus, Readiness, ScalarValue, SendResult,
    Signals, SignalsPatch, TagQuality, TagValue, Telegram, TelegramQueue, Timestamp, ZenohStatus,
};
use gateway::api::{ApiBackend, ApiError, BoxFuture, ConfigDiff};
use gateway::audit::WriteResult;
use gateway::config::{ConfigIssue, Interface};
use gateway::plant::Config;
use gateway::protocols::{LineConfig, ProtocolConfig};
use proto_core::event::EventId;

/// A port path the backend refuses at validation, as a real gateway refuses a missing device.
pub(crate) const MISSING_PORT: &str = "/dev/does-not-exist";

/// A tag's value and limits.
#[derive(Clone, Debug)]
pub(crate) struct TagSpec {
    pub(crate) value: Option<ScalarValue>,
    pub(crate) unit: &'static str,
    pub(crate) writable: bool,
    /// The device answers exception 03 (illegal data value) outside this range.
    pub(crate) range: (f64, f64),
}

#[derive(Debug)]
struct LineRt {
    started: SystemTime,
    port_opened: bool,
    port_opens: u64,
    counters: LineCounters,
    depth: usize,
    diag: VecDeque<DiagRecord>,
    status_word: u16,
    event_counts: BTreeMap<EventId, u64>,
    telegram_line: bool,
    capacity: usize,
    queue: VecDeque<(u32, SystemTime, Vec<u8>)>,
    next_seq: u32,
    dropped: u64,
    signals: Option<Signals>,
    devices: BTreeMap<String, (u8, u8, bool)>,
}

impl LineRt {
    fn start(line: &LineConfig, depth: usize) -> Self {
        let (telegram_line, capacity) = match &line.protocol {
            ProtocolConfig::Proc3964(p) => (true, usize::from(p.receive_buffer)),
            ProtocolConfig::Ascii(a) => (true, usize::from(a.receive_buffer)),
            _ => (false, 0),
        };
        let signals = (line.serial.interface == Interface::Rs232).then_some(Signals {
            dtr: true,
            rts: false,
            dsr: true,
            cts: true,
            dcd: false,
            ri: false,
        });
        Self {
            started: SystemTime::now(),
            port_opened: true,
            port_opens: 1,
            counters: LineCounters::default(),
            depth,
            diag: VecDeque::new(),
            status_word: 0,
            event_counts: BTreeMap::new(),
            telegram_line,
            capacity,
            queue: VecDeque::new(),
            next_seq: 1,
            dropped: 0,
            signals,
            devices: line
                .devices()
                .map(|(n, d)| (n.clone(), (d.address, d.unit_id, true)))
                .collect(),
        }
    }

    fn raise(&mut self, id: EventId) {
        let now = SystemTime::now();
        // As the line's buffer (003 7.3): every event an entry of its own, newest first.
        self.diag.push_front(DiagRecord {
            id,
            at: now,
            first_at: now,
            count: 1,
        });
        self.diag.truncate(self.depth);
        self.status_word = id.status_word();
        *self.event_counts.entry(id).or_default() += 1;
        self.counters.events += 1;
    }

    fn receive(&mut self, data: Vec<u8>) {
        self.counters.frames_received += 1;
        self.counters.bytes_received += data.len() as u64;
        if self.queue.len() >= self.capacity {
            self.dropped += 1;
            // 003 7.2 08 0Ah: no free receive buffer.
            self.raise(EventId::new(0x08, 0x0A));
            return;
        }
        self.queue
            .push_back((self.next_seq, SystemTime::now(), data));
        self.next_seq += 1;
    }
}

#[derive(Debug)]
struct Inner {
    config: Arc<Config>,
    lines: BTreeMap<String, LineRt>,
    tags: BTreeMap<(String, String, String), (TagSpec, Option<SystemTime>)>,
    modbus_tcp_clients: u64,
    modbus_tcp_starts: u64,
    zenoh: Option<bool>,
}

/// The in-memory gateway.
#[derive(Debug)]
pub(crate) struct MemGateway {
    inner: Mutex<Inner>,
    started: SystemTime,
    /// How long `apply` takes (a restart is not instant).
    apply_delay: Duration,
    /// The audit records: source, target, result.
    audits: Mutex<Vec<(String, String, String)>>,
}

impl MemGateway {
    pub(crate) fn new(config: Config, tags: Vec<(&str, &str, &str, TagSpec)>) -> Self {
        let depth = usize::from(config.gateway.diag_buffer_depth);
        let lines = config
            .lines
            .iter()
            .map(|(n, l)| (n.clone(), LineRt::start(l, depth)))
            .collect();
        let tags = tags
            .into_iter()
            .map(|(l, d, t, spec)| {
                (
                    (l.into(), d.into(), t.into()),
                    (spec, Some(SystemTime::now())),
                )
            })
            .collect();
        Self {
            inner: Mutex::new(Inner {
                config: Arc::new(config),
                lines,
                tags,
                modbus_tcp_clients: 0,
                modbus_tcp_starts: 1,
                zenoh: Some(true),
            }),
            started: SystemTime::now(),
            apply_delay: Duration::from_millis(5),
            audits: Mutex::new(Vec::new()),
        }
    }

    /// The audit records so far: (source, target, result).
    pub(crate) fn audits(&self) -> Vec<(String, String, String)> {
        self.audits
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }

    fn lock(&self) -> MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Raises an event on a line (diagnostic buffer, STATUS word, counters).
    pub(crate) fn raise(&self, line: &str, id: EventId) {
        self.lock().lines.get_mut(line).expect("line").raise(id);
    }

    /// A telegram arrives on a line.
    pub(crate) fn receive(&self, line: &str, data: &[u8]) {
        self.lock()
            .lines
            .get_mut(line)
            .expect("line")
            .receive(data.to_vec());
    }

    /// Modbus TCP clients connect (they stay until the server restarts).
    pub(crate) fn connect_modbus_clients(&self, n: u64) {
        self.lock().modbus_tcp_clients += n;
    }

    /// How often the Modbus TCP server was started (1 + restarts by configuration changes).
    pub(crate) fn modbus_tcp_starts(&self) -> u64 {
        self.lock().modbus_tcp_starts
    }

    pub(crate) fn set_port_opened(&self, line: &str, opened: bool) {
        self.lock().lines.get_mut(line).expect("line").port_opened = opened;
    }

    pub(crate) fn set_zenoh(&self, up: Option<bool>) {
        self.lock().zenoh = up;
    }

    pub(crate) fn set_device_online(&self, line: &str, device: &str, online: bool) {
        let mut inner = self.lock();
        let dev = inner
            .lines
            .get_mut(line)
            .and_then(|l| l.devices.get_mut(device));
        dev.expect("device").2 = online;
    }

    fn view(name: &str, line: &LineConfig, rt: &LineRt) -> LineStatusView {
        let devices: Vec<DeviceStatusView> = rt
            .devices
            .iter()
            .map(|(n, (address, unit_id, online))| DeviceStatusView {
                name: n.clone(),
                address: *address,
                unit_id: *unit_id,
                online: *online,
                polls_ok: 0,
                polls_exception: 0,
                polls_failed: 0,
                last_answer: None,
                commands_failed: 0,
                cycles: Vec::new(),
            })
            .collect();
        LineStatusView {
            name: name.to_owned(),
            protocol: line.protocol.kind().as_str().to_owned(),
            port: line.serial.port.clone(),
            port_b: line.second_port().map(str::to_owned),
            state: if rt.port_opened {
                LineState::Running
            } else {
                LineState::Starting
            },
            port_open: rt.port_opened,
            started: Timestamp(rt.started),
            port_error: None,
            port_opens: rt.port_opens,
            status_word: rt.status_word,
            last_event: EventView::from_status_word(rt.status_word),
            counters: rt.counters,
            event_counts: rt
                .event_counts
                .iter()
                .map(|(id, count)| EventCount {
                    event: EventView::new(*id),
                    count: *count,
                })
                .collect(),
            devices_online: devices.iter().filter(|d| d.online).count(),
            devices_total: devices.len(),
            devices,
        }
    }

    fn with_line<T>(
        &self,
        line: &str,
        f: impl FnOnce(&mut LineRt) -> Result<T, ApiError>,
    ) -> Result<T, ApiError> {
        let mut inner = self.lock();
        let rt = inner
            .lines
            .get_mut(line)
            .ok_or_else(|| ApiError::not_found("line", line))?;
        f(rt)
    }

    fn tag_value(&self, line: &str, device: &str, tag: &str) -> Result<TagValue, ApiError> {
        let inner = self.lock();
        let rt = inner
            .lines
            .get(line)
            .ok_or_else(|| ApiError::not_found("line", line))?;
        let online = rt
            .devices
            .get(device)
            .ok_or_else(|| ApiError::not_found("device", device))?
            .2;
        let (spec, at) = inner
            .tags
            .get(&(line.to_owned(), device.to_owned(), tag.to_owned()))
            .ok_or_else(|| ApiError::not_found("tag", &format!("{line}/{device}/{tag}")))?;
        Ok(TagValue {
            line: line.to_owned(),
            device: device.to_owned(),
            tag: tag.to_owned(),
            value: spec.value.clone(),
            unit: spec.unit.to_owned(),
            quality: if online {
                TagQuality::Good
            } else {
                TagQuality::CommFailure
            },
            timestamp: at.map(Timestamp),
            writable: spec.writable,
            description: String::new(),
        })
    }
}

impl ApiBackend for MemGateway {
    fn config(&self) -> Arc<Config> {
        Arc::clone(&self.lock().config)
    }

    fn validate(&self, config: &Config) -> Result<(), Vec<ConfigIssue>> {
        let issues: Vec<ConfigIssue> = config
            .lines
            .iter()
            .filter(|(_, l)| l.serial.port == MISSING_PORT)
            .map(|(n, l)| ConfigIssue {
                path: format!("lines.{n}.port"),
                message: format!("no such serial port {}", l.serial.port),
            })
            .collect();
        if issues.is_empty() {
            Ok(())
        } else {
            Err(issues)
        }
    }

    fn apply(&self, config: Arc<Config>) -> BoxFuture<'_, Result<ApplyReport, ApiError>> {
        Box::pin(async move {
            tokio::time::sleep(self.apply_delay).await;
            let mut inner = self.lock();
            let diff = ConfigDiff::between(&inner.config, &config);
            let depth = usize::from(config.gateway.diag_buffer_depth);
            for name in &diff.lines_removed {
                inner.lines.remove(name);
            }
            for name in diff.lines_added.iter().chain(&diff.lines_changed) {
                let rt = LineRt::start(&config.lines[name], depth);
                inner.lines.insert(name.clone(), rt);
            }
            for (line, device) in &diff.devices_changed {
                let spec = config.lines[line]
                    .devices()
                    .find(|(n, _)| *n == device)
                    .map(|(_, d)| d);
                let rt = inner.lines.get_mut(line).expect("a running line");
                match spec {
                    Some(d) => rt
                        .devices
                        .insert(device.clone(), (d.address, d.unit_id, true)),
                    None => rt.devices.remove(device),
                };
            }
            if diff.modbus_tcp_changed {
                inner.modbus_tcp_clients = 0;
                inner.modbus_tcp_starts += 1;
            }
            inner.config = config;
            Ok(diff.report())
        })
    }

    fn gateway_status(&self) -> GatewayStatus {
        let ready = self.readiness().is_ready();
        let inner = self.lock();
        GatewayStatus {
            name: inner.config.gateway.name.clone(),
            version: env!("CARGO_PKG_VERSION").to_owned(),
            started: Timestamp(self.started),
            uptime_seconds: self.started.elapsed().map_or(0, |d| d.as_secs()),
            ready,
            lines: inner
                .lines
                .iter()
                .map(|(n, rt)| Self::view(n, &inner.config.lines[n], rt))
                .collect(),
            modbus_tcp: ModbusTcpStatus {
                listen: inner.config.modbus_tcp.listen.to_string(),
                up: true,
                connections: inner.modbus_tcp_clients,
                requests_total: 0,
                exceptions_total: 0,
            },
            zenoh: inner.zenoh.map(|up| ZenohStatus {
                up,
                mode: "peer".into(),
                publications_total: 0,
                name_conflict: None,
            }),
        }
    }

    fn line_status(&self, line: &str) -> Result<LineStatusView, ApiError> {
        assert_ne!(line, "panic", "a handler panic, as a defect would cause");
        let inner = self.lock();
        let rt = inner
            .lines
            .get(line)
            .ok_or_else(|| ApiError::not_found("line", line))?;
        Ok(Self::view(line, &inner.config.lines[line], rt))
    }

    fn diag(&self, line: &str) -> Result<DiagSnapshot, ApiError> {
        self.with_line(line, |rt| {
            Ok(DiagSnapshot {
                depth: rt.depth,
                entries: rt.diag.iter().copied().collect(),
            })
        })
    }

    fn clear_diag(&self, line: &str) -> Result<(), ApiError> {
        self.with_line(line, |rt| {
            rt.diag.clear();
            Ok(())
        })
    }

    fn telegrams(&self, line: &str) -> Result<TelegramQueue, ApiError> {
        self.with_line(line, |rt| {
            if !rt.telegram_line {
                return Err(ApiError::conflict(format!(
                    "line {line} does not carry telegrams"
                )));
            }
            Ok(TelegramQueue {
                line: line.to_owned(),
                capacity: rt.capacity,
                dropped: rt.dropped,
                telegrams: rt
                    .queue
                    .iter()
                    .map(|(s, t, d)| Telegram::new(*s, *t, d))
                    .collect(),
            })
        })
    }

    fn ack_telegram(&self, line: &str, seq: u32) -> Result<(), ApiError> {
        self.with_line(line, |rt| {
            if !rt.telegram_line {
                return Err(ApiError::conflict(format!(
                    "line {line} does not carry telegrams"
                )));
            }
            match rt.queue.iter().position(|(s, _, _)| *s == seq) {
                None => Err(ApiError::not_found("telegram", &seq.to_string())),
                Some(0) => {
                    rt.queue.pop_front();
                    Ok(())
                }
                Some(_) => Err(ApiError::conflict(format!(
                    "telegram {seq} is not the oldest; acknowledge {} first",
                    rt.queue.front().map_or(0, |t| t.0)
                ))),
            }
        })
    }

    fn send_telegram(
        &self,
        line: &str,
        data: Vec<u8>,
    ) -> BoxFuture<'_, Result<SendResult, ApiError>> {
        let line = line.to_owned();
        Box::pin(async move {
            self.with_line(&line, |rt| {
                if !rt.telegram_line {
                    return Err(ApiError::conflict(format!(
                        "line {line} does not send telegrams"
                    )));
                }
                rt.counters.frames_sent += 1;
                rt.counters.bytes_sent += data.len() as u64;
                rt.counters.commands_answered += 1;
                let len = data.len();
                // The partner echoes every telegram, as the simulators do.
                rt.receive(data);
                Ok(SendResult::done(len))
            })
        })
    }

    fn tags(&self, line: Option<&str>, device: Option<&str>) -> Result<Vec<TagValue>, ApiError> {
        let keys: Vec<(String, String, String)> = {
            let inner = self.lock();
            if let Some(l) = line {
                if !inner.lines.contains_key(l) {
                    return Err(ApiError::not_found("line", l));
                }
            }
            inner
                .tags
                .keys()
                .filter(|(l, d, _)| line.is_none_or(|x| x == l) && device.is_none_or(|x| x == d))
                .cloned()
                .collect()
        };
        keys.iter()
            .map(|(l, d, t)| self.tag_value(l, d, t))
            .collect()
    }

    fn tag(
        &self,
        line: &str,
        device: &str,
        tag: &str,
    ) -> BoxFuture<'_, Result<TagValue, ApiError>> {
        let r = if device == "slow" {
            None
        } else {
            Some(self.tag_value(line, device, tag))
        };
        Box::pin(async move {
            match r {
                Some(r) => r,
                // A device that takes longer than any request timeout.
                None => {
                    tokio::time::sleep(Duration::from_secs(30)).await;
                    Err(ApiError::device_timeout("no answer"))
                }
            }
        })
    }

    fn write_tag(
        &self,
        line: &str,
        device: &str,
        tag: &str,
        value: ScalarValue,
    ) -> BoxFuture<'_, Result<TagValue, ApiError>> {
        let (line, device, tag) = (line.to_owned(), device.to_owned(), tag.to_owned());
        Box::pin(async move {
            let current = self.tag_value(&line, &device, &tag)?;
            if !current.writable {
                return Err(ApiError::conflict(format!(
                    "tag {line}/{device}/{tag} is read-only"
                )));
            }
            if current.quality == TagQuality::CommFailure {
                return Err(ApiError::device_timeout(format!(
                    "device {device} does not answer"
                )));
            }
            {
                let mut inner = self.lock();
                let (spec, at) = inner
                    .tags
                    .get_mut(&(line.clone(), device.clone(), tag.clone()))
                    .expect("tag");
                // As the gateway: a text fits only a string tag, and the fake has none.
                if matches!(value, ScalarValue::Text(_)) {
                    return Err(ApiError::invalid_body(format!(
                        "tag {line}/{device}/{tag} holds a number, not a text"
                    )));
                }
                let (lo, hi) = spec.range;
                if !(lo..=hi).contains(&value.as_f64()) {
                    return Err(ApiError::device_exception(0x03, "illegal data value"));
                }
                spec.value = Some(value);
                *at = Some(SystemTime::now());
            }
            self.tag_value(&line, &device, &tag)
        })
    }

    fn signals(&self, line: &str) -> BoxFuture<'_, Result<Signals, ApiError>> {
        let r = self.with_line(line, |rt| {
            rt.signals
                .ok_or_else(|| ApiError::conflict(format!("line {line} is not RS232")))
        });
        Box::pin(async move { r })
    }

    fn set_signals(
        &self,
        line: &str,
        patch: SignalsPatch,
    ) -> BoxFuture<'_, Result<Signals, ApiError>> {
        let r = self.with_line(line, |rt| {
            let s = rt
                .signals
                .as_mut()
                .ok_or_else(|| ApiError::conflict(format!("line {line} is not RS232")))?;
            s.dtr = patch.dtr.unwrap_or(s.dtr);
            s.rts = patch.rts.unwrap_or(s.rts);
            Ok(*s)
        });
        Box::pin(async move { r })
    }

    fn readiness(&self) -> Readiness {
        let inner = self.lock();
        Readiness {
            lines: inner
                .lines
                .iter()
                .map(|(n, rt)| (n.clone(), rt.port_opened))
                .collect(),
            modbus_tcp: true,
            zenoh: inner.zenoh,
            zenoh_name_conflict: None,
        }
    }

    fn audit(
        &self,
        caller: &Caller,
        target: &dyn std::fmt::Display,
        result: WriteResult,
        _detail: &dyn std::fmt::Display,
    ) {
        self.audits
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .push((
                caller.to_string(),
                target.to_string(),
                result.as_str().to_owned(),
            ));
    }
}
