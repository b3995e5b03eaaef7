//! The REST API's backend over the running gateway ([`ApiBackend`] over a [`Gateway`], app/'s
//! supervisor).
//!
//! Status and diagnostics come from the line handles of the configuration in force; telegrams from the
//! telegram line's mailbox (the same queue Modbus TCP clients acknowledge through), sends through
//! its `TelegramClient`, signals through its `SignalsClient`; tags from the tag directory over
//! the process image, tag writes through the device's unit service with the Modbus TCP server's
//! checks ([`super::tag_io`]). What only the running gateway knows (overrides, applying a
//! configuration, the fleet, the gateway's status and readiness) it answers itself.

use std::sync::Arc;

use crate::api::auth::Caller;
use crate::api::model::{
    ApplyReport, ConfigOverride, DiagRecord, DiagSnapshot, GatewayStatus, LineStatusView,
    Readiness, ScalarValue, SendResult, Signals, SignalsPatch, TagQuality, TagValue, Telegram,
    TelegramQueue, Timestamp,
};
use crate::api::{ApiBackend, ApiError, BoxFuture};
use crate::audit::{self, WritePath, WriteResult};
use crate::config::ConfigIssue;
use crate::line::LineHandle;
use crate::plant::Config;
use crate::protocols::telegram::TelegramSendError;
use crate::signals::{Output, SignalError};
use crate::tags::TagEntry;

use super::gateway::{line_view, Gateway, InForce, RunningLine};
use super::tag_io::{self, WriteRefused};

/// The API's view of the running gateway.
pub(crate) struct RestBackend {
    gateway: Arc<dyn Gateway>,
    /// The address the HTTP listener bound, once bound (for `--http` in `GET /config`).
    http_local: std::sync::OnceLock<std::net::SocketAddr>,
}

// === impl RestBackend ===

impl RestBackend {
    pub(crate) fn new(gateway: Arc<dyn Gateway>) -> Self {
        Self {
            gateway,
            http_local: std::sync::OnceLock::new(),
        }
    }

    /// Where the HTTP listener listens, once bound.
    pub(crate) fn set_http_local(&self, local: std::net::SocketAddr) {
        let _ = self.http_local.set(local);
    }

    fn line<'a>(snapshot: &'a dyn InForce, line: &str) -> Result<&'a RunningLine, ApiError> {
        snapshot
            .lines()
            .get(line)
            .ok_or_else(|| ApiError::not_found("line", line))
    }

    /// What `get` finds on a telegram line; a conflict on a line that carries no telegrams.
    fn telegram_line<T>(
        snapshot: &dyn InForce,
        line: &str,
        get: impl FnOnce(&LineHandle) -> Option<T>,
    ) -> Result<T, ApiError> {
        get(&Self::line(snapshot, line)?.handle).ok_or_else(|| {
            ApiError::conflict(format!(
                "line {line} is a Modbus line: it carries no telegrams (3964(R) and ASCII lines do)"
            ))
        })
    }

    /// A tag's value from the image; `None` while its registers are not in the image.
    fn image_value(&self, snapshot: &dyn InForce, entry: &TagEntry) -> Option<TagValue> {
        let reading = snapshot.tags().read(self.gateway.image(), entry)?;
        Some(TagValue {
            description: entry.description().to_owned(),
            ..TagValue::from_reading(
                entry.line(),
                entry.device(),
                entry.name(),
                entry.writable(),
                reading,
            )
        })
    }

    /// The value of a tag, read from the device when the image does not have it.
    async fn read_tag(&self, line: &str, device: &str, tag: &str) -> Result<TagValue, ApiError> {
        let snapshot = self.gateway.in_force();
        Self::line(&*snapshot, line)?;
        let entry = snapshot
            .tags()
            .find(line, device, tag)
            .ok_or_else(|| ApiError::not_found("tag", &format!("{line}/{device}/{tag}")))?
            .clone();
        if let Some(value) = self.image_value(&*snapshot, &entry) {
            return Ok(value);
        }
        let service = tag_io::service(self.gateway.units(), entry.unit_id()).ok_or_else(|| {
            ApiError::conflict(format!(
                "unit {} of {line}/{device} is not served",
                entry.unit_id()
            ))
        })?;
        let response = service.call(tag_io::read_request(&entry)).await?;
        let reading = tag_io::reading_from(&entry, &response).ok_or_else(|| {
            ApiError::internal(format!(
                "the device answered the read of {tag} with another function"
            ))
        })?;
        Ok(TagValue {
            description: entry.description().to_owned(),
            ..TagValue::from_reading(line, device, entry.name(), entry.writable(), reading)
        })
    }
}

fn refused(e: WriteRefused) -> ApiError {
    match e {
        WriteRefused::Tag(t) => t.into(),
        other => ApiError::conflict(other.to_string()),
    }
}

