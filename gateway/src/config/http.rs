//! The `[http]` section: where the REST API listens, where its token comes from, its limits.
//!
//! ```toml
//! [http]
//! listen = "127.0.0.1:8080"
//! token_file = "/etc/gateway/api-token"     # or: token_env = "GATEWAY_API_TOKEN"
//! insecure_allow_unauthenticated_changes = false
//! body_limit = 1048576                      # bytes
//! request_timeout = "30s"
//! max_connections = 64
//! max_connections_per_client = 8            # one address never takes every place
//! max_streams = 8                           # SSE follows and timed captures open at once
//! write_timeout = "10s"                     # an answer the client does not read is closed
//! header_read_timeout = "10s"               # a request head (or the next one) must arrive
//! monitoring_networks = ["10.0.9.0/24"]     # their clients have places held back for /metrics,
//!                                           # /healthz and /readyz that nobody else can take
//! hosts = ["gw1.plant.local"]               # names a request's Host may carry (besides the
//!                                           # listener's own: an IP address, localhost on
//!                                           # loopback, the gateway's name)
//! tag_metrics = true                        # process values on /metrics (default false)
//! tag_metrics_filter = ["drive/**"]         # only these <line>/<device>/<tag> (default: all)
//!
//! [http.tls]                                # HTTPS instead of HTTP on `listen`
//! cert = "/etc/gateway/tls/http.crt"
//! key = "/etc/gateway/tls/http.key"
//! ca = "/etc/gateway/tls/http-clients-ca.crt" # optional: client certificates required
//!
//! [http.tokens.ops]                         # named tokens, each with a role
//! role = "operator"
//! token_env = "GATEWAY_TOKEN_OPS"           # or: token_file = "/etc/gateway/ops.token"
//! ```
//!
//! Changes (PUT, POST, DELETE) need `Authorization: Bearer <token>`. A token itself never
//! appears in the configuration: only the file that holds it or the environment variable that
//! holds it. The token of `token_file` / `token_env` has the `admin` role (every change); each
//! `[http.tokens.<name>]` has the role it names ([`RestRole`]). With no token at all, changes
//! are refused (403) unless `insecure_allow_unauthenticated_changes` is set, which the log then
//! says at start.

use std::collections::BTreeMap;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::PathBuf;
use std::time::Duration;

use ipnet::IpNet;
use serde::{Deserialize, Deserializer, Serialize};

use super::reader::{check_name, parsed_value, string_value, Cx, Fields};

/// Local only by default: exposing the API is a decision (the demo serves 127.0.0.1:8080).
pub const DEFAULT_HTTP_LISTEN: SocketAddr = SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 8080);
/// Largest request body by default: a configuration with many devices and tags fits.
pub const DEFAULT_BODY_LIMIT: u64 = 1024 * 1024;
/// Accepted range of `body_limit` in bytes.
pub const BODY_LIMIT_RANGE: (u64, u64) = (1024, 64 * 1024 * 1024);
/// Longest time a request may take by default (a tag write waits for the device: the Modbus
/// master's reply monitoring time, 2 s by default, times its retries).
pub const DEFAULT_HTTP_REQUEST_TIMEOUT: Duration = Duration::from_secs(30);
/// Accepted range of `request_timeout`.
pub const HTTP_REQUEST_TIMEOUT_RANGE: (Duration, Duration) =
    (Duration::from_millis(100), Duration::from_secs(600));
