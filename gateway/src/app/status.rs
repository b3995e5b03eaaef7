//! The running gateway as the REST API shows it: line views with their counters since the line
//! started, device views.
//!
//! Frames and bytes of Modbus lines are counted only in the Prometheus families (labelled by
//! line, cumulative over the process): a line's counters are the family's value minus the value
//! when the line (re)started. Telegram lines keep their own counters with their mailbox.

use std::collections::BTreeMap;

use prometheus::Registry;

use super::lines::{LineKind, RunningLine};
use crate::api::model::{
    DeviceStatusView, EventCount, EventView, LineCounters, LineState, LineStatusView, Timestamp,
};
use crate::line::LineStatus;

/// Frames and bytes of one line, both directions.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct WireCounters {
    pub(crate) frames_sent: u64,
    pub(crate) frames_received: u64,
    pub(crate) bytes_sent: u64,
    pub(crate) bytes_received: u64,
}

// === impl WireCounters ===

impl WireCounters {
    /// The counts since `base` (a family's value at the line's start).
    pub(crate) fn since(self, base: Self) -> Self {
        Self {
            frames_sent: self.frames_sent.saturating_sub(base.frames_sent),
            frames_received: self.frames_received.saturating_sub(base.frames_received),
            bytes_sent: self.bytes_sent.saturating_sub(base.bytes_sent),
            bytes_received: self.bytes_received.saturating_sub(base.bytes_received),
        }
    }
}

/// `gateway_telegrams_total` and `gateway_bytes_total` of every line, from one gather.
pub(crate) fn wire_counters(registry: &Registry) -> WireCountersByLine {
    let mut out: BTreeMap<String, WireCounters> = BTreeMap::new();
    for family in registry.gather() {
        let bytes = match family.name() {
            "gateway_telegrams_total" => false,
            "gateway_bytes_total" => true,
            _ => continue,
        };
        for metric in family.get_metric() {
            let label = |name: &str| {
                metric
                    .get_label()
                    .iter()
                    .find(|l| l.name() == name)
                    .map(|l| l.value().to_owned())
            };
            let (Some(line), Some(direction)) = (label("line"), label("direction")) else {
                continue;
            };
            // Counter values are whole numbers kept as f64.
            #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
            let value = metric.get_counter().get_value().max(0.0) as u64;
            let entry = out.entry(line).or_default();
            match (bytes, direction.as_str()) {
                (false, "tx") => entry.frames_sent = value,
                (false, "rx") => entry.frames_received = value,
                (true, "tx") => entry.bytes_sent = value,
                (true, "rx") => entry.bytes_received = value,
                _ => {}
            }
        }
    }
    out
}

/// The view of one line.
pub(crate) fn line_view(
    name: &str,
    line: &RunningLine,
    status: &LineStatus,
    wire: WireCounters,
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
    let mut counters = LineCounters {
        frames_sent: wire.frames_sent,
        frames_received: wire.frames_received,
        bytes_sent: wire.bytes_sent,
        bytes_received: wire.bytes_received,
        events: status.event_counts.values().sum(),
        commands_answered: status.commands_answered,
        commands_failed: status.commands_failed,
    };
    if let LineKind::Telegram(h) = &line.kind {
        // The mailbox counts since this line started, exactly.
        let c = h.status().counters;
        counters.frames_sent = c.sent;
        counters.frames_received = c.received;
        counters.bytes_sent = c.sent_bytes;
        counters.bytes_received = c.received_bytes;
        counters.commands_answered = c.sent;
        counters.commands_failed = c.send_failed;
    }
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
        })
        .collect();
    LineStatusView {
        name: name.to_owned(),
        protocol: line.protocol.to_owned(),
        port: line.port.clone(),
        state,
        started: Timestamp(status.started),
        port_error: status.port_error.clone(),
        port_opens: status.port_opens,
        status_word: status.status_word,
        last_event: EventView::from_status_word(status.status_word),
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

/// [`WireCounters`] by line name.
pub(crate) type WireCountersByLine = BTreeMap<String, WireCounters>;
