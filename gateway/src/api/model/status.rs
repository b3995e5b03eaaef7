//! Gateway and line status.
//!
//! A line's view is built here from the line's status model and nowhere else: REST, zenoh and
//! the status page serve the same JSON for a line.

use std::time::Duration;

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::{EventView, Timestamp};
use crate::image::Table;
use crate::line::{DeviceStatus, LineStatus, LineTraffic};

/// The whole gateway (`GET /api/v1/status`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct GatewayStatus {
    /// `[gateway] name`.
    pub name: String,
    /// The gateway's version.
    pub version: String,
    /// When the process started.
    pub started: Timestamp,
    /// Seconds since the start.
    pub uptime_seconds: u64,
    /// What `/readyz` answers.
    pub ready: bool,
    /// Every line.
    pub lines: Vec<LineStatusView>,
    pub modbus_tcp: ModbusTcpStatus,
    /// Absent when zenoh is not configured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub zenoh: Option<ZenohStatus>,
}

/// The state of a line's task and port.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum LineState {
    /// The task started and has not opened its port yet.
    Starting,
    /// The port is open and the protocol runs.
    Running,
    /// The port failed or was lost; the line reopens it after a back-off.
    PortClosed,
    /// The line is being restarted after a configuration change.
    Restarting,
    /// The line task ended.
    Stopped,
}

/// One line (`GET /api/v1/lines/{line}`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, ToSchema)]
pub struct LineStatusView {
    pub name: String,
    /// The line's `protocol` (`modbus-master-rtu`, `modbus-master-ascii`, `modbus-slave-rtu`,
    /// `modbus-rtu-tap` (a listen-only tap: it never transmits, its devices refuse writes),
    /// `3964r`, `3964r-tap` (a listen-only tap of both directions of a 3964(R) link: its
    /// mailbox refuses sends), `ascii`).
    pub protocol: String,
    /// The serial port's path.
    pub port: String,
    /// The second receive port of a `3964r-tap` line (`port_b`: partner B's transmit line).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub port_b: Option<String>,
    pub state: LineState,
    /// Whether the serial port is open (`state` is `running` then, unless the line is
    /// restarting).
    pub port_open: bool,
    /// When the line's task started: a configuration change that restarts the line moves it,
    /// one that leaves the line alone does not.
    pub started: Timestamp,
    /// Why the port last failed to open or was lost.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub port_error: Option<String>,
    /// How often the port was opened (1 after a clean start).
    pub port_opens: u64,
    /// The STATUS word of the newest event (0 before any event).
    pub status_word: u16,
    /// The newest event, decoded from `status_word` with the catalog.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub last_event: Option<EventView>,
    pub counters: LineCounters,
    /// Events counted by class and number since the line started.
    pub event_counts: Vec<EventCount>,
    /// Devices answering (Modbus master lines; 0 otherwise).
    pub devices_online: usize,
    /// Devices polled (Modbus master lines; 0 otherwise).
    pub devices_total: usize,
    pub devices: Vec<DeviceStatusView>,
}

/// Counters of a line since it started; those a protocol does not have stay 0.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct LineCounters {
    /// Frames or telegrams sent.
    pub frames_sent: u64,
    /// Frames or telegrams received complete and valid.
    pub frames_received: u64,
    pub bytes_sent: u64,
    pub bytes_received: u64,
    /// Diagnostic events raised.
    pub events: u64,
    /// Commands (writes, on-demand reads, telegrams to send) completed.
    pub commands_answered: u64,
    /// Commands that failed (no answer, queue full).
    pub commands_failed: u64,
}

/// How often one event occurred.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct EventCount {
    pub event: EventView,
    pub count: u64,
}

/// One polled device.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct DeviceStatusView {
    pub name: String,
    /// Its Modbus address on the serial line.
    pub address: u8,
    /// Its Modbus TCP unit id.
    pub unit_id: u8,
    /// Whether it answers (not backed off).
    pub online: bool,
    pub polls_ok: u64,
    pub polls_exception: u64,
    pub polls_failed: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub last_answer: Option<Timestamp>,
    /// Commands (writes, on-demand reads, pass-through requests) without a valid answer; each
    /// failed for its own client only and does not put the device offline.
    #[serde(default)]
    pub commands_failed: u64,
    /// The planned and achieved cycle of each poll block (one read of the device's poll groups
    /// of one table and period).
    #[serde(default)]
    pub cycles: Vec<PollCycleView>,
}

/// What a line's status does not say about the line: its configuration and its task.
#[derive(Debug, Clone, Copy)]
pub struct LinePlace<'a> {
    /// The line's name.
    pub name: &'a str,
    /// The line's `protocol`.
    pub protocol: &'a str,
    /// The serial port's path.
    pub port: &'a str,
    /// The second receive port of a `3964r-tap` line.
    pub port_b: Option<&'a str>,
    /// Whether the line's task is being replaced after a configuration change.
    pub restarting: bool,
}