/// HTTP connections served at once by default.
pub const DEFAULT_HTTP_MAX_CONNECTIONS: u32 = 64;
/// Accepted range of `max_connections`.
pub const HTTP_MAX_CONNECTIONS_RANGE: (u32, u32) = (1, 4096);
/// Connections from one client address by default (the Modbus TCP key of the same name keeps its
/// own default): a host that opens more cannot take the other clients' places.
pub const DEFAULT_HTTP_MAX_CONNECTIONS_PER_CLIENT: u32 = 8;
/// Long-lived answers (SSE follows, timed captures) open at once by default.
pub const DEFAULT_HTTP_MAX_STREAMS: u32 = 8;
/// Accepted range of `max_streams`.
pub const HTTP_MAX_STREAMS_RANGE: (u32, u32) = (1, 1024);
/// An answer whose bytes the client does not take for this long is closed, by default.
pub const DEFAULT_HTTP_WRITE_TIMEOUT: Duration = Duration::from_secs(10);
/// Longest wait for a request head (and for the next one on a kept-alive connection) by default.
pub const DEFAULT_HTTP_HEADER_READ_TIMEOUT: Duration = Duration::from_secs(10);
/// Accepted range of `write_timeout` and `header_read_timeout`.
pub const HTTP_IO_TIMEOUT_RANGE: (Duration, Duration) =
    (Duration::from_millis(100), Duration::from_secs(600));
/// Changes are refused without a token unless this is set.
pub const DEFAULT_INSECURE: bool = false;
/// Most entries of `hosts` and `monitoring_networks`: an operator's list, kept short.
pub const HTTP_LIST_MAX: usize = 64;
/// Longest name in `hosts`: a DNS name is at most 253 characters (RFC 1035 2.3.4).
pub const HTTP_HOST_NAME_MAX: usize = 253;
/// Process values are not on `/metrics` unless asked for: 10 000 tags are about 1.3 MB a scrape.
pub const DEFAULT_TAG_METRICS: bool = false;

/// The `[http]` section.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct HttpConfig {
    pub listen: SocketAddr,
    /// A file holding the bearer token (surrounding whitespace ignored).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub token_file: Option<PathBuf>,
    /// The name of an environment variable holding the bearer token.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub token_env: Option<String>,
    /// Accept changes without a token when none is configured (for demos; logged at start).
    pub insecure_allow_unauthenticated_changes: bool,
    /// Largest request body in bytes; a larger one is answered 413.
    pub body_limit: u64,
    /// A request that takes longer is answered 504.
    #[serde(with = "humantime_serde")]
    pub request_timeout: Duration,
    /// Connections served at once; beyond them a connection is served only for `/metrics`,
    /// `/healthz` and `/readyz` (a few places held back for them), others are answered 503.
    pub max_connections: u32,
    /// Connections at once from one client address (beyond: as beyond `max_connections`).
    pub max_connections_per_client: u32,
    /// SSE follows and timed captures open at once; more are answered 503 with Retry-After.
    pub max_streams: u32,
    /// An answer the client does not read for this long is closed.
    #[serde(with = "humantime_serde")]
    pub write_timeout: Duration,
    /// Longest wait for a request head, and for the next one on a kept-alive connection.
    #[serde(with = "humantime_serde")]
    pub header_read_timeout: Duration,
    /// Client networks accepted (CIDR); empty: every client. Others are closed at accept.
    pub allowed_networks: Vec<IpNet>,
    /// Networks (CIDR) whose clients have places held back for `/metrics`, `/healthz` and
    /// `/readyz` that no other client can take (`api::places`); empty: none held back for them.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub monitoring_networks: Vec<IpNet>,
    /// Names a request's `Host` (and a change's `Origin`) may carry besides the listener's own
    /// (an IP address, `localhost` on a loopback connection, the gateway's name); lower case,
    /// without a port. Any other `Host` is refused (403), against DNS rebinding.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub hosts: Vec<String>,
    /// Export the good numeric and bool tags as `gateway_tag_value` on `/metrics`, and every
    /// tag's quality as `gateway_tag_quality` (docs/metrics.md).
    #[serde(skip_serializing_if = "is_false")]
    pub tag_metrics: bool,
    /// Key expressions over `<line>/<device>/<tag>` (as `[[zenoh.publish.tags]] key`): only the
    /// tags one of them includes are exported; empty: every tag.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub tag_metrics_filter: Vec<String>,
    /// Named tokens, each with a role (`[http.tokens.<name>]`).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub tokens: BTreeMap<String, TokenConfig>,
    /// HTTPS on `listen` (`[http.tls]`); `None`: plain HTTP.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tls: Option<HttpTlsConfig>,
}

