//! HTTPS for the listener (`[http.tls]`): the REST API, the page, `/metrics` and the health
//! paths over TLS 1.3 or 1.2, with the certificate handling of Modbus/TCP Security
//! ([`crate::modbus_tcp::tls`]: the same PEM files and checks, the same rustls settings).
//!
//! The files are read at start (and by `gateway check`); [`HttpTls::reload`] reads them again
//! (on SIGHUP): new connections get the new certificate, connections already open keep their
//! session, nobody is dropped. A reload that fails (missing file, bad PEM, a key that does not
//! match) keeps what is in force. With `ca`, clients must show a certificate that chains to it
//! (the handshake fails otherwise); without, any client may connect and the bearer token guards
//! the changes as over HTTP.

use std::path::{Path, PathBuf};
use std::sync::{Arc, PoisonError, RwLock};

use tokio_rustls::TlsAcceptor;

use crate::config::check::Check;
use crate::config::{ConfigIssue, Cx, HttpTlsConfig};
use crate::modbus_tcp::tls::server_config;
use crate::modbus_tcp::TlsError;
use crate::plant::check::{ApiChange, Start};
use crate::plant::Config;

/// The HTTPS settings of a running listener, replaceable while it runs.
#[derive(Clone, Debug)]
pub struct HttpTls {
    inner: Arc<RwLock<State>>,
}

struct State {
    cert: PathBuf,
    key: PathBuf,
    ca: Option<PathBuf>,
    acceptor: TlsAcceptor,
}

// === impl HttpTls ===

impl HttpTls {
    /// Reads the files of `cfg` and makes the settings.
    pub fn new(cfg: &HttpTlsConfig) -> Result<Self, TlsError> {
        let acceptor = acceptor(cfg)?;
        Ok(Self {
            inner: Arc::new(RwLock::new(State {
                cert: cfg.cert.clone(),
                key: cfg.key.clone(),
                ca: cfg.ca.clone(),
                acceptor,
            })),
        })
    }

    /// Reads the same files again (a renewed certificate, key or CA), for new connections. On
    /// error what is in force stays.
    pub fn reload(&self) -> Result<(), TlsError> {
        let cfg = {
            let state = self.inner.read().unwrap_or_else(PoisonError::into_inner);
            HttpTlsConfig {
                cert: state.cert.clone(),
                key: state.key.clone(),
                ca: state.ca.clone(),
            }
        };
        let acceptor = acceptor(&cfg)?;
        self.inner
            .write()
            .unwrap_or_else(PoisonError::into_inner)
            .acceptor = acceptor;
        Ok(())
    }

    /// The acceptor for a new connection.
    pub(crate) fn acceptor(&self) -> TlsAcceptor {
        self.inner
            .read()
            .unwrap_or_else(PoisonError::into_inner)
            .acceptor
            .clone()
    }
}

impl std::fmt::Debug for State {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HttpTls")
            .field("cert", &self.cert)
            .field("key", &self.key)
            .field("ca", &self.ca)
            .finish_non_exhaustive()
    }
}

fn acceptor(cfg: &HttpTlsConfig) -> Result<TlsAcceptor, TlsError> {
    let mut config = server_config(&cfg.cert, &cfg.key, cfg.ca.as_deref())?;
    // The listener speaks HTTP/1.1 only.
    config.alpn_protocols = vec![b"http/1.1".to_vec()];
    Ok(TlsAcceptor::from(Arc::new(config)))
}

/// `[http.tls]`'s files: at start read and made into TLS settings as `run` makes them (a
/// missing, unreadable or unusable file is an issue at its key, with the path); through the
/// REST API each confined to `[gateway] config_dirs`.
pub(crate) struct HttpsFiles;

/// The keys of `[http.tls]`'s files.
const HTTPS_KEYS: [&str; 3] = ["http.tls.cert", "http.tls.key", "http.tls.ca"];

impl Check<Start<'_>> for HttpsFiles {
    fn check(&self, start: &Start<'_>, cx: &mut Cx) {
        if !HTTPS_KEYS.iter().any(|k| start.refused(k)) {
            cx.issues.extend(http_tls_issues(start.config));
        }
    }
}

impl Check<ApiChange<'_>> for HttpsFiles {
    fn check(&self, change: &ApiChange<'_>, cx: &mut Cx) {
        let new = change.new.http.tls.as_ref();
        let old = change.in_force.http.tls.as_ref();
        let files: [fn(&HttpTlsConfig) -> Option<&Path>; 3] = [
            |t| Some(t.cert.as_path()),
            |t| Some(t.key.as_path()),
            |t| t.ca.as_deref(),
        ];
        for (key, file) in HTTPS_KEYS.iter().zip(files) {
            change.config_file(cx, key, new.and_then(file), old.and_then(file));
        }
    }
}

/// `[http.tls]`'s files read and made into TLS settings as `run` makes them at start.
pub(crate) fn http_tls_issues(config: &Config) -> Vec<ConfigIssue> {
    let Some(tls) = config.http.tls.as_ref() else {
        return Vec::new();
    };
    match HttpTls::new(tls) {
        Ok(_) => Vec::new(),
        Err(e) => vec![http_tls_issue(&e)],
    }
}

/// An `[http.tls]` error as an issue at the key of the file.
pub(crate) fn http_tls_issue(e: &TlsError) -> ConfigIssue {
    tls_issue(e, "HTTPS", "http.tls", HTTPS_KEYS)
}

/// A TLS settings error of `section` (`name` in the message) as an issue at the key of its file
/// (`keys`: the certificate's, the private key's, the CA's), or at the section.
pub(crate) fn tls_issue(e: &TlsError, name: &str, section: &str, keys: [&str; 3]) -> ConfigIssue {
    let key = match e {
        TlsError::File { what, .. } => match *what {
            "certificate" => keys[0],
            "private key" => keys[1],
            _ => keys[2],
        },
        TlsError::Settings(_) => section,
    };
    ConfigIssue {
        path: key.to_owned(),
        message: format!("{name}: {e}"),
    }
}
