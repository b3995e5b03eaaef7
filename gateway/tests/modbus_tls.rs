//! Modbus/TCP Security on real sockets (127.0.0.1, port 0) with certificates made here (rcgen): a
//! CA, a server certificate, client certificates with the role extension. pymodbus (the real
//! Python package) is the client of the role tests; a rustls client makes the handshakes the
//! server must refuse.

// The helpers of the plain server's tests; this file uses some of them.
#[allow(dead_code)]
#[path = "modbus_tcp/support.rs"]
mod support;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Arc, RwLock};

use gateway::modbus_tcp::{
    bind, serve_tls, RoleRights, Roles, ServerOptions, ServerStats, TlsFiles, TlsServer, ROLE_OID,
};
use gateway::unit::write_policy::{WriteRange, WriteTable};
use gateway::unit::{SharedUnits, UnitMap};
use rcgen::{
    BasicConstraints, CertificateParams, CustomExtension, DnType, IsCa, Issuer, KeyPair,
    KeyUsagePurpose,
};
use rustls::pki_types::{CertificateDer, PrivateKeyDer, PrivatePkcs8KeyDer, ServerName};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_rustls::client::TlsStream;
use tokio_rustls::TlsConnector;
use tokio_util::sync::CancellationToken;

use support::{adu, eventually, within, MemoryUnit, PATIENCE};

// === certificates ===

/// A CA that signs server and client certificates.
struct Ca {
    cert: rcgen::Certificate,
    issuer: Issuer<'static, KeyPair>,
}

impl Ca {
    fn new(name: &str) -> Self {
        let key = KeyPair::generate().expect("CA key");
        let mut params = CertificateParams::new(Vec::<String>::new()).expect("CA params");
        params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
        params.distinguished_name.push(DnType::CommonName, name);
        params.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
        let cert = params.self_signed(&key).expect("CA certificate");
        Self {
            cert,
            issuer: Issuer::new(params, key),
        }
    }

    /// A certificate for `names` (SANs), with `role` in the role extension when given.
    fn sign(&self, names: &[&str], role: Option<&str>, expired: bool) -> Leaf {
        let key = KeyPair::generate().expect("key");
        let names: Vec<String> = names.iter().map(|&n| n.to_owned()).collect();
        let mut params = CertificateParams::new(names).expect("params");
        params
            .distinguished_name
            .push(DnType::CommonName, role.unwrap_or("no role"));
        if let Some(role) = role {
            params
                .custom_extensions
                .push(CustomExtension::from_oid_content(
                    &role_oid(),
                    utf8_string(role),
                ));
        }
        if expired {
            params.not_before = rcgen::date_time_ymd(2020, 1, 1);
            params.not_after = rcgen::date_time_ymd(2021, 1, 1);
        }
        let cert = params.signed_by(&key, &self.issuer).expect("sign");
        Leaf { cert, key }
    }
}

struct Leaf {
    cert: rcgen::Certificate,
    key: KeyPair,
}

impl Leaf {
    fn chain(&self) -> Vec<CertificateDer<'static>> {
        vec![self.cert.der().clone()]
    }

    fn key_der(&self) -> PrivateKeyDer<'static> {
        PrivateKeyDer::Pkcs8(PrivatePkcs8KeyDer::from(self.key.serialize_der()))
    }

    /// Writes `<name>.crt` and `<name>.key` into `dir`.
    fn write(&self, dir: &Path, name: &str) -> (PathBuf, PathBuf) {
        let cert = dir.join(format!("{name}.crt"));
        let key = dir.join(format!("{name}.key"));
        std::fs::write(&cert, self.cert.pem()).expect("write certificate");
        std::fs::write(&key, self.key.serialize_pem()).expect("write key");
        (cert, key)
    }
}

fn role_oid() -> Vec<u64> {
    ROLE_OID
        .split('.')
        .map(|arc| arc.parse().expect("OID arc"))
        .collect()
}

/// DER UTF8String (short length form: roles here are short).
fn utf8_string(text: &str) -> Vec<u8> {
    let len = u8::try_from(text.len()).expect("short role");
    assert!(len < 0x80);
    let mut der = vec![0x0C, len];
    der.extend(text.as_bytes());
    der
}

