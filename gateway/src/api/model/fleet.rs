//! `GET /fleet`: the other gateways this one sees on the zenoh fabric.

use serde::Serialize;
use utoipa::ToSchema;

use super::Timestamp;

/// Another gateway of the fleet (a liveliness token under the parent of this gateway's key
/// prefix, `gw/*` by default), described by its own `<prefix>/status` answer.
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
    /// Its status page (`http://host:port/`), when it serves HTTP.
    pub link: Option<String>,
}

/// The answer of `GET /fleet`: empty when zenoh is off or no other gateway was seen.
#[derive(Debug, Clone, PartialEq, Serialize, ToSchema)]
pub struct Fleet {
    /// The other gateways, by key.
    pub gateways: Vec<FleetEntry>,
}
