//! What the API returns and takes: serde types with their OpenAPI schema.
//!
//! The backend fills these from the running gateway; where a value comes from the event catalog
//! (class name, description, remedy) a constructor looks it up, so every answer quotes the same
//! catalog (proto-core, 003 7.2).

mod diag;
mod fleet;
mod frame;
mod status;
mod tag;
mod telegram;

use std::collections::BTreeMap;
use std::time::SystemTime;

use proto_core::event::{self, EventId};
use serde::{Deserialize, Serialize};
use utoipa::openapi::schema::{KnownFormat, ObjectBuilder, Schema, SchemaFormat, Type};
use utoipa::openapi::RefOr;
use utoipa::{PartialSchema, ToSchema};

pub use diag::*;
pub use fleet::*;
pub use frame::*;
pub use status::*;
pub use tag::*;
pub use telegram::*;

use super::error::Issue;

/// A wall-clock time, written as RFC 3339 in UTC with milliseconds
/// (`2024-05-01T12:00:00.123Z`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct Timestamp(pub SystemTime);

impl Serialize for Timestamp {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(&humantime::format_rfc3339_millis(self.0))
    }
}

impl<'de> Deserialize<'de> for Timestamp {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let text = String::deserialize(d)?;
        humantime::parse_rfc3339_weak(&text)
            .map(Self)
            .map_err(serde::de::Error::custom)
    }
}

impl PartialSchema for Timestamp {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::String)
            .format(Some(SchemaFormat::KnownFormat(KnownFormat::DateTime)))
            .description(Some("RFC 3339, UTC, milliseconds"))
            .into()
    }
}

impl ToSchema for Timestamp {}

impl From<SystemTime> for Timestamp {
    fn from(t: SystemTime) -> Self {
        Self(t)
    }
}

/// An event of the catalog (003 7.2) as the API shows it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct EventView {
    /// Event class, e.g. 8 (08h, receive error).
    pub class: u8,
    /// Event number within the class, e.g. 48 (30h).
    pub number: u8,
    /// The STATUS word: bits 12..8 class, 7..0 number (e.g. 2096 = 0830h).
    pub status_word: u16,
    /// Class and number as four hex digits, as in the metrics' `event` label (`"0830"`).
    pub code: String,
    /// The manual's class title in English, lower case; `unknown` outside the catalog.
    pub class_name: String,
    /// What happened (7.2 "Description").
    pub description: String,
    /// What to do (7.2 "Remedy"); empty where the manual gives none.
    pub remedy: String,
    /// What this occurrence was, where the line knows it (e.g. `port not found: /dev/ttyS1`
    /// for 02 0Fh); left out otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub detail: Option<String>,
}

// === impl EventView ===

impl EventView {
    /// The catalog's entry for `id` (an id outside the catalog says so in its description).
    pub fn new(id: EventId) -> Self {
        let info = event::lookup(id);
        Self {
            class: id.class,
            number: id.number,
            status_word: id.status_word(),
            code: format!("{:04X}", id.status_word()),
            class_name: event::class_name(id.class).unwrap_or("unknown").to_owned(),
            description: info.map_or_else(
                || "event not in the catalog (003 7.2)".to_owned(),
                |i| i.description.to_owned(),
            ),
            remedy: info.map_or_else(String::new, |i| i.remedy.to_owned()),
            detail: None,
        }
    }

    /// The event a STATUS word reports; `None` for 0000h (no error, 003 7.1).
    pub fn from_status_word(word: u16) -> Option<Self> {
        event::Status(word).event().map(Self::new)
    }
}

/// What a configuration change did to the running gateway (filled by the backend).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct ApplyReport {
    /// Lines that were added and started.
    pub lines_started: Vec<String>,
    /// Lines that were removed and stopped.
    pub lines_stopped: Vec<String>,
    /// Lines whose serial or protocol settings changed, restarted as a whole.
    pub lines_restarted: Vec<String>,
    /// Devices (`line/device`) added, removed or changed on lines that kept running.
    pub devices_restarted: Vec<String>,
    /// Servers restarted (`modbus_tcp`, `zenoh`, `http`).
    pub servers_restarted: Vec<String>,
    /// Changes that take effect only at the next start of the process.
    pub pending_restart: Vec<String>,
}

impl ApplyReport {
    /// Whether nothing had to be restarted.
    pub fn is_empty(&self) -> bool {
        self.lines_started.is_empty()
            && self.lines_stopped.is_empty()
            && self.lines_restarted.is_empty()
            && self.devices_restarted.is_empty()
            && self.servers_restarted.is_empty()
            && self.pending_restart.is_empty()
    }
}

/// The answer to an accepted configuration change.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct ConfigChangeResult {
    /// The new configuration's version, as in the `ETag` header of `GET /config`.
    pub etag: String,
    /// Whether the configuration was written to the configuration file (false when the gateway
    /// runs without one, e.g. `gateway demo`).
    pub persisted: bool,
    /// What was restarted.
    pub applied: ApplyReport,
}

