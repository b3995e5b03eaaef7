//! The `[zenoh]` section of the gateway configuration.
//!
//! ```toml
//! [zenoh]
//! enabled = true                      # default true
//! mode = "peer"                       # "peer" (default), "client" or "router"
//! listen = ["tcp/0.0.0.0:7447"]       # zenoh endpoints; unset: the file's, else tcp/127.0.0.1:7447
//! connect = ["tcp/192.168.1.10:7447"] # unset: the file's or zenoh's default (none)
//! multicast_scouting = true           # unset: the file's, else off
//! lease = "10s"                       # how soon the fabric forgets a silent gateway; unset: the file's, else zenoh's 10 s
//! prefix = "plant/hall2/gw1"          # default "gw/<gateway name>"
//! writes = true                       # accept `tx` and tag `set` puts; default false
//! config_file = "/etc/gateway/zenoh.json5"  # a zenoh config file (TLS, access control, ...)
//! telegram_queue = 1024               # received telegrams waiting to be published
//! event_queue = 256                   # events waiting to be published
//! tag_queue = 4096                    # tags with a value waiting to be published (newest wins)
//! result_queue = 256                  # tx / set results waiting to be published
//! command_queue = 64                  # tx / set commands waiting for their line
//! query_queue = 64                    # queries waiting to be answered
//! max_payload = 65536                 # bytes; a larger put or query payload is refused
//!
//! [zenoh.publish]                      # how tag values are published (default: every change)
//! deadband = 0.0                       # publish a number when it moved by more than this
//! deadband_percent = 0.0               # ... and by more than this % of the last one published
//! heartbeat = "0s"                     # publish at least this often, changed or not; 0s: off
//! [[zenoh.publish.tags]]               # for the tags a key expression matches (first rule wins)
//! key = "drive/*/SFr"                  # <line>/<device>/<tag>, wildcards allowed
//! deadband = 0.5                       # keys left out take the section's
//! ```
//!
//! Precedence: `config_file` is read first (as zenoh documents it, json5), then every key set in
//! this section overrides the file. Keys left unset keep the file's value, or zenoh's default
//! when there is no file. That is how TLS endpoints (`tls/host:port`), certificates and access
//! control are configured: in the zenoh file, exactly as zenoh documents them (TLS comes with the
//! default cargo feature `zenoh-tls`).
//!
//! Overflow policy (every drop is counted by the reason named here in the bridge's counters,
//! and in `gateway_dropped_updates_total{reason}` as `queue_full`, `lagged` or `closed`):
//! - tag values: one pending value per tag key, a newer value replaces it (`tag_superseded`);
//!   a value for a new key when `tag_queue` keys are pending is dropped (`tag_queue_full`);
//! - telegrams, events and results: first in, first out; when full the new item is dropped and
//!   counted (`telegram_queue_full`, `event_queue_full`, `result_queue_full`), and the caller
//!   is told. Order per line is kept, nothing is published twice;
//! - commands and queries: when full, the command is answered `busy` on its result key
//!   (`command_queue_full`, and `gateway_writes_total{path="zenoh",result="refused",
//!   reason="queue_full"}` as every refused command), the query gets no reply
//!   (`query_queue_full`). With `writes = false` a command is refused before it is queued.
//!
//! The publisher thread takes everything pending at once, so up to twice a queue's size can be
//! held (one batch being published, one queue filling).
//!
//! Size: `max_payload` bounds what one put or query may carry. zenoh itself is told to drop
//! any message larger than `max_payload` + [`PAYLOAD_HEADROOM`] while reassembling it (its
//! `transport/link/rx/max_message_size`), so a huge put costs the gateway at most that much
//! memory; a payload between the two reaches the bridge, which refuses it (see the bridge's
//! module docs for what is counted where).

use std::num::NonZeroUsize;
use std::path::PathBuf;
use std::str::FromStr;
use std::time::Duration;

use ::zenoh::key_expr::OwnedKeyExpr;
use serde::{Deserialize, Deserializer, Serialize};

