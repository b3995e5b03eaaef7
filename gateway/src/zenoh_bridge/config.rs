//! The `[zenoh]` section of the gateway configuration.
//!
//! ```toml
//! [zenoh]
//! enabled = true                      # default true
//! mode = "peer"                       # "peer" (default) or "client"
//! listen = ["tcp/0.0.0.0:7447"]       # zenoh endpoints; unset: the file's or zenoh's default
//! connect = ["tcp/192.168.1.10:7447"] # unset: the file's or zenoh's default (none)
//! multicast_scouting = false          # unset: the file's or zenoh's default (on)
//! prefix = "plant/hall2/gw1"          # default "gw/<gateway name>"
//! config_file = "/etc/gateway/zenoh.json5"  # a zenoh config file (TLS, access control, ...)
//! telegram_queue = 1024               # received telegrams waiting to be published
//! event_queue = 256                   # events waiting to be published
//! tag_queue = 4096                    # tags with a value waiting to be published (newest wins)
//! result_queue = 256                  # tx / set results waiting to be published
//! command_queue = 64                  # tx / set commands waiting for their line
//! query_queue = 64                    # queries waiting to be answered
//! ```
//!
//! Precedence: `config_file` is read first (as zenoh documents it, json5), then every key set in
//! this section overrides the file. Keys left unset keep the file's value, or zenoh's default
//! when there is no file. That is how TLS endpoints (`tls/host:port`), certificates and access
//! control are configured: in the zenoh file, exactly as zenoh documents them (TLS needs the
//! gateway built with the `zenoh-tls` cargo feature).
//!
//! Overflow policy (every drop is counted by the reason named here in the bridge's counters,
//! and in `gateway_dropped_updates_total{reason}` as `queue_full`, `lagged` or `closed`):
//! - tag values: one pending value per tag key, a newer value replaces it (`tag_superseded`);
//!   a value for a new key when `tag_queue` keys are pending is dropped (`tag_queue_full`);
//! - telegrams, events and results: first in, first out; when full the new item is dropped and
//!   counted (`telegram_queue_full`, `event_queue_full`, `result_queue_full`), and the caller
//!   is told. Order per line is kept, nothing is published twice;
//! - commands and queries: when full, the command is answered `busy` on its result key
//!   (`command_queue_full`), the query gets no reply (`query_queue_full`).
//!
//! The publisher thread takes everything pending at once, so up to twice a queue's size can be
//! held (one batch being published, one queue filling).

use std::num::NonZeroUsize;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use super::keys::{self, KeyError};
use super::BridgeError;

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
}

impl Mode {
    /// The zenoh name of the mode.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Peer => "peer",
            Self::Client => "client",
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
        zenoh::config::EndPoint::from_str(&s)
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
    type Error = KeyError;

    fn try_from(s: String) -> Result<Self, Self::Error> {
        keys::check_prefix(&s)?;
        Ok(Self(s))
    }
}

impl From<Prefix> for String {
    fn from(p: Prefix) -> Self {
        p.0
    }
}

