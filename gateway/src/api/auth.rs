//! Bearer tokens for changes (RFC 6750).
//!
//! GET and HEAD need no token. Every other method (PUT, POST, DELETE, PATCH) needs
//! `Authorization: Bearer <token>`:
//! - no `Authorization` header: 401 with `WWW-Authenticate: Bearer realm="gateway"`;
//! - another scheme, or a token that is not the configured one: 401 with
//!   `error="invalid_token"` (RFC 6750 3.1: an invalid token is answered 401, not 403);
//! - a valid token whose role lacks the right the change needs ([`required_right`]): 403;
//! - no token configured at all: 403, the server refuses every change, unless
//!   `insecure_allow_unauthenticated_changes` is set, in which case every change is accepted
//!   (and the start-up log says so).
//!
//! Several named tokens may be configured, each with a role ([`RestRole`]); the token of
//! `[http] token_file` / `token_env` is named `default` and has the `admin` role. A presented
//! token is compared with every configured token, each in time that does not depend on where
//! they differ. Who made a change ([`Caller`]: the client address and the token's name) goes
//! to the handlers for the audit.

mod check;

pub(crate) use check::{token_issue, ApiTokens};

use std::fmt;
use std::io;
use std::net::SocketAddr;
use std::path::PathBuf;

use axum::extract::{Request, State};
use axum::http::{header, HeaderMap, Method};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use super::error::ApiError;
use super::ApiState;
use crate::audit::WriteResult;
use crate::config::{HttpConfig, RestRight, RestRole, TokenSource};

/// Shortest token accepted: 16 characters (e.g. 96 random bits in base64).
pub const MIN_TOKEN_LEN: usize = 16;

const CHALLENGE: &str = "Bearer realm=\"gateway\"";
const CHALLENGE_INVALID: &str = "Bearer realm=\"gateway\", error=\"invalid_token\"";
const CHALLENGE_REQUEST: &str = "Bearer realm=\"gateway\", error=\"invalid_request\"";

/// A bearer token. Never printed, never serialized.
#[derive(Clone)]
pub struct Token(Box<[u8]>);

impl fmt::Debug for Token {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Token(<redacted>)")
    }
}

/// Why the token could not be had.
#[derive(Debug, thiserror::Error)]
pub enum TokenError {
    #[error("cannot read the API token file {}: {source}", path.display())]
    File { path: PathBuf, source: io::Error },
    #[error("the API token variable {0} is not set")]
    EnvMissing(String),
    #[error("the API token from {0} is too short (at least {MIN_TOKEN_LEN} characters)")]
    TooShort(String),
    #[error("the API token from {0} has characters other than visible ASCII")]
    BadCharacters(String),
    #[error("the API tokens {0} and {1} are the same: every token must be its own")]
    Duplicate(String, String),
    /// A named token (`[http.tokens.<name>]`) could not be had.
    #[error("token {name}: {source}")]
    Named { name: String, source: Box<Self> },
}

// === impl Token ===

impl Token {
    /// A token from its text (surrounding whitespace removed): at least [`MIN_TOKEN_LEN`]
    /// visible ASCII characters. `source` names where it came from, for the error.
    pub fn new(text: &str, source: &str) -> Result<Self, TokenError> {
        let text = text.trim();
        if !text.bytes().all(|b| b.is_ascii_graphic()) {
            return Err(TokenError::BadCharacters(source.to_owned()));
        }
        if text.len() < MIN_TOKEN_LEN {
            return Err(TokenError::TooShort(source.to_owned()));
        }
        Ok(Self(text.as_bytes().into()))
    }

    /// Whether `presented` is this token, in time that depends only on the lengths.
    pub fn matches(&self, presented: &[u8]) -> bool {
        constant_time_eq(&self.0, presented)
    }
}

/// Equal contents, looking at every byte of the longer input whatever the first difference.
fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    let len = a.len().max(b.len());
    let mut diff = u8::from(a.len() != b.len());
    for i in 0..len {
        let x = a.get(i).copied().unwrap_or(0);
        let y = b.get(i).copied().unwrap_or(0);
        diff |= std::hint::black_box(x ^ y);
    }
    std::hint::black_box(diff) == 0
}

