//! What a line reports: its diagnostic buffer, event counters, last STATUS word, port and devices.
//!
//! The CP keeps the newest events of a line in a diagnostic buffer of 9 entries (003 7.3); the
//! catalog's [`DiagBuffer`] does that here with a configurable depth. Every event is also counted
//! by id, logged with its class name from the catalog, counted in the line's Prometheus metrics,
//! and sent to subscribers (zenoh, REST) on a bounded broadcast channel.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, SystemTime};

use proto_core::event::{self, ids, DiagBuffer, DiagEntry, EventId};
use tokio::sync::broadcast;

use super::driver::Clock;
use super::metrics::LineMetrics;

/// Depth of the diagnostic buffer by default: the CP's 9 entries (003 7.3).
pub const DEFAULT_DIAG_DEPTH: usize = event::DEFAULT_DEPTH;

/// Capacity of a line's event broadcast channel.
const EVENT_CHANNEL_CAPACITY: usize = 256;

/// An event of a line, as kept in the diagnostic buffer and sent to subscribers.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LineEvent {
    /// The line's name.
    pub line: String,
    /// The event (class and number of 003 7.2).
    pub id: EventId,
    /// The slave concerned, if any.
    pub slave: Option<u8>,
    /// When it happened.
    pub time: SystemTime,
    /// Details for the log and the REST view (e.g. the operating system's error).
    pub detail: Option<String>,
}

/// The state of one polled device.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DeviceStatus {
    /// Its name.
    pub name: String,
    /// Its slave address.
    pub slave: u8,
    /// Its unit id in the image.
    pub unit_id: u8,
    /// Whether it answers (not backed off).
    pub online: bool,
    /// Polls answered with data.
    pub polls_ok: u64,
    /// Polls answered with an exception.
    pub polls_exception: u64,
    /// Polls without a valid answer (after the master's retries).
    pub polls_failed: u64,
    /// The exception code of the newest poll or scan the device answered with an exception
    /// (`None` before any).
    pub last_exception: Option<u8>,
    /// When it last answered.
    pub last_answer: Option<SystemTime>,
    /// Commands (writes, on-demand reads, pass-through requests) that got no valid answer:
    /// each failed for its own client only.
    pub commands_failed: u64,
    /// The planned and achieved cycle of each poll block.
    pub cycles: Vec<PollCycle>,
}

// === impl DeviceStatus ===

impl DeviceStatus {
    /// A device before its first exchange: online (until its own polls say otherwise), nothing
    /// counted yet.
    pub fn new(name: &str, slave: u8, unit_id: u8) -> Self {
        Self {
            name: name.to_owned(),
            slave,
            unit_id,
            online: true,
            polls_ok: 0,
            polls_exception: 0,
            polls_failed: 0,
            last_exception: None,
            last_answer: None,
            commands_failed: 0,
            cycles: Vec::new(),
        }
    }
}

/// The planned and achieved cycle of one poll block of a device (one read of its poll groups of
/// one table and period).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PollCycle {
    /// The table read.
    pub table: crate::image::Table,
    /// The first address read.
    pub start: u16,
    /// How many addresses are read.
    pub count: u16,
    /// The configured period.
    pub planned: Duration,
    /// The longest cycle the fairness rule of the line allows (see the scheduler).
    pub bound: Duration,
    /// The last cycle while the device answered.
    pub achieved: Option<Duration>,
    /// The longest cycle while the device answered.
    pub achieved_max: Option<Duration>,
}

/// A snapshot of a line's state ([`LineHandle::status`](super::LineHandle::status)).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LineStatus {
    /// The line's name.
    pub name: String,
    /// Whether the port is open.
    pub port_open: bool,
    /// Why the port last failed to open or was lost.
    pub port_error: Option<String>,
    /// How often the port was opened (1 after a clean start).
    pub port_opens: u64,
    /// The STATUS word of the newest event (bits 12..8 class, 7..0 number; 0 before any event).
    pub status_word: u16,
    /// The diagnostic buffer, newest first (repeats of the newest event merged, see
    /// [`DiagBuffer`]); its instants count from `started`.
    pub diagnostics: Vec<DiagEntry>,
    /// The newest event with its wall-clock time and details.
    pub last_event: Option<LineEvent>,
    /// When the line started: the origin of the diagnostic buffer's instants.
    pub started: SystemTime,
    /// Events counted by id since the line started.
    pub event_counts: BTreeMap<EventId, u64>,
    /// The polled devices.
    pub devices: Vec<DeviceStatus>,
    /// Commands (writes, on-demand reads) answered by the device, exceptions included.
    pub commands_answered: u64,
    /// Commands that got no answer from the device.
    pub commands_failed: u64,
}

// === impl LineStatus ===