use super::reader::{string_value, Cx, Fields};

/// A deadband: a finite amount, 0 or more (checked when read).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
#[serde(transparent)]
pub struct Deadband(pub f64);

// The reader accepts finite numbers only, so equality is total.
impl Eq for Deadband {}

/// How the tags a rule (or the section) covers are published. With a deadband or a heartbeat
/// set, a value equal to the last one published (same quality) is not published again by a
/// change elsewhere in its poll's range; a numeric value is published when it moved by more
/// than `deadband` and by more than `deadband_percent` of the last value published (each only
/// when above 0); a change of quality, and every change of a value that is not a number, is
/// always published. With a `heartbeat`, the current value is published again
/// whenever nothing was published for that long, changed or not, so that silence means trouble.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct TagPolicy {
    /// Absolute deadband in the tag's unit; 0: every change.
    pub deadband: Deadband,
    /// Deadband in percent of the last published value; 0: off.
    pub deadband_percent: Deadband,
    /// Publish at least this often; 0: only on change.
    #[serde(with = "humantime_serde")]
    pub heartbeat: Duration,
}

impl TagPolicy {
    /// Whether the policy changes anything (a deadband or a heartbeat is set).
    pub fn is_active(&self) -> bool {
        self.deadband.0 > 0.0 || self.deadband_percent.0 > 0.0 || !self.heartbeat.is_zero()
    }
}

/// One `[[zenoh.publish.tags]]` entry: the policy of the tags its key expression matches.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct TagRule {
    /// `<line>/<device>/<tag>` below the prefix, wildcards allowed.
    pub key: String,
    /// The policy, the keys the entry leaves out taken from the section.
    #[serde(flatten)]
    pub policy: TagPolicy,
}

/// The `[zenoh.publish]` table.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct PublishConfig {
    /// The policy of every tag no rule matches.
    #[serde(flatten)]
    pub default: TagPolicy,
    /// Rules, the first that matches a tag wins.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub tags: Vec<TagRule>,
}

impl PublishConfig {
    /// The policy of the tag `<line>/<device>/<tag>`.
    pub fn policy(&self, line: &str, device: &str, tag: &str) -> TagPolicy {
        if self.tags.is_empty() {
            return self.default;
        }
        let Ok(key) = OwnedKeyExpr::new(format!("{line}/{device}/{tag}")) else {
            return self.default;
        };
        self.tags
            .iter()
            .find(|r| ::zenoh::key_expr::keyexpr::new(&r.key).is_ok_and(|rule| rule.includes(&key)))
            .map_or(self.default, |r| r.policy)
    }

    fn read(cx: &mut Cx, mut f: Fields<'_>) -> Self {
        let default = read_policy(cx, &mut f, TagPolicy::default());
        let mut tags = Vec::new();
        for (path, value) in f.array(cx, "tags") {
            let Some(mut t) = Fields::of(cx, value, path) else {
                continue;
            };
            let key = t.required_string(cx, "key").unwrap_or_default();
            if !key.is_empty() {
                if let Err(e) = OwnedKeyExpr::new(key.as_str()) {
                    cx.issue(
                        t.at("key"),
                        format!("not a canonical key expression (<line>/<device>/<tag>, wildcards allowed): {e}"),
                    );
                }
            }
            let policy = read_policy(cx, &mut t, default);
            t.finish(cx);
            tags.push(TagRule { key, policy });
        }
        f.finish(cx);
        Self { default, tags }
    }
}

