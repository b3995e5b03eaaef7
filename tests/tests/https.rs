//! End to end on the binary: the HTTP listener with `[http.tls]`: REST with a bearer token over
//! HTTPS from curl, plain HTTP refused, and the server certificate renewed in its files and read
//! again on SIGHUP while a client stays connected (its connection goes on; a new one gets the new
//! certificate). Certificates are made here (rcgen).

use std::path::Path;
use std::process::Command;
use std::sync::Arc;
use std::time::Duration;

use gateway_tests::{temp_dir, Gateway};
use rcgen::{BasicConstraints, CertificateParams, DnType, IsCa, Issuer, KeyPair, KeyUsagePurpose};
use rustls_pki_types::pem::PemObject;
use rustls_pki_types::{CertificateDer, ServerName};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_rustls::client::TlsStream;
use tokio_rustls::TlsConnector;

const TOKEN: &str = "https-test-token-0123456789";

/// A CA and a way to (re)write the server's certificate and key signed by it.
struct Ca {
    issuer: Issuer<'static, KeyPair>,
}

impl Ca {
    fn new(dir: &Path) -> Self {
        let key = KeyPair::generate().expect("CA key");
        let mut params = CertificateParams::new(Vec::<String>::new()).expect("CA params");
        params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
        params
            .distinguished_name
            .push(DnType::CommonName, "test CA");
        params.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
        let pem = params.self_signed(&key).expect("CA certificate").pem();
        std::fs::write(dir.join("ca.crt"), pem).expect("write CA");
        Self {
            issuer: Issuer::new(params, key),
        }
    }

    /// Writes `server.crt` and `server.key` (a new key each time) for 127.0.0.1 and localhost.
    fn write_server(&self, dir: &Path, name: &str) {
        let key = KeyPair::generate().expect("key");
        let mut params =
            CertificateParams::new(vec!["localhost".to_owned(), "127.0.0.1".to_owned()])
                .expect("params");
        params.distinguished_name.push(DnType::CommonName, name);
        let cert = params.signed_by(&key, &self.issuer).expect("sign");
        // The key first: a reload between the two writes fails and keeps the old pair.
        std::fs::write(dir.join("server.key"), key.serialize_pem()).expect("write key");
        std::fs::write(dir.join("server.crt"), cert.pem()).expect("write certificate");
    }
}

/// curl with the test's CA; its stdout and whether it succeeded.
fn curl(dir: &Path, args: &[&str]) -> (bool, String) {
    let out = Command::new("curl")
        .args(["-sS", "--max-time", "10", "--cacert"])
        .arg(dir.join("ca.crt"))
        .args(args)
        .output()
        .expect("curl is needed (apt install curl)");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    )
}

