//! The zenoh bridge's backend over the running gateway ([`BridgeBackend`] over a [`Gateway`]):
//! it answers queries (lines, tags, statuses) and carries commands (sends, acknowledges, tag
//! writes) from the fabric. A write from zenoh takes the same path and checks as a Modbus TCP
//! write ([`super::tag_io`]).

use std::sync::Weak;

use proto_core::profiles::Value;
use serde_json::{json, Value as Json};

use super::gateway::Gateway;
use super::tag_io::{self, WriteRefused};
use super::zenoh as feeds;
use crate::api::model::ScalarValue;
use crate::protocols::telegram::TelegramSendError;
use crate::tags::TagWriteError;
use crate::zenoh_bridge::accounting::{self, WriteReason};
use crate::zenoh_bridge::{BackendFuture, BridgeBackend, TagValue};

/// What the bridge asks of the gateway: the running [`Gateway`], held weakly (the gateway holds
/// the bridge).
pub(crate) struct ZenohBackend {
    gateway: Weak<dyn Gateway>,
}

// === impl ZenohBackend ===

impl ZenohBackend {
    pub(crate) fn new(gateway: Weak<dyn Gateway>) -> Self {
        Self { gateway }
    }
}

impl BridgeBackend for ZenohBackend {
    fn lines(&self) -> Vec<String> {
        self.gateway
            .upgrade()
            .map(|g| g.in_force().lines().keys().cloned().collect())
            .unwrap_or_default()
    }

    fn query_tags(
        &self,
        line: Option<&str>,
        device: Option<&str>,
        tag: Option<&str>,
    ) -> Vec<(String, String, String, TagValue)> {
        let Some(gateway) = self.gateway.upgrade() else {
            return Vec::new();
        };
        let snapshot = gateway.in_force();
        snapshot
            .tags()
            .iter()
            .filter(|e| line.is_none_or(|l| l == e.line()))
            .filter(|e| device.is_none_or(|d| d == e.device()))
            .filter(|e| tag.is_none_or(|t| t.eq_ignore_ascii_case(e.name())))
            .filter_map(|e| {
                let value = feeds::tag_value(snapshot.tags(), gateway.image(), e)?;
                Some((
                    e.line().to_owned(),
                    e.device().to_owned(),
                    e.name().to_owned(),
                    value,
                ))
            })
            .collect()
    }

    /// The line's view, as REST's `GET /api/v1/lines/{line}` answers it.
    fn line_status(&self, line: &str) -> Option<Json> {
        let snapshot = self.gateway.upgrade()?.in_force();
        let running = snapshot.lines().get(line)?;
        serde_json::to_value(super::gateway::line_view(line, running)).ok()
    }

    fn gateway_status(&self) -> Json {
        self.gateway
            .upgrade()
            .map_or_else(|| json!({}), |gateway| gateway.fleet_status())
    }

    fn writes_allowed(&self) -> Result<(), String> {
        let on = self.gateway.upgrade().is_some_and(|gateway| {
            gateway
                .in_force()
                .config()
                .zenoh
                .as_ref()
                .is_some_and(|z| z.writes)
        });
        if on {
            Ok(())
        } else {
            Err("writes over zenoh are off ([zenoh] writes = false)".to_owned())
        }
    }

    fn send_telegram(&self, line: &str, bytes: Vec<u8>) -> BackendFuture<Result<Json, String>> {
        let metrics = self.metrics();
        let target = format!("{line}/tx ({} bytes)", bytes.len());
        if let Err(e) = self.writes_allowed() {
            accounting::refused(metrics.as_ref(), &target, WriteReason::WritesOff, &e);
            return Box::pin(async move { Err(e) });
        }
        let client = self
            .gateway
            .upgrade()
            .and_then(|g| g.in_force().lines().get(line)?.handle.telegram_client());
        let Some(client) = client else {
            let answer = format!("line {line} does not send telegrams");
            accounting::refused(metrics.as_ref(), &target, WriteReason::Policy, &answer);
            return Box::pin(async move { Err(answer) });
        };
        Box::pin(async move {
            let len = bytes.len();
            match client.send(bytes).await {
                Ok(()) => {
                    accounting::finished(metrics.as_ref(), &target, true, &"sent");
                    Ok(json!({ "sent": len }))
                }
                Err(e) => {
                    let refused = matches!(
                        e,
                        TelegramSendError::NotAllowed { .. } | TelegramSendError::ListenOnly { .. }
                    );
                    let e = e.to_string();
                    if refused {
                        accounting::refused(metrics.as_ref(), &target, WriteReason::Policy, &e);
                    } else {
                        accounting::finished(metrics.as_ref(), &target, false, &e);
                    }
                    Err(e)
                }
            }
        })
    }

