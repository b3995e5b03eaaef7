//! The zenoh bridge wired to the running gateway: the backend that answers queries and commands
//! from the image, the tags and the lines, and the tasks that feed publications (tag values on
//! change, events, device presence).
//!
//! A write from zenoh takes the same path and the same checks as a Modbus TCP write: the tag is
//! encoded by its profile, the server's read-only mode and write ranges are applied, and the
//! request goes to the device's unit service, which answers with the device's answer.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::time::Duration;

use proto_core::event;
use proto_core::modbus::pdu::ExceptionCode;
use proto_core::profiles::Value;
use serde_json::{json, Value as Json};
use tokio::sync::broadcast::error::RecvError;
use tokio_util::sync::CancellationToken;
use tracing::{debug, warn};

use super::Running;
use crate::image::ProcessImage;
use crate::line::{LineEvent, LineHandle, LineStatus, SlaveLineHandle};
use crate::modbus_tcp::{ServerOptions, SharedUnits};
use crate::tags::{TagDirectory, TagEntry, TagWriteError};
use crate::zenoh_bridge::{BackendFuture, BridgeBackend, BridgeHandle, TagValue};

/// How often device presence is compared with the last published state.
const PRESENCE_PERIOD: Duration = Duration::from_millis(500);

/// What the bridge asks of the gateway.
pub(crate) struct GatewayBackend {
    pub(crate) name: String,
    pub(crate) image: ProcessImage,
    pub(crate) tags: Arc<TagDirectory>,
    pub(crate) lines: BTreeMap<String, LineHandle>,
    pub(crate) slave_lines: BTreeMap<String, SlaveLineHandle>,
    pub(crate) protocols: BTreeMap<String, &'static str>,
    pub(crate) units: SharedUnits,
    pub(crate) server: ServerOptions,
}

// === impl GatewayBackend ===

impl GatewayBackend {
    /// The backend over `running`.
    pub(crate) fn new(
        name: &str,
        running: &Running,
        tags: Arc<TagDirectory>,
        protocols: BTreeMap<String, &'static str>,
        server: ServerOptions,
    ) -> Self {
        Self {
            name: name.to_owned(),
            image: running.image.clone(),
            tags,
            lines: running
                .lines
                .iter()
                .map(|(k, v)| (k.clone(), v.clone()))
                .collect(),
            slave_lines: running
                .slave_lines
                .iter()
                .map(|(k, v)| (k.clone(), v.clone()))
                .collect(),
            protocols,
            units: Arc::clone(&running.units),
            server,
        }
    }

    /// A second backend over the same parts (one goes to the bridge, one feeds it).
    pub(crate) fn clone_for_bridge(&self) -> Self {
        Self {
            name: self.name.clone(),
            image: self.image.clone(),
            tags: Arc::clone(&self.tags),
            lines: self.lines.clone(),
            slave_lines: self.slave_lines.clone(),
            protocols: self.protocols.clone(),
            units: Arc::clone(&self.units),
            server: self.server.clone(),
        }
    }

    fn status_of(&self, line: &str) -> Option<LineStatus> {
        self.lines
            .get(line)
            .map(LineHandle::status)
            .or_else(|| self.slave_lines.get(line).map(SlaveLineHandle::status))
    }
}

impl BridgeBackend for GatewayBackend {
    fn lines(&self) -> Vec<String> {
        self.protocols.keys().cloned().collect()
    }

    fn query_tags(
        &self,
        line: Option<&str>,
        device: Option<&str>,
        tag: Option<&str>,
    ) -> Vec<(String, String, String, TagValue)> {
        self.tags
            .iter()
            .filter(|e| line.is_none_or(|l| l == e.line))
            .filter(|e| device.is_none_or(|d| d == e.device))
            .filter(|e| tag.is_none_or(|t| t.eq_ignore_ascii_case(&e.tag.name)))
            .filter_map(|e| {
                let value = tag_value(&self.tags, &self.image, e)?;
                Some((e.line.clone(), e.device.clone(), e.tag.name.clone(), value))
            })
            .collect()
    }