fn connector(dir: &Path) -> TlsConnector {
    let mut roots = rustls::RootCertStore::empty();
    for cert in CertificateDer::pem_file_iter(dir.join("ca.crt")).expect("CA file") {
        roots.add(cert.expect("CA")).expect("add CA");
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let config = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .expect("versions")
        .with_root_certificates(roots)
        .with_no_client_auth();
    TlsConnector::from(Arc::new(config))
}

async fn connect(dir: &Path, addr: std::net::SocketAddr) -> TlsStream<TcpStream> {
    let tcp = TcpStream::connect(addr).await.expect("connect");
    connector(dir)
        .connect(ServerName::try_from("localhost").expect("name"), tcp)
        .await
        .expect("TLS handshake")
}

/// The server certificate of a connection (DER).
fn peer_certificate(s: &TlsStream<TcpStream>) -> Vec<u8> {
    s.get_ref().1.peer_certificates().expect("certificates")[0].to_vec()
}

/// `GET path` on a kept-alive connection: the status line.
async fn get(s: &mut TlsStream<TcpStream>, path: &str) -> String {
    s.write_all(format!("GET {path} HTTP/1.1\r\nHost: localhost\r\n\r\n").as_bytes())
        .await
        .expect("request");
    let mut got = Vec::new();
    let mut buf = [0u8; 8192];
    loop {
        let n = tokio::time::timeout(Duration::from_secs(10), s.read(&mut buf))
            .await
            .expect("an answer in time")
            .expect("read");
        assert!(n > 0, "closed: {}", String::from_utf8_lossy(&got));
        got.extend_from_slice(&buf[..n]);
        let text = String::from_utf8_lossy(&got);
        if let Some((head, body)) = text.split_once("\r\n\r\n") {
            let len: usize = head
                .lines()
                .find_map(|l| {
                    l.to_ascii_lowercase()
                        .strip_prefix("content-length: ")
                        .map(str::to_owned)
                })
                .and_then(|n| n.trim().parse().ok())
                .expect("content-length");
            if body.len() >= len {
                return head.lines().next().unwrap_or_default().to_owned();
            }
        }
    }
}

#[tokio::test]
async fn rest_over_https_with_a_token_and_a_certificate_renewed_on_sighup() {
    let dir = temp_dir("https");
    let ca = Ca::new(&dir);
    ca.write_server(&dir, "first");
    std::fs::write(dir.join("token"), TOKEN).expect("token");
    let config = format!(
        "[modbus_tcp]\nlisten = \"127.0.0.1:0\"\n\n[http]\ntoken_file = \"{token}\"\n\n\
         [http.tls]\ncert = \"{cert}\"\nkey = \"{key}\"\n",
        token = dir.join("token").display(),
        cert = dir.join("server.crt").display(),
        key = dir.join("server.key").display(),
    );
    let file = dir.join("gateway.toml");
    std::fs::write(&file, config).expect("config");
    assert!(
        gateway_tests::check_config(&file).0,
        "check refuses the files"
    );
    let mut gw = Gateway::run(&file);
    let http = gw.http.expect("http");
    let base = format!("https://localhost:{}", http.port());
    let resolve = format!("localhost:{}:127.0.0.1", http.port());

    // A change with the token over HTTPS from curl: validate the configuration in force.
    let (ok, body) = curl(
        &dir,
        &["--resolve", &resolve, &format!("{base}/api/v1/config")],
    );
    assert!(ok, "GET over HTTPS failed: {body}");
    let (ok, code) = curl(
        &dir,
        &[
            "--resolve",
            &resolve,
            "-o",
            "/dev/null",
            "-w",
            "%{http_code}",
            "-X",
            "POST",
            "-H",
            &format!("Authorization: Bearer {TOKEN}"),
            "-H",
            "Content-Type: application/json",
            "--data",
            &body,
            &format!("{base}/api/v1/config/validate"),
        ],
    );
    assert!(ok && code == "200", "validate with the token: {code}");
    let (_, code) = curl(
        &dir,
        &[
            "--resolve",
            &resolve,
            "-o",
            "/dev/null",
            "-w",
            "%{http_code}",
            "-X",
            "POST",
            "-H",
            "Content-Type: application/json",
            "--data",
            &body,
            &format!("{base}/api/v1/config/validate"),
        ],
    );
    assert_eq!(code, "401", "a change without the token");
    // Plain HTTP gets no answer.
    let (ok, _) = curl(&dir, &[&format!("http://{http}/healthz")]);
    assert!(!ok, "plain HTTP was answered");

    // A client that stays connected across the renewal.
    let mut kept = connect(&dir, http).await;
    assert_eq!(get(&mut kept, "/healthz").await, "HTTP/1.1 200 OK");
    let first = peer_certificate(&kept);
    ca.write_server(&dir, "second");
    let status = Command::new("kill")
        .args(["-HUP", &gw.pid().to_string()])
        .status()
        .expect("kill -HUP");
    assert!(status.success());
    gw.wait_for("HTTPS certificates read again", Duration::from_secs(5));
    assert_eq!(get(&mut kept, "/api/v1/status").await, "HTTP/1.1 200 OK");
    let mut fresh = connect(&dir, http).await;
    assert_eq!(get(&mut fresh, "/metrics").await, "HTTP/1.1 200 OK");
    assert_ne!(
        peer_certificate(&fresh),
        first,
        "the renewed certificate is not served"
    );
    assert_eq!(peer_certificate(&kept), first);
    // curl trusts the renewed one as well.
    let (ok, _) = curl(&dir, &["--resolve", &resolve, &format!("{base}/healthz")]);
    assert!(ok);

    // A renewal that cannot be read keeps what is in force.
    std::fs::write(dir.join("server.key"), "not a key").expect("write");
    Command::new("kill")
        .args(["-HUP", &gw.pid().to_string()])
        .status()
        .expect("kill -HUP");
    gw.wait_for("HTTPS certificates not reloaded", Duration::from_secs(5));
    let mut after = connect(&dir, http).await;
    assert_eq!(get(&mut after, "/healthz").await, "HTTP/1.1 200 OK");
    assert_eq!(peer_certificate(&after), peer_certificate(&fresh));
    gw.terminate(Duration::from_secs(10));
}
