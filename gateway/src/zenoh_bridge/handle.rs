//! [`BridgeHandle`], the producer side of the bridge (lines and the image queue telegrams, tag
//! values, frames, events and presence into the bounded [`Outbox`]; no method waits), and the
//! heartbeats that republish tag values whose policy asks for them.

use std::sync::Arc;
use std::time::{Duration, SystemTime};

use serde_json::json;
use tokio_util::sync::CancellationToken;

use super::keys::{self, Keys};
use super::metrics::{BridgeStats, DropReason, PublicationKind};
use super::policy::{Publishing, Verdict};
use super::publish::{self, Message, Outbox};
use super::{BridgeBackend, TagValue};

/// The producer side of the bridge, for lines and the image. Cheap to clone; no method waits.
#[derive(Clone)]
pub struct BridgeHandle {
    pub(super) keys: Arc<Keys>,
    pub(super) outbox: Arc<Outbox>,
    pub(super) stats: Arc<BridgeStats>,
    /// Deadbands and heartbeats of the tags.
    pub(super) publishing: Arc<Publishing>,
}

// === impl BridgeHandle ===

impl BridgeHandle {
    /// Queues a received telegram for `<prefix>/<line>/rx`. `Err` when it was dropped (queue
    /// full, bridge closed, bad line name); the drop is counted and logged.
    pub fn publish_telegram(
        &self,
        line: &str,
        seq: u64,
        received: SystemTime,
        bytes: Vec<u8>,
    ) -> Result<(), DropReason> {
        self.publish_telegram_from(line, seq, received, None, bytes)
    }

    /// [`Self::publish_telegram`] for a telegram partner `side` sent (a 3964(R) tap line): the
    /// attachment also carries `"side": "a"` or `"b"`.
    ///
    /// # Errors
    ///
    /// As [`Self::publish_telegram`].
    pub fn publish_telegram_from(
        &self,
        line: &str,
        seq: u64,
        received: SystemTime,
        side: Option<&str>,
        bytes: Vec<u8>,
    ) -> Result<(), DropReason> {
        self.push_telegram(line, seq, received, side, bytes, None)
    }

    /// [`Self::publish_telegram`] that tells, once the put was made, whether zenoh took it
    /// (`true`): a line that acknowledges on publication waits for it.
    ///
    /// # Errors
    ///
    /// As [`Self::publish_telegram`].
    pub fn publish_telegram_confirmed(
        &self,
        line: &str,
        seq: u64,
        received: SystemTime,
        bytes: Vec<u8>,
    ) -> Result<tokio::sync::oneshot::Receiver<bool>, DropReason> {
        let (done, taken) = tokio::sync::oneshot::channel();
        self.push_telegram(line, seq, received, None, bytes, Some(done))?;
        Ok(taken)
    }

    fn push_telegram(
        &self,
        line: &str,
        seq: u64,
        received: SystemTime,
        side: Option<&str>,
        bytes: Vec<u8>,
        done: Option<tokio::sync::oneshot::Sender<bool>>,
    ) -> Result<(), DropReason> {
        self.check(&[line])?;
        let mut attachment = json!({"seq": seq, "time": publish::rfc3339(received)});
        if let Some(side) = side {
            attachment["side"] = json!(side);
        }
        let pushed = self.outbox.push(Message {
            kind: PublicationKind::Telegram,
            key: self.keys.rx(line),
            payload: bytes,
            json: false,
            attachment: Some(attachment.to_string().into_bytes()),
            done,
        });
        if let Err(reason) = pushed {
            crate::warn_limited!(format!("zenoh telegram dropped {line}"), %line, seq, reason = reason.as_str(), "telegram not published on zenoh");
        }
        pushed
    }

    /// Queues a tag value for `<prefix>/<line>/<device>/<tag>`: see [`Self::publish_tags`].
    pub fn publish_tag(&self, line: &str, device: &str, tag: &str, value: TagValue) {
        self.publish_tags([([line, device, tag], value)]);
    }