// === the server ===

struct TlsTest {
    dir: tempfile::TempDir,
    ca: Ca,
    addr: SocketAddr,
    memory: Arc<MemoryUnit>,
    stats: Arc<ServerStats>,
    tls: TlsServer,
    shutdown: CancellationToken,
    task: tokio::task::JoinHandle<std::io::Result<()>>,
}

/// operator: units 1, read, write registers 10..=29 of unit 1; viewer: read only.
fn roles() -> Roles {
    let operator = RoleRights {
        units: Some(vec![1]),
        read: true,
        write: true,
        diagnostics: false,
        write_ranges: Some(vec![WriteRange {
            unit: 1,
            table: WriteTable::HoldingRegisters,
            first: 10,
            last: 29,
        }]),
    };
    let viewer = RoleRights {
        read: true,
        ..RoleRights::default()
    };
    Roles::from([
        ("operator".to_owned(), operator),
        ("viewer".to_owned(), viewer),
    ])
}

async fn start() -> TlsTest {
    let dir = tempfile::tempdir().expect("temp dir");
    let ca = Ca::new("plant CA");
    std::fs::write(dir.path().join("ca.crt"), ca.cert.pem()).expect("write CA");
    let server = ca.sign(&["localhost", "127.0.0.1"], None, false);
    let (cert, key) = server.write(dir.path(), "server");
    let files = TlsFiles {
        cert,
        key,
        ca: dir.path().join("ca.crt"),
    };
    let tls = TlsServer::new(files, roles()).expect("TLS settings");
    let memory = MemoryUnit::new(100);
    let mut map = UnitMap::new();
    map.insert(1, memory.clone());
    let units: SharedUnits = Arc::new(RwLock::new(map));
    let listener = bind(([127, 0, 0, 1], 0).into()).expect("bind");
    let addr = listener.local_addr().expect("local addr");
    let stats = Arc::new(ServerStats::new());
    let shutdown = CancellationToken::new();
    let task = tokio::spawn(serve_tls(
        listener,
        units,
        ServerOptions::default(),
        tls.clone(),
        shutdown.clone(),
        stats.clone(),
    ));
    TlsTest {
        dir,
        ca,
        addr,
        memory,
        stats,
        tls,
        shutdown,
        task,
    }
}

impl TlsTest {
    /// Writes a client certificate of this CA with `role` and returns its file names.
    fn client_files(&self, name: &str, role: Option<&str>) -> (PathBuf, PathBuf) {
        self.ca
            .sign(&["client"], role, false)
            .write(self.dir.path(), name)
    }

    fn ca_file(&self) -> PathBuf {
        self.dir.path().join("ca.crt")
    }

    /// A rustls client trusting this CA, showing `client` (or no certificate).
    async fn connect(&self, client: Option<&Leaf>) -> std::io::Result<TlsStream<TcpStream>> {
        let mut roots = rustls::RootCertStore::empty();
        roots.add(self.ca.cert.der().clone()).expect("root");
        let provider = Arc::new(rustls::crypto::ring::default_provider());
        let builder = rustls::ClientConfig::builder_with_provider(provider)
            .with_safe_default_protocol_versions()
            .expect("versions")
            .with_root_certificates(roots);
        let config = match client {
            Some(leaf) => builder
                .with_client_auth_cert(leaf.chain(), leaf.key_der())
                .expect("client certificate"),
            None => builder.with_no_client_auth(),
        };
        let tcp = TcpStream::connect(self.addr).await?;
        let name = ServerName::try_from("localhost").expect("name");
        TlsConnector::from(Arc::new(config))
            .connect(name, tcp)
            .await
    }

    async fn stop(self) {
        self.shutdown.cancel();
        let result = tokio::time::timeout(PATIENCE, self.task)
            .await
            .expect("serve returns")
            .expect("no panic");
        result.expect("serve ends with Ok");
    }
}

/// Sends FC 03 for `count` registers from `address` of unit 1; the response PDU, or the error
/// that ended the connection.
async fn read_registers<S>(stream: &mut S, address: u16, count: u16) -> std::io::Result<Vec<u8>>
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin,
{
    let [ah, al] = address.to_be_bytes();
    let [ch, cl] = count.to_be_bytes();
    request(stream, &[0x03, ah, al, ch, cl]).await
}

