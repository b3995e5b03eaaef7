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

/// A Python with pymodbus: `<workspace>/.venv-sec` or `<workspace>/.venv` (`.ci/run`).
fn python() -> PathBuf {
    for venv in [".venv-sec", ".venv"] {
        let python = gateway_tests::repo_root().join(venv).join("bin/python");
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
        gateway_tests::repo_root().display()
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
        .arg(gateway_tests::repo_root().join("gateway/tests/modbus_tls/client.py"))
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
            s.write_all(
                format!("GET /metrics HTTP/1.1\r\nHost: {http}\r\nConnection: close\r\n\r\n")
                    .as_bytes(),
            )?;
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
    let series =
        r#"gateway_writes_total{path="modbus_tcp_tls",reason="policy",result="refused"} 1"#;
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

// === one write policy: Modbus TCP, REST and zenoh ===

/// The Prometheus text of `/metrics`.
fn scrape(http: std::net::SocketAddr) -> String {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(http).expect("connect /metrics");
    s.write_all(
        format!("GET /metrics HTTP/1.1\r\nHost: {http}\r\nConnection: close\r\n\r\n").as_bytes(),
    )
    .expect("request");
    let mut text = String::new();
    s.read_to_string(&mut text).expect("read");
    text
}

/// Puts `payload` on `key` and returns the JSON result published on `key/result`.
async fn zenoh_put(session: &zenoh::Session, key: &str, payload: &str) -> serde_json::Value {
    let result = session
        .declare_subscriber(format!("{key}/result"))
        .await
        .expect("subscribe");
    session.put(key, payload.to_owned()).await.expect("put");
    let sample = tokio::time::timeout(Duration::from_secs(20), result.recv_async())
        .await
        .expect("a result")
        .expect("sample");
    serde_json::from_slice(&sample.payload().to_bytes()).expect("JSON result")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_same_forbidden_write_is_refused_over_modbus_tcp_rest_and_zenoh() {
    use tokio_modbus::client::{tcp, Reader, Writer};
    use tokio_modbus::prelude::Slave;

    let dir = temp_dir("one-policy");
    let link = SocatLink::new(&dir, "drive");
    let _sim = device_sim("altivar71", &link.b);
    // Only CMD (W8501) of the drive may be written: ACC (W9001) is outside the write ranges.
    let config = |zenoh_port: u16| {
        format!(
            r#"
[gateway]
name = "policy"

[modbus_tcp]
listen = "127.0.0.1:0"
write_ranges = [{{ unit_id = 2, table = "holding", start = 8501, count = 1 }}]

[http]
insecure_allow_unauthenticated_changes = true

[zenoh]
mode = "peer"
listen = ["tcp/127.0.0.1:{zenoh_port}"]
connect = []
multicast_scouting = false
writes = true

[lines.drive]
port = "{port}"
protocol = "modbus-master-rtu"
baud = 19200
parity = "even"

[lines.drive.devices.atv71]
profile = "altivar71"
address = 2
unit_id = 2

[[lines.drive.devices.atv71.poll]]
name = "settings"
period = "200ms"
ranges = [{{ table = "holding", start = 9001, count = 2 }}]
"#,
            port = link.a.display(),
        )
    };
    let file = dir.join("gateway.toml");
    let gw = Gateway::run_on_free_zenoh_port(&file, config);
    let zenoh_port = gw.zenoh_port.expect("zenoh port");
    let http = gw.http.expect("http");
    let mut drive = tcp::connect_slave(gw.modbus_tcp, Slave(2))
        .await
        .expect("connect");
    let deadline = Instant::now() + Duration::from_secs(20);
    let acc = loop {
        if let Ok(Ok(words)) = drive.read_holding_registers(9001, 1).await {
            break words[0];
        }
        assert!(Instant::now() < deadline, "the drive never answered");
        tokio::time::sleep(Duration::from_millis(200)).await;
    };

    // Modbus TCP: exception 02 (outside the write ranges).
    let tcp_write = drive
        .write_single_register(9001, acc + 1)
        .await
        .expect("transport");
    assert_eq!(
        tcp_write,
        Err(tokio_modbus::ExceptionCode::IllegalDataAddress)
    );
    // REST: refused, with the policy named.
    let rest = reqwest::Client::new()
        .put(format!(
            "http://{http}/api/v1/lines/drive/devices/atv71/tags/ACC"
        ))
        .json(&serde_json::json!({ "value": 9.9 }))
        .send()
        .await
        .expect("REST request");
    let status = rest.status();
    let body = rest.text().await.unwrap_or_default();
    assert!(status.is_client_error(), "REST write: {status} {body}");
    assert!(body.contains("write_ranges"), "{body}");
    // zenoh: refused on the result key.
    let session = gateway_tests::zenoh_client(zenoh_port).await;
    let result = zenoh_put(&session, "gw/policy/drive/atv71/ACC/set", "9.9").await;
    assert_eq!(result["ok"], serde_json::Value::Bool(false), "{result}");
    assert!(result.to_string().contains("write_ranges"), "{result}");

    // Nothing reached the drive; every refusal is in the audit count of its path.
    let now = drive
        .read_holding_registers(9001, 1)
        .await
        .expect("transport")
        .expect("read");
    assert_eq!(now, [acc]);
    let metrics = scrape(http);
    for path in ["modbus_tcp", "rest", "zenoh"] {
        let series = format!(
            "gateway_writes_total{{path=\"{path}\",reason=\"policy\",result=\"refused\"}} 1"
        );
        assert!(metrics.contains(&series), "no {series} in:\n{metrics}");
    }
    session.close().await.expect("close");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_same_forbidden_send_is_refused_over_rest_zenoh_and_the_mailbox() {
    use tokio_modbus::client::{tcp, Reader, Writer};
    use tokio_modbus::prelude::Slave;

    let dir = temp_dir("no-sends");
    let link = SocatLink::new(&dir, "ascii");
    // The line's write policy refuses sends; every interface that can send is open.
    let config = |zenoh_port: u16| {
        format!(
            r#"
[gateway]
name = "nosend"

[modbus_tcp]
listen = "127.0.0.1:0"

[http]
insecure_allow_unauthenticated_changes = true

[zenoh]
mode = "peer"
listen = ["tcp/127.0.0.1:{zenoh_port}"]
connect = []
multicast_scouting = false
writes = true

[lines.ascii]
port = "{port}"
protocol = "ascii"
end_criterion = "end-chars"
end_chars = [0x03]
unit_id = 101
sends = false
"#,
            port = link.a.display(),
        )
    };
    let file = dir.join("gateway.toml");
    let gw = Gateway::run_on_free_zenoh_port(&file, config);
    let zenoh_port = gw.zenoh_port.expect("zenoh port");
    let http = gw.http.expect("http");

    // REST: 409 with the policy named.
    let rest = reqwest::Client::new()
        .post(format!("http://{http}/api/v1/lines/ascii/send"))
        .json(&serde_json::json!({ "text": "HELLO" }))
        .send()
        .await
        .expect("REST request");
    let status = rest.status();
    let body = rest.text().await.unwrap_or_default();
    assert_eq!(status.as_u16(), 409, "REST send: {body}");
    assert!(body.contains("sends = false"), "{body}");
    // zenoh: refused on the result key.
    let session = gateway_tests::zenoh_client(zenoh_port).await;
    let result = zenoh_put(&session, "gw/nosend/ascii/tx", "HELLO").await;
    assert_eq!(result["ok"], serde_json::Value::Bool(false), "{result}");
    assert!(result.to_string().contains("sends = false"), "{result}");
    // Modbus TCP, the mailbox's send block: REQ, TX_LEN, TX_DATA in one FC 16, exception 01;
    // REQ alone and TX_DATA alone too.
    let mut mailbox = tcp::connect_slave(gw.modbus_tcp, Slave(101))
        .await
        .expect("connect");
    for (address, values) in [
        (1008, vec![1, 5, 0x4845, 0x4C4C, 0x4F00]),
        (1008, vec![2]),
        (1010, vec![0x4142]),
    ] {
        let answer = mailbox
            .write_multiple_registers(address, &values)
            .await
            .expect("transport");
        assert_eq!(
            answer,
            Err(tokio_modbus::ExceptionCode::IllegalFunction),
            "FC 16 at {address}"
        );
    }
    // The receive side and the acknowledgement stay open: only sends are closed.
    let sent = mailbox
        .read_holding_registers(524, 4)
        .await
        .expect("transport")
        .expect("read SENT and SEND_FAILED");
    assert_eq!(sent, [0, 0, 0, 0], "nothing was sent or attempted");

    let metrics = scrape(http);
    for (path, n) in [("modbus_tcp", 3), ("rest", 1), ("zenoh", 1)] {
        let series = format!(
            "gateway_writes_total{{path=\"{path}\",reason=\"policy\",result=\"refused\"}} {n}"
        );
        assert!(metrics.contains(&series), "no {series} in:\n{metrics}");
    }
    for path in ["modbus_tcp", "rest", "zenoh"] {
        let series = format!(
            "gateway_writes_total{{path=\"{path}\",reason=\"none\",result=\"accepted\"}} 0"
        );
        assert!(metrics.contains(&series), "no {series} in:\n{metrics}");
    }
    session.close().await.expect("close");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn zenoh_writes_are_off_unless_switched_on() {
    let dir = temp_dir("zenoh-writes");
    let link = SocatLink::new(&dir, "ascii");
    let config = |zenoh_port: u16| {
        format!(
            r#"
[gateway]
name = "quiet"

[modbus_tcp]
listen = "127.0.0.1:0"

[zenoh]
listen = ["tcp/127.0.0.1:{zenoh_port}"]

[lines.ascii]
port = "{port}"
protocol = "ascii"
end_criterion = "end-chars"
end_chars = [0x03]
"#,
            port = link.a.display(),
        )
    };
    let file = dir.join("gateway.toml");
    let mut gw = Gateway::run_on_free_zenoh_port(&file, config);
    let zenoh_port = gw.zenoh_port.expect("zenoh port");
    let session = gateway_tests::zenoh_client(zenoh_port).await;
    let result = zenoh_put(&session, "gw/quiet/ascii/tx", "HELLO").await;
    assert_eq!(result["ok"], serde_json::Value::Bool(false), "{result}");
    assert!(result.to_string().contains("writes = false"), "{result}");
    let metrics = scrape(gw.http.expect("http"));
    let series = r#"gateway_writes_total{path="zenoh",reason="writes_off",result="refused"} 1"#;
    assert!(metrics.contains(series), "no {series} in:\n{metrics}");
    gw.wait_for("writes over zenoh are off", Duration::from_secs(5));
    session.close().await.expect("close");
}

// === paths a configuration change may name ===

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_config_change_cannot_point_ports_or_the_persistence_file_outside_their_directories() {
    let dir = temp_dir("paths");
    let link = SocatLink::new(&dir, "ascii");
    let config = format!(
        r#"
[gateway]
name = "paths"

[modbus_tcp]
listen = "127.0.0.1:0"

[http]
insecure_allow_unauthenticated_changes = true

[lines.ascii]
port = "{port}"
protocol = "ascii"
end_criterion = "end-chars"
end_chars = [0x03]
"#,
        port = link.a.display(),
    );
    let file = dir.join("gateway.toml");
    std::fs::write(&file, config).expect("write config");
    let gw = Gateway::run(&file);
    let base = format!("http://{}", gw.http.expect("http"));
    let http = reqwest::Client::new();
    let current: serde_json::Value = http
        .get(format!("{base}/api/v1/config"))
        .send()
        .await
        .expect("GET config")
        .json()
        .await
        .expect("JSON");
    let refused = |change: &dyn Fn(&mut serde_json::Value), path: &'static str| {
        let mut config = current.clone();
        change(&mut config);
        let http = http.clone();
        let url = format!("{base}/api/v1/config");
        async move {
            let reply = http
                .put(url)
                .json(&config)
                .send()
                .await
                .expect("PUT config");
            let status = reply.status();
            let body: serde_json::Value = reply.json().await.expect("JSON");
            assert_eq!(status.as_u16(), 422, "{path}: {body:#}");
            let paths: Vec<&str> = body["error"]["issues"]
                .as_array()
                .expect("issues")
                .iter()
                .filter_map(|i| i["path"].as_str())
                .collect();
            assert_eq!(paths, [path], "{body:#}");
        }
    };
    // A serial port outside /dev (the file exists: only the directory refuses it).
    refused(
        &|c| c["lines"]["ascii"]["port"] = serde_json::json!("/etc/passwd"),
        "lines.ascii.port",
    )
    .await;
    // `..` does not leave /dev either.
    refused(
        &|c| c["lines"]["ascii"]["port"] = serde_json::json!("/dev/../etc/passwd"),
        "lines.ascii.port",
    )
    .await;
    // The persistence file outside the state directory.
    refused(
        &|c| c["cp_memory"]["persist_file"] = serde_json::json!("/etc/cron.d/gateway"),
        "cp_memory.persist_file",
    )
    .await;
    // Nor can the change widen the directories themselves.
    refused(
        &|c| c["gateway"]["port_dirs"] = serde_json::json!(["/"]),
        "gateway.port_dirs",
    )
    .await;
    let text = std::fs::read_to_string(&file).expect("config file");
    assert!(!text.contains("/etc/"), "nothing was saved:\n{text}");
}
