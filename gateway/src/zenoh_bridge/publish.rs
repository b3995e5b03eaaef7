//! The outbox between the gateway and the session, and the publisher thread that empties it.
//!
//! ```text
//! serial line / image / command worker          publisher thread (std, owns publishers + tokens)
//!   BridgeHandle::publish_*  --try, never waits-->  Outbox { telegrams, events, results: FIFO,
//!                                                            tags: newest value per key, taken
//!                                                                  a chunk of 1024 at a time,
//!                                                            presence: latest state per device }
//!                                                       --> Publisher::put / Session::put
//! ```
//!
//! Telegrams and events go through a declared publisher per key (two keys per line). Tag
//! values and command results are plain session puts with the options given per call: a
//! declared publisher holds state in the session and in zenoh's routing tables (its interest in
//! matching subscribers), about 3 KiB each, 35 MiB for 10 000 tags; a put keeps nothing between
//! samples and sends the same message. A tag's key expression is checked once, when the key
//! becomes pending ([`BridgeHandle::publish_tags`](super::BridgeHandle::publish_tags)), and
//! published as it is. The pending tag values are kept compact ([`super::tag_queue`]): with
//! 100 000 tags pending the outbox holds 6.6 MiB, and each take hands the thread at most
//! [`CHUNK`](super::tag_queue::CHUNK) of them, so no batch of every pending tag is ever built.
//!
//! A zenoh put with `CongestionControl::Block` waits while the network is congested; that wait
//! happens on the publisher thread only, so a slow subscriber slows the outbox, never a serial
//! line: when a queue is full the producer's item is dropped and counted (see
//! [`super::config`] for the policy per kind). zenoh closes a link whose put stayed blocked for
//! `transport/link/tx/queue/congestion_control/block/wait_before_close` (5 s by default), so a
//! stuck peer costs at most that long before the thread moves on.

use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, SystemTime};

use zenoh::bytes::Encoding;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;
use zenoh::sample::Locality;
use zenoh::{Session, Wait};

use super::metrics::{BridgeStats, DropReason, PublicationKind};
use super::presence::Presence;
use super::tag_queue::{Chunk, Pushed, TagQueue};
use super::TagValue;

/// How long the thread sleeps between checks of a closed outbox when nothing arrives.
const IDLE_WAIT: Duration = Duration::from_millis(500);
/// At most this many presence changes wait (the devices of one gateway are far fewer).
const PRESENCE_LIMIT: usize = 4096;
/// Room for a tag payload without a description (about 80 bytes).
const TAG_PAYLOAD: usize = 128;

/// One publication that must not be coalesced: a telegram, an event, a command result.
#[derive(Debug)]
pub(crate) struct Message {
    pub(crate) kind: PublicationKind,
    pub(crate) key: String,
    pub(crate) payload: Vec<u8>,
    /// JSON (`application/json`) or raw bytes (`application/octet-stream`).
    pub(crate) json: bool,
    pub(crate) attachment: Option<Vec<u8>>,
    /// Told whether the put succeeded, once it was made (a telegram acknowledged on
    /// publication waits for it); dropped unanswered when the item is.
    pub(crate) done: Option<tokio::sync::oneshot::Sender<bool>>,
}

/// Queue limits, from the config.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Limits {
    pub(crate) telegrams: usize,
    pub(crate) events: usize,
    pub(crate) results: usize,
    pub(crate) tags: usize,
    pub(crate) frames: usize,
}

/// What waits for the publisher thread.
struct Pending {
    telegrams: VecDeque<Message>,
    events: VecDeque<Message>,
    results: VecDeque<Message>,
    frames: VecDeque<Message>,
    /// Newest value per tag key, in the order in which keys became pending.
    tags: TagQueue,
    /// Latest online state per device token key, in order of first change.
    presence: HashMap<String, bool>,
    presence_order: VecDeque<String>,
    /// Set once the session is open; the thread publishes only then.
    session: Option<Session>,
    /// No more items are accepted; the thread drains and exits.
    closed: bool,
    /// The thread waits for items: a producer wakes it (otherwise it takes them when it is done
    /// with what it holds, without a wake-up call per item).
    idle: bool,
}

