//! The running gateway as the REST API shows it: line views with their counters since the line
//! started, device views.
//!
//! Every line counts its frames, bytes and commands itself since it started
//! ([`LineHandle::traffic`](crate::line::LineHandle::traffic)); the Prometheus families are fed
//! from the same counting, cumulative over the process.

use super::lines::RunningLine;
use crate::api::model::{
    DeviceStatusView, EventCount, EventView, LineCounters, LineState, LineStatusView,
    PollCycleView, Timestamp,
};
use crate::line::{LineStatus, LineTraffic};

/// The view of one line.
pub(crate) fn line_view(
    name: &str,
    line: &RunningLine,
    status: &LineStatus,
    traffic: LineTraffic,
) -> LineStatusView {
    let state = if line.token.is_cancelled() {
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
    let devices: Vec<DeviceStatusView> = status
        .devices
        .iter()
        .map(|d| DeviceStatusView {
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
        })
        .collect();
    LineStatusView {
        name: name.to_owned(),
        protocol: line.protocol.to_owned(),
        port: line.port.clone(),
        port_b: line.port_b.clone(),
        state,
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

/// The config's name of a table.
fn table_name(table: crate::image::Table) -> &'static str {
    match table {
        crate::image::Table::HoldingRegisters => "holding",
        crate::image::Table::InputRegisters => "input",
        crate::image::Table::Coils => "coil",
        crate::image::Table::DiscreteInputs => "discrete",
    }
}

/// A duration in whole milliseconds.
fn millis(d: std::time::Duration) -> u64 {
    u64::try_from(d.as_millis()).unwrap_or(u64::MAX)
}
