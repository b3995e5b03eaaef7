//! Bearer tokens for changes (RFC 6750).
//!
//! GET and HEAD need no token. Every other method (PUT, POST, DELETE, PATCH) needs
//! `Authorization: Bearer <token>`:
//! - no `Authorization` header: 401 with `WWW-Authenticate: Bearer realm="gateway"`;
//! - another scheme, or a token that is not the configured one: 401 with
//!   `error="invalid_token"` (RFC 6750 3.1: an invalid token is answered 401, not 403);
//! - no token configured at all: 403, the server refuses every change, unless
//!   `insecure_allow_unauthenticated_changes` is set, in which case every change is accepted
//!   (and the start-up log says so).
//!
//! Tokens are compared in time that does not depend on where they differ.

use std::fmt;
use std::io;
use std::path::PathBuf;

use axum::extract::{Request, State};
use axum::http::{header, HeaderMap, Method};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use super::error::ApiError;
use super::ApiState;
use crate::config::{HttpConfig, TokenSource};

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

/// Who may change things.
#[derive(Clone, Debug)]
pub struct Auth {
    token: Option<Token>,
    insecure: bool,
}

/// The three ways [`Auth`] can be set up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AuthMode {
    /// Changes need the token.
    Token,
    /// No token configured: changes refused (403).
    Locked,
    /// No token configured: changes accepted from anyone.
    Insecure,
}

// === impl Auth ===

impl Auth {
    /// Changes need `token`.
    pub fn with_token(token: Token) -> Self {
        Self {
            token: Some(token),
            insecure: false,
        }
    }

    /// No token: every change is refused.
    pub fn locked() -> Self {
        Self {
            token: None,
            insecure: false,
        }
    }

    /// No token: every change is accepted. For demos only.
    pub fn insecure() -> Self {
        Self {
            token: None,
            insecure: true,
        }
    }

    /// The token named by `[http]` read from its file or the process environment.
    pub fn from_config(config: &HttpConfig) -> Result<Self, TokenError> {
        Self::from_config_with(config, |name| std::env::var(name).ok())
    }

    /// As [`from_config`](Self::from_config) with `env` in place of the process environment.
    pub fn from_config_with(
        config: &HttpConfig,
        env: impl Fn(&str) -> Option<String>,
    ) -> Result<Self, TokenError> {
        let token = match config.token_source() {
            None => None,
            Some(TokenSource::File(path)) => {
                warn_if_readable_by_others(&path);
                let text = std::fs::read_to_string(&path).map_err(|source| TokenError::File {
                    path: path.clone(),
                    source,
                })?;
                Some(Token::new(&text, &path.display().to_string())?)
            }
            Some(TokenSource::Env(name)) => {
                let text = env(&name).ok_or_else(|| TokenError::EnvMissing(name.clone()))?;
                Some(Token::new(&text, &format!("${name}"))?)
            }
        };
        Ok(Self {
            token,
            insecure: config.insecure_allow_unauthenticated_changes,
        })
    }

    pub fn mode(&self) -> AuthMode {
        match (&self.token, self.insecure) {
            (Some(_), _) => AuthMode::Token,
            (None, false) => AuthMode::Locked,
            (None, true) => AuthMode::Insecure,
        }
    }

    /// Whether a request with `method` and `headers` may go on. Only the methods that change
    /// something (PUT, POST, DELETE, PATCH) need the token; any other method (GET, HEAD, and
    /// those no route serves, such as TRACE or OPTIONS, which the router answers 405) goes on.
    pub fn check(&self, method: &Method, headers: &HeaderMap) -> Result<(), ApiError> {
        if !matches!(
            *method,
            Method::PUT | Method::POST | Method::DELETE | Method::PATCH
        ) {
            return Ok(());
        }
        let Some(token) = &self.token else {
            return if self.insecure {
                Ok(())
            } else {
                Err(ApiError::forbidden(
                    "changes are disabled: no API token is configured ([http] token_file or token_env)",
                ))
            };
        };
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
        match presented {
            None => Err(ApiError::unauthorized(
                "the Authorization scheme must be Bearer",
                CHALLENGE_REQUEST,
            )),
            Some(p) if token.matches(p) => Ok(()),
            Some(_) => Err(ApiError::unauthorized(
                "the bearer token is not valid",
                CHALLENGE_INVALID,
            )),
        }
    }

    /// Says in the log how changes are guarded (the insecure mode as a warning).
    pub fn log_mode(&self) {
        match self.mode() {
            AuthMode::Token => tracing::info!("REST API: changes need the bearer token"),
            AuthMode::Locked => tracing::warn!(
                "REST API: no token configured ([http] token_file or token_env): every change is refused"
            ),
            AuthMode::Insecure => tracing::warn!(
                "REST API: INSECURE: changes are accepted without a token (insecure_allow_unauthenticated_changes = true)"
            ),
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

/// The middleware that applies [`Auth::check`] to every request.
pub(crate) async fn require_auth(
    State(state): State<ApiState>,
    req: Request,
    next: Next,
) -> Response {
    match state.auth().check(req.method(), req.headers()) {
        Ok(()) => next.run(req).await,
        Err(e) => e.into_response(),
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