    /// Queues tag values, each `([line, device, tag], value)` for `<prefix>/<line>/<device>/<tag>`,
    /// into the outbox at once (one lock, one wake-up of the publisher thread at most); a newer
    /// value of the same tag replaces one not yet published. The key is written into the outbox
    /// (no allocation per value), checked as a key expression once when it becomes pending, and
    /// published as it is.
    pub fn publish_tags<'a>(&self, tags: impl IntoIterator<Item = ([&'a str; 3], TagValue)>) {
        let now = tokio::time::Instant::now();
        let prefix = self.keys.prefix();
        let admitted: Vec<([&str; 4], TagValue)> = tags
            .into_iter()
            .filter(|([line, device, tag], value)| {
                self.check(&[line, device, tag]).is_ok()
                    && match self.publishing.admit((line, device, tag), value, now) {
                        Verdict::Publish => true,
                        Verdict::WithinDeadband => {
                            self.stats.suppressed_by_deadband();
                            false
                        }
                    }
            })
            .map(|([line, device, tag], value)| ([prefix, line, device, tag], value))
            .collect();
        self.outbox.push_tags(admitted);
    }

    /// Queues a monitored frame (JSON) for `<prefix>/<line>/frames`. `Err` when it was dropped
    /// (counted).
    pub fn publish_frame(&self, line: &str, json: Vec<u8>) -> Result<(), DropReason> {
        self.check(&[line])?;
        self.outbox.push(Message {
            kind: PublicationKind::Frame,
            key: self.keys.frames(line),
            payload: json,
            json: true,
            attachment: None,
            done: None,
        })
    }

    /// Queues an event for `<prefix>/<line>/events`. `Err` when it was dropped (counted).
    pub fn publish_event(
        &self,
        line: &str,
        class: u8,
        number: u8,
        name: &str,
        text: &str,
    ) -> Result<(), DropReason> {
        self.check(&[line])?;
        let body = json!({
            "class": class,
            "number": number,
            "event": format!("{class:02X}{number:02X}"),
            "name": name,
            "text": text,
            "time": publish::rfc3339(SystemTime::now()),
        });
        let pushed = self.outbox.push(Message {
            kind: PublicationKind::Event,
            key: self.keys.events(line),
            payload: body.to_string().into_bytes(),
            json: true,
            attachment: None,
            done: None,
        });
        if let Err(reason) = pushed {
            crate::warn_limited!(format!("zenoh event dropped {line}"), %line, class, number, reason = reason.as_str(), "event not published on zenoh");
        }
        pushed
    }

    /// Declares (online) or undeclares (offline) the liveliness token of a line.
    pub fn line_online(&self, line: &str, online: bool) {
        if self.check(&[line]).is_ok() {
            self.outbox
                .push_presence(self.keys.line_token(line), online);
        }
    }

    /// Declares (online) or undeclares (offline) the liveliness token of a device.
    pub fn device_online(&self, line: &str, device: &str, online: bool) {
        if self.check(&[line, device]).is_ok() {
            self.outbox
                .push_presence(self.keys.device_token(line, device), online);
        }
    }

    /// The bridge's counters.
    pub fn stats(&self) -> &Arc<BridgeStats> {
        &self.stats
    }

    /// The key prefix in use.
    pub fn prefix(&self) -> &str {
        self.keys.prefix()
    }

    fn check(&self, names: &[&str]) -> Result<(), DropReason> {
        for name in names {
            if let Err(e) = keys::check_chunk("name", name) {
                self.stats.dropped(DropReason::BadKey);
                crate::warn_limited!("zenoh bad name", error = %e, "update not published on zenoh");
                return Err(DropReason::BadKey);
            }
        }
        Ok(())
    }
}

impl std::fmt::Debug for BridgeHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BridgeHandle")
            .field("prefix", &self.keys.prefix())
            .finish_non_exhaustive()
    }
}

/// Publishes the current value of every tag whose heartbeat fell due, every `tick`, until
/// shutdown; first every current value once (through the policy). The values come from the
/// backend (the image), with the time their poll read them.
pub(super) async fn heartbeats(
    handle: BridgeHandle,
    backend: Arc<dyn BridgeBackend>,
    tick: Duration,
    shutdown: CancellationToken,
) {
    let mut ticker = tokio::time::interval(tick);
    ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut first_round = true;
    loop {
        tokio::select! {
            () = shutdown.cancelled() => return,
            _ = ticker.tick() => {}
        }
        let (handle, backend) = (handle.clone(), backend.clone());
        let first = std::mem::take(&mut first_round);
        let round = tokio::task::spawn_blocking(move || {
            let now = tokio::time::Instant::now();
            if first {
                // Values read before the bridge started were never announced to it: publish
                // those of tags with a policy once, which starts their heartbeats.
                let current = backend.query_tags(None, None, None);
                handle.publish_tags(
                    current
                        .iter()
                        .filter(|(line, device, tag, _)| {
                            handle.publishing.has_policy(line, device, tag)
                        })
                        .map(|(line, device, tag, value)| {
                            ([line.as_str(), device, tag], value.clone())
                        }),
                );
            }
            for (line, device, tag) in handle.publishing.due(now) {
                let current = backend
                    .query_tags(Some(&line), Some(&device), Some(&tag))
                    .into_iter()
                    .find(|(l, d, t, _)| *l == line && *d == device && *t == tag);
                if let Some((_, _, _, value)) = current {
                    handle
                        .publishing
                        .record((&line, &device, &tag), &value, now);
                    handle.stats.heartbeat_sent();
                    handle
                        .outbox
                        .push_tag(&[handle.keys.prefix(), &line, &device, &tag], value);
                }
            }
        })
        .await;
        if let Err(e) = round {
            crate::error_limited!("zenoh heartbeat round failed", error = %e, "zenoh heartbeat round failed");
        }
    }
}
