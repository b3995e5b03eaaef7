//! The fleet: the gateways beside this one on the fabric, and what a gateway does when its name
//! (its key prefix) is already live.
//!
//! Every gateway holds the liveliness token `<prefix>` while its bridge publishes (see
//! [`super::keys`]). Two gateways under the same prefix would answer each other's queries and
//! take each other's writes, so a gateway that finds the token of its own prefix live when its
//! session opens does not take the name: it keeps serving its lines, Modbus TCP and REST, keeps
//! its zenoh publications, queryables and subscribers off, reports who holds the name (an ERROR
//! log line, `/readyz` not ready with the reason, a problem on the page, the metric
//! `gateway_zenoh_name_conflict` at 1) and asks again every [`NAME_RETRY`]; once the token is
//! gone it takes the name and starts publishing ([`take_name`]). A token nobody answers for is
//! one a vanished gateway left behind until zenoh's lease expires (a crashed process's own
//! restart, a cut cable): for the first [`STALE_WAIT`] that is logged at INFO only.
//! `gateway run --exit-on-duplicate-name` refuses the start instead ([`refuse_duplicate`]).
//! Two gateways opened in the same instant can both miss each other: the check is made when
//! the session opens.
//!
//! The fleet a gateway sees are the gateway tokens under the parent of its prefix
//! ([`Keys::fleet_pattern`], `gw/*` for the default prefix), followed with a liveliness
//! subscriber (with history, so the ones live before this gateway are seen too). A new token is
//! described by its gateway's `<key>/status` answer; a token that goes marks the gateway
//! offline. Nothing a peer says is trusted to be small: the view holds at most
//! [`MEMBER_LIMIT`] gateways (a token beyond is left out and counted), a token key longer than
//! [`KEY_MAX`] bytes is left out, a gateway offline for longer than [`OFFLINE_KEEP`] is dropped,
//! a status answer over [`STATUS_MAX`] bytes is not read, and every text taken from an answer is
//! escaped and cut ([`bounded_text`]: name [`NAME_MAX`], host [`HOST_MAX`], HTTP address
//! [`HTTP_MAX`] bytes; a zenoh id is 1 to 32 hex digits or nothing). A member's HTTP address is
//! offered as a link only when it is a plain `http(s)://host:port` URL ([`plain_http_url`]).
//!
//! Where the fabric authenticates (mutual TLS), zenoh does not tell a subscriber which
//! certificate declared a token or sent a reply (a liveliness sample carries no source, and a
//! session knows the certificate only of the link to its own router): the rule "only the
//! certificate named `<name>` holds `gw/<name>`" is enforced at the router by its
//! `access_control` (subjects by `cert_common_names`, docs/fleet.md), before a token reaches any
//! gateway.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, SystemTime};

use serde::Serialize;
use serde_json::Value;
use tokio_util::sync::CancellationToken;
use zenoh::sample::SampleKind;
use zenoh::Session;

use super::keys::Keys;
use super::metrics::BridgeStats;
use super::BridgeError;

/// How long a status or liveliness query waits for its replies.
pub const QUERY_TIMEOUT: Duration = Duration::from_secs(2);
/// How long a token nobody answers for is taken for one a vanished gateway left behind
/// (zenoh's default lease is 10 s): logged at INFO only, then reported as a conflict.
pub const STALE_WAIT: Duration = Duration::from_secs(12);
/// How often the token is asked for again while waiting for a stale token to go
/// (`--exit-on-duplicate-name`).
const STALE_POLL: Duration = Duration::from_millis(500);
/// How often a gateway whose name is held asks again whether it is free.
pub const NAME_RETRY: Duration = Duration::from_secs(2);
/// The most gateways kept in the view (the oldest offline one goes first when full; with none
/// offline a new token is left out and counted). A plant of forty gateways is far below it.
pub const MEMBER_LIMIT: usize = 256;
/// How long a gateway that went stays listed as offline.
pub const OFFLINE_KEEP: Duration = Duration::from_secs(600);
/// The longest token key kept (bytes): `gw/<name>` with a name of the configuration's 64
/// characters is 67.
pub const KEY_MAX: usize = 128;
/// The longest name kept from a status answer (bytes, after escaping), as a configured name.
pub const NAME_MAX: usize = 64;
/// The longest host name kept (bytes, after escaping), as DNS allows.
pub const HOST_MAX: usize = 253;
/// The longest HTTP address kept (bytes, after escaping).
pub const HTTP_MAX: usize = 256;
/// The longest zenoh id kept (hex digits of 16 bytes).
pub const ZID_MAX: usize = 32;
/// The largest status answer read (bytes); a larger one is not parsed. A gateway of 32 lines
/// with 8 devices each answers about 60 KiB.
pub const STATUS_MAX: usize = 256 * 1024;
/// Status queries of the fleet in flight at once.
const DESCRIBE_AT_ONCE: usize = 8;
/// How often a gateway whose answer lacked its name or HTTP address (its HTTP listener binds
/// after its zenoh session opens) is asked again, and how many times.
const DESCRIBE_AGAIN: Duration = Duration::from_secs(2);
const DESCRIBE_TRIES: u8 = 10;