/// The policy keys of a table, those left out taken from `inherit`.
fn read_policy(cx: &mut Cx, f: &mut Fields<'_>, inherit: TagPolicy) -> TagPolicy {
    let mut amount = |cx: &mut Cx, key: &'static str, default: f64, max: f64| {
        let had = f.has(key);
        let v = f.float_or(cx, key, default);
        if had && !(0.0..=max).contains(&v) {
            cx.issue(f.at(key), format!("must be between 0 and {max}, found {v}"));
            return Deadband(default);
        }
        Deadband(v)
    };
    let deadband = amount(cx, "deadband", inherit.deadband.0, f64::MAX);
    let deadband_percent = amount(cx, "deadband_percent", inherit.deadband_percent.0, 100.0);
    let heartbeat = match f.duration(cx, "heartbeat", Duration::ZERO..=MAX_HEARTBEAT, "") {
        Some(h) if !h.is_zero() && h < MIN_HEARTBEAT => {
            cx.issue(f.at("heartbeat"), "must be 0s (off) or at least 100ms");
            inherit.heartbeat
        }
        Some(h) => h,
        None => inherit.heartbeat,
    };
    TagPolicy {
        deadband,
        deadband_percent,
        heartbeat,
    }
}

/// Default for [`ZenohConfig::telegram_queue`].
pub const DEFAULT_TELEGRAM_QUEUE: usize = 1024;
/// Default for [`ZenohConfig::event_queue`].
pub const DEFAULT_EVENT_QUEUE: usize = 256;
/// Default for [`ZenohConfig::tag_queue`].
pub const DEFAULT_TAG_QUEUE: usize = 4096;
/// Default for [`ZenohConfig::result_queue`].
pub const DEFAULT_RESULT_QUEUE: usize = 256;
/// Default for [`ZenohConfig::command_queue`].
pub const DEFAULT_COMMAND_QUEUE: usize = 64;
/// Default for [`ZenohConfig::query_queue`].
pub const DEFAULT_QUERY_QUEUE: usize = 64;
/// Default for [`ZenohConfig::max_payload`]: 64 KiB, a zenoh batch, far more than a telegram
/// or a tag value takes.
pub const DEFAULT_MAX_PAYLOAD: usize = 65_536;
/// The largest [`ZenohConfig::max_payload`]: 16 MiB.
pub const MAX_MAX_PAYLOAD: usize = 16 * 1024 * 1024;
/// What a message may carry besides its payload before zenoh drops it unread: the key
/// expression, the attachment (a command's correlation data) and zenoh's framing. zenoh's
/// `transport/link/rx/max_message_size` is `max_payload` plus this (131 072 bytes by default).
pub const PAYLOAD_HEADROOM: usize = 65_536;
/// The shortest `[zenoh] lease`.
pub const MIN_LEASE: Duration = Duration::from_millis(500);
/// The longest `[zenoh] lease`.
pub const MAX_LEASE: Duration = Duration::from_secs(3600);
/// The shortest heartbeat other than 0 (off).
pub const MIN_HEARTBEAT: Duration = Duration::from_millis(100);
/// The longest heartbeat.
pub const MAX_HEARTBEAT: Duration = Duration::from_secs(24 * 3600);
/// The bridge starts when the section is there, unless `enabled = false`.
pub const DEFAULT_ZENOH_ENABLED: bool = true;
/// zenoh carries no credentials of its own: `tx` and tag `set` puts are refused unless
/// `writes = true` (and then zenoh's access control should say who may put).
pub const DEFAULT_ZENOH_WRITES: bool = false;

/// How the session joins the fabric.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Talks to other peers directly and to routers (zenoh's default for a session).
    #[default]
    Peer,
    /// Talks only through one router (or peer) it connects to. The bridge keeps retrying the
    /// first connection, and zenoh reconnects after a loss.
    Client,
    /// Routes for others: clients and peers (local applications, other gateways) connect to
    /// it, and it forwards between them and the routers it connects to.
    Router,
}

impl Mode {
    /// The zenoh name of the mode.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Peer => "peer",
            Self::Client => "client",
            Self::Router => "router",
        }
    }
}

/// A zenoh endpoint (`tcp/127.0.0.1:7447`, `tls/host:7447`...), checked when the config is read.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct Endpoint(String);

impl TryFrom<String> for Endpoint {
    type Error = String;

    fn try_from(s: String) -> Result<Self, Self::Error> {
        ::zenoh::config::EndPoint::from_str(&s)
            .map_err(|e| format!("bad zenoh endpoint {s:?}: {e}"))?;
        Ok(Self(s))
    }
}