/// The `[http.tls]` section: the listener speaks HTTPS (TLS 1.3 and 1.2) only.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct HttpTlsConfig {
    /// The server's certificate chain (PEM), its own certificate first.
    pub cert: PathBuf,
    /// The server's private key (PEM).
    pub key: PathBuf,
    /// When set, clients must show a certificate that chains to these CA certificates (PEM).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ca: Option<PathBuf>,
}

/// What a REST token may change. Reading (GET) needs no token.
///
/// The rights are named as the function classes of a Modbus/TCP Security role where they
/// mean the same (`write`, `diagnostics`), plus the two the REST API has beyond Modbus:
/// `send` (telegrams) and `config`:
///
/// | role | tag writes (`write`) | telegram send and acknowledge (`send`) | diagnostic buffer clear, DTR/RTS (`diagnostics`) | configuration (`config`) |
/// |---|---|---|---|---|
/// | `viewer` | no | no | no | no |
/// | `operator` | yes | yes | yes | no |
/// | `admin` | yes | yes | yes | yes |
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RestRole {
    Viewer,
    Operator,
    Admin,
}

/// One right a REST change needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RestRight {
    /// Tag writes.
    Write,
    /// Telegram sends and acknowledgements.
    Send,
    /// Clearing the diagnostic buffer, setting DTR / RTS.
    Diagnostics,
    /// Replacing, changing or validating the configuration.
    Config,
}

// === impl RestRole ===

impl RestRole {
    /// The TOML spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Viewer => "viewer",
            Self::Operator => "operator",
            Self::Admin => "admin",
        }
    }

    /// Whether the role has `right`.
    pub fn allows(self, right: RestRight) -> bool {
        match self {
            Self::Viewer => false,
            Self::Operator => right != RestRight::Config,
            Self::Admin => true,
        }
    }
}

// === impl RestRight ===

impl RestRight {
    /// The name used in answers and docs.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Write => "write",
            Self::Send => "send",
            Self::Diagnostics => "diagnostics",
            Self::Config => "config",
        }
    }
}

/// One `[http.tokens.<name>]`: a role and where its token comes from (a file or an
/// environment variable, exactly one).
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct TokenConfig {
    pub role: RestRole,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub token_file: Option<PathBuf>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub token_env: Option<String>,
}

impl Default for HttpConfig {
    fn default() -> Self {
        Self {
            listen: DEFAULT_HTTP_LISTEN,
            token_file: None,
            token_env: None,
            insecure_allow_unauthenticated_changes: DEFAULT_INSECURE,
            body_limit: DEFAULT_BODY_LIMIT,
            request_timeout: DEFAULT_HTTP_REQUEST_TIMEOUT,
            max_connections: DEFAULT_HTTP_MAX_CONNECTIONS,
            max_connections_per_client: DEFAULT_HTTP_MAX_CONNECTIONS_PER_CLIENT,
            max_streams: DEFAULT_HTTP_MAX_STREAMS,
            write_timeout: DEFAULT_HTTP_WRITE_TIMEOUT,
            header_read_timeout: DEFAULT_HTTP_HEADER_READ_TIMEOUT,
            allowed_networks: Vec::new(),
            monitoring_networks: Vec::new(),
            hosts: Vec::new(),
            tag_metrics: DEFAULT_TAG_METRICS,
            tag_metrics_filter: Vec::new(),
            tokens: BTreeMap::new(),
            tls: None,
        }
    }
}

fn is_false(b: &bool) -> bool {
    !*b
}

