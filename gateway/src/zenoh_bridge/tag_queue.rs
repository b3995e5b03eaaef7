//! The tag values waiting in the outbox: the newest value per key, in the order the keys became
//! pending, taken by the publisher thread one chunk at a time.
//!
//! A gateway of 100 000 changing tags has every one of them pending at once (the bench's ceiling
//! sets `tag_queue` above that), so what a pending value costs is what the outbox costs:
//!
//! - slots live in chunks of at most [`CHUNK`], oldest first. The publisher thread takes the
//!   oldest chunk whole and hands it back to be reused: no batch of every pending tag is ever
//!   built, and the lock is held for one chunk's worth of work, never for all pending tags;
//! - a key is written once, into its chunk's text, when it becomes pending: a value costs no
//!   allocation for its key. An index (the key's hash to the slot's sequence number) finds the
//!   pending slot of a key, so a newer value replaces the older in place (counted as superseded
//!   by the caller) and the key keeps its place in the order;
//! - a slot is 40 bytes: a JSON number or bool inline (any other value boxed), the timestamp in
//!   the microseconds the payload shows, the quality as a small number, and unit and description
//!   shared by every pending value that has the same (interned here, dropped when no pending
//!   value uses them any more);
//! - the payload is written at publication, byte for byte the JSON [`TagValue::to_json`] gives.
//!
//! At 100 000 pending tags (keys like `gw/bench/l31/d7/t446`): 98 chunks of 1024 slots (3.9 MiB),
//! the keys' text (2.1 MiB; a new chunk's text is sized for the fullest chunk so far) and the index
//! (0.7 MiB): 6.6 MiB in heaptrack, where a map of the values, an order of the keys and the batch
//! of all of them took 38 MiB.

use std::collections::VecDeque;
use std::hash::BuildHasher;
use std::io::Write as _;
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use hashbrown::{DefaultHashBuilder, HashSet, HashTable};
use serde_json::{Number, Value};
use zenoh::key_expr::keyexpr;

use super::TagValue;

/// Slots per chunk: what the publisher thread takes at once.
pub(crate) const CHUNK: usize = 1024;
/// The most keys pending, whatever `tag_queue` says (a sequence number is 32 bits; a billion
/// pending values would need 40 GiB).
const MAX_PENDING: usize = 1 << 30;
/// Distinct quality names a slot can name (the image and the profiles have seven).
const QUALITY_LIMIT: usize = 256;
/// Interned units and descriptions are pruned of unused ones from this many on.
const META_PRUNE_MIN: usize = 1024;

/// What became of a value offered to the queue.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum Pushed {
    /// Its key became pending.
    New,
    /// It replaced the pending value of its key.
    Superseded,
    /// Its key was not pending and the queue is full: dropped.
    Full,
    /// Its key is not a key expression: dropped (the key and zenoh's reason).
    BadKey(String, String),
}

/// A tag's value, compact: JSON numbers and bools inline.
#[derive(Clone, Debug, PartialEq)]
enum Scalar {
    Number(Number),
    Bool(bool),
    Null,
    /// A text, or any other JSON a caller gave.
    Other(Box<Value>),
}

// === impl Scalar ===

impl Scalar {
    fn from_json(value: Value) -> Self {
        match value {
            Value::Number(n) => Self::Number(n),
            Value::Bool(b) => Self::Bool(b),
            Value::Null => Self::Null,
            other => Self::Other(Box::new(other)),
        }
    }

    #[cfg(test)]
    fn to_json(&self) -> Value {
        match self {
            Self::Number(n) => Value::Number(n.clone()),
            Self::Bool(b) => Value::Bool(*b),
            Self::Null => Value::Null,
            Self::Other(v) => (**v).clone(),
        }
    }

    fn write(&self, out: &mut Vec<u8>) -> serde_json::Result<()> {
        match self {
            Self::Number(n) => serde_json::to_writer(out, n),
            Self::Bool(b) => serde_json::to_writer(out, b),
            Self::Null => serde_json::to_writer(out, &()),
            Self::Other(v) => serde_json::to_writer(out, v),
        }
    }
}

