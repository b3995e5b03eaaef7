//! End to end on the binary: Modbus/TCP Security from `[modbus_tcp.tls]`, a KS vario simulator
//! behind it, pymodbus (the real Python package) as the TLS client, certificates made here
//! (rcgen), the server certificate renewed and read again on SIGHUP.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use gateway_tests::{device_sim, temp_dir, Gateway, SocatLink};
use rcgen::{
    BasicConstraints, CertificateParams, CustomExtension, DnType, IsCa, Issuer, KeyPair,
    KeyUsagePurpose,
};

/// The role extension (MODBUS/TCP Security): OID 1.3.6.1.4.1.50316.802.1, a UTF8String.
const ROLE_OID: [u64; 9] = [1, 3, 6, 1, 4, 1, 50316, 802, 1];
/// KS vario input registers 1004..1006 of the simulator (README).
const KS_WORDS: &str = "ok 1066,140,4158";

struct Ca {
    pem: String,
    issuer: Issuer<'static, KeyPair>,
}

impl Ca {
    fn new() -> Self {
        let key = KeyPair::generate().expect("CA key");
        let mut params = CertificateParams::new(Vec::<String>::new()).expect("CA params");
        params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
        params
            .distinguished_name
            .push(DnType::CommonName, "plant CA");
        params.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
        let pem = params.self_signed(&key).expect("CA certificate").pem();
        Self {
            pem,
            issuer: Issuer::new(params, key),
        }
    }

    /// Writes `<name>.crt` and `<name>.key` signed by this CA, with `role` when given.
    fn write(&self, dir: &Path, name: &str, role: Option<&str>) -> (PathBuf, PathBuf) {
        let key = KeyPair::generate().expect("key");
        let mut params =
            CertificateParams::new(vec!["localhost".to_owned(), "127.0.0.1".to_owned()])
                .expect("params");
        params.distinguished_name.push(DnType::CommonName, name);
        if let Some(role) = role {
            let mut der = vec![0x0C, u8::try_from(role.len()).expect("short role")];
            der.extend(role.as_bytes());
            params
                .custom_extensions
                .push(CustomExtension::from_oid_content(&ROLE_OID, der));
        }
        let cert = params.signed_by(&key, &self.issuer).expect("sign");
        let (cert_file, key_file) = (
            dir.join(format!("{name}.crt")),
            dir.join(format!("{name}.key")),
        );
        std::fs::write(&cert_file, cert.pem()).expect("write certificate");
        std::fs::write(&key_file, key.serialize_pem()).expect("write key");
        (cert_file, key_file)
    }
}

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// A Python with pymodbus: `<workspace>/.venv-sec` or `<workspace>/.venv` (`.ci/run`).
fn python() -> PathBuf {
    for venv in [".venv-sec", ".venv"] {
        let python = root().join(venv).join("bin/python");
        if Command::new(&python)
            .args(["-c", "import pymodbus"])
            .output()
            .is_ok_and(|out| out.status.success())
        {
            return python;
        }
    }
    panic!(
        "pymodbus not found: run `python3 -m venv .venv && .venv/bin/pip install pymodbus` at {}",
        root().display()
    );
}