/// The `[zenoh]` section: one session per gateway.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZenohConfig {
    /// Whether the gateway starts the bridge at all (the bridge itself does not look at it).
    #[serde(default = "default_enabled")]
    pub enabled: bool,
    /// Peer or client; unset: the file's, else peer.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mode: Option<Mode>,
    /// Endpoints to listen on; unset: the file's, else zenoh's default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub listen: Option<Vec<Endpoint>>,
    /// Endpoints to connect to; unset: the file's, else none.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub connect: Option<Vec<Endpoint>>,
    /// UDP multicast scouting; unset: the file's, else zenoh's default (on). Turn it off
    /// wherever the endpoints are known (and always in tests).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub multicast_scouting: Option<bool>,
    /// Key prefix; unset: `gw/<gateway name>`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prefix: Option<Prefix>,
    /// A zenoh configuration file (json5) read first; the keys above override it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub config_file: Option<PathBuf>,
    /// Received telegrams waiting for the session (FIFO, overflow counted).
    #[serde(default = "default_telegram_queue")]
    pub telegram_queue: NonZeroUsize,
    /// Events waiting for the session (FIFO, overflow counted).
    #[serde(default = "default_event_queue")]
    pub event_queue: NonZeroUsize,
    /// Tag keys with a pending value (newest value per key wins, overflow counted).
    #[serde(default = "default_tag_queue")]
    pub tag_queue: NonZeroUsize,
    /// Command results waiting for the session (FIFO, overflow counted).
    #[serde(default = "default_result_queue")]
    pub result_queue: NonZeroUsize,
    /// Commands (`tx`, `set`) waiting, in total and per line (overflow answered `busy`).
    #[serde(default = "default_command_queue")]
    pub command_queue: NonZeroUsize,
    /// Queries waiting to be answered (overflow counted, the query gets no reply).
    #[serde(default = "default_query_queue")]
    pub query_queue: NonZeroUsize,
}

fn default_enabled() -> bool {
    true
}

fn nonzero(n: usize) -> NonZeroUsize {
    NonZeroUsize::new(n).unwrap_or(NonZeroUsize::MIN)
}

fn default_telegram_queue() -> NonZeroUsize {
    nonzero(DEFAULT_TELEGRAM_QUEUE)
}

fn default_event_queue() -> NonZeroUsize {
    nonzero(DEFAULT_EVENT_QUEUE)
}

fn default_tag_queue() -> NonZeroUsize {
    nonzero(DEFAULT_TAG_QUEUE)
}

fn default_result_queue() -> NonZeroUsize {
    nonzero(DEFAULT_RESULT_QUEUE)
}

fn default_command_queue() -> NonZeroUsize {
    nonzero(DEFAULT_COMMAND_QUEUE)
}

fn default_query_queue() -> NonZeroUsize {
    nonzero(DEFAULT_QUERY_QUEUE)
}