impl Pending {
    fn new(tag_limit: usize) -> Self {
        Self {
            telegrams: VecDeque::new(),
            events: VecDeque::new(),
            results: VecDeque::new(),
            frames: VecDeque::new(),
            tags: TagQueue::new(tag_limit),
            presence: HashMap::new(),
            presence_order: VecDeque::new(),
            session: None,
            closed: false,
            idle: false,
        }
    }

    fn is_empty(&self) -> bool {
        self.telegrams.is_empty()
            && self.events.is_empty()
            && self.results.is_empty()
            && self.frames.is_empty()
            && self.tags.is_empty()
            && self.presence_order.is_empty()
    }

    /// Takes every message and presence change pending, and the oldest chunk of pending tag
    /// values; presence changes and tags in the order their keys became pending.
    fn drain(&mut self) -> Batch {
        let mut presence_map = std::mem::take(&mut self.presence);
        let presence = std::mem::take(&mut self.presence_order)
            .into_iter()
            .filter_map(|k| presence_map.remove(&k).map(|on| (k, on)))
            .collect();
        let tags = self.tags.take();
        Batch {
            presence,
            results: std::mem::take(&mut self.results),
            telegrams: std::mem::take(&mut self.telegrams),
            events: std::mem::take(&mut self.events),
            frames: std::mem::take(&mut self.frames),
            tags,
        }
    }
}

/// What the publisher thread takes from the outbox in one go.
struct Batch {
    presence: Vec<(String, bool)>,
    results: VecDeque<Message>,
    telegrams: VecDeque<Message>,
    events: VecDeque<Message>,
    frames: VecDeque<Message>,
    tags: Option<Chunk>,
}

/// The bounded hand-over between producers and the publisher thread.
pub(crate) struct Outbox {
    pending: Mutex<Pending>,
    wake: Condvar,
    limits: Limits,
    stats: Arc<BridgeStats>,
}

// === impl Outbox ===

impl Outbox {
    pub(crate) fn new(limits: Limits, stats: Arc<BridgeStats>) -> Self {
        Self {
            pending: Mutex::new(Pending::new(limits.tags)),
            wake: Condvar::new(),
            limits,
            stats,
        }
    }

    fn lock(&self) -> MutexGuard<'_, Pending> {
        // A panic while holding the lock leaves plain queues behind; keep using them.
        self.pending.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Queues a telegram, event or result; on a full queue (or a closed outbox) drops it and
    /// counts the drop.
    pub(crate) fn push(&self, msg: Message) -> Result<(), DropReason> {
        let mut p = self.lock();
        let p_closed = p.closed;
        let (queue, limit, full) = match msg.kind {
            PublicationKind::Telegram => (
                &mut p.telegrams,
                self.limits.telegrams,
                DropReason::TelegramQueueFull,
            ),
            PublicationKind::Event => (
                &mut p.events,
                self.limits.events,
                DropReason::EventQueueFull,
            ),
            PublicationKind::Frame => (
                &mut p.frames,
                self.limits.frames,
                DropReason::FrameQueueFull,
            ),
            PublicationKind::TxResult | PublicationKind::SetResult | PublicationKind::Tag => (
                &mut p.results,
                self.limits.results,
                DropReason::ResultQueueFull,
            ),
        };
        let reason = if p_closed {
            Some(DropReason::BridgeClosed)
        } else if queue.len() >= limit {
            Some(full)
        } else {
            None
        };
        if let Some(reason) = reason {
            drop(p);
            self.stats.dropped(reason);
            return Err(reason);
        }
        queue.push_back(msg);
        self.wake_if_idle(p);
        Ok(())
    }

    /// Sets the pending value of the tag key made of `key` joined by `/`: see [`Self::push_tags`].
    pub(crate) fn push_tag(&self, key: &[&str], value: TagValue) {
        self.push_tags([(key, value)]);
    }

