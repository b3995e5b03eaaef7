//! What the gateway's log tells an operator, read from the real binary's stderr: a device's first
//! answer, its going offline and its return; a line event with the manual's description and
//! remedy; every master transaction at DEBUG; refused Modbus TCP connections with the client's
//! address; `/readyz` probes that are not warnings; and the audit's source of a REST change made
//! without a token outside the demo.

use std::net::SocketAddr;
use std::path::Path;
use std::time::Duration;

use gateway_tests::{device_sim, temp_dir, Gateway, SocatLink};
use proto_core::event::{self, ids};
use tokio::io::AsyncReadExt;
use tokio::net::{TcpSocket, TcpStream};

const WAIT: Duration = Duration::from_secs(30);

/// An Altivar on `port`, polled every 100 ms, quick to give up on a silent device and to retry.
fn drive_config(port: &Path) -> String {
    format!(
        r#"
[gateway]
name = "logs"

[modbus_tcp]
listen = "127.0.0.1:0"

[lines.drive]
port = "{port}"
protocol = "modbus-master-rtu"
baud = 19200
parity = "even"
reply_timeout = "300ms"

[lines.drive.devices.atv71]
profile = "altivar71"
address = 2
unit_id = 2
offline_backoff_min = "200ms"
offline_backoff_max = "1s"

[[lines.drive.devices.atv71.poll]]
name = "settings"
period = "100ms"
ranges = [{{ table = "holding", start = 3102, count = 4 }}]
"#,
        port = port.display()
    )
}

/// Starts `gateway run` on `config` (written into `dir`) with `RUST_LOG=filter`.
fn run(dir: &Path, config: &str, filter: &str) -> Gateway {
    let file = dir.join("gateway.toml");
    std::fs::write(&file, config).expect("write config");
    Gateway::start_logging(&Gateway::run_args(&file), filter)
}

#[test]
fn a_device_is_logged_when_it_first_answers_goes_offline_and_comes_back() {
    let dir = temp_dir("device-logs");
    let link = SocatLink::new(&dir, "drive");
    let mut sim = device_sim("altivar71", &link.b);
    let mut gw = run(&dir, &drive_config(&link.a), "info,gateway::line=debug");

    // The first answer, at INFO, once.
    let first = gw.wait_for("device answers line=drive device=atv71", WAIT);
    assert!(first.contains(" INFO "), "{first}");
    assert!(first.contains("slave=2 unit_id=2"), "{first}");

    // Every master transaction at DEBUG: the request and its answer, with the slave, function,
    // address, count, result and time (as the README promises for gateway::line=debug).
    let answer = gw.wait_for(
        "answer line=drive device=atv71 slave=2 function=3 address=3102 count=4 result=ok time_ms=",
        WAIT,
    );
    assert!(answer.contains(" DEBUG "), "{answer}");
    let out = gw.output();
    assert!(
        out.contains("request line=drive slave=2 function=3 address=3102 count=4 job=poll"),
        "{out}"
    );

    // The device goes silent: offline at WARN, and the line event with the manual's description
    // and remedy (as REST gives them), not the class title.
    sim.kill();
    let offline = gw.wait_for("device offline line=drive device=atv71", WAIT);
    assert!(offline.contains(" WARN "), "{offline}");
    let out = gw.output();
    let no_reply = event::lookup(ids::MODBUS_NO_REPLY).expect("in the catalog");
    let event_line = out
        .lines()
        .find(|l| l.contains(&format!("event={}", ids::MODBUS_NO_REPLY)))
        .unwrap_or_else(|| panic!("no line of event {}:\n{out}", ids::MODBUS_NO_REPLY));
    assert!(event_line.contains(" WARN "), "{event_line}");
    assert!(event_line.contains(no_reply.description), "{event_line}");
    assert!(
        event_line.contains(&format!("remedy={:?}", no_reply.remedy)),
        "{event_line}"
    );
    assert!(!event_line.contains("class="), "{event_line}");
    assert!(
        out.contains(&format!("result=no reply ({})", ids::MODBUS_NO_REPLY)),
        "{out}"
    );

    // It answers again: INFO with how long it was offline; no second "first answer".
    let _sim = device_sim("altivar71", &link.b);
    let back = gw.wait_for("device answers again line=drive device=atv71", WAIT);
    assert!(back.contains(" INFO "), "{back}");
    assert!(back.contains("offline_for="), "{back}");
    assert_eq!(
        gw.output()
            .matches("device answers line=drive device=atv71")
            .count(),
        1
    );
}

