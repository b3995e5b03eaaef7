//! The zenoh feeds: what flows from the lines, their mailboxes and monitors and the process
//! image to the zenoh bridge (tag values on change, device and line presence, events, received
//! telegrams, monitored frames). app/ starts them with the bridge and for every line a
//! configuration change starts; each feed ends with its line's token or the bridge's.

use std::collections::BTreeSet;
use std::sync::Arc;
use std::time::Duration;

use proto_core::event;
use serde_json::json;
use tokio::sync::broadcast::error::RecvError;
use tokio_util::sync::CancellationToken;
use tracing::debug;

use crate::api::model::ScalarValue;
use crate::image::ProcessImage;
use crate::line::{LineEvent, LineHandle, LineStatus};
use crate::mailbox::AckMode;
use crate::tags::{TagDirectory, TagEntry};
use crate::zenoh_bridge::{BridgeHandle, DropReason, TagValue};

/// How often device presence is compared with the last published state.
const PRESENCE_PERIOD: Duration = Duration::from_millis(500);

/// A tag's value as the bridge publishes it.
pub fn tag_value(tags: &TagDirectory, image: &ProcessImage, entry: &TagEntry) -> Option<TagValue> {
    let reading = tags.read(image, entry)?;
    let value = json!(ScalarValue::from(reading.value));
    let unit = (!reading.unit.is_empty()).then_some(reading.unit);
    Some(TagValue {
        value,
        unit,
        quality: reading.quality,
        timestamp: reading.timestamp,
        description: (!entry.description().is_empty()).then(|| entry.description().to_owned()),
    })
}