    /// Sets the pending value of each tag key (its parts joined by `/`), all under one lock and
    /// with one wake-up of the thread at most; a pending older value is replaced (counted as
    /// superseded). A key not pending yet is checked as a key expression (a bad one is dropped
    /// and counted) and waits behind the others.
    pub(crate) fn push_tags<'a, K: AsRef<[&'a str]>>(
        &self,
        tags: impl IntoIterator<Item = (K, TagValue)>,
    ) {
        let mut p = self.lock();
        let mut drops = [0u64; 3];
        let mut bad = None;
        let mut new = false;
        for (key, value) in tags {
            if p.closed {
                drops[0] += 1;
                continue;
            }
            match p.tags.push(key.as_ref(), value) {
                Pushed::New => new = true,
                Pushed::Superseded => drops[1] += 1,
                Pushed::Full => drops[2] += 1,
                Pushed::BadKey(key, error) => {
                    self.stats.dropped(DropReason::BadKey);
                    bad = Some((key, error));
                }
            }
        }
        if new {
            self.wake_if_idle(p);
        } else {
            drop(p);
        }
        let reasons = [
            DropReason::BridgeClosed,
            DropReason::TagSuperseded,
            DropReason::TagQueueFull,
        ];
        for (reason, n) in reasons.into_iter().zip(drops).filter(|(_, n)| *n > 0) {
            self.stats.dropped_many(reason, n);
        }
        if let Some((key, error)) = bad {
            crate::warn_limited!("zenoh bad tag key", %key, %error, "tag value not published on zenoh");
        }
    }

    /// Lets go of the outbox and wakes the thread if it waits for items.
    fn wake_if_idle(&self, p: MutexGuard<'_, Pending>) {
        let idle = p.idle;
        drop(p);
        if idle {
            self.wake.notify_one();
        }
    }

    /// Takes back a chunk of tag values the publisher thread has published, to be reused.
    fn recycle(&self, chunk: Chunk) {
        self.lock().tags.recycle(chunk);
    }

    /// Sets the latest online state of a device token key.
    pub(crate) fn push_presence(&self, key: String, online: bool) {
        let mut p = self.lock();
        if p.closed {
            return;
        }
        if let Some(slot) = p.presence.get_mut(&key) {
            *slot = online;
        } else if p.presence.len() >= PRESENCE_LIMIT {
            drop(p);
            crate::warn_limited!("zenoh presence queue full", %key, online, "zenoh presence queue full, change dropped");
            return;
        } else {
            p.presence_order.push_back(key.clone());
            p.presence.insert(key, online);
        }
        self.wake_if_idle(p);
    }

    /// Hands the open session to the publisher thread.
    pub(crate) fn set_session(&self, session: Session) {
        self.lock().session = Some(session);
        self.wake.notify_all();
    }

    /// Stops accepting items; the thread publishes what is pending and exits.
    pub(crate) fn close(&self) {
        self.lock().closed = true;
        self.wake.notify_all();
    }

    /// Waits until there is something to publish and a session to publish it on. `None` when
    /// the outbox is closed and nothing can be published any more.
    fn take(&self) -> Option<(Session, Batch)> {
        let mut p = self.lock();
        loop {
            match (&p.session, p.is_empty(), p.closed) {
                (Some(_), false, _) => break,
                (_, true, true) | (None, _, true) => return None,
                _ => {
                    p.idle = true;
                    p = self
                        .wake
                        .wait_timeout(p, IDLE_WAIT)
                        .unwrap_or_else(|e| e.into_inner())
                        .0;
                    p.idle = false;
                }
            }
        }
        let session = p.session.clone()?;
        Some((session, p.drain()))
    }
}

/// The publisher thread: declared publishers of telegram and event keys, liveliness tokens, the
/// drain loop.
pub(crate) struct PublisherThread {
    outbox: Arc<Outbox>,
    stats: Arc<BridgeStats>,
    /// One per telegram or event key (`<line>/rx`, `<line>/events`): a bounded set.
    publishers: HashMap<String, Publisher<'static>>,
    presence: Presence,
}

// === impl PublisherThread ===

impl PublisherThread {
    pub(crate) fn new(outbox: Arc<Outbox>, stats: Arc<BridgeStats>, presence: Presence) -> Self {
        Self {
            outbox,
            stats,
            publishers: HashMap::new(),
            presence,
        }
    }

    /// Runs until the outbox is closed and drained. Blocks: run it on its own thread.
    pub(crate) fn run(mut self) {
        while let Some((session, batch)) = self.outbox.take() {
            for (key, online) in batch.presence {
                self.presence.set(&session, key, online);
            }
            for msg in batch
                .results
                .into_iter()
                .chain(batch.telegrams)
                .chain(batch.events)
                .chain(batch.frames)
            {
                self.publish_message(&session, msg);
            }
            if let Some(chunk) = batch.tags {
                let published = (0..chunk.len())
                    .filter(|&i| self.put_tag(&session, &chunk, i))
                    .count();
                self.stats
                    .published_many(PublicationKind::Tag, published as u64);
                self.outbox.recycle(chunk);
            }
        }
        // Undeclare in order: tokens first (peers see the devices and the gateway go), then
        // the publishers. The session itself is closed by the driver.
        self.presence.clear();
        self.publishers.clear();
    }

