//! Modbus/TCP Security (MODBUS/TCP Security Protocol Specification, MB-TCP-Security-v21, 2018):
//! the Modbus TCP server over TLS, with the client's role taken from its certificate.
//!
//! The rules of the specification this module encodes:
//!
//! - TLS 1.2 or later; the server offers TLS 1.3 and 1.2 and nothing older;
//! - mutual authentication with X.509v3 certificates: the server shows its certificate and
//!   requires one from the client, verified against the configured CA (chain, validity period,
//!   signature). A client without a certificate, with one from another CA or an expired one fails
//!   the handshake and is never served;
//! - the client's role is the X.509v3 extension with OID 1.3.6.1.4.1.50316.802.1 of its
//!   certificate, an ASN.1 UTF8String; authorization is decided from the role (see
//!   [`super::access`]). A certificate without that extension, or with a role that is not
//!   configured, passes the handshake and has no rights: every request is answered with the
//!   authorization failure (exception 01);
//! - port 802 is the registered port of the protocol (the default of `[modbus_tcp.tls] listen`).
//!
//! The framing, validation, limits and connection handling are the plain server's: the TLS
//! stream is served by the same connection task.
//!
//! The certificate, key and CA are read from files and can be read again ([`TlsServer::reload`],
//! on SIGHUP and on a configuration reload): new connections get the new ones, connections
//! already open keep their session, nobody is dropped. A reload that fails (missing file, bad
//! PEM, key not matching) keeps what is in force.

use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, PoisonError, RwLock};

use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use rustls::server::WebPkiClientVerifier;
use rustls::{RootCertStore, ServerConfig};
use tokio_rustls::TlsAcceptor;

use super::access::Roles;

/// The role extension's OID (MODBUS/TCP Security, "Role-based client authorization").
pub const ROLE_OID: &str = "1.3.6.1.4.1.50316.802.1";

/// The files a Modbus/TCP Security server reads.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TlsFiles {
    /// The server's certificate chain (PEM), its own certificate first.
    pub cert: PathBuf,
    /// The server's private key (PEM: PKCS#8, PKCS#1 or SEC1).
    pub key: PathBuf,
    /// The CA certificates client certificates must chain to (PEM).
    pub ca: PathBuf,
}

/// Why the TLS settings could not be made.
#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    /// A file could not be read or holds no usable PEM item.
    #[error("{what} {path}: {message}")]
    File {
        what: &'static str,
        path: PathBuf,
        message: String,
    },
    /// rustls refused the settings (a key not matching the certificate, a bad CA).
    #[error("TLS settings: {0}")]
    Settings(String),
}

/// The TLS settings and roles of a running Modbus/TCP Security server, replaceable while it runs.
#[derive(Clone)]
pub struct TlsServer {
    inner: Arc<Inner>,
}

struct Inner {
    state: RwLock<State>,
}

struct State {
    files: TlsFiles,
    roles: Arc<Roles>,
    acceptor: TlsAcceptor,
}

impl fmt::Debug for TlsServer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let state = self
            .inner
            .state
            .read()
            .unwrap_or_else(PoisonError::into_inner);
        f.debug_struct("TlsServer")
            .field("files", &state.files)
            .field("roles", &state.roles.keys().collect::<Vec<_>>())
            .finish()
    }
}

// === impl TlsServer ===

impl TlsServer {
    /// Reads the files and makes the server's TLS settings.
    pub fn new(files: TlsFiles, roles: Roles) -> Result<Self, TlsError> {
        let acceptor = acceptor(&files)?;
        Ok(Self {
            inner: Arc::new(Inner {
                state: RwLock::new(State {
                    files,
                    roles: Arc::new(roles),
                    acceptor,
                }),
            }),
        })
    }

    /// Reads the same files again (a renewed certificate, key or CA). On error what is in force
    /// stays.
    pub fn reload(&self) -> Result<(), TlsError> {
        let files = self.state().files.clone();
        let acceptor = acceptor(&files)?;
        self.write().acceptor = acceptor;
        Ok(())
    }

    /// Takes other files and roles (a configuration change). On error what is in force stays.
    pub fn replace(&self, files: TlsFiles, roles: Roles) -> Result<(), TlsError> {
        let acceptor = acceptor(&files)?;
        *self.write() = State {
            files,
            roles: Arc::new(roles),
            acceptor,
        };
        Ok(())
    }

    /// The acceptor for a new connection.
    pub(crate) fn acceptor(&self) -> TlsAcceptor {
        self.state().acceptor.clone()
    }

    /// The roles for a new connection.
    pub(crate) fn roles(&self) -> Arc<Roles> {
        Arc::clone(&self.state().roles)
    }

    fn state(&self) -> std::sync::RwLockReadGuard<'_, State> {
        self.inner
            .state
            .read()
            .unwrap_or_else(PoisonError::into_inner)
    }

    fn write(&self) -> std::sync::RwLockWriteGuard<'_, State> {
        self.inner
            .state
            .write()
            .unwrap_or_else(PoisonError::into_inner)
    }
}