/// A configured token with its name and role.
#[derive(Clone, Debug)]
struct NamedToken {
    name: String,
    role: RestRole,
    token: Token,
}

/// Who may change things.
#[derive(Clone, Debug)]
pub struct Auth {
    tokens: Vec<NamedToken>,
    insecure: bool,
}

/// The three ways [`Auth`] can be set up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AuthMode {
    /// Changes need a token.
    Token,
    /// No token configured: changes refused (403).
    Locked,
    /// No token configured: changes accepted from anyone.
    Insecure,
}

/// Who a request came from, as far as the API knows.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Who {
    /// A request that changes nothing: no token looked at.
    Reader,
    /// A configured token, by name.
    Token { name: String, role: RestRole },
    /// No token configured and changes open to anyone (the demo's insecure mode).
    Anonymous,
    /// A change refused before a token was recognised (none, or a wrong one).
    Unauthenticated,
}

/// The client address of a connection, put into every request by the accept loop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PeerAddr(pub SocketAddr);

/// The source of a request for the audit: the client address (when the server knows it) and
/// who it is; shown as e.g. `127.0.0.1:50312 token ops`, or `127.0.0.1:50312 no token
/// (insecure_allow_unauthenticated_changes)` where changes are open to anyone.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Caller {
    pub addr: Option<SocketAddr>,
    pub who: Who,
}

impl fmt::Display for Caller {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.addr {
            Some(a) => write!(f, "{a} ")?,
            None => f.write_str("(address unknown) ")?,
        }
        match &self.who {
            Who::Reader => f.write_str("reader"),
            Who::Token { name, .. } => write!(f, "token {name}"),
            Who::Anonymous => f.write_str("no token (insecure_allow_unauthenticated_changes)"),
            Who::Unauthenticated => f.write_str("no valid token"),
        }
    }
}

/// The right a request needs, by method and path; `None` for a request that changes nothing
/// (GET, HEAD, and the methods no route serves, which the router answers 405).
///
/// - `/api/v1/config...` (replace, change or delete a line, validate): `config`;
/// - `/api/v1/lines/{line}/send`, `/api/v1/lines/{line}/telegrams/{seq}/ack`: `send`;
/// - `/api/v1/lines/{line}/diag`, `/api/v1/lines/{line}/signals`: `diagnostics`;
/// - `/api/v1/lines/{line}/devices/{device}/tags/{tag}`: `write`;
/// - any other path: `config` (the strictest right; no route serves it anyway).
pub fn required_right(method: &Method, path: &str) -> Option<RestRight> {
    if !matches!(
        *method,
        Method::PUT | Method::POST | Method::DELETE | Method::PATCH
    ) {
        return None;
    }
    let rest = path.strip_prefix(super::API_PREFIX).unwrap_or("");
    let segments: Vec<&str> = rest.split('/').skip(1).collect();
    Some(match segments.as_slice() {
        ["lines", _, "send"] | ["lines", _, "telegrams", _, "ack"] => RestRight::Send,
        ["lines", _, "diag"] | ["lines", _, "signals"] => RestRight::Diagnostics,
        ["lines", _, "devices", _, "tags", _] => RestRight::Write,
        _ => RestRight::Config,
    })
}

// === impl Auth ===

impl Auth {
    /// Changes need `token` (named `default`, every right).
    pub fn with_token(token: Token) -> Self {
        Self::with_tokens(vec![("default".to_owned(), RestRole::Admin, token)])
    }

    /// Changes need one of `tokens` (name, role, token), and its role the change's right.
    pub fn with_tokens(tokens: Vec<(String, RestRole, Token)>) -> Self {
        Self {
            tokens: tokens
                .into_iter()
                .map(|(name, role, token)| NamedToken { name, role, token })
                .collect(),
            insecure: false,
        }
    }

    /// No token: every change is refused.
    pub fn locked() -> Self {
        Self::with_tokens(Vec::new())
    }

    /// No token: every change is accepted. For demos only.
    pub fn insecure() -> Self {
        Self {
            tokens: Vec::new(),
            insecure: true,
        }
    }

    /// The tokens named by `[http]` read from their files or the process environment.
    pub fn from_config(config: &HttpConfig) -> Result<Self, TokenError> {
        Self::from_config_with(config, |name| std::env::var(name).ok())
    }