/// Where the token comes from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TokenSource {
    File(PathBuf),
    Env(String),
}

impl TokenSource {
    /// The file when one is set, else the variable.
    fn of(file: Option<&PathBuf>, env: Option<&String>) -> Option<Self> {
        file.map(|f| Self::File(f.clone()))
            .or_else(|| env.map(|e| Self::Env(e.clone())))
    }
}

// === impl HttpConfig ===

impl HttpConfig {
    /// Reads the `[http]` table: every key converted and checked, every problem with its path.
    pub(crate) fn read(cx: &mut Cx, mut f: Fields<'_>) -> Self {
        let (blo, bhi) = BODY_LIMIT_RANGE;
        let (rlo, rhi) = HTTP_REQUEST_TIMEOUT_RANGE;
        let (clo, chi) = HTTP_MAX_CONNECTIONS_RANGE;
        let (slo, shi) = HTTP_MAX_STREAMS_RANGE;
        let (ilo, ihi) = HTTP_IO_TIMEOUT_RANGE;
        let mut config = Self {
            listen: f.parsed_or(
                cx,
                "listen",
                "socket address (e.g. \"127.0.0.1:8080\")",
                DEFAULT_HTTP_LISTEN,
            ),
            token_file: f.string(cx, "token_file").map(PathBuf::from),
            token_env: f.string(cx, "token_env"),
            insecure_allow_unauthenticated_changes: f.bool_or(
                cx,
                "insecure_allow_unauthenticated_changes",
                DEFAULT_INSECURE,
            ),
            body_limit: f
                .int::<u32>(cx, "body_limit", narrow(blo)..=narrow(bhi), "")
                .map_or(DEFAULT_BODY_LIMIT, u64::from),
            request_timeout: f.duration_or(
                cx,
                "request_timeout",
                rlo..=rhi,
                DEFAULT_HTTP_REQUEST_TIMEOUT,
                "",
            ),
            max_connections: f.int_or(
                cx,
                "max_connections",
                clo..=chi,
                DEFAULT_HTTP_MAX_CONNECTIONS,
                "",
            ),
            max_connections_per_client: f.int_or(
                cx,
                "max_connections_per_client",
                clo..=chi,
                DEFAULT_HTTP_MAX_CONNECTIONS_PER_CLIENT,
                "",
            ),
            max_streams: f.int_or(cx, "max_streams", slo..=shi, DEFAULT_HTTP_MAX_STREAMS, ""),
            write_timeout: f.duration_or(
                cx,
                "write_timeout",
                ilo..=ihi,
                DEFAULT_HTTP_WRITE_TIMEOUT,
                "",
            ),
            header_read_timeout: f.duration_or(
                cx,
                "header_read_timeout",
                ilo..=ihi,
                DEFAULT_HTTP_HEADER_READ_TIMEOUT,
                "",
            ),
            tls: f.table(cx, "tls").map(|t| HttpTlsConfig::read(cx, t)),
            allowed_networks: networks(cx, &mut f, "allowed_networks", "10.0.0.0/8", usize::MAX),
            monitoring_networks: networks(
                cx,
                &mut f,
                "monitoring_networks",
                "10.0.9.0/24",
                HTTP_LIST_MAX,
            ),
            hosts: hosts(cx, &mut f),
            tag_metrics: f.bool_or(cx, "tag_metrics", DEFAULT_TAG_METRICS),
            tag_metrics_filter: tag_metrics_filter(cx, &mut f),
            tokens: BTreeMap::new(),
        };
        if f.has("token_file") && f.has("token_env") {
            cx.issue(f.at("token_env"), "set token_file or token_env, not both");
        }
        check_token_place(
            cx,
            &f,
            config.token_file.as_ref(),
            config.token_env.as_ref(),
        );
        config.tokens = tokens(cx, &mut f);
        f.finish(cx);
        config
    }