impl Default for ZenohConfig {
    fn default() -> Self {
        Self {
            enabled: default_enabled(),
            mode: None,
            listen: None,
            connect: None,
            multicast_scouting: None,
            prefix: None,
            config_file: None,
            telegram_queue: default_telegram_queue(),
            event_queue: default_event_queue(),
            tag_queue: default_tag_queue(),
            result_queue: default_result_queue(),
            command_queue: default_command_queue(),
            query_queue: default_query_queue(),
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

    /// The prefix in use for a gateway named `gateway_name`.
    pub fn prefix_for(&self, gateway_name: &str) -> Result<String, KeyError> {
        match &self.prefix {
            Some(p) => Ok(p.0.clone()),
            None => keys::default_prefix(gateway_name),
        }
    }

    /// The zenoh configuration: the file (if any), then this section's keys on top.
    pub fn to_zenoh(&self) -> Result<(zenoh::Config, Mode), BridgeError> {
        let mut z = match &self.config_file {
            Some(path) => read_file(path)?,
            None => zenoh::Config::default(),
        };
        let mut set = |key: &str, value: String| {
            z.insert_json5(key, &value)
                .map_err(|e| BridgeError::Config(format!("zenoh config {key} = {value}: {e}")))
        };
        if let Some(mode) = self.mode {
            set("mode", json_string(mode.as_str()))?;
        }
        if let Some(listen) = &self.listen {
            set("listen/endpoints", json_list(listen))?;
        }
        if let Some(connect) = &self.connect {
            set("connect/endpoints", json_list(connect))?;
        }
        if let Some(on) = self.multicast_scouting {
            set("scouting/multicast/enabled", on.to_string())?;
        }
        let mode = match z.get_json("mode").ok().as_deref() {
            Some("\"client\"") => Mode::Client,
            _ => Mode::Peer,
        };
        Ok((z, mode))
    }
}

fn read_file(path: &Path) -> Result<zenoh::Config, BridgeError> {
    zenoh::Config::from_file(path).map_err(|e| BridgeError::ConfigFile {
        path: path.to_owned(),
        reason: e.to_string(),
    })
}

fn json_string(s: &str) -> String {
    serde_json::Value::String(s.to_owned()).to_string()
}

fn json_list(endpoints: &[Endpoint]) -> String {
    serde_json::Value::Array(
        endpoints
            .iter()
            .map(|e| serde_json::Value::String(e.0.clone()))
            .collect(),
    )
    .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<ZenohConfig, toml::de::Error> {
        toml::from_str(text)
    }

    #[test]
    fn empty_section_gives_the_defaults() {
        let c = parse("").unwrap();
        assert_eq!(c, ZenohConfig::default());
        assert!(c.enabled);
        assert_eq!(c.telegram_queue.get(), DEFAULT_TELEGRAM_QUEUE);
        assert_eq!(c.prefix_for("demo").unwrap(), "gw/demo");
        let (_, mode) = c.to_zenoh().unwrap();
        assert_eq!(mode, Mode::Peer);
    }

    #[test]
    fn every_key_parses() {
        let c = parse(
            r#"
            enabled = true
            mode = "client"
            listen = ["tcp/127.0.0.1:7447"]
            connect = ["tcp/10.0.0.1:7447", "tcp/[::1]:7448"]
            multicast_scouting = false
            prefix = "plant/hall2/gw1"
            telegram_queue = 10
            event_queue = 11
            tag_queue = 12
            result_queue = 13
            command_queue = 14
            query_queue = 15
            "#,
        )
        .unwrap();
        assert_eq!(c.mode, Some(Mode::Client));
        assert_eq!(c.prefix_for("x").unwrap(), "plant/hall2/gw1");
        assert_eq!(c.query_queue.get(), 15);
        let (z, mode) = c.to_zenoh().unwrap();
        assert_eq!(mode, Mode::Client);
        assert_eq!(
            z.get_json("connect/endpoints").unwrap().replace(' ', ""),
            r#"["tcp/10.0.0.1:7447","tcp/[::1]:7448"]"#
        );
        assert_eq!(z.get_json("scouting/multicast/enabled").unwrap(), "false");
    }

    #[test]
    fn bad_values_are_refused_when_read() {
        for text in [
            "bogus = 1",
            "mode = \"router\"",
            "listen = [\"nonsense\"]",
            "connect = [\"tcp\"]",
            "prefix = \"gw/*\"",
            "prefix = \"gw//x\"",
            "telegram_queue = 0",
        ] {
            assert!(parse(text).is_err(), "{text}");
        }
    }

    #[test]
    fn roundtrip_through_toml() {
        let c = ZenohConfig::loopback_peer("tcp/127.0.0.1:7447").unwrap();
        let text = toml::to_string(&c).unwrap();
        assert_eq!(parse(&text).unwrap(), c);
    }

    #[test]
    fn section_overrides_the_file() {
        let dir = std::env::temp_dir().join(format!("zenoh-cfg-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("zenoh.json5");
        std::fs::write(
            &file,
            r#"{ mode: "client", connect: { endpoints: ["tcp/10.1.1.1:7447"] },
                 scouting: { multicast: { enabled: false } } }"#,
        )
        .unwrap();
        let mut c = ZenohConfig {
            config_file: Some(file.clone()),
            ..ZenohConfig::default()
        };
        let (z, mode) = c.to_zenoh().unwrap();
        assert_eq!(mode, Mode::Client);
        assert!(z
            .get_json("connect/endpoints")
            .unwrap()
            .contains("10.1.1.1"));
        c.mode = Some(Mode::Peer);
        let (_, mode) = c.to_zenoh().unwrap();
        assert_eq!(mode, Mode::Peer);
        c.config_file = Some(dir.join("missing.json5"));
        assert!(matches!(c.to_zenoh(), Err(BridgeError::ConfigFile { .. })));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