    /// As [`from_config`](Self::from_config) with `env` in place of the process environment.
    pub fn from_config_with(
        config: &HttpConfig,
        env: impl Fn(&str) -> Option<String>,
    ) -> Result<Self, TokenError> {
        let mut tokens = Vec::new();
        if let Some(source) = config.token_source() {
            tokens.push(NamedToken {
                name: "default".to_owned(),
                role: RestRole::Admin,
                token: read_token(&source, &env)?,
            });
        }
        for (name, t) in &config.tokens {
            let Some(source) = t.source() else {
                continue;
            };
            let token = read_token(&source, &env).map_err(|e| TokenError::Named {
                name: name.clone(),
                source: Box::new(e),
            })?;
            tokens.push(NamedToken {
                name: name.clone(),
                role: t.role,
                token,
            });
        }
        for (i, a) in tokens.iter().enumerate() {
            if let Some(b) = tokens[i + 1..].iter().find(|b| b.token.matches(&a.token.0)) {
                return Err(TokenError::Duplicate(a.name.clone(), b.name.clone()));
            }
        }
        Ok(Self {
            tokens,
            insecure: config.insecure_allow_unauthenticated_changes,
        })
    }

    pub fn mode(&self) -> AuthMode {
        match (self.tokens.is_empty(), self.insecure) {
            (false, _) => AuthMode::Token,
            (true, false) => AuthMode::Locked,
            (true, true) => AuthMode::Insecure,
        }
    }

    /// Whether a request with `method` and `headers` may go on, with every right needed
    /// (as [`authenticate`](Self::authenticate) then [`authorize`](Self::authorize) for a
    /// configuration change).
    pub fn check(&self, method: &Method, headers: &HeaderMap) -> Result<(), ApiError> {
        let who = self.authenticate(method, headers)?;
        Self::authorize(&who, method, API_CONFIG_PATH)
    }

    /// Who sends a request with `method` and `headers`. Only the methods that change
    /// something (PUT, POST, DELETE, PATCH) need a token; any other method (GET, HEAD, and
    /// those no route serves, such as TRACE or OPTIONS, which the router answers 405) goes on
    /// as [`Who::Reader`].
    pub fn authenticate(&self, method: &Method, headers: &HeaderMap) -> Result<Who, ApiError> {
        if !matches!(
            *method,
            Method::PUT | Method::POST | Method::DELETE | Method::PATCH
        ) {
            return Ok(Who::Reader);
        }
        if self.tokens.is_empty() {
            return if self.insecure {
                Ok(Who::Anonymous)
            } else {
                Err(ApiError::forbidden(
                    "changes are disabled: no API token is configured ([http] token_file, token_env or [http.tokens.<name>])",
                ))
            };
        }
        let Some(value) = headers.get(header::AUTHORIZATION) else {
            return Err(ApiError::unauthorized(
                "this request needs Authorization: Bearer <token>",
                CHALLENGE,
            ));
        };
        let presented = value
            .as_bytes()
            .split_at_checked(7)
            .filter(|(scheme, _)| scheme.eq_ignore_ascii_case(b"bearer "))
            .map(|(_, rest)| rest.trim_ascii());
        let Some(presented) = presented else {
            return Err(ApiError::unauthorized(
                "the Authorization scheme must be Bearer",
                CHALLENGE_REQUEST,
            ));
        };
        // Every token is compared, whichever matches, so the time says nothing about which.
        let mut found = None;
        for t in &self.tokens {
            if t.token.matches(presented) && found.is_none() {
                found = Some(t);
            }
        }
        match found {
            Some(t) => Ok(Who::Token {
                name: t.name.clone(),
                role: t.role,
            }),
            None => Err(ApiError::unauthorized(
                "the bearer token is not valid",
                CHALLENGE_INVALID,
            )),
        }
    }

    /// Whether `who` may make the change of `method` on `path`: 403 when its token's role
    /// lacks the right ([`required_right`]).
    pub fn authorize(who: &Who, method: &Method, path: &str) -> Result<(), ApiError> {
        let (Some(right), Who::Token { name, role }) = (required_right(method, path), who) else {
            return Ok(());
        };
        if role.allows(right) {
            return Ok(());
        }
        Err(ApiError::forbidden(format!(
            "the token {name} has the role {} which does not grant the right {:?} this change needs",
            role.as_str(),
            right.as_str()
        )))
    }