/// Runs the pymodbus TLS client against `unit` on `port`; its output lines.
fn pymodbus(
    port: u16,
    ca: &Path,
    files: &(PathBuf, PathBuf),
    unit: u8,
    ops: &[&str],
) -> Vec<String> {
    let out = Command::new(python())
        .arg(root().join("gateway/tests/modbus_tls/client.py"))
        .arg(port.to_string())
        .arg(ca)
        .arg(&files.0)
        .arg(&files.1)
        .arg(unit.to_string())
        .args(ops)
        .output()
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

#[test]
fn modbus_tcp_security_serves_roles_and_reloads_on_sighup() {
    let dir = temp_dir("modbus-tls");
    let link = SocatLink::new(&dir, "ks");
    let _sim = device_sim("ksvario", &link.b);
    let ca = Ca::new();
    let ca_file = dir.join("ca.crt");
    std::fs::write(&ca_file, &ca.pem).expect("write CA");
    let (cert, key) = ca.write(&dir, "server", None);
    let config = format!(
        r#"
[gateway]
name = "sec"

[modbus_tcp]
listen = "127.0.0.1:0"

[modbus_tcp.tls]
listen = "127.0.0.1:0"
cert = "{cert}"
key = "{key}"
ca = "{ca}"

[modbus_tcp.tls.roles.operator]
units = [17]
functions = ["read", "write"]

[modbus_tcp.tls.roles.viewer]
functions = ["read"]

[lines.ks]
port = "{port}"
protocol = "modbus-master-rtu"
baud = 19200
parity = "even"
reply_timeout = "300ms"

[lines.ks.devices.ks]
profile = "ksvario"
address = 17
unit_id = 17

[[lines.ks.devices.ks.poll]]
name = "process"
period = "100ms"
ranges = [{{ table = "input", start = 1004, count = 3 }}]
"#,
        cert = cert.display(),
        key = key.display(),
        ca = ca_file.display(),
        port = link.a.display(),
    );
    let file = dir.join("gateway.toml");
    std::fs::write(&file, config).expect("write config");
    let mut gw = Gateway::run(&file);
    // Printed before the plain server's line, which `run` waited for.
    let output = gw.output();
    let port: u16 = output
        .lines()
        .find_map(|l| l.strip_prefix("modbus-tcp-tls listening on "))
        .and_then(|addr| addr.trim().rsplit(':').next()?.parse().ok())
        .unwrap_or_else(|| panic!("no Modbus/TCP Security address in:\n{output}"));

    let operator = ca.write(&dir, "operator", Some("operator"));
    let viewer = ca.write(&dir, "viewer", Some("viewer"));
    let no_role = ca.write(&dir, "nobody", None);

    // The operator reads the KS vario once the first poll filled the image.
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let lines = pymodbus(port, &ca_file, &operator, 17, &["i:1004:3"]);
        if lines.get(1).map(String::as_str) == Some(KS_WORDS) {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "unit 17 never answered: {lines:?}"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    // A unit outside the operator's units and a viewer's write: exception 01.
    let lines = pymodbus(port, &ca_file, &operator, 2, &["r:3102:1"]);
    assert_eq!(lines, ["connected", "exception 1"]);
    let lines = pymodbus(port, &ca_file, &viewer, 17, &["i:1004:3", "w:0:1"]);
    assert_eq!(lines, ["connected", KS_WORDS, "exception 1"]);
    let lines = pymodbus(port, &ca_file, &no_role, 17, &["i:1004:3"]);
    assert_eq!(lines, ["connected", "exception 1"]);

    // A renewed server certificate in the same files, read again on SIGHUP.
    let before = pymodbus(port, &ca_file, &operator, 17, &["cert:-:-"]);
    ca.write(&dir, "server", None);
    let status = Command::new("kill")
        .args(["-HUP", &gw.pid().to_string()])
        .status()
        .expect("kill -HUP");
    assert!(status.success());
    gw.wait_for("certificates read again", Duration::from_secs(5));
    let after = pymodbus(port, &ca_file, &operator, 17, &["cert:-:-", "i:1004:3"]);
    assert_eq!(after.len(), 3, "{after:?}");
    assert_ne!(
        before.get(1),
        after.get(1),
        "the renewed certificate is served"
    );
    assert_eq!(after[2], KS_WORDS);

    // The refusals are counted per role on /metrics.
    let http = gw.http.expect("http");
    let metrics = std::net::TcpStream::connect(http)
        .and_then(|mut s| {
            use std::io::{Read, Write};
            s.write_all(b"GET /metrics HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")?;
            let mut text = String::new();
            s.read_to_string(&mut text)?;
            Ok(text)
        })
        .expect("scrape");
    for role in ["operator", "viewer", "none"] {
        let series = format!("gateway_modbus_tcp_refused_total{{role=\"{role}\"}} 1");
        assert!(metrics.contains(&series), "no {series} in:\n{metrics}");
    }
    // The viewer's write is in the audit count and the audit log, with its source.
    let series = r#"gateway_writes_total{path="modbus_tcp_tls",result="refused"} 1"#;
    assert!(metrics.contains(series), "no {series} in:\n{metrics}");
    let output = gw.output();
    assert!(
        output
            .lines()
            .any(|l| l.contains("audit") && l.contains("role=viewer") && l.contains("refused")),
        "no audit line for the viewer's write:\n{output}"
    );
    gw.terminate(Duration::from_secs(10));
}