    fn line_status(&self, line: &str) -> Option<Json> {
        let protocol = *self.protocols.get(line)?;
        Some(match self.status_of(line) {
            Some(status) => status_json(&status, protocol),
            None => json!({ "name": line, "protocol": protocol, "served": false }),
        })
    }

    fn gateway_status(&self) -> Json {
        let lines: Vec<Json> = self
            .protocols
            .keys()
            .filter_map(|l| self.line_status(l))
            .collect();
        json!({
            "name": self.name,
            "version": env!("CARGO_PKG_VERSION"),
            "lines": lines,
        })
    }

    fn send_telegram(&self, line: &str, _bytes: Vec<u8>) -> BackendFuture<Result<Json, String>> {
        let answer = Err(format!("line {line} does not send telegrams"));
        Box::pin(async move { answer })
    }

    fn write_tag(
        &self,
        line: &str,
        device: &str,
        tag: &str,
        value: Json,
    ) -> BackendFuture<Result<Json, String>> {
        let prepared = self.prepare_write(line, device, tag, &value);
        Box::pin(async move {
            let (service, request, name) = prepared?;
            match service.call(request).await {
                Ok(_) => Ok(json!({ "tag": name, "written": value })),
                Err(code) => Err(TagWriteError::Exception(code).to_string()),
            }
        })
    }
}

type PreparedWrite = (
    Arc<dyn crate::unit::UnitService>,
    proto_core::modbus::pdu::Request,
    String,
);

impl GatewayBackend {
    /// The unit service and the checked request of a tag write, or why there is none.
    fn prepare_write(
        &self,
        line: &str,
        device: &str,
        tag: &str,
        value: &Json,
    ) -> Result<PreparedWrite, String> {
        let entry = self
            .tags
            .find(line, device, tag)
            .ok_or_else(|| format!("no tag {line}/{device}/{tag}"))?;
        let number = match value {
            Json::Number(n) => n.as_f64(),
            Json::Bool(b) => Some(f64::from(u8::from(*b))),
            Json::Object(o) => o.get("value").and_then(Json::as_f64),
            _ => None,
        }
        .ok_or_else(|| format!("value {value} is not a number (send a JSON number)"))?;
        let request = TagDirectory::write_request(entry, number).map_err(|e| e.to_string())?;
        if self.server.read_only {
            return Err(
                TagWriteError::Exception(ExceptionCode::IllegalFunction).to_string()
                    + " (read-only gateway)",
            );
        }
        if let Some(code) = self.server.check_write(entry.unit_id, &request) {
            return Err(TagWriteError::Exception(code).to_string() + " (outside the write ranges)");
        }
        let service = self
            .units
            .read()
            .ok()
            .and_then(|u| u.get(entry.unit_id).cloned())
            .ok_or_else(|| format!("unit {} is not served", entry.unit_id))?;
        Ok((
            service,
            request,
            format!("{line}/{device}/{}", entry.tag.name),
        ))
    }
}

/// A tag's value as the bridge publishes it.
fn tag_value(tags: &TagDirectory, image: &ProcessImage, entry: &TagEntry) -> Option<TagValue> {
    let reading = tags.read(image, entry)?;
    let value = match reading.value {
        Value::Int(v) => json!(v),
        Value::Float(v) => json!(v),
        Value::Bool(v) => json!(v),
    };
    let unit = (!reading.unit.is_empty()).then_some(reading.unit);
    Some(TagValue {
        value,
        unit,
        quality: reading.quality,
        timestamp: reading.timestamp,
    })
}

/// A line's status as JSON.
pub(crate) fn status_json(status: &LineStatus, protocol: &str) -> Json {
    let last = status.last_event.as_ref().map(|e| event_json(e.id));
    json!({
        "name": status.name,
        "protocol": protocol,
        "port_open": status.port_open,
        "port_error": status.port_error,
        "port_opens": status.port_opens,
        "status_word": format!("{:04X}", status.status_word),
        "last_event": last,
        "commands_answered": status.commands_answered,
        "commands_failed": status.commands_failed,
        "events": status.event_counts.iter().map(|(id, n)| json!({
            "event": format!("{:02X}{:02X}", id.class, id.number), "count": n })).collect::<Vec<_>>(),
        "devices": status.devices.iter().map(|d| json!({
            "name": d.name, "slave": d.slave, "unit_id": d.unit_id, "online": d.online,
            "polls_ok": d.polls_ok, "polls_exception": d.polls_exception, "polls_failed": d.polls_failed,
        })).collect::<Vec<_>>(),
    })
}