/// The unit and description of a tag, shared by its pending values.
#[derive(Debug, PartialEq, Eq, Hash)]
struct Meta {
    unit: Option<Box<str>>,
    description: Option<Box<str>>,
}

/// One pending value. Its key is its chunk's text from the previous slot's `key_end`.
#[derive(Debug)]
struct Slot {
    key_end: u32,
    quality: u8,
    value: Scalar,
    /// Microseconds since the Unix epoch (what the payload's timestamp shows).
    micros: u64,
    meta: Option<Arc<Meta>>,
}

// A slot stays small: 100 000 of them are pending in the bench's ceiling.
const _: () = assert!(size_of::<Slot>() <= 40);

/// Up to [`CHUNK`] pending values in order, with their keys; what the publisher thread takes.
#[derive(Debug, Default)]
pub(crate) struct Chunk {
    keys: String,
    slots: Vec<Slot>,
    /// The quality names the slots' numbers stand for (copied in when the chunk is taken).
    qualities: Vec<&'static str>,
}

// === impl Chunk ===

impl Chunk {
    fn with_capacity(slots: usize, key_bytes: usize) -> Self {
        Self {
            keys: String::with_capacity(key_bytes),
            slots: Vec::with_capacity(slots),
            qualities: Vec::new(),
        }
    }

    /// How many values the chunk holds.
    pub(crate) fn len(&self) -> usize {
        self.slots.len()
    }

    /// The key of value `i`.
    pub(crate) fn key(&self, i: usize) -> &str {
        let start = match i.checked_sub(1) {
            Some(prev) => self.slots[prev].key_end as usize,
            None => 0,
        };
        &self.keys[start..self.slots[i].key_end as usize]
    }

    /// Appends the payload of value `i` to `out`: `{"description"?, "quality", "timestamp",
    /// "unit", "value"}`, as [`TagValue::to_json`] serializes.
    pub(crate) fn write_payload(&self, i: usize, out: &mut Vec<u8>) -> std::io::Result<()> {
        let slot = &self.slots[i];
        let quality = self
            .qualities
            .get(usize::from(slot.quality))
            .copied()
            .unwrap_or_default();
        let meta = slot.meta.as_deref();
        write_payload(
            out,
            &slot.value,
            quality,
            slot.micros,
            meta.and_then(|m| m.unit.as_deref()),
            meta.and_then(|m| m.description.as_deref()),
        )
    }

    /// Value `i` as it was offered (the timestamp to the microsecond).
    #[cfg(test)]
    pub(crate) fn get(&self, i: usize) -> (&str, TagValue) {
        let slot = &self.slots[i];
        let meta = slot.meta.as_deref();
        let value = TagValue {
            value: slot.value.to_json(),
            unit: meta.and_then(|m| m.unit.as_deref()).map(str::to_owned),
            quality: self.qualities[usize::from(slot.quality)],
            timestamp: time_of(slot.micros),
            description: meta
                .and_then(|m| m.description.as_deref())
                .map(str::to_owned),
        };
        (self.key(i), value)
    }

    fn clear(&mut self) {
        self.keys.clear();
        self.slots.clear();
        self.qualities.clear();
    }
}

/// The pending tag values.
#[derive(Debug)]
pub(crate) struct TagQueue {
    /// Most keys pending.
    limit: usize,
    /// Slots per chunk.
    chunk: usize,
    /// Oldest first; chunk `n` holds sequence numbers `head + n * chunk ..`, filled from its
    /// start (only the last one may be partly filled).
    chunks: VecDeque<Chunk>,
    head: u32,
    len: usize,
    /// Pending key (hashed by its text in its chunk) to its sequence number.
    index: HashTable<u32>,
    hasher: DefaultHashBuilder,
    /// The key being offered, built here to hash and compare it before it is kept.
    scratch: String,
    qualities: Vec<&'static str>,
    metas: HashSet<Arc<Meta>>,
    prune_at: usize,
    /// A chunk taken and published, kept to be filled again.
    spare: Option<Chunk>,
    /// The most key bytes a chunk has held: a new chunk's text is sized for it.
    key_bytes: usize,
}