impl LineStatus {
    /// The status of line `name` with `devices` as it starts: port not yet open, no events.
    pub(crate) fn new(name: String, devices: Vec<DeviceStatus>) -> Self {
        Self {
            name,
            port_open: false,
            port_error: None,
            port_opens: 0,
            status_word: 0,
            diagnostics: Vec::new(),
            last_event: None,
            started: SystemTime::now(),
            event_counts: BTreeMap::new(),
            devices,
            commands_answered: 0,
            commands_failed: 0,
        }
    }
}

/// The state shared between a line task and its handle.
#[derive(Debug)]
pub(crate) struct Shared {
    status: Mutex<LineStatus>,
    /// The diagnostic buffer, newest first.
    diag: Mutex<DiagBuffer>,
    /// The line's clock (the diagnostic buffer's instants).
    clock: Clock,
    events: broadcast::Sender<LineEvent>,
    /// The line's Prometheus metrics (no-ops without).
    metrics: LineMetrics,
}

// === impl Shared ===

impl Shared {
    /// The shared state of a line without metrics.
    #[allow(dead_code)] // for lines without metrics (the unit tests; the telegram lines)
    pub(crate) fn new(status: LineStatus, depth: usize, clock: Clock) -> Arc<Self> {
        Self::with_metrics(status, depth, clock, LineMetrics::default())
    }

    /// The shared state of a line whose events are also counted in `metrics`.
    pub(crate) fn with_metrics(
        status: LineStatus,
        depth: usize,
        clock: Clock,
        metrics: LineMetrics,
    ) -> Arc<Self> {
        let (events, _) = broadcast::channel(EVENT_CHANNEL_CAPACITY);
        Arc::new(Self {
            status: Mutex::new(status),
            diag: Mutex::new(DiagBuffer::new(depth)),
            clock,
            events,
            metrics,
        })
    }

    /// The line's metrics.
    pub(crate) fn metrics(&self) -> &LineMetrics {
        &self.metrics
    }

    /// Runs `f` on the status under its lock.
    pub(crate) fn update<R>(&self, f: impl FnOnce(&mut LineStatus) -> R) -> R {
        f(&mut self.status.lock().unwrap_or_else(PoisonError::into_inner))
    }

    /// Empties the diagnostic buffer (the event counters and the STATUS word stay).
    pub(crate) fn clear_diagnostics(&self) {
        self.diag
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clear();
    }

    /// A snapshot with the diagnostic buffer.
    pub(crate) fn snapshot(&self) -> LineStatus {
        let mut status = self.update(|s| s.clone());
        let diag = self.diag.lock().unwrap_or_else(PoisonError::into_inner);
        status.diagnostics = diag.iter().copied().collect();
        status
    }

    pub(crate) fn subscribe(&self) -> broadcast::Receiver<LineEvent> {
        self.events.subscribe()
    }

    /// Whether the device at `index` answers.
    pub(crate) fn device_online(&self, index: usize) -> bool {
        self.update(|s| s.devices.get(index).is_some_and(|d| d.online))
    }

    /// Records an event: diagnostic buffer, counter, STATUS word, log, metrics, subscribers.
    pub(crate) fn raise(&self, id: EventId, slave: Option<u8>, detail: Option<String>) {
        self.record(id, slave, detail);
        self.metrics.event(id);
    }

    /// The line took its parameters and its port is open: port state in the status, event 00 03h
    /// "PtP parameters accepted" recorded as the CP reports it at start-up (003 7.2, class 00h),
    /// and in the metrics the line up with that event counted.
    ///
    /// The gateway sets the port's parameters each time it opens it, so a port reopened after a
    /// failure reports 00 03h again, after the 02 0Fh or 08 0Dh of the failure.
    pub(crate) fn started(&self) {
        self.update(|s| {
            s.port_open = true;
            s.port_error = None;
            s.port_opens += 1;
        });
        self.record(ids::PTP_PARAMS_ACCEPTED, None, None);
        self.metrics.started();
    }

    /// The port closed (failure or shutdown).
    pub(crate) fn port_closed(&self) {
        self.update(|s| s.port_open = false);
        self.metrics.port_closed();
    }

