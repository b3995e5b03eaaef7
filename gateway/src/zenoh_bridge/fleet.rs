//! The fleet: the gateways beside this one on the fabric, and the refusal of a second gateway
//! under a name (a key prefix) that is already live.
//!
//! Every gateway holds the liveliness token `<prefix>` while its bridge runs (see [`super::keys`]).
//! Two gateways under the same prefix would answer each other's queries and take each other's
//! writes, so a gateway that finds the token of its own prefix live when its session opens does
//! not join: it asks `<prefix>/status` who holds it (name, host, zenoh id, HTTP address) and
//! refuses to start with that in the message. A token nobody answers for is one a vanished
//! gateway left behind until zenoh's lease expires (a crashed process's own restart, a cut
//! cable): the gateway waits up to [`STALE_WAIT`] for it to go before it refuses. Two gateways
//! opened in the same instant can both miss each other: the check is made once, at start.
//!
//! The fleet a gateway sees are the gateway tokens under the parent of its prefix
//! ([`Keys::fleet_pattern`], `gw/*` for the default prefix), followed with a liveliness
//! subscriber (with history, so the ones live before this gateway are seen too). A new token is
//! described by its gateway's `<key>/status` answer; a token that goes marks the gateway
//! offline, and it stays listed as such.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, SystemTime};

use serde::Serialize;
use serde_json::Value;
use tokio_util::sync::CancellationToken;
use zenoh::sample::SampleKind;
use zenoh::Session;

use super::keys::Keys;
use super::BridgeError;

/// How long a status or liveliness query waits for its replies.
pub const QUERY_TIMEOUT: Duration = Duration::from_secs(2);
/// How long a start waits for a token nobody answers for to go (zenoh's default lease is 10 s).
pub const STALE_WAIT: Duration = Duration::from_secs(12);
/// How often the token is asked for again while waiting.
const STALE_POLL: Duration = Duration::from_millis(500);
/// The most gateways kept in the view (the oldest offline one goes first when full).
const MEMBER_LIMIT: usize = 4096;
/// How often a gateway whose answer lacked its name or HTTP address (its HTTP listener binds
/// after its zenoh session opens) is asked again, and how many times.
const DESCRIBE_AGAIN: Duration = Duration::from_secs(2);
const DESCRIBE_TRIES: u8 = 10;

/// One other gateway of the fleet.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FleetMember {
    /// Its key prefix (the key of its liveliness token).
    pub key: String,
    /// Its name, from its status answer.
    pub name: Option<String>,
    /// Its zenoh id, from its status answer.
    pub zid: Option<String>,
    /// The host it runs on, from its status answer.
    pub host: Option<String>,
    /// Its HTTP listener (`http://host:port`), if it serves HTTP.
    pub http: Option<String>,
    /// Whether its token is live.
    pub online: bool,
    /// When its token came or went last.
    #[serde(serialize_with = "rfc3339")]
    pub since: SystemTime,
    /// Status queries made since its token came.
    #[serde(skip)]
    asked: u8,
}

fn rfc3339<S: serde::Serializer>(t: &SystemTime, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(&super::publish::rfc3339(*t))
}

/// The gateways seen so far, by key.
#[derive(Debug, Default)]
pub struct FleetView {
    members: Mutex<BTreeMap<String, FleetMember>>,
}

// === impl FleetView ===