fn signal_error(e: SignalError) -> ApiError {
    match e {
        SignalError::PortClosed { .. } | SignalError::ShuttingDown { .. } => {
            ApiError::busy(e.to_string())
        }
        SignalError::Unsupported { .. }
        | SignalError::NotRs232 { .. }
        | SignalError::DrivenByDriver { .. }
        | SignalError::ListenOnly { .. } => ApiError::conflict(e.to_string()),
    }
}

fn signals_view(s: crate::signals::ModemSignals) -> Signals {
    Signals {
        dtr: s.dtr.unwrap_or(false),
        rts: s.rts.unwrap_or(false),
        dsr: s.dsr,
        cts: s.cts,
        dcd: s.dcd,
        ri: s.ri,
    }
}

impl ApiBackend for RestBackend {
    fn config(&self) -> Arc<Config> {
        Arc::clone(self.gateway.in_force().config())
    }

    fn overrides(&self) -> Vec<ConfigOverride> {
        self.gateway.overrides(self.http_local.get().copied())
    }

    fn validate(&self, config: &Config) -> Result<(), Vec<ConfigIssue>> {
        self.gateway.validate(config)
    }

    fn config_issues(&self, config: &Config, found: &[ConfigIssue]) -> Vec<ConfigIssue> {
        self.gateway.config_issues(config, found)
    }