    /// Says in the log how changes are guarded (the insecure mode as a warning).
    pub fn log_mode(&self) {
        match self.mode() {
            AuthMode::Token => {
                for t in &self.tokens {
                    tracing::info!(
                        token = %t.name,
                        role = t.role.as_str(),
                        "REST API: changes need a bearer token"
                    );
                }
            }
            AuthMode::Locked => tracing::warn!(
                "REST API: no token configured ([http] token_file or token_env): every change is refused"
            ),
            AuthMode::Insecure => tracing::warn!(
                "REST API: INSECURE: changes are accepted without a token (insecure_allow_unauthenticated_changes = true)"
            ),
        }
    }
}

/// A path under the API whose changes need every right, for [`Auth::check`].
const API_CONFIG_PATH: &str = "/api/v1/config";

/// A token from its file (warned about when others may read it) or its variable.
fn read_token(
    source: &TokenSource,
    env: &impl Fn(&str) -> Option<String>,
) -> Result<Token, TokenError> {
    match source {
        TokenSource::File(path) => {
            warn_if_readable_by_others(path);
            let text = std::fs::read_to_string(path).map_err(|source| TokenError::File {
                path: path.clone(),
                source,
            })?;
            Token::new(&text, &path.display().to_string())
        }
        TokenSource::Env(name) => {
            let text = env(name).ok_or_else(|| TokenError::EnvMissing(name.clone()))?;
            Token::new(&text, &format!("${name}"))
        }
    }
}

#[cfg(unix)]
fn warn_if_readable_by_others(path: &std::path::Path) {
    use std::os::unix::fs::PermissionsExt;
    if let Ok(meta) = std::fs::metadata(path) {
        if meta.permissions().mode() & 0o077 != 0 {
            tracing::warn!(file = %path.display(), "the API token file can be read by other users (chmod 600)");
        }
    }
}

#[cfg(not(unix))]
fn warn_if_readable_by_others(_path: &std::path::Path) {}

/// The middleware that authenticates and authorizes every request and hands the handlers its
/// [`Caller`]. A refused change is audited here (the handler never sees it).
pub(crate) async fn require_auth(
    State(state): State<ApiState>,
    mut req: Request,
    next: Next,
) -> Response {
    let addr = req.extensions().get::<PeerAddr>().map(|p| p.0);
    let method = req.method().clone();
    let checked = match state.auth().authenticate(&method, req.headers()) {
        Err(e) => Err((Who::Unauthenticated, e)),
        Ok(who) => match Auth::authorize(&who, &method, req.uri().path()) {
            Ok(()) => Ok(who),
            Err(e) => Err((who, e)),
        },
    };
    match checked {
        Ok(who) => {
            req.extensions_mut().insert(Caller { addr, who });
            next.run(req).await
        }
        Err((who, e)) => {
            let caller = Caller { addr, who };
            let target = format!("{method} {}", req.uri().path());
            state
                .backend()
                .audit(&caller, &target, WriteResult::Refused, &e.message());
            e.into_response()
        }
    }
}

#[cfg(test)]
mod tests {
    use axum::http::{HeaderValue, StatusCode};

    use super::*;

    const SECRET: &str = "0123456789abcdef-secret";

    fn headers(auth: Option<&str>) -> HeaderMap {
        let mut h = HeaderMap::new();
        if let Some(a) = auth {
            h.insert(header::AUTHORIZATION, HeaderValue::from_str(a).unwrap());
        }
        h
    }

    fn status(auth: &Auth, method: Method, header: Option<&str>) -> Option<StatusCode> {
        auth.check(&method, &headers(header))
            .err()
            .map(|e| e.status())
    }