fn file_error(what: &'static str, path: &Path, message: impl fmt::Display) -> TlsError {
    TlsError::File {
        what,
        path: path.to_owned(),
        message: message.to_string(),
    }
}

pub(crate) fn certificates(
    what: &'static str,
    path: &Path,
) -> Result<Vec<CertificateDer<'static>>, TlsError> {
    let certs = CertificateDer::pem_file_iter(path)
        .map_err(|e| file_error(what, path, e))?
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| file_error(what, path, e))?;
    if certs.is_empty() {
        return Err(file_error(what, path, "no CERTIFICATE in the file"));
    }
    Ok(certs)
}

/// The acceptor for `files`: TLS 1.3 and 1.2 with the ring provider, client certificates required
/// and verified against the CA.
fn acceptor(files: &TlsFiles) -> Result<TlsAcceptor, TlsError> {
    let config = server_config(&files.cert, &files.key, Some(&files.ca))?;
    Ok(TlsAcceptor::from(Arc::new(config)))
}

/// TLS server settings from PEM files: TLS 1.3 and 1.2 with the ring provider, the certificate
/// chain `cert` and its key; with `ca`, client certificates are required and verified against
/// it (chain, validity, signature), without, none is asked for. Shared by Modbus/TCP Security
/// and the HTTPS listener.
pub(crate) fn server_config(
    cert: &Path,
    key: &Path,
    ca: Option<&Path>,
) -> Result<ServerConfig, TlsError> {
    let chain = certificates("certificate", cert)?;
    let key = PrivateKeyDer::from_pem_file(key).map_err(|e| file_error("private key", key, e))?;
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = ServerConfig::builder_with_provider(provider.clone())
        .with_protocol_versions(&[&rustls::version::TLS13, &rustls::version::TLS12])
        .map_err(|e| TlsError::Settings(e.to_string()))?;
    let builder = match ca {
        Some(ca) => {
            let mut roots = RootCertStore::empty();
            for cert in certificates("CA certificate", ca)? {
                roots
                    .add(cert)
                    .map_err(|e| file_error("CA certificate", ca, e))?;
            }
            let verifier = WebPkiClientVerifier::builder_with_provider(Arc::new(roots), provider)
                .build()
                .map_err(|e| TlsError::Settings(e.to_string()))?;
            builder.with_client_cert_verifier(verifier)
        }
        None => builder.with_no_client_auth(),
    };
    builder
        .with_single_cert(chain, key)
        .map_err(|e| TlsError::Settings(e.to_string()))
}

/// The role of a client certificate (DER): the UTF8String of its role extension, if it has one.
pub fn role_of(certificate: &[u8]) -> Option<String> {
    let (_, parsed) = x509_parser::parse_x509_certificate(certificate).ok()?;
    let extension = parsed
        .extensions()
        .iter()
        .find(|e| e.oid.to_id_string() == ROLE_OID)?;
    utf8_string(extension.value)
}

/// The text of a DER UTF8String (tag 0x0C, definite length) that fills `der` exactly.
fn utf8_string(der: &[u8]) -> Option<String> {
    const UTF8_STRING: u8 = 0x0C;
    let (&tag, rest) = der.split_first()?;
    if tag != UTF8_STRING {
        return None;
    }
    let (&first, rest) = rest.split_first()?;
    let (len, body) = if first < 0x80 {
        (usize::from(first), rest)
    } else {
        let n = usize::from(first & 0x7F);
        if n == 0 || n > 2 {
            return None;
        }
        let (bytes, body) = rest.split_at_checked(n)?;
        let len = bytes
            .iter()
            .fold(0usize, |len, &b| (len << 8) | usize::from(b));
        (len, body)
    };
    if body.len() != len {
        return None;
    }
    String::from_utf8(body.to_vec()).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_utf8_string_is_read_in_both_length_forms() {
        assert_eq!(
            utf8_string(b"\x0c\x08operator").as_deref(),
            Some("operator")
        );
        let long = "r".repeat(200);
        let mut der = vec![0x0C, 0x81, 200];
        der.extend(long.as_bytes());
        assert_eq!(utf8_string(&der), Some(long));
    }

    #[test]
    fn anything_else_is_no_role() {
        // PrintableString, a short body, trailing bytes, bad UTF-8, an indefinite length.
        assert_eq!(utf8_string(b"\x13\x02ab"), None);
        assert_eq!(utf8_string(b"\x0c\x05ab"), None);
        assert_eq!(utf8_string(b"\x0c\x01ab"), None);
        assert_eq!(utf8_string(b"\x0c\x01\xff"), None);
        assert_eq!(utf8_string(b"\x0c\x80ab\x00\x00"), None);
        assert_eq!(utf8_string(b""), None);
        assert_eq!(role_of(b"not a certificate"), None);
    }
}