    /// Where the token comes from, if anywhere.
    pub fn token_source(&self) -> Option<TokenSource> {
        TokenSource::of(self.token_file.as_ref(), self.token_env.as_ref())
    }
}

/// The networks of list `key`, each as `IpNet` (`example` in the message of one that is not),
/// at most `max`.
fn networks(
    cx: &mut Cx,
    f: &mut Fields<'_>,
    key: &'static str,
    example: &str,
    max: usize,
) -> Vec<IpNet> {
    let what = format!("network (e.g. \"{example}\")");
    let mut networks = Vec::new();
    for (path, v) in f.array(cx, key) {
        networks.extend(parsed_value::<IpNet>(cx, v, &path, &what));
    }
    if networks.len() > max {
        cx.issue(f.at(key), format!("at most {max} networks"));
    }
    networks
}

/// `hosts`: the names a request's Host may carry besides the gateway's, at most
/// [`HTTP_LIST_MAX`].
fn hosts(cx: &mut Cx, f: &mut Fields<'_>) -> Vec<String> {
    let mut hosts = Vec::new();
    for (path, v) in f.array(cx, "hosts") {
        let Some(name) = string_value(cx, v, &path) else {
            continue;
        };
        match host_name(&name) {
            Ok(name) => hosts.push(name),
            Err(why) => cx.issue(path, why),
        }
    }
    if hosts.len() > HTTP_LIST_MAX {
        cx.issue(f.at("hosts"), format!("at most {HTTP_LIST_MAX} names"));
    }
    hosts
}

/// `tag_metrics_filter`: canonical key expressions.
fn tag_metrics_filter(cx: &mut Cx, f: &mut Fields<'_>) -> Vec<String> {
    let mut filter = Vec::new();
    for (path, v) in f.array(cx, "tag_metrics_filter") {
        let Some(key) = string_value(cx, v, &path) else {
            continue;
        };
        if let Err(e) = zenoh::key_expr::OwnedKeyExpr::new(key.as_str()) {
            cx.issue(
                path,
                format!("not a canonical key expression (<line>/<device>/<tag>, wildcards allowed): {e}"),
            );
            continue;
        }
        filter.push(key);
    }
    filter
}

/// `[http.tokens.<name>]`: the named tokens.
fn tokens(cx: &mut Cx, f: &mut Fields<'_>) -> BTreeMap<String, TokenConfig> {
    let mut tokens = BTreeMap::new();
    for (name, path, v) in f.named_tables(cx, "tokens") {
        check_name(cx, &path, &name);
        let Some(t) = Fields::of(cx, v, path) else {
            continue;
        };
        if let Some(token) = TokenConfig::read(cx, t) {
            tokens.insert(name, token);
        }
    }
    tokens
}

// === impl HttpTlsConfig ===

impl HttpTlsConfig {
    fn read(cx: &mut Cx, mut f: Fields<'_>) -> Self {
        let mut file = |cx: &mut Cx, key| {
            f.required_string(cx, key)
                .map(PathBuf::from)
                .unwrap_or_default()
        };
        let cert = file(cx, "cert");
        let key = file(cx, "key");
        let ca = f.string(cx, "ca").map(PathBuf::from);
        if ca.as_ref().is_some_and(|p| p.as_os_str().is_empty()) {
            cx.issue(f.at("ca"), "empty path");
        }
        f.finish(cx);
        Self { cert, key, ca }
    }
}

// === impl TokenConfig ===

