//! End to end on the binary: a `modbus-rtu-tap` line on a socat pty link. The test plays the bus
//! (another master's requests and the drive's answers, with real silences between the frames)
//! on the link's other end; SCADA reads what the tap stored over Modbus TCP, and every write path
//! (Modbus TCP, REST, zenoh) is refused.

use std::time::{Duration, Instant};

use gateway_tests::{check_config, free_port, temp_dir, Gateway, SocatLink};
use proto_core::modbus::rtu::encode_frame;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_modbus::client::{tcp, Reader, Writer};
use tokio_modbus::prelude::{ExceptionCode, Slave};

/// Between two frames on the bus: far above t3.5 (32 ms at 1200 Bd, 003 6.4.3).
const GAP: Duration = Duration::from_millis(150);

fn frame(address: u8, pdu: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    encode_frame(address, pdu, &mut out);
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_tap_line_serves_another_masters_values_and_refuses_every_write() {
    let dir = temp_dir("tap-line");
    let link = SocatLink::new(&dir, "bus");
    let config = |zenoh_port: u16| {
        format!(
            r#"
[gateway]
name = "tap"

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

[lines.bus]
port = "{port}"
protocol = "modbus-rtu-tap"
baud = 1200
parity = "even"
answer_timeout = "400ms"
expected_cycle = "30s"

[lines.bus.devices.atv71]
profile = "altivar71"
address = 2
unit_id = 2
"#,
            port = link.a.display()
        )
    };
    let cfg = dir.join("gateway.toml");
    std::fs::write(&cfg, config(free_port())).expect("write config");
    let (passed, report) = check_config(&cfg);
    assert!(passed, "{report}");

    let mut gw = Gateway::run_on_free_zenoh_port(&cfg, config);
    let zenoh_port = gw.zenoh_port.expect("zenoh port");
    let mut bus = tokio_serial::SerialStream::open(&tokio_serial::new(
        link.b.to_str().expect("utf-8 path"),
        1200,
    ))
    .expect("the bus end of the link");

    // Another master reads SFr, tFr, HSP, LSP (W3102..W3105) of the drive; the drive answers
    // 40 600 500 0. The tap pairs them and stores the answer.
    let request = frame(2, &[0x03, 0x0C, 0x1E, 0x00, 0x04]);
    let answer = frame(
        2,
        &[0x03, 0x08, 0x00, 0x28, 0x02, 0x58, 0x01, 0xF4, 0x00, 0x00],
    );
    let mut scada = tcp::connect_slave(gw.modbus_tcp, Slave(2))
        .await
        .expect("connect");
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        for f in [&request, &answer] {
            bus.write_all(f).await.expect("write to the bus");
            tokio::time::sleep(GAP).await;
        }
        let read = scada
            .read_holding_registers(3102, 4)
            .await
            .expect("transport");
        if read.as_deref() == Ok(&[40, 600, 500, 0][..]) {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the tapped values never arrived: {read:?}\n{}",
            gw.output()
        );
    }

    // The drive's first answer the tap heard is logged at INFO, once.
    let first = gw.wait_for(
        "device answers line=bus device=atv71",
        Duration::from_secs(10),
    );
    assert!(
        first.contains(" INFO ") && first.contains("unit_id=2"),
        "{first}"
    );

    // Modbus TCP: exception 01 for a write to the tapped drive.
    let write = scada
        .write_single_register(9001, 20)
        .await
        .expect("transport");
    assert_eq!(write, Err(ExceptionCode::IllegalFunction));

    // REST: the line is a tap; a tag write is refused with the reason.
    let http = gw.http.expect("HTTP");
    let client = reqwest::Client::new();
    let status: serde_json::Value = client
        .get(format!("http://{http}/api/v1/lines/bus"))
        .send()
        .await
        .expect("GET line")
        .json()
        .await
        .expect("JSON");
    assert_eq!(status["protocol"], "modbus-rtu-tap", "{status}");
    let put = client
        .put(format!(
            "http://{http}/api/v1/lines/bus/devices/atv71/tags/ACC"
        ))
        .json(&serde_json::json!({ "value": 4.5 }))
        .send()
        .await
        .expect("PUT");
    let code = put.status();
    let body = put.text().await.unwrap_or_default();
    assert_eq!(code.as_u16(), 409, "{body}");
    assert!(body.contains("listen-only"), "{body}");

    // zenoh: the set is refused on its result key.
    let session = gateway_tests::zenoh_client(zenoh_port).await;
    let key = "gw/tap/bus/atv71/ACC/set";
    let result = session
        .declare_subscriber(format!("{key}/result"))
        .await
        .expect("subscribe");
    session.put(key, "4.5").await.expect("put");
    let sample = tokio::time::timeout(Duration::from_secs(20), result.recv_async())
        .await
        .expect("a result")
        .expect("sample");
    let result: serde_json::Value =
        serde_json::from_slice(&sample.payload().to_bytes()).expect("JSON result");
    assert_eq!(result["ok"], serde_json::Value::Bool(false), "{result}");
    assert!(result.to_string().contains("listen-only"), "{result}");
    session.close().await.expect("close");

    // Nothing was ever sent on the bus.
    let mut buf = [0u8; 64];
    let silent = tokio::time::timeout(Duration::from_millis(500), bus.read(&mut buf)).await;
    assert!(silent.is_err(), "the tap transmitted: {silent:?}");
}