    /// Tag value `i` of `chunk`: a session put with the options a tag publisher had (congestion
    /// control drop, default priority, not express), JSON, the session's timestamp, for remote
    /// subscribers only (the gateway's own subscribe to commands, never to values: the session
    /// does not match each put against them). `true` when it was published (the caller counts
    /// those of a chunk at once); a failure is counted here.
    fn put_tag(&self, session: &Session, chunk: &Chunk, i: usize) -> bool {
        let key = chunk.key(i);
        let mut payload = Vec::with_capacity(TAG_PAYLOAD);
        if let Err(e) = chunk.write_payload(i, &mut payload) {
            self.stats.dropped(DropReason::PublishError);
            crate::warn_limited!("zenoh tag payload not written", %key, error = %e, "zenoh tag payload not written");
            return false;
        }
        let result = session
            .put(key, payload)
            .congestion_control(congestion(PublicationKind::Tag))
            .allowed_destination(Locality::Remote)
            .encoding(Encoding::APPLICATION_JSON)
            .timestamp(session.new_timestamp())
            .wait();
        self.failed(PublicationKind::Tag, key, result)
    }

    /// A telegram, an event (declared publisher) or a command result (session put).
    fn publish_message(&mut self, session: &Session, msg: Message) {
        let Message {
            kind,
            key,
            payload,
            json,
            attachment,
            done,
        } = msg;
        let encoding = if json {
            Encoding::APPLICATION_JSON
        } else {
            Encoding::APPLICATION_OCTET_STREAM
        };
        let result = if kind.declared_publisher() {
            let publisher = match self.publishers.get(&key) {
                Some(p) => p,
                None => match declare(session, &key, kind) {
                    Ok(p) => self.publishers.entry(key.clone()).or_insert(p),
                    Err(e) => {
                        self.stats.dropped(DropReason::BadKey);
                        crate::warn_limited!("zenoh publisher not declared", %key, error = %e, "zenoh publisher not declared, update dropped");
                        return;
                    }
                },
            };
            publisher
                .put(payload)
                .encoding(encoding)
                .timestamp(session.new_timestamp())
                .attachment(attachment)
                .wait()
        } else {
            // Result keys name whatever a command named: no publisher is kept for them, or any
            // peer could grow the map without bound.
            session
                .put(key.as_str(), payload)
                .congestion_control(congestion(kind))
                .express(express(kind))
                .encoding(encoding)
                .timestamp(session.new_timestamp())
                .attachment(attachment)
                .wait()
        };
        let ok = self.failed(kind, &key, result);
        if ok {
            self.stats.published(kind);
        }
        if let Some(done) = done {
            let _ = done.send(ok);
        }
    }

    /// Whether the put went through; a failure is counted and logged.
    fn failed(&self, kind: PublicationKind, key: &str, result: zenoh::Result<()>) -> bool {
        let Err(e) = result else { return true };
        self.stats.dropped(DropReason::PublishError);
        crate::warn_limited!(format!("zenoh put failed {}", kind.as_str()), %key, kind = kind.as_str(), error = %e, "zenoh put failed");
        false
    }
}

/// Telegrams, events and results wait under congestion (they must not be lost); tag values
/// are dropped by zenoh under congestion (a newer one follows), and so are monitored frames (a
/// view of the line that must never slow the bridge; the ring keeps them for REST).
fn congestion(kind: PublicationKind) -> CongestionControl {
    match kind {
        PublicationKind::Tag | PublicationKind::Frame => CongestionControl::Drop,
        _ => CongestionControl::Block,
    }
}

/// Telegrams, events and results are sent express: zenoh hands each to the link at once, in a
/// batch of its own. A message that is not express waits in the batch being filled, and when the
/// link's task finds that batch still being written to it backs off for up to
/// `transport/link/tx/queue/batching/time_limit` (1 ms) on tokio's timer, whose ticks are a
/// millisecond: up to 2 ms in the tail of a telegram's delivery. Tag values and frames, the
/// bulk, keep being batched.
fn express(kind: PublicationKind) -> bool {
    congestion(kind) == CongestionControl::Block
}