async fn request<S>(stream: &mut S, pdu: &[u8]) -> std::io::Result<Vec<u8>>
where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin,
{
    stream.write_all(&adu(7, 1, pdu)).await?;
    stream.flush().await?;
    let mut header = [0u8; 7];
    stream.read_exact(&mut header).await?;
    let len = usize::from(u16::from_be_bytes([header[4], header[5]]));
    let mut pdu = vec![0u8; len.saturating_sub(1)];
    stream.read_exact(&mut pdu).await?;
    Ok(pdu)
}

// === pymodbus ===

/// A Python with pymodbus: `<workspace>/.venv-sec` or `<workspace>/.venv` (where `.ci/run`
/// installs it).
fn python() -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    for venv in [".venv-sec", ".venv"] {
        let python = root.join(venv).join("bin/python");
        let has_pymodbus = Command::new(&python)
            .args(["-c", "import pymodbus"])
            .output()
            .is_ok_and(|out| out.status.success());
        if has_pymodbus {
            return python;
        }
    }
    panic!(
        "pymodbus not found: run `python3 -m venv .venv && .venv/bin/pip install pymodbus` at {}",
        root.display()
    );
}

/// Runs the pymodbus client with the certificate `files` against unit 1; its output lines.
async fn pymodbus(test: &TlsTest, files: &(PathBuf, PathBuf), ops: &[&str]) -> Vec<String> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/modbus_tls/client.py");
    let mut command = tokio::process::Command::new(python());
    command
        .arg(script)
        .arg(test.addr.port().to_string())
        .arg(test.ca_file())
        .arg(&files.0)
        .arg(&files.1)
        .arg("1")
        .args(ops)
        .kill_on_drop(true);
    let out = within("the pymodbus client", command.output())
        .await
        .expect("run pymodbus");
    assert!(
        out.status.success(),
        "pymodbus client failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(str::to_owned)
        .collect()
}

// === the tests ===

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pymodbus_operator_reads_and_writes_and_a_viewer_write_is_refused_with_01() {
    let test = start().await;
    let operator = test.client_files("operator", Some("operator"));
    let lines = pymodbus(&test, &operator, &["r:10:3", "w:20:7", "r:20:1", "w:40:1"]).await;
    // The write outside the operator's ranges is the authorization failure too.
    assert_eq!(
        lines,
        ["connected", "ok 10,11,12", "ok", "ok 7", "exception 1"]
    );
    assert_eq!(test.memory.register(20), Some(7));
    assert_eq!(test.memory.register(40), Some(40));

    let viewer = test.client_files("viewer", Some("viewer"));
    let lines = pymodbus(&test, &viewer, &["r:20:2", "w:21:99"]).await;
    assert_eq!(lines, ["connected", "ok 7,21", "exception 1"]);
    assert_eq!(
        test.memory.register(21),
        Some(21),
        "the refused write left no trace"
    );
    assert_eq!(test.stats.refused("viewer"), 1);
    assert_eq!(test.stats.refused("operator"), 1);
    assert_eq!(test.stats.handshakes_failed(), 0);
    test.stop().await;
}

/// The handshake ends with the server's alert; with TLS 1.3 the client learns it at its first
/// read. Either way no request is answered and nothing is served.
async fn assert_refused_at_handshake(test: &TlsTest, client: Option<&Leaf>, what: &str) {
    let before = test.stats.handshakes_failed();
    match test.connect(client).await {
        Err(_) => {}
        Ok(mut stream) => {
            let answer = within(what, read_registers(&mut stream, 0, 1)).await;
            assert!(answer.is_err(), "{what}: answered {answer:?}");
        }
    }
    eventually(what, || test.stats.handshakes_failed() == before + 1).await;
    assert_eq!(test.stats.connections_accepted(), 0, "{what}: served");
}

