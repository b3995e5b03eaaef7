//! The Modbus/TCP Security row: the same cached FC 03 reads of the gateway over TLS (port 802's
//! protocol: TLS 1.3, a client certificate with the role extension) against plain Modbus TCP,
//! both served by the gateway from one polled line. The ratio is what TLS costs.
//!
//! The certificates are made here (rcgen): a CA, the server's certificate for `localhost`, and a
//! client certificate with the role `bench` (extension 1.3.6.1.4.1.50316.802.1, a UTF8String),
//! which has every right.

use std::path::PathBuf;
use std::sync::Arc;

use gateway::modbus_tcp::{RoleRights, Roles, TlsFiles, TlsServer};
use rcgen::{BasicConstraints, CertificateParams, CustomExtension, IsCa, Issuer, KeyPair};
use rustls::RootCertStore;
use rustls_pki_types::{CertificateDer, PrivateKeyDer, PrivatePkcs8KeyDer};
use tokio_rustls::TlsConnector;

/// The role of the bench's client certificate.
const ROLE: &str = "bench";
/// The role extension's OID (MODBUS/TCP Security: 1.3.6.1.4.1.50316.802.1), as rcgen takes it.
const ROLE_OID: [u64; 9] = [1, 3, 6, 1, 4, 1, 50316, 802, 1];

/// The server's TLS settings and a client connector with the role's certificate; the files live
/// in a directory removed when this is dropped.
pub(crate) struct BenchTls {
    pub(crate) server: TlsServer,
    pub(crate) connector: TlsConnector,
    dir: PathBuf,
}

impl Drop for BenchTls {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn other(e: impl std::fmt::Display) -> std::io::Error {
    std::io::Error::other(e.to_string())
}

/// Makes the CA, the server's and the client's certificates, the server and the connector.
pub(crate) fn make() -> std::io::Result<BenchTls> {
    let dir = std::env::temp_dir().join(format!("gateway-bench-tls-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;

    let ca_key = KeyPair::generate().map_err(other)?;
    let mut ca_params = CertificateParams::new(Vec::<String>::new()).map_err(other)?;
    ca_params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    let ca = ca_params.self_signed(&ca_key).map_err(other)?;
    let ca_der = ca.der().clone();
    let issuer = Issuer::new(ca_params, ca_key);

    let server_key = KeyPair::generate().map_err(other)?;
    let server = CertificateParams::new(vec!["localhost".to_owned()])
        .map_err(other)?
        .signed_by(&server_key, &issuer)
        .map_err(other)?;

    let client_key = KeyPair::generate().map_err(other)?;
    let mut client_params = CertificateParams::new(vec!["bench".to_owned()]).map_err(other)?;
    let mut role = vec![0x0C, u8::try_from(ROLE.len()).map_err(other)?];
    role.extend(ROLE.as_bytes());
    client_params
        .custom_extensions
        .push(CustomExtension::from_oid_content(&ROLE_OID, role));
    let client = client_params
        .signed_by(&client_key, &issuer)
        .map_err(other)?;

    let files = TlsFiles {
        cert: dir.join("server.crt"),
        key: dir.join("server.key"),
        ca: dir.join("ca.crt"),
    };
    std::fs::write(&files.cert, server.pem())?;
    std::fs::write(&files.key, server_key.serialize_pem())?;
    std::fs::write(&files.ca, ca.pem())?;
    let roles: Roles = [(ROLE.to_owned(), RoleRights::all())].into_iter().collect();
    let tls_server = TlsServer::new(files, roles).map_err(other)?;

    let mut roots = RootCertStore::empty();
    roots.add(ca_der).map_err(other)?;
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let key: PrivateKeyDer<'static> = PrivatePkcs8KeyDer::from(client_key.serialize_der()).into();
    let config = rustls::ClientConfig::builder_with_provider(provider)
        .with_protocol_versions(&[&rustls::version::TLS13])
        .map_err(other)?
        .with_root_certificates(roots)
        .with_client_auth_cert(vec![CertificateDer::from(client.der().to_vec())], key)
        .map_err(other)?;
    Ok(BenchTls {
        server: tls_server,
        connector: TlsConnector::from(Arc::new(config)),
        dir,
    })
}
