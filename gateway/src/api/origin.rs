//! Browser-safe requests: the `Host` and `Origin` checks, in every mode (with tokens, locked, and
//! with `insecure_allow_unauthenticated_changes`).
//!
//! A web page the operator happens to have open in a browser on the plant network can send
//! requests to the gateway: a cross-site form POST (no CORS preflight for
//! `application/x-www-form-urlencoded`), or, after DNS rebinding, any request to a name the
//! attacker controls that now resolves to the gateway. Two checks, before the token is looked at:
//!
//! - **`Host`, on every request (reads too):** it must be one of the listener's names, or absent
//!   (HTTP/1.0; no browser omits it). The listener's names: any IP address literal (a page can
//!   only reach it under that address, which is the gateway's own origin, so rebinding cannot
//!   produce it; port mapping and NAT change which address a client sees, so any is accepted),
//!   `localhost` on a connection that arrived on a loopback address, the gateway's name (`[gateway]
//!   name`: a fleet reaches its members by it), and the names of `[http] hosts`. Any other name
//!   is refused (403): after DNS rebinding the browser sends the attacker's name, so no answer,
//!   not even a read, reaches the attacker's page. `/metrics` scraped by a name needs the name in
//!   `hosts`.
//! - **`Origin`, on every change (any method but GET, HEAD and OPTIONS):** absent (curl, scripts,
//!   Prometheus) or the request's own origin: its host and port equal to the `Host` header's (the
//!   default port of the scheme when none is written), or its host in `[http] hosts` (a reverse
//!   proxy's public name). `null` (sandboxed frames, `file:` pages) and any other origin are
//!   refused (403).
//!
//! Refusals are counted (`gateway_http_rejected_total{reason="host"|"origin"}`), logged
//! rate-limited with the client's address, and a refused change is audited as every other refused
//! change. What the peer sent is shown at most [`SHOWN_MAX`] bytes long, escaped.

use std::net::{IpAddr, SocketAddr};

use axum::extract::{Request, State};
use axum::http::{header, HeaderMap, Method};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use super::auth::{AuthMode, Caller, PeerAddr, Who};
use super::error::ApiError;
use super::metrics::HttpRejectReason;
use super::ApiState;
use crate::audit::WriteResult;

/// At most this many bytes of a `Host` or `Origin` a peer sent are shown in a log, an audit line
/// or an answer (escaped, then marked as cut).
pub const SHOWN_MAX: usize = 100;

/// The address of the listener a connection reached, put into every request by the accept loop
/// (with `0.0.0.0` bound, the interface's own address).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LocalAddr(pub SocketAddr);

/// The names a request's `Host` may carry besides an IP address (and `localhost` on loopback).
#[derive(Clone, Debug, Default)]
pub struct HostNames {
    /// Lower case, without a trailing dot.
    names: Vec<String>,
    /// The listener speaks HTTPS (the default port of a `Host` without one is 443).
    https: bool,
}

/// Why a request was refused.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Refusal {
    pub reason: HttpRejectReason,
    pub message: String,
}

// === impl HostNames ===