/// Connects to `server` from `source` (a loopback address); the stream when the server kept it.
async fn connect_from(source: &str, server: SocketAddr) -> Option<TcpStream> {
    let socket = TcpSocket::new_v4().expect("socket");
    socket
        .bind(format!("{source}:0").parse().expect("source"))
        .expect("bind the source address");
    let mut stream = socket.connect(server).await.expect("connect");
    // A refused connection is closed at accept: its read ends at once.
    let mut byte = [0u8; 1];
    match tokio::time::timeout(Duration::from_millis(500), stream.read(&mut byte)).await {
        Err(_) => Some(stream),
        Ok(_) => None,
    }
}

#[tokio::test]
async fn refused_modbus_tcp_connections_are_logged_with_the_address() {
    let dir = temp_dir("refused-logs");
    // Clients from 127.0.0.4..7 only, one connection each, two in all.
    let config = "[gateway]\nname = \"logs\"\n\n[modbus_tcp]\nlisten = \"127.0.0.1:0\"\n\
                  allowed_networks = [\"127.0.0.4/30\"]\nmax_connections = 2\n\
                  max_connections_per_client = 1\n";
    let mut gw = run(&dir, config, "info");
    let server = gw.modbus_tcp;

    assert!(connect_from("127.0.0.1", server).await.is_none());
    let line = gw.wait_for("Modbus TCP connection refused", WAIT);
    assert!(line.contains(" WARN "), "{line}");
    assert!(line.contains("peer=127.0.0.1:"), "{line}");
    assert!(line.contains("allowed_networks"), "{line}");

    let _first = connect_from("127.0.0.4", server).await.expect("served");
    assert!(connect_from("127.0.0.4", server).await.is_none());
    let line = gw.wait_for("Modbus TCP connection refused", WAIT);
    assert!(line.contains("peer=127.0.0.4:"), "{line}");
    assert!(line.contains("max_connections_per_client"), "{line}");

    let _second = connect_from("127.0.0.5", server).await.expect("served");
    assert!(connect_from("127.0.0.6", server).await.is_none());
    let line = gw.wait_for("Modbus TCP connection refused", WAIT);
    assert!(line.contains("peer=127.0.0.6:"), "{line}");
    assert!(line.contains("has max_connections open"), "{line}");
}

#[tokio::test]
async fn readyz_probes_are_not_warnings_and_the_audit_names_a_change_without_a_token() {
    let dir = temp_dir("probe-logs");
    // A line whose port is not there (an adapter not plugged in): the gateway runs, reopening it
    // with back-off, and is not ready. Changes are open to anyone, outside the demo.
    let config = format!(
        "[gateway]\nname = \"logs\"\n\n[modbus_tcp]\nlisten = \"127.0.0.1:0\"\n\n[http]\n\
         insecure_allow_unauthenticated_changes = true\n\n[lines.absent]\nport = \"{}\"\n\
         protocol = \"ascii\"\n",
        dir.join("no-such-tty").display()
    );
    let mut gw = run(&dir, &config, "info");
    let http = gw.http.expect("HTTP listener");
    let client = reqwest::Client::new();
    for _ in 0..5 {
        let r = client
            .get(format!("http://{http}/readyz"))
            .send()
            .await
            .expect("GET /readyz");
        assert_eq!(r.status().as_u16(), 503);
    }
    let line = gw.wait_for("readyz: not ready", WAIT);
    assert!(line.contains(" INFO "), "{line}");
    assert!(line.contains("lines.absent"), "{line}");

    let r = client
        .delete(format!("http://{http}/api/v1/lines/absent/diag"))
        .send()
        .await
        .expect("DELETE diag");
    assert!(r.status().is_success(), "{}", r.status());
    let audit = gw.wait_for(" audit: ", WAIT);
    assert!(
        audit.contains("no token (insecure_allow_unauthenticated_changes)"),
        "{audit}"
    );
    assert!(audit.contains("source=127.0.0.1:"), "{audit}");

    let out = gw.output();
    // Five probes, one line: the answer changed once (to not ready).
    assert_eq!(out.matches("readyz: not ready").count(), 1, "{out}");
    assert!(!out.contains("anonymous demo"), "{out}");
    let warnings: Vec<&str> = out
        .lines()
        .filter(|l| {
            l.contains(" WARN ")
                && (l.contains("readyz") || l.contains("not_ready") || l.contains("api error"))
        })
        .collect();
    assert!(warnings.is_empty(), "{warnings:#?}");
}