impl TokenConfig {
    /// Reads one `[http.tokens.<name>]`; `None` when it has no role or no place for the token.
    fn read(cx: &mut Cx, mut f: Fields<'_>) -> Option<Self> {
        let role = f.choice::<RestRole>(cx, "role");
        if !f.has("role") {
            cx.issue(
                f.at("role"),
                "missing required key (\"viewer\", \"operator\" or \"admin\")",
            );
        }
        let token_file = f.string(cx, "token_file").map(PathBuf::from);
        let token_env = f.string(cx, "token_env");
        match (f.has("token_file"), f.has("token_env")) {
            (true, true) => cx.issue(f.at("token_env"), "set token_file or token_env, not both"),
            (false, false) => cx.issue(
                f.at("token_file"),
                "missing: the token's file (token_file) or variable (token_env)",
            ),
            _ => {}
        }
        check_token_place(cx, &f, token_file.as_ref(), token_env.as_ref());
        f.finish(cx);
        Some(Self {
            role: role?,
            token_file,
            token_env,
        })
    }

    /// Where the token comes from (the file when both are set, which the reader refuses).
    pub fn source(&self) -> Option<TokenSource> {
        TokenSource::of(self.token_file.as_ref(), self.token_env.as_ref())
    }
}

/// Checks a token's file path (not empty) and variable name.
fn check_token_place(
    cx: &mut Cx,
    f: &Fields<'_>,
    token_file: Option<&PathBuf>,
    token_env: Option<&String>,
) {
    if let Some(name) = token_env {
        let valid = !name.is_empty()
            && !name.starts_with(|c: char| c.is_ascii_digit())
            && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        if !valid {
            cx.issue(
                f.at("token_env"),
                format!("{name:?} is not an environment variable name ([A-Za-z_][A-Za-z0-9_]*)"),
            );
        }
    }
    if token_file.is_some_and(|p| p.as_os_str().is_empty()) {
        cx.issue(f.at("token_file"), "empty path");
    }
}

/// A name of `[http] hosts` as it is compared: a DNS name (letters, digits, `-`, `.`, at most
/// [`HTTP_HOST_NAME_MAX`] characters) in lower case, without a trailing dot; no port, no scheme,
/// no wildcard.
pub fn host_name(text: &str) -> Result<String, String> {
    let name = text.trim_end_matches('.').to_ascii_lowercase();
    if name.is_empty() {
        return Err("empty name".to_owned());
    }
    if name.len() > HTTP_HOST_NAME_MAX {
        return Err(format!("longer than {HTTP_HOST_NAME_MAX} characters"));
    }
    if name.contains(':') || name.contains('/') {
        return Err(format!(
            "{text:?} is not a host name: give the name alone (e.g. \"gw1.plant.local\"), without scheme or port"
        ));
    }
    let valid = name.split('.').all(|label| {
        !label.is_empty()
            && label.len() <= 63
            && !label.starts_with('-')
            && !label.ends_with('-')
            && label
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_')
    });
    if !valid {
        return Err(format!(
            "{text:?} is not a host name (labels of letters, digits and '-', separated by '.')"
        ));
    }
    Ok(name)
}

/// A byte count of [`BODY_LIMIT_RANGE`] as the reader's integer type (the range fits in `u32`).
fn narrow(n: u64) -> u32 {
    u32::try_from(n).unwrap_or(u32::MAX)
}

/// Reads the section through [`HttpConfig::read`]: unknown keys are refused, every problem is
/// reported.
impl<'de> Deserialize<'de> for HttpConfig {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        super::read_section(deserializer, "http", Self::read)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::ConfigIssue;

    fn read(text: &str) -> Result<HttpConfig, Vec<ConfigIssue>> {
        let table: toml::Table = text.parse().unwrap();
        let mut cx = Cx::default();
        let config = HttpConfig::read(&mut cx, Fields::new(&table, "http".into()));
        if cx.issues.is_empty() {
            Ok(config)
        } else {
            Err(cx.issues)
        }
    }

    #[test]
    fn an_empty_section_takes_the_defaults() {
        assert_eq!(read("").unwrap(), HttpConfig::default());
        let d = HttpConfig::default();
        assert_eq!(d.listen.to_string(), "127.0.0.1:8080");
        assert!(!d.insecure_allow_unauthenticated_changes);
        assert_eq!(d.token_source(), None);
    }

