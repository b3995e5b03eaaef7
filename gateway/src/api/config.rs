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
//! ```
//!
//! Changes (PUT, POST, DELETE) need `Authorization: Bearer <token>`. The token itself never
//! appears in the configuration: only the file that holds it or the environment variable that
//! holds it. With neither, changes are refused (403) unless
//! `insecure_allow_unauthenticated_changes` is set, which the log then says at start.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::config::ConfigIssue;

/// Local only by default: exposing the API is a decision (SPEC: the demo serves 127.0.0.1:8080).
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
/// Accepted range of `max_connections`.
pub const MAX_CONNECTIONS_RANGE: (u32, u32) = (1, 4096);
/// Changes are refused without a token unless this is set.
pub const DEFAULT_INSECURE: bool = false;

pub fn default_http_listen() -> SocketAddr {
    DEFAULT_HTTP_LISTEN
}
pub fn default_body_limit() -> u64 {
    DEFAULT_BODY_LIMIT
}
pub fn default_http_request_timeout() -> Duration {
    DEFAULT_HTTP_REQUEST_TIMEOUT
}
pub fn default_http_max_connections() -> u32 {
    super::DEFAULT_MAX_CONNECTIONS
}

/// The `[http]` section.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HttpConfig {
    #[serde(default = "default_http_listen")]
    pub listen: SocketAddr,
    /// A file holding the bearer token (surrounding whitespace ignored).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub token_file: Option<PathBuf>,
    /// The name of an environment variable holding the bearer token.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub token_env: Option<String>,
    /// Accept changes without a token when none is configured (for demos; logged at start).
    #[serde(default)]
    pub insecure_allow_unauthenticated_changes: bool,
    /// Largest request body in bytes; a larger one is answered 413.
    #[serde(default = "default_body_limit")]
    pub body_limit: u64,
    /// A request that takes longer is answered 504.
    #[serde(default = "default_http_request_timeout", with = "humantime_serde")]
    pub request_timeout: Duration,
    /// Connections served at once; further clients wait in the listen backlog.
    #[serde(default = "default_http_max_connections")]
    pub max_connections: u32,
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
            max_connections: super::DEFAULT_MAX_CONNECTIONS,
        }
    }
}

/// Where the token comes from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TokenSource {
    File(PathBuf),
    Env(String),
}

// === impl HttpConfig ===

impl HttpConfig {
    /// Reads the `[http]` table at `path` (e.g. `"http"`), reporting every problem at once:
    /// unknown keys, values of the wrong type, values out of range.
    pub fn from_toml(value: &toml::Value, path: &str) -> Result<Self, Vec<ConfigIssue>> {
        let mut issues = Vec::new();
        let Some(table) = value.as_table() else {
            return Err(vec![issue(path, "expected a table")]);
        };
        let mut config = Self::default();
        for (key, v) in table {
            let at = format!("{path}.{key}");
            match key.as_str() {
                "listen" => {
                    if let Some(x) = typed(&mut issues, &at, v, "socket address (e.g. \"127.0.0.1:8080\")") {
                        config.listen = x;
                    }
                }
                "token_file" => config.token_file = typed(&mut issues, &at, v, "file path"),
                "token_env" => config.token_env = typed(&mut issues, &at, v, "environment variable name"),
                "insecure_allow_unauthenticated_changes" => {
                    if let Some(x) = typed(&mut issues, &at, v, "true or false") {
                        config.insecure_allow_unauthenticated_changes = x;
                    }
                }
                "body_limit" => {
                    if let Some(x) = typed(&mut issues, &at, v, "a number of bytes") {
                        config.body_limit = x;
                    }
                }
                "max_connections" => {
                    if let Some(x) = typed(&mut issues, &at, v, "a number of connections") {
                        config.max_connections = x;
                    }
                }
                "request_timeout" => {
                    let text: Option<String> = typed(&mut issues, &at, v, "a duration (e.g. \"30s\")");
                    match text.map(|t| humantime::parse_duration(&t)) {
                        Some(Ok(d)) => config.request_timeout = d,
                        Some(Err(e)) => issues.push(issue(&at, format!("expected a duration (e.g. \"30s\"): {e}"))),
                        None => {}
                    }
                }
                _ => issues.push(issue(
                    &at,
                    "unknown key (listen, token_file, token_env, insecure_allow_unauthenticated_changes, body_limit, request_timeout, max_connections)",
                )),
            }
        }
        issues.extend(config.issues(path));
        if issues.is_empty() {
            Ok(config)
        } else {
            Err(issues)
        }
    }