    fn apply(&self, config: Arc<Config>) -> BoxFuture<'_, Result<ApplyReport, ApiError>> {
        Arc::clone(&self.gateway).apply(config)
    }

    fn fleet(&self) -> Vec<crate::api::model::FleetEntry> {
        self.gateway
            .fleet()
            .into_iter()
            .map(|m| crate::api::model::FleetEntry {
                link: m
                    .http
                    .as_deref()
                    .filter(|u| crate::zenoh_bridge::fleet::plain_http_url(u))
                    .map(|u| format!("{}/", u.trim_end_matches('/'))),
                http: m.http,
                key: m.key,
                name: m.name,
                zid: m.zid,
                host: m.host,
                online: m.online,
                since: Timestamp(m.since),
            })
            .collect()
    }

    fn gateway_status(&self) -> GatewayStatus {
        self.gateway.status()
    }

    fn line_status(&self, line: &str) -> Result<LineStatusView, ApiError> {
        let snapshot = self.gateway.in_force();
        let running = Self::line(&*snapshot, line)?;
        Ok(line_view(line, running))
    }

    fn monitor(&self, line: &str) -> Result<Arc<crate::line::FrameMonitor>, ApiError> {
        let snapshot = self.gateway.in_force();
        Self::line(&*snapshot, line)?
            .handle
            .monitor()
            .cloned()
            .ok_or_else(|| {
                ApiError::conflict(format!(
                    "line {line} has no frame monitor (monitor_frames = 0)"
                ))
            })
    }

    fn diag(&self, line: &str) -> Result<DiagSnapshot, ApiError> {
        let snapshot = self.gateway.in_force();
        let status = Self::line(&*snapshot, line)?.handle.status();
        Ok(DiagSnapshot {
            depth: usize::from(snapshot.config().gateway.diag_buffer_depth),
            entries: status
                .diagnostics
                .iter()
                .map(|e| DiagRecord::from_entry(e, status.started))
                .collect(),
        })
    }

    fn clear_diag(&self, line: &str) -> Result<(), ApiError> {
        let snapshot = self.gateway.in_force();
        // The line's own buffer is emptied: an event that comes again starts a new entry with a
        // count of 1, not the count it had before the clear.
        Self::line(&*snapshot, line)?.handle.clear_diagnostics();
        Ok(())
    }

    fn telegrams(&self, line: &str) -> Result<TelegramQueue, ApiError> {
        let mailbox = Self::telegram_line(&*self.gateway.in_force(), line, LineHandle::mailbox)?;
        Ok(TelegramQueue {
            line: line.to_owned(),
            capacity: mailbox.settings().queue_depth,
            dropped: mailbox.counters().overflows,
            telegrams: mailbox
                .waiting()
                .iter()
                .map(|t| {
                    Telegram::new(u32::from(t.seq), t.received, &t.data)
                        .from_side(t.side.map(proto_core::proc3964::tap::Side::as_str))
                })
                .collect(),
        })
    }

    fn ack_telegram(&self, line: &str, seq: u32) -> Result<(), ApiError> {
        let mailbox = Self::telegram_line(&*self.gateway.in_force(), line, LineHandle::mailbox)?;
        let waiting = mailbox.waiting();
        let Some(seq16) = u16::try_from(seq)
            .ok()
            .filter(|s| waiting.iter().any(|t| t.seq == *s))
        else {
            return Err(ApiError::not_found("telegram", &seq.to_string()));
        };
        mailbox.ack(seq16).map_err(|_| {
            ApiError::conflict(format!(
                "telegram {seq} is not the oldest; acknowledge {} first",
                waiting.first().map_or(0, |t| t.seq)
            ))
        })
    }

    fn send_telegram(
        &self,
        line: &str,
        data: Vec<u8>,
    ) -> BoxFuture<'_, Result<SendResult, ApiError>> {
        let client =
            Self::telegram_line(&*self.gateway.in_force(), line, LineHandle::telegram_client);
        Box::pin(async move {
            let client = client?;
            let len = data.len();
            match client.send(data).await {
                Ok(()) => Ok(SendResult::done(len)),
                Err(
                    e @ (TelegramSendError::QueueFull { .. } | TelegramSendError::ShuttingDown),
                ) => Err(ApiError::busy(e.to_string())),
                Err(e @ TelegramSendError::Refused(_)) => {
                    Err(ApiError::invalid_body(e.to_string()))
                }
                Err(
                    e @ (TelegramSendError::NotAllowed { .. }
                    | TelegramSendError::ListenOnly { .. }),
                ) => Err(ApiError::conflict(e.to_string())),
                Err(e @ (TelegramSendError::Failed { .. } | TelegramSendError::PortClosed)) => {
                    Ok(SendResult::failed(e.event().status_word(), len))
                }
            }
        })
    }

    fn tags(&self, line: Option<&str>, device: Option<&str>) -> Result<Vec<TagValue>, ApiError> {
        let snapshot = self.gateway.in_force();
        if let Some(l) = line {
            Self::line(&*snapshot, l)?;
        }
        Ok(snapshot
            .tags()
            .iter()
            .filter(|e| {
                line.is_none_or(|l| l == e.line()) && device.is_none_or(|d| d == e.device())
            })
            .map(|e| {
                self.image_value(&*snapshot, e).unwrap_or_else(|| TagValue {
                    line: e.line().to_owned(),
                    device: e.device().to_owned(),
                    tag: e.name().to_owned(),
                    value: None,
                    unit: e.unit().to_owned(),
                    quality: TagQuality::Unknown,
                    timestamp: None,
                    writable: e.writable(),
                    description: e.description().to_owned(),
                })
            })
            .collect())
    }

    fn tag(
        &self,
        line: &str,
        device: &str,
        tag: &str,
    ) -> BoxFuture<'_, Result<TagValue, ApiError>> {
        let (line, device, tag) = (line.to_owned(), device.to_owned(), tag.to_owned());
        Box::pin(async move { self.read_tag(&line, &device, &tag).await })
    }

    fn write_tag(
        &self,
        line: &str,
        device: &str,
        tag: &str,
        value: ScalarValue,
    ) -> BoxFuture<'_, Result<TagValue, ApiError>> {
        let snapshot = self.gateway.in_force();
        let prepared = Self::line(&*snapshot, line).and_then(|_| {
            tag_io::prepare_write(
                snapshot.tags(),
                snapshot.writes(),
                self.gateway.units(),
                line,
                device,
                tag,
                &value.clone().into(),
            )
            .map_err(refused)
        });
        let write = match prepared {
            Ok(write) => write,
            Err(e) => return Box::pin(async move { Err(e) }),
        };
        let (line, device) = (line.to_owned(), device.to_owned());
        let name = write.entry.name().to_owned();
        Box::pin(async move {
            write.send().await.map_err(ApiError::from)?;
            self.read_tag(&line, &device, &name).await
        })
    }

    fn signals(&self, line: &str) -> BoxFuture<'_, Result<Signals, ApiError>> {
        let handle = self.signals_client(line);
        Box::pin(async move {
            let client = handle?;
            client.read().await.map(signals_view).map_err(signal_error)
        })
    }

    fn set_signals(
        &self,
        line: &str,
        patch: SignalsPatch,
    ) -> BoxFuture<'_, Result<Signals, ApiError>> {
        let handle = self.signals_client(line);
        Box::pin(async move {
            let client = handle?;
            for (output, on) in [(Output::Dtr, patch.dtr), (Output::Rts, patch.rts)] {
                if let Some(on) = on {
                    client.set(output, on).await.map_err(signal_error)?;
                }
            }
            client.read().await.map(signals_view).map_err(signal_error)
        })
    }

    fn audit(
        &self,
        caller: &Caller,
        target: &dyn std::fmt::Display,
        result: WriteResult,
        detail: &dyn std::fmt::Display,
    ) {
        audit::record(
            Some(self.gateway.audit_metrics()),
            WritePath::Rest,
            caller,
            target,
            result,
            detail,
        );
    }

    fn readiness(&self) -> Readiness {
        self.gateway.readiness()
    }
}

impl RestBackend {
    fn signals_client(
        &self,
        line: &str,
    ) -> Result<crate::protocols::telegram::SignalsClient, ApiError> {
        let snapshot = self.gateway.in_force();
        Self::line(&*snapshot, line)?
            .handle
            .signals()
            .ok_or_else(|| {
                ApiError::conflict(format!(
                    "line {line}: the RS232 signals are served on 3964(R) and ASCII lines only"
                ))
            })
    }
}