    /// Diagnostic buffer, counter, STATUS word, log and subscribers of one event.
    fn record(&self, id: EventId, slave: Option<u8>, detail: Option<String>) {
        let (_, at) = self.clock.now();
        self.diag
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .push(DiagEntry::new(id, at));
        let event = self.update(|s| {
            *s.event_counts.entry(id).or_default() += 1;
            s.status_word = id.status_word();
            let event = LineEvent {
                line: s.name.clone(),
                id,
                slave,
                time: SystemTime::now(),
                detail,
            };
            s.last_event = Some(event.clone());
            event
        });
        // The manual's description and remedy, as the REST API gives them (003 7.2).
        let info = event::lookup(id);
        let description = info.map_or("Event not in the catalog (003 7.2).", |i| i.description);
        let remedy = info.map(|i| i.remedy).filter(|r| !r.is_empty());
        // A disturbed line raises the same event for every frame: once per interval in the log
        // (with the count left out), every one in the counters and the diagnostic buffer.
        let key = || format!("line/{}/{id}", event.line);
        match &event.detail {
            Some(detail) => {
                crate::warn_limited!(key(), line = %event.line, event = %id, slave, detail, remedy, "{description}");
            }
            // Class 00h "CP start-up" reports normal operation.
            None if id.class == 0 => {
                tracing::info!(line = %event.line, event = %id, "{description}")
            }
            None => {
                crate::warn_limited!(key(), line = %event.line, event = %id, slave, remedy, "{description}");
            }
        }
        // No subscriber: nobody to lose it.
        let _ = self.events.send(event);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn status() -> LineStatus {
        LineStatus::new("drive".into(), Vec::new())
    }

    #[test]
    fn the_diagnostic_buffer_keeps_the_newest_events_first() {
        let shared = Shared::new(status(), 3, Clock::start());
        let mut rx = shared.subscribe();
        for n in 0..5u8 {
            shared.raise(EventId::new(0x08, 0x30 + n), Some(2), None);
        }
        shared.raise(EventId::new(0x08, 0x30), None, Some("again".into()));
        shared.raise(EventId::new(0x08, 0x30), None, None);
        let s = shared.snapshot();
        let ids: Vec<(u8, u32)> = s
            .diagnostics
            .iter()
            .map(|e| (e.id.number, e.count))
            .collect();
        // 003 7.3: every event an entry of its own, newest first, a ring of three.
        assert_eq!(ids, vec![(0x30, 1), (0x30, 1), (0x34, 1)]);
        assert_eq!(s.status_word, 0x0830);
        assert_eq!(s.event_counts[&EventId::new(0x08, 0x30)], 3);
        assert_eq!(s.event_counts[&EventId::new(0x08, 0x34)], 1);
        assert_eq!(s.last_event.unwrap().detail, None);
        assert_eq!(rx.try_recv().unwrap().id, EventId::new(0x08, 0x30));
    }

    #[test]
    fn a_cleared_buffer_starts_a_repeated_event_afresh_and_keeps_the_counters() {
        let shared = Shared::new(status(), 9, Clock::start());
        let no_reply = EventId::new(0x08, 0x30);
        for _ in 0..3 {
            shared.raise(no_reply, Some(2), None);
        }
        assert_eq!(shared.snapshot().diagnostics.len(), 3);
        shared.clear_diagnostics();
        let s = shared.snapshot();
        assert!(s.diagnostics.is_empty());
        // The counters and the STATUS word are not the buffer: they stay.
        assert_eq!(s.event_counts[&no_reply], 3);
        assert_eq!(s.status_word, 0x0830);
        shared.raise(no_reply, Some(2), None);
        let s = shared.snapshot();
        let entries: Vec<(EventId, u32)> = s.diagnostics.iter().map(|e| (e.id, e.count)).collect();
        assert_eq!(entries, vec![(no_reply, 1)]);
        assert_eq!(s.event_counts[&no_reply], 4);
    }

    #[test]
    fn start_up_is_recorded_like_every_event_and_counted_once_in_the_metrics() {
        let registry = prometheus::Registry::new();
        let metrics = crate::line::metrics::LineFamilies::register(&registry).expect("register");
        let line = LineMetrics::new(Some(metrics), "drive", "modbus-master-rtu");
        let shared = Shared::with_metrics(status(), 9, Clock::start(), line);
        let mut rx = shared.subscribe();
        shared.started();
        shared.raise(EventId::new(0x08, 0x30), Some(2), None);
        let s = shared.snapshot();
        assert!(s.port_open);
        assert_eq!(s.port_opens, 1);
        assert_eq!(s.event_counts[&ids::PTP_PARAMS_ACCEPTED], 1);
        let newest_first: Vec<EventId> = s.diagnostics.iter().map(|e| e.id).collect();
        assert_eq!(
            newest_first,
            [EventId::new(0x08, 0x30), ids::PTP_PARAMS_ACCEPTED]
        );
        assert_eq!(rx.try_recv().unwrap().id, ids::PTP_PARAMS_ACCEPTED);
        let text = crate::metrics::encode_text(&registry);
        for expected in [
            r#"gateway_events_total{class="00",class_name="cp start-up",event="0003",line="drive"} 1"#,
            r#"gateway_events_total{class="08",class_name="receive error",event="0830",line="drive"} 1"#,
            r#"gateway_line_up{line="drive",protocol="modbus-master-rtu"} 1"#,
        ] {
            assert!(text.contains(expected), "{expected} missing in\n{text}");
        }
        shared.port_closed();
        assert!(!shared.snapshot().port_open);
        let text = crate::metrics::encode_text(&registry);
        assert!(text.contains(r#"gateway_line_up{line="drive",protocol="modbus-master-rtu"} 0"#));
    }
}