impl FleetView {
    /// Every gateway seen, by key.
    pub fn members(&self) -> Vec<FleetMember> {
        self.lock().values().cloned().collect()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, BTreeMap<String, FleetMember>> {
        self.members.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The token `key` is live (`true`) or went.
    pub(crate) fn token(&self, key: &str, online: bool) {
        let mut members = self.lock();
        if !members.contains_key(key) && members.len() >= MEMBER_LIMIT {
            let oldest = members
                .values()
                .filter(|m| !m.online)
                .min_by_key(|m| m.since)
                .map(|m| m.key.clone());
            match oldest {
                Some(k) => {
                    members.remove(&k);
                }
                None => return,
            }
        }
        let member = members
            .entry(key.to_owned())
            .or_insert_with(|| FleetMember {
                key: key.to_owned(),
                name: None,
                zid: None,
                host: None,
                http: None,
                online,
                since: SystemTime::now(),
                asked: 0,
            });
        if member.online != online {
            member.online = online;
            member.since = SystemTime::now();
        }
        if online {
            member.asked = 1;
        }
    }

    /// The online gateways to ask again: their answer lacked the name or HTTP address, and
    /// they were asked fewer than [`DESCRIBE_TRIES`] times.
    fn to_ask_again(&self) -> Vec<String> {
        let mut members = self.lock();
        members
            .values_mut()
            .filter(|m| m.online && (m.name.is_none() || m.http.is_none()))
            .filter(|m| m.asked < DESCRIBE_TRIES)
            .map(|m| {
                m.asked += 1;
                m.key.clone()
            })
            .collect()
    }

    /// What the gateway `key` answered on `<key>/status`.
    pub(crate) fn describe(&self, key: &str, status: &Value) {
        if let Some(m) = self.lock().get_mut(key) {
            let text = |v: &Value| v.as_str().map(str::to_owned);
            m.name = status.get("name").and_then(text).or(m.name.take());
            m.zid = status.pointer("/zenoh/zid").and_then(text).or(m.zid.take());
            m.host = status.get("host").and_then(text).or(m.host.take());
            m.http = status.get("http").and_then(text).or(m.http.take());
        }
    }
}

/// Where the gateway that answered `status` runs, in words: "host H, zenoh id Z, HTTP U".
pub fn describe_other(status: &Value) -> String {
    let mut parts = Vec::new();
    if let Some(h) = status.get("host").and_then(Value::as_str) {
        parts.push(format!("host {h}"));
    }
    if let Some(p) = status.get("pid").and_then(Value::as_u64) {
        parts.push(format!("pid {p}"));
    }
    if let Some(z) = status.pointer("/zenoh/zid").and_then(Value::as_str) {
        parts.push(format!("zenoh id {z}"));
    }
    if let Some(l) = status
        .pointer("/zenoh/listen")
        .and_then(Value::as_array)
        .filter(|l| !l.is_empty())
    {
        let l: Vec<&str> = l.iter().filter_map(Value::as_str).collect();
        parts.push(format!("listening on {}", l.join(", ")));
    }
    if let Some(u) = status.get("http").and_then(Value::as_str) {
        parts.push(format!("HTTP {u}"));
    }
    if parts.is_empty() {
        "a gateway that does not say where it runs".to_owned()
    } else {
        parts.join(", ")
    }
}

/// Whether a liveliness token matching `key` is live on the fabric.
pub(crate) async fn token_live(session: &Session, key: &str) -> zenoh::Result<bool> {
    let replies = session.liveliness().get(key).timeout(QUERY_TIMEOUT).await?;
    while let Ok(reply) = replies.recv_async().await {
        if reply.result().is_ok() {
            return Ok(true);
        }
    }
    Ok(false)
}

/// The first JSON reply to a get on `key`, if any within [`QUERY_TIMEOUT`].
pub(crate) async fn first_json(session: &Session, key: &str) -> Option<Value> {
    let replies = session.get(key).timeout(QUERY_TIMEOUT).await.ok()?;
    while let Ok(reply) = replies.recv_async().await {
        if let Ok(sample) = reply.result() {
            if let Ok(v) = serde_json::from_slice(&sample.payload().to_bytes()) {
                return Some(v);
            }
        }
    }
    None
}

/// Refuses the start when the token of this gateway's prefix is already live (see the module
/// docs): `Err(BridgeError::Duplicate)` naming the other gateway.
pub(crate) async fn refuse_duplicate(
    session: &Session,
    keys: &Keys,
    gateway_name: &str,
) -> Result<(), BridgeError> {
    let token = keys.gateway_token();
    let deadline = tokio::time::Instant::now() + STALE_WAIT;
    loop {
        let live = token_live(session, &token)
            .await
            .map_err(|e| BridgeError::Open(format!("liveliness query on {token}: {e}")))?;
        if !live {
            return Ok(());
        }
        if let Some(status) = first_json(session, &keys.gateway_status()).await {
            return Err(BridgeError::Duplicate {
                name: gateway_name.to_owned(),
                key: token,
                other: format!(
                    "gateway {:?} on {}",
                    status.get("name").and_then(Value::as_str).unwrap_or("?"),
                    describe_other(&status)
                ),
            });
        }
        if tokio::time::Instant::now() >= deadline {
            return Err(BridgeError::Duplicate {
                name: gateway_name.to_owned(),
                key: token,
                other: format!(
                    "a gateway that holds the token but answered no status query for {STALE_WAIT:?}"
                ),
            });
        }
        tracing::info!(%token, "the gateway token is live but nobody answers for it: waiting for zenoh's lease to end it");
        tokio::time::sleep(STALE_POLL).await;
    }
}

/// Follows the gateway tokens of the fleet into `view` until shutdown (see the module docs).
pub(crate) async fn follow(
    session: Session,
    keys: Arc<Keys>,
    view: Arc<FleetView>,
    shutdown: CancellationToken,
) {
    let own = keys.gateway_token();
    let pattern = keys.fleet_pattern();
    let subscriber = match session
        .liveliness()
        .declare_subscriber(&pattern)
        .history(true)
        .await
    {
        Ok(s) => s,
        Err(e) => {
            crate::warn_limited!("zenoh fleet subscriber", %pattern, error = %e, "the fleet's gateways are not followed");
            return;
        }
    };
    let describe = |key: String| {
        let (session, view) = (session.clone(), view.clone());
        tokio::spawn(async move {
            if let Some(status) = first_json(&session, &format!("{key}/status")).await {
                view.describe(&key, &status);
            }
        });
    };
    let mut again = tokio::time::interval(DESCRIBE_AGAIN);
    loop {
        let sample = tokio::select! {
            () = shutdown.cancelled() => break,
            _ = again.tick() => {
                view.to_ask_again().into_iter().for_each(&describe);
                continue;
            }
            s = subscriber.recv_async() => match s { Ok(s) => s, Err(_) => break },
        };
        let key = sample.key_expr().as_str().to_owned();
        if key == own {
            continue;
        }
        let online = sample.kind() == SampleKind::Put;
        view.token(&key, online);
        if online {
            describe(key);
        }
    }
    drop(subscriber);
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn a_gateway_seen_is_described_and_stays_listed_offline() {
        let view = FleetView::default();
        view.token("gw/a", true);
        view.describe(
            "gw/a",
            &json!({"name": "a", "host": "h1", "http": "http://10.0.0.1:8080",
                    "zenoh": {"zid": "abc"}}),
        );
        // A status of a gateway never seen adds nothing.
        view.describe("gw/b", &json!({"name": "b"}));
        let m = view.members();
        assert_eq!(m.len(), 1);
        assert_eq!(m[0].name.as_deref(), Some("a"));
        assert_eq!(m[0].zid.as_deref(), Some("abc"));
        assert_eq!(m[0].http.as_deref(), Some("http://10.0.0.1:8080"));
        assert!(m[0].online);
        view.token("gw/a", false);
        assert!(view.to_ask_again().is_empty(), "described in full");
        view.token("gw/c", true);
        for _ in 1..DESCRIBE_TRIES {
            assert_eq!(view.to_ask_again(), ["gw/c"]);
        }
        assert!(
            view.to_ask_again().is_empty(),
            "asked {DESCRIBE_TRIES} times"
        );
        let m = view.members();
        assert!(!m[0].online);
        assert_eq!(m[0].host.as_deref(), Some("h1"));
    }

    #[test]
    fn the_other_gateway_is_named_with_where_it_runs() {
        let text = describe_other(&json!({
            "host": "cab7", "pid": 42, "http": "http://cab7:8080",
            "zenoh": {"zid": "f00d", "listen": ["tcp/0.0.0.0:7447"]}
        }));
        assert_eq!(
            text,
            "host cab7, pid 42, zenoh id f00d, listening on tcp/0.0.0.0:7447, HTTP http://cab7:8080"
        );
        assert_eq!(
            describe_other(&json!({})),
            "a gateway that does not say where it runs"
        );
    }
}