/// A publisher for `key`, with the congestion control of its kind.
fn declare(
    session: &Session,
    key: &str,
    kind: PublicationKind,
) -> zenoh::Result<Publisher<'static>> {
    session
        .declare_publisher(key.to_owned())
        .congestion_control(congestion(kind))
        .express(express(kind))
        .wait()
}

/// RFC 3339 with microseconds, UTC: `2024-05-01T12:00:00.123456Z`.
pub(crate) fn rfc3339(t: SystemTime) -> String {
    humantime::format_rfc3339_micros(t).to_string()
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::super::tag_queue::CHUNK;
    use super::*;

    fn outbox(limit: usize) -> (Arc<BridgeStats>, Outbox) {
        let stats = Arc::new(BridgeStats::new());
        let limits = Limits {
            telegrams: limit,
            events: limit,
            results: limit,
            tags: limit,
            frames: limit,
        };
        (stats.clone(), Outbox::new(limits, stats))
    }

    fn msg(kind: PublicationKind, n: u8) -> Message {
        Message {
            kind,
            key: "a/rx".into(),
            payload: vec![n],
            json: false,
            attachment: None,
            done: None,
        }
    }

    fn value(v: i64) -> TagValue {
        TagValue {
            value: v.into(),
            unit: None,
            quality: "good",
            timestamp: SystemTime::UNIX_EPOCH,
            description: None,
        }
    }

    #[test]
    fn full_fifo_drops_the_new_item_and_counts_it() {
        let (stats, o) = outbox(2);
        assert!(o.push(msg(PublicationKind::Telegram, 1)).is_ok());
        assert!(o.push(msg(PublicationKind::Telegram, 2)).is_ok());
        assert_eq!(
            o.push(msg(PublicationKind::Telegram, 3)),
            Err(DropReason::TelegramQueueFull)
        );
        assert!(o.push(msg(PublicationKind::Event, 1)).is_ok());
        assert_eq!(stats.drops(DropReason::TelegramQueueFull), 1);
        let p = o.lock();
        let kept: Vec<u8> = p.telegrams.iter().map(|m| m.payload[0]).collect();
        assert_eq!(kept, [1, 2]);
    }

    #[test]
    fn newest_tag_value_wins_and_keys_keep_their_order() {
        let (stats, o) = outbox(2);
        o.push_tag(&["k", "a"], value(1));
        o.push_tag(&["k", "b"], value(2));
        o.push_tag(&["k", "a"], value(3));
        o.push_tag(&["k", "c"], value(4));
        assert_eq!(stats.drops(DropReason::TagSuperseded), 1);
        assert_eq!(stats.drops(DropReason::TagQueueFull), 1);
        let p = o.lock();
        assert_eq!(p.tags.keys(), ["k/a", "k/b"]);
        assert_eq!(p.tags.value("k/a").unwrap().value, 3);
    }

    #[test]
    fn the_thread_takes_tags_a_chunk_at_a_time_in_order() {
        let (stats, o) = outbox(3 * CHUNK);
        let key = |n: usize| format!("t{n}");
        for n in 0..2 * CHUNK + 5 {
            o.push_tag(&["gw", "l", "d", &key(n)], value(n as i64));
        }
        // Newer values for keys of the first and the last chunk keep their places.
        o.push_tag(&["gw", "l", "d", &key(1)], value(-1));
        o.push_tag(&["gw", "l", "d", &key(2 * CHUNK + 4)], value(-2));
        assert_eq!(stats.drops(DropReason::TagSuperseded), 2);
        let mut sizes = Vec::new();
        let mut taken = Vec::new();
        loop {
            let batch = o.lock().drain();
            let Some(chunk) = batch.tags else { break };
            sizes.push(chunk.len());
            taken.extend((0..chunk.len()).map(|i| {
                let (k, v) = chunk.get(i);
                (k.to_owned(), v.value.as_i64().unwrap_or(i64::MIN))
            }));
            o.recycle(chunk);
        }
        assert_eq!(sizes, [CHUNK, CHUNK, 5]);
        let expected: Vec<(String, i64)> = (0..2 * CHUNK + 5)
            .map(|n| {
                let v = match n {
                    1 => -1,
                    n if n == 2 * CHUNK + 4 => -2,
                    n => n as i64,
                };
                (format!("gw/l/d/t{n}"), v)
            })
            .collect();
        assert_eq!(taken, expected);
        assert!(o.lock().is_empty());
    }

    #[derive(Clone, Debug)]
    enum Op {
        /// A value for tag key `k/<n>`.
        Tag(u8, i64),
        /// A command result.
        Result(u8),
        /// The publisher thread takes what is pending.
        Drain,
    }

    fn op() -> impl Strategy<Value = Op> {
        prop_oneof![
            4 => (0u8..6, any::<i64>()).prop_map(|(k, v)| Op::Tag(k, v)),
            2 => any::<u8>().prop_map(Op::Result),
            1 => Just(Op::Drain),
        ]
    }

    /// What a drain must give: keys in the order they became pending, newest value each; the
    /// results in order.
    #[derive(Default)]
    struct Model {
        tags: Vec<(String, i64)>,
        results: Vec<u8>,
    }

    fn check_drain(o: &Outbox, model: &mut Model) -> Result<(), TestCaseError> {
        // The thread takes a chunk of tags at a time: what it takes until nothing is pending.
        let (mut tags, mut results) = (Vec::new(), Vec::new());
        loop {
            let batch = o.lock().drain();
            results.extend(batch.results.iter().map(|m| m.payload[0]));
            let Some(chunk) = batch.tags else { break };
            tags.extend((0..chunk.len()).map(|i| {
                let (k, v) = chunk.get(i);
                (k.to_owned(), v.value.as_i64().unwrap_or(i64::MIN))
            }));
            o.recycle(chunk);
        }
        let tags: Vec<(String, i64)> = tags;
        let results: Vec<u8> = results;
        prop_assert_eq!(tags, std::mem::take(&mut model.tags));
        prop_assert_eq!(results, std::mem::take(&mut model.results));
        prop_assert!(o.lock().is_empty());
        Ok(())
    }

    proptest! {
        /// Tag values of several keys, results and the thread's takes in any interleaving: each
        /// key's newest value is taken once, no key is lost or overwritten by another's value.
        #[test]
        fn no_key_loses_its_value_whatever_the_interleaving(
            ops in prop::collection::vec(op(), 0..200)
        ) {
            let (stats, o) = outbox(256);
            let mut model = Model::default();
            let mut superseded = 0u64;
            for op in ops {
                match op {
                    Op::Tag(k, v) => {
                        let key = format!("k/{k}");
                        o.push_tag(&["k", &k.to_string()], value(v));
                        match model.tags.iter_mut().find(|(m, _)| *m == key) {
                            Some(slot) => {
                                slot.1 = v;
                                superseded += 1;
                            }
                            None => model.tags.push((key, v)),
                        }
                    }
                    Op::Result(n) => {
                        let mut m = msg(PublicationKind::SetResult, n);
                        m.key = format!("k/{n}/set/result");
                        prop_assert!(o.push(m).is_ok());
                        model.results.push(n);
                    }
                    Op::Drain => check_drain(&o, &mut model)?,
                }
            }
            check_drain(&o, &mut model)?;
            prop_assert_eq!(stats.drops(DropReason::TagSuperseded), superseded);
            prop_assert_eq!(stats.drops(DropReason::TagQueueFull), 0);
        }
    }

    #[test]
    fn closed_outbox_refuses_and_take_ends() {
        let (stats, o) = outbox(4);
        o.close();
        assert_eq!(
            o.push(msg(PublicationKind::Event, 1)),
            Err(DropReason::BridgeClosed)
        );
        o.push_tag(&["k"], value(1));
        assert_eq!(stats.drops(DropReason::BridgeClosed), 2);
        assert!(o.take().is_none());
    }

    #[test]
    fn presence_keeps_the_latest_state() {
        let (_, o) = outbox(4);
        o.push_presence("d1".into(), true);
        o.push_presence("d1".into(), false);
        o.push_presence("d2".into(), true);
        let p = o.lock();
        assert_eq!(p.presence_order, ["d1", "d2"]);
        assert!(!p.presence["d1"]);
    }

    #[test]
    fn timestamps_are_rfc3339_utc() {
        let t = SystemTime::UNIX_EPOCH + Duration::from_micros(1_700_000_000_123_456);
        assert_eq!(rfc3339(t), "2023-11-14T22:13:20.123456Z");
    }
}
