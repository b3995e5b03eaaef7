//! `GET /fleet`: the other gateways this one sees on the zenoh fabric.

use serde::Serialize;
use utoipa::ToSchema;

use super::Timestamp;

/// Another gateway of the fleet (a liveliness token under the parent of this gateway's key
/// prefix, `gw/*` by default), described by its own `<prefix>/status` answer. Every text a
/// peer gave is escaped and cut (key 128, name 64, zid 32, host 253, http 256 bytes, plus `…`
/// when cut), so one entry is under 1 KiB of JSON and the whole answer (at most 256 gateways)
/// under 256 KiB.
#[derive(Debug, Clone, PartialEq, Serialize, ToSchema)]
pub struct FleetEntry {
    /// Its key prefix on zenoh (`gw/<name>`).
    pub key: String,
    /// Its name, once it answered its status.
    pub name: Option<String>,
    /// Its zenoh id.
    pub zid: Option<String>,
    /// The host it runs on.
    pub host: Option<String>,
    /// Whether its liveliness token is live now.
    pub online: bool,
    /// When it came online or went offline last.
    pub since: Timestamp,
    /// Its HTTP address as it gave it (text; may be anything a peer sends, bounded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub http: Option<String>,
    /// Its status page (`http://host:port/`): only when its HTTP address is a plain
    /// `http(s)://host:port` URL, else absent (the page then shows `http` as text).
    pub link: Option<String>,
}

/// The answer of `GET /fleet`: empty when zenoh is off or no other gateway was seen.
#[derive(Debug, Clone, PartialEq, Serialize, ToSchema)]
pub struct Fleet {
    /// The other gateways, by key.
    pub gateways: Vec<FleetEntry>,
}