#[tokio::test]
async fn clients_without_a_valid_certificate_are_refused_at_the_handshake() {
    let test = start().await;
    assert_refused_at_handshake(&test, None, "no client certificate").await;
    let other_ca = Ca::new("office CA");
    let foreign = other_ca.sign(&["client"], Some("operator"), false);
    assert_refused_at_handshake(&test, Some(&foreign), "a certificate of another CA").await;
    let expired = test.ca.sign(&["client"], Some("operator"), true);
    assert_refused_at_handshake(&test, Some(&expired), "an expired certificate").await;
    // pymodbus without a certificate the server trusts does not get a connection either.
    let files = other_ca
        .sign(&["client"], Some("operator"), false)
        .write(test.dir.path(), "foreign");
    let lines = pymodbus(&test, &files, &["r:10:1"]).await;
    assert!(
        lines.first().map(String::as_str) == Some("not connected")
            || lines.get(1).is_some_and(|l| l.starts_with("error")),
        "pymodbus with a foreign certificate: {lines:?}"
    );
    assert_eq!(test.stats.connections_accepted(), 0);
    assert_eq!(test.memory.register(10), Some(10));
    test.stop().await;
}

#[tokio::test]
async fn a_certificate_without_the_role_extension_has_no_rights() {
    let test = start().await;
    let no_role = test.ca.sign(&["client"], None, false);
    let mut stream = test.connect(Some(&no_role)).await.expect("handshake");
    let read = read_registers(&mut stream, 10, 1).await.expect("answered");
    assert_eq!(read, [0x83, 0x01]);
    let write = request(&mut stream, &[0x06, 0, 20, 0, 9])
        .await
        .expect("answered");
    assert_eq!(write, [0x86, 0x01]);
    assert_eq!(test.memory.register(20), Some(20));
    // A role the configuration does not know is no better.
    let admin = test.ca.sign(&["client"], Some("admin"), false);
    let mut stream = test.connect(Some(&admin)).await.expect("handshake");
    let read = read_registers(&mut stream, 10, 1).await.expect("answered");
    assert_eq!(read, [0x83, 0x01]);
    assert_eq!(test.stats.refused("none"), 2);
    assert_eq!(test.stats.refused("unknown"), 1);
    test.stop().await;
}

#[tokio::test]
async fn a_certificate_reload_keeps_a_connected_client_working() {
    let test = start().await;
    let operator = test.ca.sign(&["client"], Some("operator"), false);
    let mut old_client = test.connect(Some(&operator)).await.expect("handshake");
    let before = read_registers(&mut old_client, 10, 1).await.expect("read");
    assert_eq!(before, [0x03, 2, 0, 10]);
    let old_server_cert = old_client
        .get_ref()
        .1
        .peer_certificates()
        .and_then(<[_]>::first)
        .expect("server certificate")
        .clone();

    // A renewed server certificate (new key) in the same files.
    let renewed = test.ca.sign(&["localhost", "127.0.0.1"], None, false);
    renewed.write(test.dir.path(), "server");
    test.tls.reload().expect("reload");

    let after = read_registers(&mut old_client, 11, 1).await.expect("read");
    assert_eq!(
        after,
        [0x03, 2, 0, 11],
        "the connected client keeps its session"
    );
    let mut new_client = test.connect(Some(&operator)).await.expect("handshake");
    let new_server_cert = new_client
        .get_ref()
        .1
        .peer_certificates()
        .and_then(<[_]>::first)
        .expect("server certificate")
        .clone();
    assert_ne!(new_server_cert, old_server_cert);
    assert_eq!(&new_server_cert, renewed.cert.der());
    let read = read_registers(&mut new_client, 12, 1).await.expect("read");
    assert_eq!(read, [0x03, 2, 0, 12]);

    // A reload that fails (a key that is not PEM) keeps what is in force.
    std::fs::write(test.dir.path().join("server.key"), "garbage").expect("write");
    assert!(test.tls.reload().is_err());
    let mut third = test.connect(Some(&operator)).await.expect("handshake");
    let read = read_registers(&mut third, 13, 1).await.expect("read");
    assert_eq!(read, [0x03, 2, 0, 13]);
    let read = read_registers(&mut old_client, 14, 1).await.expect("read");
    assert_eq!(read, [0x03, 2, 0, 14]);
    test.stop().await;
}
