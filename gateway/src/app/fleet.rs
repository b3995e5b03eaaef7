//! The gateway as one member of a fleet: its status as `<prefix>/status` answers it (gateway,
//! lines, devices: online, STATUS word of the last event, ages), where it runs (host, HTTP
//! address), and the other gateways it sees for `GET /api/v1/fleet`.
//!
//! Each line's object is the line status the bridge answers on `<prefix>/<line>/status` and REST
//! on `/api/v1/lines/{line}` ([`line_view`]) with the fleet's fields added (`online`, `last_event_age_s`,
//! a device's `last_answer_age_s`), so that the line status stays defined in one place.

use std::net::SocketAddr;
use std::sync::PoisonError;
use std::time::SystemTime;

use serde_json::{json, Value as Json};

use super::supervisor::Supervisor;
use crate::feeds::gateway::{line_view, RunningLine};

/// Remembers where the HTTP listener is, for the fleet's links (`http` in the gateway status).
/// An unspecified address (`0.0.0.0`, `::`) is named by the host name.
pub(crate) fn set_http_url(sup: &Supervisor, scheme: &str, local: SocketAddr) {
    let host = if local.ip().is_unspecified() {
        host_name().unwrap_or_else(|| local.ip().to_string())
    } else if local.is_ipv6() {
        format!("[{}]", local.ip())
    } else {
        local.ip().to_string()
    };
    let _ = sup
        .http_url
        .set(format!("{scheme}://{host}:{}", local.port()));
}

/// The gateway status `<prefix>/status` answers (the bridge adds its `zenoh` member).
pub(crate) fn gateway_status(sup: &Supervisor) -> Json {
    let snapshot = sup.snapshot();
    let now = SystemTime::now();
    let lines: Vec<Json> = snapshot
        .lines
        .iter()
        .map(|(name, l)| line_json(name, l, now))
        .collect();
    json!({
        "name": snapshot.config.gateway.name,
        "version": env!("CARGO_PKG_VERSION"),
        "host": host_name(),
        "pid": std::process::id(),
        "http": sup.http_url.get(),
        "uptime_s": age(sup.started, now),
        "lines": lines,
    })
}

/// The other gateways seen on the fabric, as the bridge keeps them; empty without zenoh.
pub(crate) fn members(sup: &Supervisor) -> Vec<crate::zenoh_bridge::fleet::FleetMember> {
    sup.zenoh_state
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .as_ref()
        .and_then(|z| z.fleet.clone())
        .map(|f| f.members())
        .unwrap_or_default()
}

/// One line: its status view ([`line_view`]) with the fleet's fields.
pub(crate) fn line_json(name: &str, running: &RunningLine, now: SystemTime) -> Json {
    let status = running.handle.status();
    let mut line =
        serde_json::to_value(line_view(name, running)).unwrap_or_else(|_| json!({ "name": name }));
    line["online"] = json!(status.port_open);
    line["last_event_age_s"] = json!(status.last_event.as_ref().map(|e| age(e.time, now)));
    if let Some(devices) = line.get_mut("devices").and_then(Json::as_array_mut) {
        for device in devices {
            let found = status
                .devices
                .iter()
                .find(|d| device.get("name").and_then(Json::as_str) == Some(d.name.as_str()));
            if let Some(d) = found {
                device["last_answer_age_s"] = json!(d.last_answer.map(|t| age(t, now)));
            }
        }
    }
    line
}

/// Seconds from `then` to `now`, to the millisecond (0 for a time in the future).
fn age(then: SystemTime, now: SystemTime) -> f64 {
    let d = now.duration_since(then).unwrap_or_default();
    (d.as_secs_f64() * 1000.0).round() / 1000.0
}

/// The machine's host name, if the system gives one (Linux: the kernel's, as `hostname`
/// prints it; elsewhere `HOSTNAME`).
pub(crate) fn host_name() -> Option<String> {
    let name = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .or_else(|| std::env::var("HOSTNAME").ok())?;
    let name = name.trim();
    (!name.is_empty()).then(|| name.to_owned())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn ages_are_seconds_to_the_millisecond_and_never_negative() {
        let now = SystemTime::UNIX_EPOCH + Duration::from_secs(100);
        assert_eq!(age(now - Duration::from_millis(1500), now), 1.5);
        assert_eq!(age(now + Duration::from_secs(3), now), 0.0);
    }

    #[test]
    fn the_host_name_is_known() {
        assert!(host_name().is_some_and(|h| !h.is_empty()));
    }
}