// === impl TagQueue ===

impl TagQueue {
    /// A queue of at most `limit` pending keys.
    pub(crate) fn new(limit: usize) -> Self {
        Self::with_chunk(limit, CHUNK)
    }

    fn with_chunk(limit: usize, chunk: usize) -> Self {
        let limit = limit.clamp(1, MAX_PENDING);
        Self {
            limit,
            chunk: chunk.clamp(1, limit),
            chunks: VecDeque::new(),
            head: 0,
            len: 0,
            index: HashTable::new(),
            hasher: DefaultHashBuilder::default(),
            scratch: String::new(),
            qualities: Vec::new(),
            metas: HashSet::new(),
            prune_at: META_PRUNE_MIN,
            spare: None,
            key_bytes: 0,
        }
    }

    /// How many keys are pending.
    #[cfg(test)]
    pub(crate) fn len(&self) -> usize {
        self.len
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Offers `value` for the key made of `parts` joined by `/`: it replaces the pending value
    /// of that key, or the key becomes pending (last in order) if there is room.
    pub(crate) fn push(&mut self, parts: &[&str], value: TagValue) -> Pushed {
        self.scratch.clear();
        for (n, part) in parts.iter().enumerate() {
            if n > 0 {
                self.scratch.push('/');
            }
            self.scratch.push_str(part);
        }
        let hash = self.hasher.hash_one(self.scratch.as_str());
        let (head, chunk) = (self.head, self.chunk);
        let found = {
            let (chunks, key) = (&self.chunks, self.scratch.as_str());
            self.index
                .find(hash, |&seq| key_of(chunks, head, chunk, seq) == key)
                .copied()
        };
        if let Some(seq) = found {
            let Some(quality) = self.quality(value.quality) else {
                return Pushed::Full;
            };
            let meta = self.intern(value.unit, value.description);
            let (n, i) = locate(head, chunk, seq);
            let slot = &mut self.chunks[n].slots[i];
            slot.value = Scalar::from_json(value.value);
            slot.micros = micros(value.timestamp);
            slot.quality = quality;
            slot.meta = meta;
            return Pushed::Superseded;
        }
        if self.len >= self.limit {
            return Pushed::Full;
        }
        if let Err(e) = <&keyexpr>::try_from(self.scratch.as_str()) {
            return Pushed::BadKey(self.scratch.clone(), e.to_string());
        }
        let Some(quality) = self.quality(value.quality) else {
            return Pushed::Full;
        };
        let meta = self.intern(value.unit, value.description);
        let fits = |c: &Chunk| {
            c.slots.len() < chunk && c.keys.len() + self.scratch.len() <= u32::MAX as usize
        };
        if !self.chunks.back().is_some_and(fits) {
            if let Some(full) = self.chunks.back() {
                self.key_bytes = self.key_bytes.max(full.keys.len());
            }
            let mut fresh = self.spare.take().unwrap_or_else(|| {
                Chunk::with_capacity(chunk, self.key_bytes + self.key_bytes / 8)
            });
            fresh.clear();
            self.chunks.push_back(fresh);
        }
        let filled = self.chunks.len() - 1;
        let Some(back) = self.chunks.back_mut() else {
            return Pushed::Full;
        };
        // Wrapping: the numbers in use span less than 2^32 (at most MAX_PENDING + one chunk).
        let seq = head.wrapping_add((filled * chunk + back.slots.len()) as u32);
        back.keys.push_str(&self.scratch);
        back.slots.push(Slot {
            key_end: back.keys.len() as u32,
            quality,
            value: Scalar::from_json(value.value),
            micros: micros(value.timestamp),
            meta,
        });
        let (chunks, hasher) = (&self.chunks, &self.hasher);
        self.index.insert_unique(hash, seq, |&s| {
            hasher.hash_one(key_of(chunks, head, chunk, s))
        });
        self.len += 1;
        Pushed::New
    }

    /// Takes the oldest chunk of pending values; their keys are no longer pending.
    pub(crate) fn take(&mut self) -> Option<Chunk> {
        let mut taken = self.chunks.pop_front()?;
        for i in 0..taken.len() {
            let seq = self.head.wrapping_add(i as u32);
            let hash = self.hasher.hash_one(taken.key(i));
            if let Ok(entry) = self.index.find_entry(hash, |&s| s == seq) {
                entry.remove();
            }
        }
        self.head = self.head.wrapping_add(self.chunk as u32);
        self.len -= taken.len();
        self.key_bytes = self.key_bytes.max(taken.keys.len());
        taken.qualities.clone_from(&self.qualities);
        Some(taken)
    }

    /// Takes back a chunk the publisher thread is done with, to be filled again.
    pub(crate) fn recycle(&mut self, mut chunk: Chunk) {
        if self.spare.is_none() && chunk.slots.capacity() == self.chunk {
            chunk.clear();
            self.spare = Some(chunk);
        }
    }

    /// The number of a quality name; `None` when the table is full (it never is: the names are
    /// the program's own).
    fn quality(&mut self, name: &'static str) -> Option<u8> {
        let n = match self.qualities.iter().position(|q| *q == name) {
            Some(n) => n,
            None if self.qualities.len() < QUALITY_LIMIT => {
                self.qualities.push(name);
                self.qualities.len() - 1
            }
            None => return None,
        };
        u8::try_from(n).ok()
    }

    /// The shared unit and description of a value (none for a tag with neither).
    fn intern(&mut self, unit: Option<String>, description: Option<String>) -> Option<Arc<Meta>> {
        if unit.is_none() && description.is_none() {
            return None;
        }
        let meta = Meta {
            unit: unit.map(String::into_boxed_str),
            description: description.map(String::into_boxed_str),
        };
        if let Some(shared) = self.metas.get(&meta) {
            return Some(Arc::clone(shared));
        }
        if self.metas.len() >= self.prune_at {
            // Only the set holds them: no pending or publishing value uses them any more.
            self.metas.retain(|m| Arc::strong_count(m) > 1);
            self.prune_at = (self.metas.len() * 2).max(META_PRUNE_MIN);
        }
        let shared = Arc::new(meta);
        self.metas.insert(Arc::clone(&shared));
        Some(shared)
    }

    /// The pending keys in order.
    #[cfg(test)]
    pub(crate) fn keys(&self) -> Vec<&str> {
        self.chunks
            .iter()
            .flat_map(|c| (0..c.len()).map(move |i| c.key(i)))
            .collect()
    }

    /// The pending value of `key`.
    #[cfg(test)]
    pub(crate) fn value(&self, key: &str) -> Option<TagValue> {
        let hash = self.hasher.hash_one(key);
        let seq = *self.index.find(hash, |&s| {
            key_of(&self.chunks, self.head, self.chunk, s) == key
        })?;
        let (n, i) = locate(self.head, self.chunk, seq);
        let c = &self.chunks[n];
        let slot = &c.slots[i];
        let meta = slot.meta.as_deref();
        Some(TagValue {
            value: slot.value.to_json(),
            unit: meta.and_then(|m| m.unit.as_deref()).map(str::to_owned),
            quality: self.qualities[usize::from(slot.quality)],
            timestamp: time_of(slot.micros),
            description: meta
                .and_then(|m| m.description.as_deref())
                .map(str::to_owned),
        })
    }
}

/// The chunk and slot of sequence number `seq`.
fn locate(head: u32, chunk: usize, seq: u32) -> (usize, usize) {
    let at = seq.wrapping_sub(head) as usize;
    (at / chunk, at % chunk)
}

/// The key of the pending slot `seq`.
fn key_of(chunks: &VecDeque<Chunk>, head: u32, chunk: usize, seq: u32) -> &str {
    let (n, i) = locate(head, chunk, seq);
    chunks[n].key(i)
}

/// Microseconds since the epoch (a time before it counts as the epoch).
fn micros(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_micros()).unwrap_or(u64::MAX))
}

