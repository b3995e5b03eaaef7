//! Gateway and line status.

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::{EventView, Timestamp};

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
}