impl HostNames {
    /// `names` (`[http] hosts` and the gateway's name; names that are not valid host names are
    /// left out); `https` when the listener speaks HTTPS.
    pub fn new<'a>(names: impl IntoIterator<Item = &'a str>, https: bool) -> Self {
        let mut names: Vec<String> = names
            .into_iter()
            .filter_map(|n| crate::config::host_name(n).ok())
            .collect();
        names.sort();
        names.dedup();
        Self { names, https }
    }

    fn default_port(&self) -> u16 {
        if self.https {
            443
        } else {
            80
        }
    }

    fn listed(&self, host: &str) -> bool {
        let host = host.trim_end_matches('.');
        self.names.iter().any(|n| n.eq_ignore_ascii_case(host))
    }

    /// Whether `host` (a `Host`'s or `Origin`'s host part) names this listener for a connection
    /// that reached `local`.
    fn names_listener(&self, host: &str, local: Option<SocketAddr>) -> bool {
        let bare = host
            .strip_prefix('[')
            .and_then(|h| h.strip_suffix(']'))
            .unwrap_or(host);
        if bare.parse::<IpAddr>().is_ok() {
            return true;
        }
        let loopback = local.is_some_and(|l| l.ip().to_canonical().is_loopback());
        (loopback && host.trim_end_matches('.').eq_ignore_ascii_case("localhost"))
            || self.listed(host)
    }

    /// Checks a request's `Host`, and for a change its `Origin`, for a connection that reached
    /// `local`.
    pub fn check(
        &self,
        method: &Method,
        headers: &HeaderMap,
        local: Option<SocketAddr>,
    ) -> Result<(), Refusal> {
        let mut hosts = headers.get_all(header::HOST).iter();
        let host = match (hosts.next(), hosts.next()) {
            (None, _) => None,
            (Some(one), None) => Some(one),
            (Some(_), Some(_)) => {
                return Err(refusal(HttpRejectReason::Host, "more than one Host header"));
            }
        };
        let authority = match host {
            None => None,
            Some(value) => {
                let parsed = value
                    .to_str()
                    .ok()
                    .and_then(|v| v.parse::<axum::http::uri::Authority>().ok())
                    .filter(|a| !a.as_str().contains('@'));
                let Some(a) = parsed else {
                    return Err(refusal(
                        HttpRejectReason::Host,
                        &format!("Host {} is not a host[:port]", shown(value.as_bytes())),
                    ));
                };
                if !self.names_listener(a.host(), local) {
                    return Err(refusal(
                        HttpRejectReason::Host,
                        &format!(
                            "Host {} is not a name of this listener (an IP address, localhost on \
                             loopback, the gateway's name, or one of [http] hosts)",
                            shown(value.as_bytes())
                        ),
                    ));
                }
                Some(a)
            }
        };
        if matches!(*method, Method::GET | Method::HEAD | Method::OPTIONS) {
            return Ok(());
        }
        let Some(origin) = headers.get(header::ORIGIN) else {
            return Ok(());
        };
        let foreign = || {
            refusal(
                HttpRejectReason::Origin,
                &format!(
                    "a change from the origin {} (a web page of another site) is refused: \
                     changes come from this listener's own origin, one of [http] hosts, or \
                     without Origin (curl, scripts)",
                    shown(origin.as_bytes())
                ),
            )
        };
        let uri = origin
            .to_str()
            .ok()
            .and_then(|o| o.parse::<axum::http::Uri>().ok())
            .ok_or_else(foreign)?;
        let (Some(scheme), Some(o)) = (uri.scheme_str(), uri.authority()) else {
            return Err(foreign());
        };
        let default_port = match scheme {
            "http" => 80,
            "https" => 443,
            _ => return Err(foreign()),
        };
        let origin_port = o.port_u16().unwrap_or(default_port);
        if self.listed(o.host()) {
            return Ok(());
        }
        let same = authority.is_some_and(|a| {
            a.host().eq_ignore_ascii_case(o.host())
                && a.port_u16().unwrap_or_else(|| self.default_port()) == origin_port
        });
        if same {
            Ok(())
        } else {
            Err(foreign())
        }
    }
}

fn refusal(reason: HttpRejectReason, message: &str) -> Refusal {
    Refusal {
        reason,
        message: message.to_owned(),
    }
}

/// What a peer sent, for a log line or an answer: at most [`SHOWN_MAX`] bytes, quoted and
/// escaped (control characters, quotes and anything not ASCII as escapes), `...` when cut.
pub fn shown(value: &[u8]) -> String {
    let cut = value.len() > SHOWN_MAX;
    let text = String::from_utf8_lossy(&value[..value.len().min(SHOWN_MAX)]);
    let mut out = String::with_capacity(text.len() + 8);
    out.push('"');
    for c in text.chars() {
        if c.is_ascii_graphic() && c != '"' && c != '\\' || c == ' ' {
            out.push(c);
        } else {
            out.extend(c.escape_default());
        }
    }
    out.push('"');
    if cut {
        out.push_str("...");
    }
    out
}

/// The middleware: refuses a request whose `Host` or (for a change) `Origin` is foreign, before
/// its token is looked at.
pub(crate) async fn require_own_origin(
    State(state): State<ApiState>,
    req: Request,
    next: Next,
) -> Response {
    let local = req.extensions().get::<LocalAddr>().map(|l| l.0);
    let Err(refused) = state.host_names().check(req.method(), req.headers(), local) else {
        return next.run(req).await;
    };
    let peer = req.extensions().get::<PeerAddr>().map(|p| p.0);
    let method = req.method().clone();
    let target = format!(
        "{method} {}",
        shown(req.uri().path().as_bytes()).trim_matches('"')
    );
    state.refused(
        refused.reason,
        peer,
        &format!("{target}: {}", refused.message),
    );
    if super::auth::required_right(&method, req.uri().path()).is_some() {
        let who = match state.auth().mode() {
            AuthMode::Insecure => Who::Anonymous,
            AuthMode::Token | AuthMode::Locked => Who::Unauthenticated,
        };
        let caller = Caller { addr: peer, who };
        state
            .backend()
            .audit(&caller, &target, WriteResult::Refused, &refused.message);
    }
    ApiError::forbidden(refused.message).into_response()
}

#[cfg(test)]
mod tests {
    use axum::http::HeaderValue;

    use super::*;