    #[test]
    fn every_key_reads() {
        let c = read(
            "listen = \"0.0.0.0:9000\"\ntoken_env = \"API_TOKEN\"\n\
             insecure_allow_unauthenticated_changes = true\nbody_limit = 4096\nrequest_timeout = \"2s\"\n\
             max_connections = 8\nmax_connections_per_client = 2\nmax_streams = 3\n\
             write_timeout = \"1s\"\nheader_read_timeout = \"500ms\"\n\
             [tls]\ncert = \"/etc/gateway/tls/http.crt\"\nkey = \"/etc/gateway/tls/http.key\"",
        )
        .unwrap();
        assert_eq!(c.max_connections_per_client, 2);
        assert_eq!(c.max_streams, 3);
        assert_eq!(c.write_timeout, Duration::from_secs(1));
        assert_eq!(c.header_read_timeout, Duration::from_millis(500));
        let tls = c.tls.as_ref().expect("tls");
        assert_eq!(tls.cert, PathBuf::from("/etc/gateway/tls/http.crt"));
        assert_eq!(tls.ca, None);
        let text = toml::to_string(&c).unwrap();
        assert_eq!(read(&text).unwrap(), c);
        assert_eq!(c.listen.port(), 9000);
        assert_eq!(c.token_source(), Some(TokenSource::Env("API_TOKEN".into())));
        assert!(c.insecure_allow_unauthenticated_changes);
        assert_eq!(c.body_limit, 4096);
        assert_eq!(c.request_timeout, Duration::from_secs(2));
        assert_eq!(c.max_connections, 8);
    }

    #[test]
    fn every_problem_is_reported_at_once() {
        let issues = read(
            "listen = \"nowhere\"\ntoken_file = \"/a\"\ntoken_env = \"1X\"\nbody_limit = 10\n\
             request_timeout = \"soon\"\ncolour = \"blue\"\nmax_connections = 0\n\
             max_streams = 0\nwrite_timeout = \"1ms\"\n[tls]\nkey = \"/k\"\nca = \"\"",
        )
        .unwrap_err();
        let mut paths: Vec<&str> = issues.iter().map(|i| i.path.as_str()).collect();
        paths.sort_unstable();
        assert_eq!(
            paths,
            [
                "http.body_limit",
                "http.colour",
                "http.listen",
                "http.max_connections",
                "http.max_streams",
                "http.request_timeout",
                "http.tls.ca",
                "http.tls.cert",
                "http.token_env",
                "http.token_env",
                "http.write_timeout",
            ],
            "{issues:?}"
        );
    }

    #[test]
    fn named_tokens_read_with_their_roles() {
        let c = read(
            "[tokens.ops]\nrole = \"operator\"\ntoken_env = \"GATEWAY_TOKEN_OPS\"\n\
             [tokens.eng]\nrole = \"admin\"\ntoken_file = \"/etc/gateway/eng.token\"\n",
        )
        .unwrap();
        assert_eq!(c.tokens.len(), 2);
        assert_eq!(c.tokens["ops"].role, RestRole::Operator);
        assert_eq!(
            c.tokens["ops"].source(),
            Some(TokenSource::Env("GATEWAY_TOKEN_OPS".into()))
        );
        assert_eq!(
            c.tokens["eng"].source(),
            Some(TokenSource::File("/etc/gateway/eng.token".into()))
        );
        let text = toml::to_string(&c).unwrap();
        assert_eq!(read(&text).unwrap(), c);

        let issues = read(
            "[tokens.a]\nrole = \"root\"\ntoken_env = \"A\"\n\
             [tokens.b]\ntoken_env = \"B\"\n\
             [tokens.c]\nrole = \"viewer\"\n\
             [tokens.d]\nrole = \"viewer\"\ntoken_env = \"D\"\ntoken_file = \"/d\"\n\
             [tokens.e]\nrole = \"viewer\"\ntoken_env = \"1E\"\ntoken = \"secret-in-text\"\n",
        )
        .unwrap_err();
        let mut paths: Vec<&str> = issues.iter().map(|i| i.path.as_str()).collect();
        paths.sort_unstable();
        assert_eq!(
            paths,
            [
                "http.tokens.a.role",
                "http.tokens.b.role",
                "http.tokens.c.token_file",
                "http.tokens.d.token_env",
                "http.tokens.e.token",
                "http.tokens.e.token_env",
            ],
            "{issues:?}"
        );
    }