/// One other gateway of the fleet. Every text is bounded and escaped ([`bounded_text`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FleetMember {
    /// Its key prefix (the key of its liveliness token, at most [`KEY_MAX`] bytes).
    pub key: String,
    /// Its name, from its status answer.
    pub name: Option<String>,
    /// Its zenoh id, from its status answer (hex).
    pub zid: Option<String>,
    /// The host it runs on, from its status answer.
    pub host: Option<String>,
    /// Its HTTP listener as it gave it (`http://host:port`), if it serves HTTP: text, which
    /// [`plain_http_url`] says whether to offer as a link.
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
    /// Tokens left out since the start: the view was full of online gateways, or the key was
    /// longer than [`KEY_MAX`].
    left_out: AtomicU64,
}

// === impl FleetView ===

impl FleetView {
    /// Every gateway seen, by key (at most [`MEMBER_LIMIT`]; those offline for longer than
    /// [`OFFLINE_KEEP`] are dropped).
    pub fn members(&self) -> Vec<FleetMember> {
        let mut members = self.lock();
        prune(&mut members, SystemTime::now());
        members.values().cloned().collect()
    }

    /// Tokens left out since the start (view full, or a key too long).
    pub fn left_out(&self) -> u64 {
        self.left_out.load(Ordering::Relaxed)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, BTreeMap<String, FleetMember>> {
        self.members.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The token `key` is live (`true`) or went. Whether the view keeps it (a token beyond
    /// [`MEMBER_LIMIT`] online gateways, or with a key over [`KEY_MAX`] bytes, is left out).
    pub(crate) fn token(&self, key: &str, online: bool) -> bool {
        self.token_at(key, online, SystemTime::now())
    }

    fn token_at(&self, key: &str, online: bool, now: SystemTime) -> bool {
        let mut members = self.lock();
        if key.len() > KEY_MAX {
            if online {
                self.left_out.fetch_add(1, Ordering::Relaxed);
            }
            return false;
        }
        prune(&mut members, now);
        if !members.contains_key(key) {
            if !online {
                return false;
            }
            if members.len() >= MEMBER_LIMIT {
                let oldest = members
                    .values()
                    .filter(|m| !m.online)
                    .min_by_key(|m| m.since)
                    .map(|m| m.key.clone());
                match oldest {
                    Some(k) => {
                        members.remove(&k);
                    }
                    None => {
                        self.left_out.fetch_add(1, Ordering::Relaxed);
                        return false;
                    }
                }
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
                since: now,
                asked: 0,
            });
        if member.online != online {
            member.online = online;
            member.since = now;
        }
        if online {
            member.asked = 1;
        }
        true
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

    /// What the gateway `key` answered on `<key>/status`, each text bounded and escaped.
    pub(crate) fn describe(&self, key: &str, status: &Value) {
        if let Some(m) = self.lock().get_mut(key) {
            let text = |pointer: &str, max: usize| {
                status
                    .pointer(pointer)
                    .and_then(Value::as_str)
                    .map(|t| bounded_text(t, max))
            };
            m.name = text("/name", NAME_MAX).or(m.name.take());
            m.zid = zid_of(status).or(m.zid.take());
            m.host = text("/host", HOST_MAX).or(m.host.take());
            m.http = text("/http", HTTP_MAX).or(m.http.take());
        }
    }
}

/// Drops the gateways offline for longer than [`OFFLINE_KEEP`].
fn prune(members: &mut BTreeMap<String, FleetMember>, now: SystemTime) {
    members
        .retain(|_, m| m.online || now.duration_since(m.since).unwrap_or_default() <= OFFLINE_KEEP);
}

/// `text` as it may be stored, logged and shown: every control character and every character
/// that changes the direction or visibility of text (U+200B..U+200F, U+202A..U+202E,
/// U+2066..U+2069, U+FEFF) written as an escape (`\u{1b}`), cut to at most `max` bytes at a
/// character boundary and then marked with `…` (so at most `max` + 3 bytes).
pub fn bounded_text(text: &str, max: usize) -> String {
    let mut out = String::with_capacity(text.len().min(max) + 3);
    for c in text.chars() {
        let hidden = c.is_control()
            || matches!(c, '\u{200B}'..='\u{200F}' | '\u{202A}'..='\u{202E}' | '\u{2066}'..='\u{2069}' | '\u{FEFF}');
        let piece: std::borrow::Cow<'_, str> = if hidden {
            format!("\\u{{{:x}}}", u32::from(c)).into()
        } else {
            c.encode_utf8(&mut [0; 4]).to_owned().into()
        };
        if out.len() + piece.len() > max {
            out.push('…');
            return out;
        }
        out.push_str(&piece);
    }
    out
}

/// The zenoh id of a status answer, when it is 1 to [`ZID_MAX`] hex digits.
fn zid_of(status: &Value) -> Option<String> {
    status
        .pointer("/zenoh/zid")
        .and_then(Value::as_str)
        .filter(|z| !z.is_empty() && z.len() <= ZID_MAX && z.bytes().all(|b| b.is_ascii_hexdigit()))
        .map(str::to_owned)
}

/// Whether `url` is a plain `http://host:port` or `https://host:port` URL (an optional `/` at
/// the end): a DNS name or IPv4 address of letters, digits, `-` and `.`, or an IPv6 address in
/// brackets, and a port 1 to 65535; no user, path, query or fragment. Only such an address is
/// offered as a link.
pub fn plain_http_url(url: &str) -> bool {
    let Some(rest) = url
        .strip_prefix("http://")
        .or_else(|| url.strip_prefix("https://"))
    else {
        return false;
    };
    let rest = rest.strip_suffix('/').unwrap_or(rest);
    let Some((host, port)) = rest.rsplit_once(':') else {
        return false;
    };
    let port_ok = !port.is_empty()
        && port.len() <= 5
        && port.bytes().all(|b| b.is_ascii_digit())
        && port.parse::<u16>().is_ok_and(|p| p > 0);
    let host_ok = if let Some(inner) = host.strip_prefix('[').and_then(|h| h.strip_suffix(']')) {
        inner.parse::<std::net::Ipv6Addr>().is_ok()
    } else {
        !host.is_empty()
            && host.len() <= HOST_MAX
            && host
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'.')
            && !host.starts_with(['-', '.'])
    };
    port_ok && host_ok
}

/// Where the gateway that answered `status` runs, in words: "host H, pid P, zenoh id Z,
/// listening on E, HTTP U"; every text bounded and escaped ([`bounded_text`]), at most four
/// listen endpoints, so the whole is under 1.5 KiB.
pub fn describe_other(status: &Value) -> String {
    let mut parts = Vec::new();
    if let Some(h) = status.get("host").and_then(Value::as_str) {
        parts.push(format!("host {}", bounded_text(h, HOST_MAX)));
    }
    if let Some(p) = status.get("pid").and_then(Value::as_u64) {
        parts.push(format!("pid {p}"));
    }
    if let Some(z) = zid_of(status) {
        parts.push(format!("zenoh id {z}"));
    }
    if let Some(l) = status
        .pointer("/zenoh/listen")
        .and_then(Value::as_array)
        .filter(|l| !l.is_empty())
    {
        let mut l: Vec<String> = l
            .iter()
            .filter_map(Value::as_str)
            .take(4)
            .map(|e| bounded_text(e, 128))
            .collect();
        if status
            .pointer("/zenoh/listen")
            .and_then(Value::as_array)
            .is_some_and(|a| a.len() > 4)
        {
            l.push("…".to_owned());
        }
        parts.push(format!("listening on {}", l.join(", ")));
    }
    if let Some(u) = status.get("http").and_then(Value::as_str) {
        parts.push(format!("HTTP {}", bounded_text(u, HTTP_MAX)));
    }
    if parts.is_empty() {
        "a gateway that does not say where it runs".to_owned()
    } else {
        parts.join(", ")
    }
}

/// Who holds a name, in words: `gateway "NAME" on host ...` ([`describe_other`]), bounded.
pub fn holder(status: &Value) -> String {
    format!(
        "gateway \"{}\" on {}",
        status
            .get("name")
            .and_then(Value::as_str)
            .map_or_else(|| "?".to_owned(), |n| bounded_text(n, NAME_MAX)),
        describe_other(status)
    )
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

/// The first JSON reply to a get on `key` of at most [`STATUS_MAX`] bytes, if any within
/// [`QUERY_TIMEOUT`].
pub(crate) async fn first_json(session: &Session, key: &str) -> Option<Value> {
    let replies = session.get(key).timeout(QUERY_TIMEOUT).await.ok()?;
    while let Ok(reply) = replies.recv_async().await {
        if let Ok(sample) = reply.result() {
            if sample.payload().len() > STATUS_MAX {
                continue;
            }
            if let Ok(v) = serde_json::from_slice(&sample.payload().to_bytes()) {
                return Some(v);
            }
        }
    }
    None
}

/// `--exit-on-duplicate-name`: refuses the start when the token of this gateway's prefix is
/// already live (see the module docs): `Err(BridgeError::Duplicate)` naming the other gateway.
/// A token nobody answers for is waited for up to [`STALE_WAIT`].
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
                other: holder(&status),
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

/// Waits until no other session holds this gateway's token, reporting the conflict meanwhile
/// (see the module docs): `true` once the name is free (the caller then declares and
/// publishes), `false` on shutdown. The conflict is kept in `stats`
/// ([`BridgeStats::name_conflict`]) for `/readyz`, the page and the metric; an ERROR line is
/// written when it starts and whenever the holder changes (rate-limited), an INFO line when the
/// name is taken.
pub(crate) async fn take_name(
    session: &Session,
    keys: &Keys,
    gateway_name: &str,
    stats: &BridgeStats,
    shutdown: &CancellationToken,
) -> bool {
    let token = keys.gateway_token();
    let started = tokio::time::Instant::now();
    let mut reported: Option<String> = None;
    loop {
        let live = tokio::select! {
            () = shutdown.cancelled() => return false,
            live = token_live(session, &token) => live,
        };
        match live {
            Ok(false) => {
                if reported.is_some() || stats.name_conflict().is_some() {
                    tracing::info!(%token, "zenoh: the gateway name is free now: this gateway takes it and publishes");
                }
                stats.set_name_conflict(None);
                return true;
            }
            Ok(true) => {
                let status_key = keys.gateway_status();
                let status = tokio::select! {
                    () = shutdown.cancelled() => return false,
                    s = first_json(session, &status_key) => s,
                };
                let other = match status {
                    Some(status) => Some(holder(&status)),
                    None if started.elapsed() < STALE_WAIT => {
                        tracing::info!(%token, "the gateway token is live but nobody answers for it: waiting for zenoh's lease to end it");
                        None
                    }
                    None => Some(format!(
                        "a session that holds the token but answered no status query for {STALE_WAIT:?}"
                    )),
                };
                let text = other.map(|other| {
                    BridgeError::Duplicate {
                        name: bounded_text(gateway_name, NAME_MAX),
                        key: token.clone(),
                        other,
                    }
                    .to_string()
                });
                match text {
                    Some(text) if reported.as_deref() != Some(text.as_str()) => {
                        crate::error_limited!("zenoh gateway name held", conflict = %text, "zenoh: the gateway name is held by another session: this gateway serves its lines, Modbus TCP and REST, publishes nothing on zenoh, and takes the name when it is free");
                        stats.set_name_conflict(Some(text.clone()));
                        reported = Some(text);
                    }
                    Some(_) => {}
                    None => stats.set_name_conflict(Some(format!(
                        "the token {token} of this gateway's name is live but nobody answers for it yet (a gateway gone, until zenoh's lease ends it): waiting up to {STALE_WAIT:?}"
                    ))),
                }
            }
            Err(e) => {
                tracing::debug!(%token, error = %e, "liveliness query failed; asking again");
            }
        }
        tokio::select! {
            () = shutdown.cancelled() => return false,
            () = tokio::time::sleep(NAME_RETRY) => {}
        }
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
    // At most DESCRIBE_AT_ONCE status queries in flight; the rest wait their turn (one task
    // per kept member at most, so at most MEMBER_LIMIT waiting).
    let permits = Arc::new(tokio::sync::Semaphore::new(DESCRIBE_AT_ONCE));
    let describe = |key: String| {
        let (session, view, permits) = (session.clone(), view.clone(), permits.clone());
        crate::task::spawn("zenoh fleet describe", async move {
            let Ok(_permit) = permits.acquire().await else {
                return;
            };
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
        let key = sample.key_expr().as_str();
        if key == own {
            continue;
        }
        let online = sample.kind() == SampleKind::Put;
        if view.token(key, online) {
            if online {
                describe(key.to_owned());
            }
        } else if online {
            crate::warn_limited!("zenoh fleet view full", left_out = view.left_out(), limit = MEMBER_LIMIT, key_max = KEY_MAX, "zenoh: a gateway token was left out of the fleet view (the view is full of online gateways, or its key is too long)");
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

    #[test]
    fn texts_from_peers_are_escaped_and_cut() {
        assert_eq!(bounded_text("cab7", HOST_MAX), "cab7");
        assert_eq!(bounded_text("a\u{1b}[31mb\n", 64), "a\\u{1b}[31mb\\u{a}");
        assert_eq!(bounded_text("x\u{202e}y", 64), "x\\u{202e}y");
        let long = "A".repeat(28 * 1024);
        let cut = bounded_text(&long, NAME_MAX);
        assert_eq!(cut.len(), NAME_MAX + '…'.len_utf8());
        assert!(cut.ends_with('…'));
        // Cut at a character boundary, never inside one.
        let cut = bounded_text(&"é".repeat(100), 5);
        assert_eq!(cut, "éé…");
    }

    #[test]
    fn only_a_plain_http_address_is_a_link() {
        for good in [
            "http://10.1.1.2:8080",
            "http://10.1.1.2:8080/",
            "https://gw1.plant.local:8443",
            "http://[::1]:8080",
        ] {
            assert!(plain_http_url(good), "{good}");
        }
        for bad in [
            "http://evil.example/phish",
            "javascript:alert(1)",
            "http://user@host:80",
            "http://host:80/x",
            "http://host:80?x",
            "http://host",
            "http://host:0",
            "http://host:65536",
            "http://-host:80",
            "http://ho st:80",
            "ftp://host:21",
            "http://[nothex]:80",
        ] {
            assert!(!plain_http_url(bad), "{bad}");
        }
    }

    #[test]
    fn a_flood_of_tokens_is_bounded_and_those_gone_are_dropped() {
        let view = FleetView::default();
        let t0 = SystemTime::UNIX_EPOCH + Duration::from_secs(1_000_000);
        for i in 0..1000 {
            view.token_at(&format!("gw/rogue{i}"), true, t0);
        }
        assert_eq!(view.lock().len(), MEMBER_LIMIT);
        assert_eq!(view.left_out(), (1000 - MEMBER_LIMIT) as u64);
        // A key longer than KEY_MAX is never kept.
        assert!(!view.token_at(&format!("gw/{}", "k".repeat(KEY_MAX)), true, t0));
        // Every field of a 28 KiB answer is cut.
        let fill = "A".repeat(28 * 1024);
        view.describe(
            "gw/rogue0",
            &json!({"name": fill, "host": fill, "http": format!("http://x/{fill}"),
                    "zenoh": {"zid": fill}}),
        );
        let m = view.lock().get("gw/rogue0").cloned().expect("kept");
        assert!(m.name.as_ref().is_some_and(|n| n.len() <= NAME_MAX + 3));
        assert!(m.host.as_ref().is_some_and(|h| h.len() <= HOST_MAX + 3));
        assert!(m.http.as_ref().is_some_and(|h| h.len() <= HTTP_MAX + 3));
        assert_eq!(m.zid, None, "not a zenoh id");
        // One goes: a new token takes its place; gone longer than OFFLINE_KEEP it is dropped.
        view.token_at("gw/rogue1", false, t0);
        assert!(view.token_at("gw/real", true, t0));
        assert!(!view.lock().contains_key("gw/rogue1"));
        view.token_at("gw/rogue2", false, t0);
        view.token_at("gw/real", true, t0 + OFFLINE_KEEP + Duration::from_secs(1));
        assert!(
            !view.lock().contains_key("gw/rogue2"),
            "dropped after OFFLINE_KEEP"
        );
        assert_eq!(view.lock().len(), MEMBER_LIMIT - 1);
    }

    #[test]
    fn the_holder_of_a_name_is_described_within_bounds() {
        let fill = "\u{1b}".repeat(10_000);
        let text = holder(&json!({
            "name": fill, "host": fill, "http": fill, "pid": 7,
            "zenoh": {"zid": "abcd", "listen": vec![fill.clone(); 100]}
        }));
        assert!(text.len() < 1536, "{} bytes", text.len());
        assert!(!text.chars().any(char::is_control), "{text}");
        assert!(
            text.contains("pid 7") && text.contains("zenoh id abcd"),
            "{text}"
        );
    }
}