impl From<Endpoint> for String {
    fn from(e: Endpoint) -> Self {
        e.0
    }
}

impl Endpoint {
    /// The endpoint text.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}

/// A key prefix: a canonical key expression without wildcards, checked when the config is read.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct Prefix(String);

impl TryFrom<String> for Prefix {
    type Error = String;

    fn try_from(s: String) -> Result<Self, Self::Error> {
        check_prefix(&s).map_err(|reason| {
            format!(
                "key prefix {s:?} is not a canonical key expression without wildcards: {reason}"
            )
        })?;
        Ok(Self(s))
    }
}

impl From<Prefix> for String {
    fn from(p: Prefix) -> Self {
        p.0
    }
}

impl Prefix {
    /// The prefix text.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}

/// Checks a prefix: a canonical key expression without wildcards; else why not.
pub fn check_prefix(prefix: &str) -> Result<OwnedKeyExpr, String> {
    let ke = OwnedKeyExpr::new(prefix).map_err(|e| e.to_string())?;
    if ke.is_wild() {
        return Err("it contains a wildcard".to_owned());
    }
    Ok(ke)
}

/// The `[zenoh]` section: one session per gateway.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct ZenohConfig {
    /// Whether the gateway starts the bridge at all (the bridge itself does not look at it).
    pub enabled: bool,
    /// Peer, client or router; unset: the file's, else peer.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mode: Option<Mode>,
    /// Endpoints to listen on; unset: the file's, else loopback only (`tcp/127.0.0.1:7447`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub listen: Option<Vec<Endpoint>>,
    /// Endpoints to connect to; unset: the file's, else none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub connect: Option<Vec<Endpoint>>,
    /// UDP multicast scouting; unset: the file's, else off (the gateway is not announced on
    /// the network unless asked to be).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub multicast_scouting: Option<bool>,
    /// Key prefix; unset: `gw/<gateway name>`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub prefix: Option<Prefix>,
    /// zenoh's lease: a router or peer that hears nothing of this gateway for this long closes
    /// its session, and its liveliness tokens go; unset: the file's, else zenoh's (10 s).
    #[serde(
        skip_serializing_if = "Option::is_none",
        with = "humantime_serde::option"
    )]
    pub lease: Option<Duration>,
    /// Accept telegram sends (`<line>/tx`) and tag writes (`.../set`); off by default.
    pub writes: bool,
    /// A zenoh configuration file (json5) read first; the keys above override it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub config_file: Option<PathBuf>,
    /// Received telegrams waiting for the session (FIFO, overflow counted).
    pub telegram_queue: NonZeroUsize,
    /// Events waiting for the session (FIFO, overflow counted).
    pub event_queue: NonZeroUsize,
    /// Tag keys with a pending value (newest value per key wins, overflow counted).
    pub tag_queue: NonZeroUsize,
    /// Command results waiting for the session (FIFO, overflow counted).
    pub result_queue: NonZeroUsize,
    /// Commands (`tx`, `set`) waiting, in total and per line (overflow answered `busy`).
    pub command_queue: NonZeroUsize,
    /// Queries waiting to be answered (overflow counted, the query gets no reply).
    pub query_queue: NonZeroUsize,
    /// The largest payload of a put or query, in bytes; a larger one is refused (and zenoh drops
    /// a message larger than this plus [`PAYLOAD_HEADROOM`] before it reaches the bridge).
    pub max_payload: NonZeroUsize,
    /// How tag values are published (`[zenoh.publish]`): deadbands and heartbeats.
    pub publish: PublishConfig,
}

fn nonzero(n: usize) -> NonZeroUsize {
    NonZeroUsize::new(n).unwrap_or(NonZeroUsize::MIN)
}