    #[test]
    fn tag_metrics_read_with_their_filter_and_a_bad_expression_is_refused() {
        assert!(!HttpConfig::default().tag_metrics);
        let c =
            read("tag_metrics = true\ntag_metrics_filter = [\"drive/**\", \"*/ks/PV\"]").unwrap();
        assert!(c.tag_metrics);
        assert_eq!(c.tag_metrics_filter, ["drive/**", "*/ks/PV"]);
        let text = toml::to_string(&c).unwrap();
        assert_eq!(read(&text).unwrap(), c);

        let issues = read("tag_metrics_filter = [\"drive/**/**\", 3]").unwrap_err();
        assert_eq!(issues.len(), 2, "{issues:?}");
        assert!(
            issues
                .iter()
                .all(|i| i.path.starts_with("http.tag_metrics_filter")),
            "{issues:?}"
        );
    }

    #[test]
    fn monitoring_networks_and_hosts_are_read_checked_and_written_back() {
        let c = read(
            "monitoring_networks = [\"10.0.9.0/24\", \"127.0.0.1/32\"]\nhosts = [\"GW1.Plant.Local.\", \"gateway\"]",
        )
        .unwrap();
        assert_eq!(c.monitoring_networks.len(), 2);
        assert_eq!(c.hosts, ["gw1.plant.local", "gateway"]);
        let text = toml::to_string(&c).unwrap();
        assert_eq!(read(&text).unwrap(), c);
        // Not written back when empty.
        assert!(!toml::to_string(&HttpConfig::default())
            .unwrap()
            .contains("hosts"));

        let issues = read(
            "monitoring_networks = [\"10.0.9.0/33\"]\nhosts = [\"gw1:8080\", \"http://gw1\", \"\", \"a b\", \"*.plant\"]",
        )
        .unwrap_err();
        let paths: Vec<&str> = issues.iter().map(|i| i.path.as_str()).collect();
        assert_eq!(
            paths,
            [
                "http.monitoring_networks[0]",
                "http.hosts[0]",
                "http.hosts[1]",
                "http.hosts[2]",
                "http.hosts[3]",
                "http.hosts[4]",
            ],
            "{issues:?}"
        );
        let many: Vec<String> = (0..=HTTP_LIST_MAX).map(|n| format!("\"h{n}\"")).collect();
        let issues = read(&format!("hosts = [{}]", many.join(","))).unwrap_err();
        assert_eq!(issues[0].path, "http.hosts", "{issues:?}");
    }

    #[test]
    fn roles_grant_their_rights() {
        use RestRight::{Config, Diagnostics, Send, Write};
        for right in [Write, Send, Diagnostics, Config] {
            assert!(!RestRole::Viewer.allows(right));
            assert!(RestRole::Admin.allows(right));
            assert_eq!(RestRole::Operator.allows(right), right != Config);
        }
    }

    #[test]
    fn serde_refuses_unknown_keys_and_round_trips() {
        assert!(toml::from_str::<HttpConfig>("colour = 1").is_err());
        let c = HttpConfig {
            token_file: Some("/run/secrets/token".into()),
            ..HttpConfig::default()
        };
        let text = toml::to_string(&c).unwrap();
        assert_eq!(toml::from_str::<HttpConfig>(&text).unwrap(), c);
        assert_eq!(read(&text).unwrap(), c);
    }
}