    fn ack_telegram(&self, line: &str, seq: u16) -> BackendFuture<Result<Json, String>> {
        let metrics = self.metrics();
        let target = format!("{line}/telegrams/{seq} ack");
        if let Err(e) = self.writes_allowed() {
            accounting::refused(metrics.as_ref(), &target, WriteReason::WritesOff, &e);
            return Box::pin(async move { Err(e) });
        }
        let mailbox = self
            .gateway
            .upgrade()
            .and_then(|g| g.in_force().lines().get(line)?.handle.mailbox());
        let Some(mailbox) = mailbox else {
            let answer = format!("line {line} does not receive telegrams");
            accounting::refused(
                metrics.as_ref(),
                &target,
                WriteReason::UnknownTarget,
                &answer,
            );
            return Box::pin(async move { Err(answer) });
        };
        let answer = match mailbox.ack(seq) {
            Ok(()) => {
                accounting::finished(metrics.as_ref(), &target, true, &"acknowledged");
                Ok(json!({ "acknowledged": seq }))
            }
            Err(e) => {
                let e = e.to_string();
                accounting::refused(metrics.as_ref(), &target, WriteReason::Policy, &e);
                Err(e)
            }
        };
        Box::pin(async move { answer })
    }

    fn write_tag(
        &self,
        line: &str,
        device: &str,
        tag: &str,
        value: Json,
    ) -> BackendFuture<Result<Json, String>> {
        let prepared = self
            .writes_allowed()
            .map_err(|e| (WriteReason::WritesOff, e))
            .and_then(|()| self.prepare_write(line, device, tag, &value));
        let metrics = self.metrics();
        let target = format!("{line}/{device}/{tag} = {value}");
        Box::pin(async move {
            let (write, name) = match prepared {
                Ok(prepared) => prepared,
                Err((reason, e)) => {
                    accounting::refused(metrics.as_ref(), &target, reason, &e);
                    return Err(e);
                }
            };
            match write.send().await {
                Ok(_) => {
                    accounting::finished(metrics.as_ref(), &target, true, &"ok");
                    Ok(json!({ "tag": name, "written": value }))
                }
                Err(code) => {
                    let e = TagWriteError::Exception(code).to_string();
                    accounting::finished(metrics.as_ref(), &target, false, &e);
                    Err(e)
                }
            }
        })
    }
}

impl ZenohBackend {
    /// The audit's family the bridge's commands are counted in (while the gateway runs).
    fn metrics(&self) -> Option<crate::audit::AuditMetrics> {
        self.gateway.upgrade().map(|g| g.audit_metrics().clone())
    }

    /// The checked write of a JSON value, or why there is none (and which check refused it).
    fn prepare_write(
        &self,
        line: &str,
        device: &str,
        tag: &str,
        value: &Json,
    ) -> Result<(tag_io::PreparedWrite, String), (WriteReason, String)> {
        let gateway = self
            .gateway
            .upgrade()
            .ok_or((WriteReason::Policy, "the gateway is stopping".to_owned()))?;
        let value = json_value(value).ok_or_else(|| {
            (
                WriteReason::BadPayload,
                format!(
                    "value {value} is not a number, a bool or a text (send JSON: 4.5, true, \"SN-1\")"
                ),
            )
        })?;
        let snapshot = gateway.in_force();
        let (tags, writes) = (snapshot.tags(), snapshot.writes());
        let write = tag_io::prepare_write(tags, writes, gateway.units(), line, device, tag, &value)
            .map_err(|e| {
                let reason = match e {
                    WriteRefused::Tag(TagWriteError::UnknownTag(_)) => WriteReason::UnknownTarget,
                    _ => WriteReason::Policy,
                };
                (reason, e.to_string())
            })?;
        let name = format!("{line}/{device}/{}", write.entry.name());
        Ok((write, name))
    }
}

/// The value of a tag write sent as JSON: a number (whole numbers exact up to 64 bits), a bool,
/// a string, or an object with one of them under `value`.
fn json_value(value: &Json) -> Option<Value> {
    let scalar = match value {
        Json::Object(o) => o.get("value").filter(|v| !v.is_object())?,
        other => other,
    };
    // As a REST tag write reads its `value`.
    let scalar: ScalarValue = serde_json::from_value(scalar.clone()).ok()?;
    Some(scalar.into())
}