fn event_json(id: event::EventId) -> Json {
    let info = event::lookup(id);
    json!({
        "class": format!("{:02X}", id.class),
        "number": format!("{:02X}", id.number),
        "class_name": event::class_name(id.class),
        "description": info.map(|i| i.description),
        "remedy": info.map(|i| i.remedy),
    })
}

/// Starts the tasks that feed the bridge: tag values on change, line events, device presence.
pub(crate) fn spawn_feeds(
    bridge: &BridgeHandle,
    backend: &GatewayBackend,
    shutdown: &CancellationToken,
) {
    // Tag values on change: every image change maps to the tags it overlaps.
    {
        let bridge = bridge.clone();
        let tags = Arc::clone(&backend.tags);
        let image = backend.image.clone();
        let mut changes = image.subscribe();
        let shutdown = shutdown.clone();
        tokio::spawn(async move {
            loop {
                let change = tokio::select! {
                    () = shutdown.cancelled() => return,
                    change = changes.recv() => change,
                };
                match change {
                    Ok(change) => {
                        let count = u16::try_from(change.values.len()).unwrap_or(u16::MAX);
                        for entry in
                            tags.overlapping(change.unit, change.table, change.start, count)
                        {
                            if let Some(value) = tag_value(&tags, &image, entry) {
                                bridge.publish_tag(
                                    &entry.line,
                                    &entry.device,
                                    &entry.tag.name,
                                    value,
                                );
                            }
                        }
                    }
                    Err(RecvError::Lagged(n)) => {
                        // The newest values follow; publishing skipped ones would be stale.
                        debug!(
                            skipped = n,
                            "zenoh feed fell behind the image; newest values win"
                        );
                    }
                    Err(RecvError::Closed) => return,
                }
            }
        });
    }
    // Events of every line.
    let receivers: Vec<_> = backend
        .lines
        .values()
        .map(LineHandle::subscribe_events)
        .chain(
            backend
                .slave_lines
                .values()
                .map(SlaveLineHandle::subscribe_events),
        )
        .collect();
    for mut events in receivers {
        let bridge = bridge.clone();
        let shutdown = shutdown.clone();
        tokio::spawn(async move {
            loop {
                let received = tokio::select! {
                    () = shutdown.cancelled() => return,
                    e = events.recv() => e,
                };
                match received {
                    Ok(e) => publish_event(&bridge, &e),
                    Err(RecvError::Lagged(n)) => {
                        warn!(missed = n, "zenoh event feed fell behind a line")
                    }
                    Err(RecvError::Closed) => return,
                }
            }
        });
    }
    // Device presence: a liveliness token per online device.
    let bridge = bridge.clone();
    let lines: Vec<LineHandle> = backend.lines.values().cloned().collect();
    let shutdown = shutdown.clone();
    tokio::spawn(async move {
        let mut online: BTreeSet<(String, String)> = BTreeSet::new();
        let mut ticker = tokio::time::interval(PRESENCE_PERIOD);
        loop {
            tokio::select! {
                () = shutdown.cancelled() => return,
                _ = ticker.tick() => {}
            }
            for line in &lines {
                let status = line.status();
                for d in &status.devices {
                    let key = (status.name.clone(), d.name.clone());
                    if d.online && online.insert(key.clone()) {
                        bridge.device_online(&key.0, &key.1, true);
                    } else if !d.online && online.remove(&key) {
                        bridge.device_online(&key.0, &key.1, false);
                    }
                }
            }
        }
    });
}

fn publish_event(bridge: &BridgeHandle, e: &LineEvent) {
    let name = event::class_name(e.id.class).unwrap_or("unknown");
    let text = event::lookup(e.id).map_or("", |i| i.description);
    if bridge
        .publish_event(&e.line, e.id.class, e.id.number, name, text)
        .is_err()
    {
        debug!(line = %e.line, event = %e.id, "zenoh event queue full; the drop is counted");
    }
}