    fn headers(pairs: &[(&str, &str)]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for (k, v) in pairs {
            h.append(
                axum::http::HeaderName::from_bytes(k.as_bytes()).unwrap(),
                HeaderValue::from_str(v).unwrap(),
            );
        }
        h
    }

    fn loopback() -> Option<SocketAddr> {
        Some("127.0.0.1:8080".parse().unwrap())
    }

    fn check(
        names: &HostNames,
        method: Method,
        pairs: &[(&str, &str)],
    ) -> Option<HttpRejectReason> {
        names
            .check(&method, &headers(pairs), loopback())
            .err()
            .map(|r| r.reason)
    }

    #[test]
    fn a_foreign_host_is_refused_on_every_request() {
        let names = HostNames::new(["gw1.plant.local", "demo"], false);
        for ok in [
            "127.0.0.1:8080",
            "127.0.0.1",
            "[::1]:8080",
            "10.0.0.5:80",
            "localhost:8080",
            "LocalHost",
            "gw1.plant.local:8080",
            "GW1.plant.local.",
            "demo:8080",
        ] {
            assert_eq!(check(&names, Method::GET, &[("host", ok)]), None, "{ok}");
            assert_eq!(check(&names, Method::POST, &[("host", ok)]), None, "{ok}");
        }
        // No Host at all (HTTP/1.0, no browser): served.
        assert_eq!(check(&names, Method::GET, &[]), None);
        for foreign in [
            "evil.example",
            "evil.example:8080",
            "gw1.plant.local.evil.example",
            "user@127.0.0.1",
            "127.0.0.1.nip.io",
            "a b",
        ] {
            assert_eq!(
                check(&names, Method::GET, &[("host", foreign)]),
                Some(HttpRejectReason::Host),
                "{foreign}"
            );
        }
        assert_eq!(
            check(
                &names,
                Method::GET,
                &[("host", "127.0.0.1"), ("host", "evil.example")]
            ),
            Some(HttpRejectReason::Host)
        );
        // localhost only on a loopback connection.
        let outside = Some("10.0.0.5:8080".parse().unwrap());
        assert!(names
            .check(&Method::GET, &headers(&[("host", "localhost")]), outside)
            .is_err());
    }

    #[test]
    fn a_change_needs_its_own_origin_or_none() {
        let names = HostNames::new(["gw1.plant.local"], false);
        let host = ("host", "127.0.0.1:8080");
        // curl: no Origin.
        assert_eq!(check(&names, Method::POST, &[host]), None);
        // The page itself.
        assert_eq!(
            check(
                &names,
                Method::POST,
                &[host, ("origin", "http://127.0.0.1:8080")]
            ),
            None
        );
        assert_eq!(
            check(
                &names,
                Method::DELETE,
                &[("host", "localhost"), ("origin", "http://localhost")]
            ),
            None
        );
        // A listed name (a reverse proxy's public name, any scheme).
        assert_eq!(
            check(
                &names,
                Method::PUT,
                &[host, ("origin", "https://gw1.plant.local")]
            ),
            None
        );
        for foreign in [
            "http://evil.example",
            "http://127.0.0.1:8081",
            "http://127.0.0.1",
            "https://127.0.0.1:8080.evil.example",
            "null",
            "file://",
            "ftp://127.0.0.1:8080",
            "not an origin",
        ] {
            assert_eq!(
                check(&names, Method::POST, &[host, ("origin", foreign)]),
                Some(HttpRejectReason::Origin),
                "{foreign}"
            );
        }
        // Reads are not checked for their Origin (a cross-site read cannot see the answer
        // without CORS, which the gateway never grants).
        assert_eq!(
            check(
                &names,
                Method::GET,
                &[host, ("origin", "http://evil.example")]
            ),
            None
        );
        // HTTPS: the default port is 443.
        let tls = HostNames::new([], true);
        assert_eq!(
            check(
                &tls,
                Method::POST,
                &[("host", "10.0.0.5"), ("origin", "https://10.0.0.5")]
            ),
            None
        );
        assert_eq!(
            check(
                &tls,
                Method::POST,
                &[("host", "10.0.0.5"), ("origin", "http://10.0.0.5")]
            ),
            Some(HttpRejectReason::Origin)
        );
    }

    #[test]
    fn what_a_peer_sent_is_shown_bounded_and_escaped() {
        assert_eq!(shown(b"evil.example"), "\"evil.example\"");
        assert_eq!(shown(b"a\"b\\c\n\x1b"), "\"a\\\"b\\\\c\\n\\u{1b}\"");
        let long = vec![b'a'; 1000];
        let s = shown(&long);
        assert!(s.len() <= SHOWN_MAX + 8, "{}", s.len());
        assert!(s.ends_with("..."));
        assert_eq!(shown("ü".as_bytes()), "\"\\u{fc}\"");
    }
}