impl Default for ZenohConfig {
    fn default() -> Self {
        Self {
            enabled: DEFAULT_ZENOH_ENABLED,
            mode: None,
            listen: None,
            connect: None,
            multicast_scouting: None,
            prefix: None,
            lease: None,
            writes: DEFAULT_ZENOH_WRITES,
            config_file: None,
            telegram_queue: nonzero(DEFAULT_TELEGRAM_QUEUE),
            event_queue: nonzero(DEFAULT_EVENT_QUEUE),
            tag_queue: nonzero(DEFAULT_TAG_QUEUE),
            result_queue: nonzero(DEFAULT_RESULT_QUEUE),
            command_queue: nonzero(DEFAULT_COMMAND_QUEUE),
            query_queue: nonzero(DEFAULT_QUERY_QUEUE),
            max_payload: nonzero(DEFAULT_MAX_PAYLOAD),
            publish: PublishConfig::default(),
        }
    }
}

// === impl ZenohConfig ===

impl ZenohConfig {
    /// A peer listening on `listen` only, multicast scouting off: the shape every test uses.
    pub fn loopback_peer(listen: &str) -> Result<Self, String> {
        Ok(Self {
            mode: Some(Mode::Peer),
            listen: Some(vec![Endpoint::try_from(listen.to_owned())?]),
            connect: Some(Vec::new()),
            multicast_scouting: Some(false),
            ..Self::default()
        })
    }

    /// Reads the `[zenoh]` table: every key converted and checked, every problem with its path.
    pub(crate) fn read(cx: &mut Cx, mut f: Fields<'_>) -> Self {
        let enabled = f.bool_or(cx, "enabled", DEFAULT_ZENOH_ENABLED);
        let mode = f.choice::<Mode>(cx, "mode");
        let listen = endpoints(cx, &mut f, "listen");
        let connect = endpoints(cx, &mut f, "connect");
        let multicast_scouting = f.bool(cx, "multicast_scouting");
        let prefix = f.string(cx, "prefix").and_then(|text| {
            Prefix::try_from(text)
                .map_err(|e| cx.issue(f.at("prefix"), e))
                .ok()
        });
        let mut config = Self {
            enabled,
            mode,
            listen,
            connect,
            multicast_scouting,
            prefix,
            lease: f.duration(cx, "lease", MIN_LEASE..=MAX_LEASE, ""),
            writes: f.bool_or(cx, "writes", DEFAULT_ZENOH_WRITES),
            config_file: f.string(cx, "config_file").map(PathBuf::from),
            ..Self::default()
        };
        for (key, field, max) in [
            ("telegram_queue", &mut config.telegram_queue, u32::MAX),
            ("event_queue", &mut config.event_queue, u32::MAX),
            ("tag_queue", &mut config.tag_queue, u32::MAX),
            ("result_queue", &mut config.result_queue, u32::MAX),
            ("command_queue", &mut config.command_queue, u32::MAX),
            ("query_queue", &mut config.query_queue, u32::MAX),
            (
                "max_payload",
                &mut config.max_payload,
                MAX_MAX_PAYLOAD as u32,
            ),
        ] {
            if let Some(n) = f.int::<u32>(cx, key, 1..=max, "") {
                *field = nonzero(n as usize);
            }
        }
        if let Some(t) = f.table(cx, "publish") {
            config.publish = PublishConfig::read(cx, t);
        }
        f.finish(cx);
        config
    }
}

/// A list of endpoints, each checked; `None` when the key is not set.
fn endpoints(cx: &mut Cx, f: &mut Fields<'_>, key: &'static str) -> Option<Vec<Endpoint>> {
    if !f.has(key) {
        let _ = f.raw(key);
        return None;
    }
    let mut list = Vec::new();
    for (path, value) in f.array(cx, key) {
        let Some(text) = string_value(cx, value, &path) else {
            continue;
        };
        match Endpoint::try_from(text) {
            Ok(e) => list.push(e),
            Err(e) => cx.issue(path, e),
        }
    }
    Some(list)
}

/// Reads the section through [`ZenohConfig::read`]: unknown keys are refused, every problem is
/// reported.
impl<'de> Deserialize<'de> for ZenohConfig {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        super::read_section(deserializer, "zenoh", Self::read)
    }
}