/// A setting given on the command line that is in force in place of a key of the configuration
/// (`--modbus-tcp`, `--http`, `--zenoh-listen`). `GET /config` shows it beside the configuration
/// (JSON: the array `overrides`; TOML: a comment before the tables), never in it: a `PUT` of what
/// `GET` answered leaves it out, and the file keeps its own value.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct ConfigOverride {
    /// The key of the configuration it stands in for: `modbus_tcp.listen`, `http.listen`,
    /// `zenoh.listen`.
    pub key: String,
    /// The command-line option: `--modbus-tcp`, `--http`, `--zenoh-listen`.
    pub option: String,
    /// What the command line gave (`127.0.0.1:0`).
    pub given: String,
    /// What runs: the address bound (the port the system chose for port 0), the endpoint.
    pub in_force: String,
    /// What else the option implies, when it does more than replace the key.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// The answer to `POST /config/validate` for a valid configuration.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct ValidationResult {
    /// Always true here: an invalid configuration is answered 422 with every issue.
    pub valid: bool,
    /// The lines of the configuration.
    pub lines: usize,
    /// The devices over all lines.
    pub devices: usize,
}

/// What `/readyz` checks (filled by the backend).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct Readiness {
    /// Per line: whether its port has been opened at least once (by the line's task, or, for a
    /// line restarted by a configuration change on the same port, by the task before it).
    pub lines: BTreeMap<String, bool>,
    /// Whether the Modbus TCP listener is bound.
    pub modbus_tcp: bool,
    /// Whether the zenoh session is up; absent when zenoh is not configured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub zenoh: Option<bool>,
    /// While another zenoh session holds this gateway's name: who (bounded, escaped text).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub zenoh_name_conflict: Option<String>,
}

// === impl Readiness ===

impl Readiness {
    /// Every line opened its port once, the Modbus TCP listener and the zenoh session are up.
    pub fn is_ready(&self) -> bool {
        self.issues().is_empty()
    }

    /// What is not ready yet, each with its place.
    pub fn issues(&self) -> Vec<Issue> {
        let mut issues: Vec<Issue> = self
            .lines
            .iter()
            .filter(|(_, opened)| !**opened)
            .map(|(name, _)| Issue {
                path: format!("lines.{name}"),
                message: "the port has not been opened yet".into(),
            })
            .collect();
        if !self.modbus_tcp {
            issues.push(Issue {
                path: "modbus_tcp".into(),
                message: "the Modbus TCP listener is not up".into(),
            });
        }
        if self.zenoh == Some(false) {
            issues.push(Issue {
                path: "zenoh".into(),
                message: "the zenoh session is not up".into(),
            });
        }
        if let Some(conflict) = &self.zenoh_name_conflict {
            issues.push(Issue {
                path: "zenoh.name".into(),
                message: format!(
                    "{conflict}; this gateway publishes nothing on zenoh until the name is free"
                ),
            });
        }
        issues
    }
}

/// The answer of `/healthz` and of `/readyz` when ready.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct Health {
    /// `alive` or `ready`.
    pub status: String,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn events_carry_the_catalog_texts() {
        let e = EventView::new(EventId::new(0x08, 0x30));
        assert_eq!(e.status_word, 0x0830);
        assert_eq!(e.code, "0830");
        assert_eq!(e.class_name, "receive error");
        assert!(!e.description.is_empty());
        assert!(!e.remedy.is_empty());
        let unknown = EventView::new(EventId::new(0x1F, 0xFF));
        assert_eq!(unknown.class_name, "unknown");
        assert_eq!(EventView::from_status_word(0), None);
        assert_eq!(EventView::from_status_word(0x0830), Some(e));
    }

    #[test]
    fn timestamps_are_rfc3339_and_read_back() {
        let t = Timestamp(SystemTime::UNIX_EPOCH + std::time::Duration::from_millis(1_500));
        let json = serde_json::to_string(&t).unwrap();
        assert_eq!(json, "\"1970-01-01T00:00:01.500Z\"");
        assert_eq!(serde_json::from_str::<Timestamp>(&json).unwrap(), t);
    }

    #[test]
    fn readiness_lists_what_is_missing() {
        let mut r = Readiness {
            lines: [("a".to_owned(), true), ("b".to_owned(), false)].into(),
            modbus_tcp: true,
            zenoh: None,
            zenoh_name_conflict: None,
        };
        assert!(!r.is_ready());
        assert_eq!(r.issues()[0].path, "lines.b");
        r.lines.insert("b".into(), true);
        assert!(r.is_ready());
        r.zenoh = Some(false);
        assert_eq!(r.issues()[0].path, "zenoh");
        r.zenoh = Some(true);
        r.zenoh_name_conflict = Some("held by gateway \"g2\" on host cab7".into());
        assert_eq!(r.issues()[0].path, "zenoh.name");
        assert!(r.issues()[0].message.contains("cab7"));
    }
}