// === impl LineStatusView ===

impl LineStatusView {
    /// The view of the line at `place` from its status and its traffic since it started.
    pub fn new(place: LinePlace<'_>, status: &LineStatus, traffic: LineTraffic) -> Self {
        let state = if place.restarting {
            LineState::Restarting
        } else if status.port_open {
            LineState::Running
        } else if status.port_opens == 0 && status.port_error.is_none() {
            LineState::Starting
        } else {
            LineState::PortClosed
        };
        let counters = LineCounters {
            frames_sent: traffic.frames_sent,
            frames_received: traffic.frames_received,
            bytes_sent: traffic.bytes_sent,
            bytes_received: traffic.bytes_received,
            events: status.event_counts.values().sum(),
            commands_answered: traffic.commands_answered,
            commands_failed: traffic.commands_failed,
        };
        let devices: Vec<DeviceStatusView> =
            status.devices.iter().map(DeviceStatusView::new).collect();
        Self {
            name: place.name.to_owned(),
            protocol: place.protocol.to_owned(),
            port: place.port.to_owned(),
            port_b: place.port_b.map(str::to_owned),
            state,
            port_open: status.port_open,
            started: Timestamp(status.started),
            port_error: status.port_error.clone(),
            port_opens: status.port_opens,
            status_word: status.status_word,
            last_event: EventView::from_status_word(status.status_word).map(|mut view| {
                // The newest event's own words (the catalog's are generic: 02 0Fh says "invalid
                // parameterization" where the port was not found).
                view.detail = status
                    .last_event
                    .as_ref()
                    .filter(|e| e.id.status_word() == status.status_word)
                    .and_then(|e| e.detail.clone());
                view
            }),
            counters,
            event_counts: status
                .event_counts
                .iter()
                .map(|(id, n)| EventCount {
                    event: EventView::new(*id),
                    count: *n,
                })
                .collect(),
            devices_online: devices.iter().filter(|d| d.online).count(),
            devices_total: devices.len(),
            devices,
        }
    }
}

// === impl DeviceStatusView ===

impl DeviceStatusView {
    /// The view of one polled device.
    pub fn new(d: &DeviceStatus) -> Self {
        Self {
            name: d.name.clone(),
            address: d.slave,
            unit_id: d.unit_id,
            online: d.online,
            polls_ok: d.polls_ok,
            polls_exception: d.polls_exception,
            polls_failed: d.polls_failed,
            last_answer: d.last_answer.map(Timestamp),
            commands_failed: d.commands_failed,
            cycles: d
                .cycles
                .iter()
                .map(|c| PollCycleView {
                    table: table_name(c.table).to_owned(),
                    start: c.start,
                    count: c.count,
                    planned_ms: millis(c.planned),
                    bound_ms: millis(c.bound),
                    achieved_ms: c.achieved.map(millis),
                    achieved_max_ms: c.achieved_max.map(millis),
                })
                .collect(),
        }
    }
}

/// The config's name of a table.
fn table_name(table: Table) -> &'static str {
    match table {
        Table::HoldingRegisters => "holding",
        Table::InputRegisters => "input",
        Table::Coils => "coil",
        Table::DiscreteInputs => "discrete",
    }
}

/// A duration in whole milliseconds.
fn millis(d: Duration) -> u64 {
    u64::try_from(d.as_millis()).unwrap_or(u64::MAX)
}

/// The planned and achieved cycle of one poll block, in milliseconds.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct PollCycleView {
    /// The table read: `holding`, `input`, `coil` or `discrete`.
    pub table: String,
    /// The first address read.
    pub start: u16,
    /// How many addresses are read.
    pub count: u16,
    /// The configured period.
    pub planned_ms: u64,
    /// The longest cycle the line's fairness rule allows: the period, plus the request in flight
    /// when the poll fell due, plus for each poll block of the line one poll and
    /// `commands_in_row` commands, each exchange at its longest (reply monitoring time and
    /// repetitions).
    pub bound_ms: u64,
    /// The last cycle while the device answered.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub achieved_ms: Option<u64>,
    /// The longest cycle while the device answered.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub achieved_max_ms: Option<u64>,
}

/// The Modbus TCP server.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct ModbusTcpStatus {
    /// The address it listens on.
    pub listen: String,
    /// Whether the listener is bound.
    pub up: bool,
    /// Clients connected now.
    pub connections: u64,
    pub requests_total: u64,
    /// Requests answered with an exception.
    pub exceptions_total: u64,
}

/// The zenoh session.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct ZenohStatus {
    pub up: bool,
    /// `peer`, `client` or `router`.
    pub mode: String,
    pub publications_total: u64,
    /// While another zenoh session holds this gateway's name: who (bounded, escaped text);
    /// the gateway publishes nothing on zenoh meanwhile.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name_conflict: Option<String>,
}