/// Tag values on change: every change of `image` maps to the tags it overlaps in the directory
/// `tags` gives (the one in force; `None` when the gateway is gone, which ends the feed).
pub fn spawn_tag_feed<F>(
    bridge: &BridgeHandle,
    image: ProcessImage,
    tags: F,
    token: &CancellationToken,
) where
    F: Fn() -> Option<Arc<TagDirectory>> + Send + 'static,
{
    let bridge = bridge.clone();
    let mut changes = image.subscribe();
    let token = token.clone();
    crate::task::spawn("zenoh tag feed", async move {
        loop {
            let change = tokio::select! {
                () = token.cancelled() => return,
                change = changes.recv() => change,
            };
            match change {
                Ok(change) => {
                    let Some(tags) = tags() else { return };
                    let count = u16::try_from(change.values.len()).unwrap_or(u16::MAX);
                    let overlapping =
                        tags.overlapping(change.unit, change.table, change.start, count);
                    bridge.publish_tags(overlapping.filter_map(|entry| {
                        let value = tag_value(&tags, &image, entry)?;
                        Some(([entry.line(), entry.device(), entry.name()], value))
                    }));
                }
                Err(RecvError::Lagged(n)) => {
                    // The newest values follow; publishing skipped ones would be stale.
                    bridge.stats().dropped_many(DropReason::FeedLagged, n);
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

/// Presence: a liveliness token per line whose port is open and per online device, of the
/// lines `statuses` gives (those in force; `None` when the gateway is gone, which ends the
/// feed), compared every [`PRESENCE_PERIOD`].
pub fn spawn_presence_feed<F>(bridge: &BridgeHandle, statuses: F, token: &CancellationToken)
where
    F: Fn() -> Option<Vec<LineStatus>> + Send + 'static,
{
    let bridge = bridge.clone();
    let token = token.clone();
    crate::task::spawn("zenoh presence feed", async move {
        let mut online: BTreeSet<(String, String)> = BTreeSet::new();
        let mut open: BTreeSet<String> = BTreeSet::new();
        let mut ticker = tokio::time::interval(PRESENCE_PERIOD);
        loop {
            tokio::select! {
                () = token.cancelled() => return,
                _ = ticker.tick() => {}
            }
            let Some(statuses) = statuses() else { return };
            let mut now: BTreeSet<(String, String)> = BTreeSet::new();
            let mut open_now: BTreeSet<String> = BTreeSet::new();
            for status in &statuses {
                if status.port_open {
                    open_now.insert(status.name.clone());
                }
                for d in status.devices.iter().filter(|d| d.online) {
                    now.insert((status.name.clone(), d.name.clone()));
                }
            }
            for key in online.difference(&now) {
                bridge.device_online(&key.0, &key.1, false);
            }
            for line in open.difference(&open_now) {
                bridge.line_online(line, false);
            }
            for line in open_now.difference(&open) {
                bridge.line_online(line, true);
            }
            open = open_now;
            for key in now.difference(&online) {
                bridge.device_online(&key.0, &key.1, true);
            }
            online = now;
        }
    });
}

/// The feeds of one line: its events and its received telegrams (in order, each once; the
/// bridge's queue counts what it must drop). They end with the line or the bridge.
pub fn spawn_line_feeds(
    bridge: &BridgeHandle,
    name: &str,
    line: &LineHandle,
    line_token: &CancellationToken,
    token: &CancellationToken,
) {
    let mut events = line.subscribe_events();
    {
        let bridge = bridge.clone();
        let (token, line_token) = (token.clone(), line_token.clone());
        crate::task::spawn("zenoh event feed", async move {
            loop {
                let received = tokio::select! {
                    () = token.cancelled() => return,
                    () = line_token.cancelled() => return,
                    e = events.recv() => e,
                };
                match received {
                    Ok(e) => publish_event(&bridge, &e),
                    Err(RecvError::Lagged(n)) => {
                        bridge.stats().dropped_many(DropReason::FeedLagged, n);
                        crate::warn_limited!(
                            "zenoh event feed lagged",
                            missed = n,
                            "zenoh event feed fell behind a line"
                        );
                    }
                    Err(RecvError::Closed) => return,
                }
            }
        });
    }
    if let Some(monitor) = line.monitor() {
        spawn_frame_feed(bridge, Arc::clone(monitor), token, line_token);
    }
    let Some(mut rx) = line.subscribe_rx() else {
        return;
    };
    if let Some(mailbox) = line
        .mailbox()
        .filter(|m| m.settings().ack == AckMode::OnPublish)
    {
        spawn_on_publish_feed(bridge, mailbox, rx, token, line_token);
        return;
    }
    let bridge = bridge.clone();
    let (token, line_token) = (token.clone(), line_token.clone());
    let name = name.to_owned();
    crate::task::spawn("zenoh telegram feed", async move {
        loop {
            let received = tokio::select! {
                () = token.cancelled() => return,
                () = line_token.cancelled() => return,
                t = rx.recv() => t,
            };
            match received {
                Ok(t) => {
                    let data = t.data.to_vec();
                    if bridge
                        .publish_telegram_from(
                            &t.line,
                            u64::from(t.seq),
                            t.received,
                            t.side.map(proto_core::proc3964::tap::Side::as_str),
                            data,
                        )
                        .is_err()
                    {
                        debug!(line = %t.line, seq = t.seq, "zenoh telegram queue full; the drop is counted");
                    }
                }
                Err(RecvError::Lagged(n)) => {
                    bridge.stats().dropped_many(DropReason::FeedLagged, n);
                    crate::warn_limited!(format!("zenoh telegram feed lagged {name}"), line = %name, missed = n, "zenoh telegram feed fell behind a line; the telegrams stay in the mailbox");
                }
                Err(RecvError::Closed) => return,
            }
        }
    });
}

/// How long the feed of a line acknowledged on publication waits before it offers a telegram
/// again that zenoh did not take (its queue full, a put that failed).
const ON_PUBLISH_RETRY: Duration = Duration::from_millis(100);

/// `<prefix>/<line>/rx` of a line with `ack = "on-publish"`: the mailbox's waiting telegrams,
/// oldest first, each acknowledged once zenoh took its put (so a telegram the journal restored
/// is published after a restart, and one zenoh did not take waits and is offered again). The
/// broadcast of received telegrams only wakes the feed.
fn spawn_on_publish_feed(
    bridge: &BridgeHandle,
    mailbox: Arc<crate::mailbox::Mailbox>,
    mut arrivals: tokio::sync::broadcast::Receiver<crate::mailbox::TelegramRx>,
    token: &CancellationToken,
    line_token: &CancellationToken,
) {
    let bridge = bridge.clone();
    let (token, line_token) = (token.clone(), line_token.clone());
    crate::task::spawn("zenoh on-publish telegram feed", async move {
        loop {
            while let Some(t) = mailbox.head() {
                let pushed = bridge.publish_telegram_confirmed(
                    &t.line,
                    u64::from(t.seq),
                    t.received,
                    t.data.to_vec(),
                );
                let taken = match pushed {
                    Ok(done) => tokio::select! {
                        () = token.cancelled() => return,
                        () = line_token.cancelled() => return,
                        ok = done => ok.unwrap_or(false),
                    },
                    Err(DropReason::BridgeClosed) => return,
                    Err(_) => false,
                };
                if taken {
                    // A client may have acknowledged it meanwhile: either way it is done.
                    let _ = mailbox.ack(t.seq);
                } else {
                    tokio::select! {
                        () = token.cancelled() => return,
                        () = line_token.cancelled() => return,
                        () = tokio::time::sleep(ON_PUBLISH_RETRY) => {}
                    }
                }
            }
            let arrived = tokio::select! {
                () = token.cancelled() => return,
                () = line_token.cancelled() => return,
                t = arrivals.recv() => t,
            };
            if let Err(RecvError::Closed) = arrived {
                return;
            }
        }
    });
}

/// `<prefix>/<line>/frames`: every frame of the line's monitor, as the REST API shows it. The
/// copy of each frame is made only while this feed listens (the bridge is on).
fn spawn_frame_feed(
    bridge: &BridgeHandle,
    monitor: Arc<crate::line::FrameMonitor>,
    token: &CancellationToken,
    line_token: &CancellationToken,
) {
    let mut frames = monitor.subscribe();
    let bridge = bridge.clone();
    let (token, line_token) = (token.clone(), line_token.clone());
    crate::task::spawn("zenoh frame feed", async move {
        let ended = monitor.ended();
        tokio::pin!(ended);
        loop {
            let received = tokio::select! {
                () = token.cancelled() => return,
                () = line_token.cancelled() => return,
                () = &mut ended => return,
                f = frames.recv() => f,
            };
            match received {
                Ok(frame) => {
                    let view = crate::api::model::FrameView::new(&monitor, &frame);
                    let json = serde_json::to_vec(&view).unwrap_or_default();
                    if bridge.publish_frame(monitor.line(), json).is_err() {
                        debug!(line = %monitor.line(), seq = frame.seq, "zenoh frame queue full; the drop is counted");
                    }
                }
                Err(RecvError::Lagged(n)) => {
                    monitor.count_lagged(n);
                    bridge.stats().dropped_many(DropReason::FeedLagged, n);
                }
                Err(RecvError::Closed) => return,
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