    /// The rules that span keys or ranges, with paths under `path`.
    pub fn issues(&self, path: &str) -> Vec<ConfigIssue> {
        let mut issues = Vec::new();
        let (lo, hi) = BODY_LIMIT_RANGE;
        if !(lo..=hi).contains(&self.body_limit) {
            issues.push(issue(
                &format!("{path}.body_limit"),
                format!("{} is out of range {lo}..={hi} bytes", self.body_limit),
            ));
        }
        let (lo, hi) = HTTP_REQUEST_TIMEOUT_RANGE;
        if !(lo..=hi).contains(&self.request_timeout) {
            issues.push(issue(
                &format!("{path}.request_timeout"),
                format!(
                    "{} is out of range {}..={}",
                    humantime::format_duration(self.request_timeout),
                    humantime::format_duration(lo),
                    humantime::format_duration(hi)
                ),
            ));
        }
        let (lo, hi) = MAX_CONNECTIONS_RANGE;
        if !(lo..=hi).contains(&self.max_connections) {
            issues.push(issue(
                &format!("{path}.max_connections"),
                format!("{} is out of range {lo}..={hi}", self.max_connections),
            ));
        }
        if self.token_file.is_some() && self.token_env.is_some() {
            issues.push(issue(
                &format!("{path}.token_env"),
                "set token_file or token_env, not both",
            ));
        }
        if let Some(name) = &self.token_env {
            let valid = !name.is_empty()
                && !name.starts_with(|c: char| c.is_ascii_digit())
                && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
            if !valid {
                issues.push(issue(
                    &format!("{path}.token_env"),
                    format!(
                        "{name:?} is not an environment variable name ([A-Za-z_][A-Za-z0-9_]*)"
                    ),
                ));
            }
        }
        if self
            .token_file
            .as_ref()
            .is_some_and(|p| p.as_os_str().is_empty())
        {
            issues.push(issue(&format!("{path}.token_file"), "empty path"));
        }
        issues
    }

    /// Where the token comes from, if anywhere.
    pub fn token_source(&self) -> Option<TokenSource> {
        match (&self.token_file, &self.token_env) {
            (Some(f), _) => Some(TokenSource::File(f.clone())),
            (None, Some(e)) => Some(TokenSource::Env(e.clone())),
            (None, None) => None,
        }
    }
}

fn issue(path: &str, message: impl Into<String>) -> ConfigIssue {
    ConfigIssue {
        path: path.to_owned(),
        message: message.into(),
    }
}

/// `v` as a `T`, or an issue at `at` saying what was expected.
fn typed<T: serde::de::DeserializeOwned>(
    issues: &mut Vec<ConfigIssue>,
    at: &str,
    v: &toml::Value,
    expected: &str,
) -> Option<T> {
    match v.clone().try_into::<T>() {
        Ok(x) => Some(x),
        Err(e) => {
            let what = e.message().trim().replace('\n', "; ");
            issues.push(issue(at, format!("expected {expected}: {what}")));
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> Result<HttpConfig, Vec<ConfigIssue>> {
        let table: toml::Table = text.parse().unwrap();
        HttpConfig::from_toml(&toml::Value::Table(table), "http")
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
             max_connections = 8",
        )
        .unwrap();
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
             request_timeout = \"soon\"\ncolour = \"blue\"\nmax_connections = 0",
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
                "http.request_timeout",
                "http.token_env",
                "http.token_env",
            ],
            "{issues:?}"
        );
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