fn time_of(micros: u64) -> SystemTime {
    UNIX_EPOCH
        .checked_add(Duration::from_micros(micros))
        .unwrap_or(UNIX_EPOCH)
}

/// Writes `{"description"?, "quality", "timestamp", "unit", "value"}` in the order and form
/// `serde_json` gives [`TagValue::to_json`] (its object's keys sorted, no spaces).
fn write_payload(
    out: &mut Vec<u8>,
    value: &Scalar,
    quality: &str,
    micros: u64,
    unit: Option<&str>,
    description: Option<&str>,
) -> std::io::Result<()> {
    out.push(b'{');
    if let Some(d) = description {
        out.extend_from_slice(b"\"description\":");
        serde_json::to_writer(&mut *out, d)?;
        out.push(b',');
    }
    out.extend_from_slice(b"\"quality\":");
    serde_json::to_writer(&mut *out, quality)?;
    out.extend_from_slice(b",\"timestamp\":\"");
    write!(out, "{}", humantime::format_rfc3339_micros(time_of(micros)))?;
    out.extend_from_slice(b"\",\"unit\":");
    serde_json::to_writer(&mut *out, unit.unwrap_or(""))?;
    out.extend_from_slice(b",\"value\":");
    value.write(out)?;
    out.push(b'}');
    Ok(())
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;
    use serde_json::json;

    use super::*;

    fn value(v: i64) -> TagValue {
        TagValue {
            value: v.into(),
            unit: None,
            quality: "good",
            timestamp: UNIX_EPOCH,
            description: None,
        }
    }

    /// Takes every chunk: (key, value) in the order taken.
    fn take_all(q: &mut TagQueue) -> Vec<(String, i64)> {
        let mut out = Vec::new();
        while let Some(c) = q.take() {
            for i in 0..c.len() {
                let (k, v) = c.get(i);
                out.push((k.to_owned(), v.value.as_i64().unwrap_or(i64::MIN)));
            }
            q.recycle(c);
        }
        out
    }

    #[test]
    fn a_chunked_take_keeps_the_order_and_the_newest_value_across_chunks() {
        let mut q = TagQueue::with_chunk(100, 3);
        for (k, v) in [("a", 1), ("b", 2), ("c", 3), ("d", 4), ("e", 5)] {
            assert_eq!(q.push(&["k", k], value(v)), Pushed::New);
        }
        // A newer value in the first chunk and in the second keeps its key's place.
        assert_eq!(q.push(&["k", "b"], value(20)), Pushed::Superseded);
        assert_eq!(q.push(&["k", "e"], value(50)), Pushed::Superseded);
        assert_eq!(q.keys(), ["k/a", "k/b", "k/c", "k/d", "k/e"]);
        let first = q.take().expect("a chunk");
        assert_eq!(first.len(), 3);
        assert_eq!(
            (0..3).map(|i| first.key(i)).collect::<Vec<_>>(),
            ["k/a", "k/b", "k/c"]
        );
        assert_eq!(first.get(1).1.value, 20);
        q.recycle(first);
        // Taken keys are pending no more: a value for one of them is new, behind the others.
        assert_eq!(q.push(&["k", "a"], value(10)), Pushed::New);
        assert_eq!(q.push(&["k", "d"], value(40)), Pushed::Superseded);
        assert_eq!(q.len(), 3);
        assert_eq!(
            take_all(&mut q),
            [("k/d".into(), 40), ("k/e".into(), 50), ("k/a".into(), 10)]
        );
        assert!(q.is_empty());
        // A partly filled chunk taken: the next key starts a new one.
        assert_eq!(q.push(&["k", "x"], value(1)), Pushed::New);
        assert_eq!(q.take().map(|c| c.len()), Some(1));
        assert_eq!(q.push(&["k", "x"], value(2)), Pushed::New);
        assert_eq!(q.push(&["k", "x"], value(3)), Pushed::Superseded);
        assert_eq!(take_all(&mut q), [("k/x".into(), 3)]);
    }

    #[test]
    fn the_limit_holds_and_taking_makes_room() {
        let mut q = TagQueue::with_chunk(4, 3);
        for k in ["a", "b", "c", "d"] {
            assert_eq!(q.push(&[k], value(1)), Pushed::New);
        }
        assert_eq!(q.push(&["e"], value(1)), Pushed::Full);
        // A pending key still takes a newer value when the queue is full.
        assert_eq!(q.push(&["d"], value(2)), Pushed::Superseded);
        assert_eq!(q.len(), 4);
        let c = q.take().expect("a chunk");
        assert_eq!(c.len(), 3);
        assert_eq!(q.push(&["e"], value(1)), Pushed::New);
        assert_eq!(q.push(&["f"], value(1)), Pushed::New);
        assert_eq!(q.push(&["g"], value(1)), Pushed::New);
        assert_eq!(q.push(&["h"], value(1)), Pushed::Full);
        assert_eq!(
            take_all(&mut q),
            [
                ("d".into(), 2),
                ("e".into(), 1),
                ("f".into(), 1),
                ("g".into(), 1)
            ]
        );
    }

    #[test]
    fn a_key_that_is_no_key_expression_is_refused() {
        let mut q = TagQueue::new(8);
        assert!(matches!(q.push(&["a", "b?c"], value(1)), Pushed::BadKey(k, _) if k == "a/b?c"));
        assert!(matches!(q.push(&["a", ""], value(1)), Pushed::BadKey(..)));
        assert!(q.is_empty());
    }

    #[test]
    fn unit_and_description_are_shared_and_pruned_when_unused() {
        let mut q = TagQueue::with_chunk(10_000, 100);
        let described = |n: usize| TagValue {
            unit: Some("rpm".to_owned()),
            description: Some(format!("speed {}", n % 2)),
            ..value(1)
        };
        for n in 0..10 {
            q.push(&["t", &n.to_string()], described(n));
        }
        assert_eq!(q.metas.len(), 2);
        let v = q.value("t/3").expect("pending");
        assert_eq!(
            (v.unit.as_deref(), v.description.as_deref()),
            (Some("rpm"), Some("speed 1"))
        );
        // Thousands of distinct texts come and go: the set keeps those still in use.
        for n in 0..5_000 {
            let v = TagValue {
                description: Some(format!("d{n}")),
                ..value(1)
            };
            q.push(&["u", &n.to_string()], v);
            if q.len() > 100 {
                let c = q.take();
                drop(c);
            }
        }
        assert!(
            q.metas.len() <= 2 * META_PRUNE_MIN + q.len(),
            "{}",
            q.metas.len()
        );
    }

    #[test]
    fn a_hundred_thousand_keys_come_out_in_order() {
        let mut q = TagQueue::new(131_072);
        for n in 0..100_000 {
            q.push(&["gw", "bench", "l0", "d1", &format!("t{n}")], value(n));
        }
        for n in (0..100_000).step_by(7) {
            q.push(&["gw", "bench", "l0", "d1", &format!("t{n}")], value(-n));
        }
        let taken = take_all(&mut q);
        assert_eq!(taken.len(), 100_000);
        for (n, (k, v)) in taken.iter().enumerate() {
            let n = n as i64;
            assert_eq!(*k, format!("gw/bench/l0/d1/t{n}"));
            assert_eq!(*v, if n % 7 == 0 { -n } else { n });
        }
    }

    #[derive(Clone, Debug)]
    enum Op {
        Tag(u8, i64),
        /// The publisher thread takes one chunk.
        Take,
    }

    fn op() -> impl Strategy<Value = Op> {
        prop_oneof![
            6 => (0u8..12, any::<i64>()).prop_map(|(k, v)| Op::Tag(k, v)),
            1 => Just(Op::Take),
        ]
    }

    proptest! {
        /// Against a model of chunks: every take gives the oldest chunk's keys in the order they
        /// became pending, each with its newest value; the limit holds; every value offered is
        /// taken, superseded or refused as full.
        #[test]
        fn takes_match_a_model_of_chunks(
            ops in prop::collection::vec(op(), 0..300),
            chunk in 1usize..5,
            limit in 1usize..10,
        ) {
            let mut q = TagQueue::with_chunk(limit, chunk);
            let chunk = chunk.min(limit);
            let mut model: VecDeque<Vec<(String, i64)>> = VecDeque::new();
            let (mut offered, mut superseded, mut full, mut taken) = (0, 0, 0, 0);
            for op in ops {
                match op {
                    Op::Tag(k, v) => {
                        offered += 1;
                        let key = format!("k/{k}");
                        let pending: usize = model.iter().map(Vec::len).sum();
                        let slot = model.iter_mut().flatten().find(|(m, _)| *m == key);
                        let expect = match slot {
                            Some(slot) => {
                                slot.1 = v;
                                Pushed::Superseded
                            }
                            None if pending >= limit => Pushed::Full,
                            None => {
                                match model.back_mut() {
                                    Some(back) if back.len() < chunk => back.push((key, v)),
                                    _ => model.push_back(vec![(key, v)]),
                                }
                                Pushed::New
                            }
                        };
                        match expect {
                            Pushed::Superseded => superseded += 1,
                            Pushed::Full => full += 1,
                            _ => {}
                        }
                        prop_assert_eq!(q.push(&["k", &k.to_string()], value(v)), expect);
                    }
                    Op::Take => {
                        let got = q.take().map(|c| {
                            let got: Vec<_> = (0..c.len())
                                .map(|i| (c.key(i).to_owned(), c.get(i).1.value.as_i64().unwrap_or(i64::MIN)))
                                .collect();
                            q.recycle(c);
                            got
                        });
                        taken += got.as_ref().map_or(0, Vec::len);
                        prop_assert_eq!(got, model.pop_front());
                    }
                }
                prop_assert_eq!(q.len(), model.iter().map(Vec::len).sum::<usize>());
                prop_assert!(q.len() <= limit);
            }
            let rest = take_all(&mut q);
            let expected: Vec<_> = model.into_iter().flatten().collect();
            taken += rest.len();
            prop_assert_eq!(rest, expected);
            prop_assert_eq!(offered, taken + superseded + full);
        }

        /// The payload written from a slot is byte for byte `TagValue::to_json`'s text.
        #[test]
        fn the_payload_is_the_json_of_the_value(
            n in any::<i64>(),
            u in any::<u64>(),
            f in any::<f64>().prop_filter("finite", |f| f.is_finite()),
            text in ".{0,12}",
            kind in 0u8..7,
            unit in proptest::option::of(".{0,6}"),
            description in proptest::option::of(".{0,20}"),
            nanos in 0u64..4_102_444_800_000_000_000,
            quality in prop::sample::select(vec!["good", "stale", "comm_failure", "not_defined"]),
        ) {
            let value = match kind {
                0 => json!(n),
                1 => json!(u),
                2 => json!(f),
                3 => json!(n % 2 == 0),
                4 => json!(text),
                5 => Value::Null,
                _ => json!([n, text]),
            };
            let tag = TagValue {
                value,
                unit,
                quality,
                timestamp: UNIX_EPOCH + Duration::from_nanos(nanos),
                description,
            };
            let expected = tag.to_json().to_string();
            let mut q = TagQueue::new(4);
            prop_assert_eq!(q.push(&["gw", "t", "l", "d", "x"], tag), Pushed::New);
            let c = q.take().expect("a chunk");
            let mut out = Vec::new();
            c.write_payload(0, &mut out).expect("written");
            prop_assert_eq!(String::from_utf8(out).expect("utf-8"), expected);
        }
    }
}