    #[test]
    fn the_auth_matrix() {
        let auth = Auth::with_token(Token::new(SECRET, "test").unwrap());
        let right = format!("Bearer {SECRET}");
        assert_eq!(status(&auth, Method::GET, None), None);
        assert_eq!(
            status(&auth, Method::PUT, None),
            Some(StatusCode::UNAUTHORIZED)
        );
        assert_eq!(
            status(&auth, Method::PUT, Some("Bearer nope")),
            Some(StatusCode::UNAUTHORIZED)
        );
        assert_eq!(
            status(&auth, Method::PUT, Some(&format!("Basic {SECRET}"))),
            Some(StatusCode::UNAUTHORIZED)
        );
        assert_eq!(
            status(&auth, Method::PUT, Some(&format!("Bearer {SECRET}x"))),
            Some(StatusCode::UNAUTHORIZED)
        );
        assert_eq!(status(&auth, Method::DELETE, Some(&right)), None);
        assert_eq!(
            status(&auth, Method::POST, Some(&format!("bearer  {SECRET}"))),
            None
        );

        let locked = Auth::locked();
        assert_eq!(status(&locked, Method::GET, None), None);
        assert_eq!(
            status(&locked, Method::POST, None),
            Some(StatusCode::FORBIDDEN)
        );
        assert_eq!(
            status(&locked, Method::POST, Some(&right)),
            Some(StatusCode::FORBIDDEN)
        );

        let open = Auth::insecure();
        assert_eq!(status(&open, Method::PUT, None), None);
        assert_eq!(open.mode(), AuthMode::Insecure);
    }

    #[test]
    fn each_change_needs_its_right_and_the_role_has_it_or_403() {
        use RestRight::{Config, Diagnostics, Send, Write};
        for (method, path, right) in [
            (Method::PUT, "/api/v1/config", Some(Config)),
            (Method::POST, "/api/v1/config/validate", Some(Config)),
            (Method::DELETE, "/api/v1/config/lines/x", Some(Config)),
            (Method::POST, "/api/v1/lines/x/send", Some(Send)),
            (Method::POST, "/api/v1/lines/x/telegrams/3/ack", Some(Send)),
            (Method::DELETE, "/api/v1/lines/x/diag", Some(Diagnostics)),
            (Method::PUT, "/api/v1/lines/x/signals", Some(Diagnostics)),
            (Method::PUT, "/api/v1/lines/x/devices/d/tags/t", Some(Write)),
            // Paths that look alike but are not the routes need every right.
            (
                Method::PUT,
                "/api/v1/lines/x/devices/d/tags/t/extra",
                Some(Config),
            ),
            (Method::POST, "/api/v1/lines/send", Some(Config)),
            (Method::POST, "/lines/x/send", Some(Config)),
            (Method::POST, "/metrics", Some(Config)),
            (Method::GET, "/api/v1/config", None),
            (Method::OPTIONS, "/api/v1/config", None),
        ] {
            assert_eq!(required_right(&method, path), right, "{method} {path}");
        }
        let ops = Who::Token {
            name: "ops".into(),
            role: RestRole::Operator,
        };
        assert!(Auth::authorize(&ops, &Method::POST, "/api/v1/lines/x/send").is_ok());
        let e = Auth::authorize(&ops, &Method::PUT, "/api/v1/config").unwrap_err();
        assert_eq!(e.status(), StatusCode::FORBIDDEN);
        assert!(e.message().contains("operator"), "{}", e.message());
        assert!(Auth::authorize(&Who::Anonymous, &Method::PUT, "/api/v1/config").is_ok());
    }

    #[test]
    fn several_tokens_each_find_their_name_and_equal_ones_are_refused() {
        let token = |t: &str| Token::new(t, "test").unwrap();
        let auth = Auth::with_tokens(vec![
            ("a".into(), RestRole::Admin, token(SECRET)),
            (
                "b".into(),
                RestRole::Viewer,
                token("another-secret-0123456"),
            ),
        ]);
        let who = |t: &str| {
            auth.authenticate(&Method::PUT, &headers(Some(&format!("Bearer {t}"))))
                .map_err(|e| e.status())
        };
        assert_eq!(
            who(SECRET),
            Ok(Who::Token {
                name: "a".into(),
                role: RestRole::Admin
            })
        );
        assert_eq!(
            who("another-secret-0123456"),
            Ok(Who::Token {
                name: "b".into(),
                role: RestRole::Viewer
            })
        );
        assert_eq!(
            who("another-secret-01234567"),
            Err(StatusCode::UNAUTHORIZED)
        );

        let mut config = HttpConfig {
            token_env: Some("A".into()),
            ..HttpConfig::default()
        };
        config.tokens.insert(
            "ops".into(),
            crate::config::TokenConfig {
                role: RestRole::Operator,
                token_file: None,
                token_env: Some("B".into()),
            },
        );
        let auth = Auth::from_config_with(&config, |n| {
            Some(
                if n == "A" {
                    SECRET
                } else {
                    "ops-token-0123456789"
                }
                .to_owned(),
            )
        })
        .unwrap();
        assert_eq!(auth.mode(), AuthMode::Token);
        assert!(matches!(
            Auth::from_config_with(&config, |_| Some(SECRET.to_owned())),
            Err(TokenError::Duplicate(..))
        ));
        let caller = Caller {
            addr: Some("10.0.0.5:4711".parse().unwrap()),
            who: Who::Token {
                name: "ops".into(),
                role: RestRole::Operator,
            },
        };
        assert_eq!(caller.to_string(), "10.0.0.5:4711 token ops");
        // Changes open to anyone (the demo, or any config that sets the insecure key): the
        // client address and that no token was asked for, never a name that is not true.
        let open = Caller {
            addr: Some("192.0.2.7:50312".parse().unwrap()),
            who: Who::Anonymous,
        };
        assert_eq!(
            open.to_string(),
            "192.0.2.7:50312 no token (insecure_allow_unauthenticated_changes)"
        );
    }

    #[test]
    fn tokens_compare_by_content_only() {
        let t = Token::new(SECRET, "test").unwrap();
        assert!(t.matches(SECRET.as_bytes()));
        assert!(!t.matches(b""));
        assert!(!t.matches(&SECRET.as_bytes()[..SECRET.len() - 1]));
        assert!(constant_time_eq(b"", b""));
        assert!(!constant_time_eq(b"a", b"b"));
        assert!(!constant_time_eq(b"ab", b"a\0"));
        assert!(!constant_time_eq(b"a", b"a\0"));
        assert_eq!(format!("{t:?}"), "Token(<redacted>)");
    }

    #[test]
    fn tokens_are_checked_when_read() {
        assert!(matches!(
            Token::new("short", "x"),
            Err(TokenError::TooShort(_))
        ));
        assert!(matches!(
            Token::new("with a space inside it", "x"),
            Err(TokenError::BadCharacters(_))
        ));
        assert!(Token::new(&format!("  {SECRET}\n"), "x")
            .unwrap()
            .matches(SECRET.as_bytes()));
    }

    #[test]
    fn the_token_comes_from_a_file_or_the_environment() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("token");
        std::fs::write(&file, format!("{SECRET}\n")).unwrap();
        let config = HttpConfig {
            token_file: Some(file.clone()),
            ..HttpConfig::default()
        };
        let auth = Auth::from_config_with(&config, |_| None).unwrap();
        assert_eq!(auth.mode(), AuthMode::Token);
        assert!(auth
            .check(&Method::PUT, &headers(Some(&format!("Bearer {SECRET}"))))
            .is_ok());

        let missing = HttpConfig {
            token_file: Some(dir.path().join("absent")),
            ..HttpConfig::default()
        };
        assert!(matches!(
            Auth::from_config_with(&missing, |_| None),
            Err(TokenError::File { .. })
        ));

        let env = HttpConfig {
            token_env: Some("GW_TOKEN".into()),
            ..HttpConfig::default()
        };
        let auth =
            Auth::from_config_with(&env, |n| (n == "GW_TOKEN").then(|| SECRET.to_owned())).unwrap();
        assert!(auth
            .check(&Method::POST, &headers(Some(&format!("Bearer {SECRET}"))))
            .is_ok());
        assert!(matches!(
            Auth::from_config_with(&env, |_| None),
            Err(TokenError::EnvMissing(_))
        ));

        let insecure = HttpConfig {
            insecure_allow_unauthenticated_changes: true,
            ..HttpConfig::default()
        };
        assert_eq!(
            Auth::from_config_with(&insecure, |_| None).unwrap().mode(),
            AuthMode::Insecure
        );
        assert_eq!(
            Auth::from_config_with(&HttpConfig::default(), |_| None)
                .unwrap()
                .mode(),
            AuthMode::Locked
        );
    }
}
