//! End to end on the binary: one simulated port carrying three devices of different kinds (an
//! Altivar 71, a KS vario and the demo's meter, `gateway sim` with `--device` and `--address`
//! repeated) on one end of a socat pty link, polled by one master line of a gateway, and every
//! device's values read over Modbus TCP under its own unit id.

use std::process::Command;
use std::time::{Duration, Instant};

use gateway_tests::{check_config, gateway_bin, start_sim, temp_dir, Gateway, SocatLink};
use tokio_modbus::client::{tcp, Reader};
use tokio_modbus::prelude::Slave;

/// The slave addresses (and unit ids) of the three devices: none of them the model's default,
/// so that each `--address` is seen to go with its own `--device`.
const DRIVE: u8 = 4;
const KS: u8 = 18;
const METER: u8 = 31;

fn config(port: &std::path::Path) -> String {
    format!(
        r#"
[gateway]
name = "e2e"

[modbus_tcp]
listen = "127.0.0.1:0"

[lines.bus]
port = "{port}"
protocol = "modbus-master-rtu"
baud = 19200
parity = "even"
reply_timeout = "500ms"

[lines.bus.devices.atv71]
profile = "altivar71"
address = {DRIVE}
unit_id = {DRIVE}

[[lines.bus.devices.atv71.poll]]
name = "settings"
period = "200ms"
ranges = [{{ table = "holding", start = 3102, count = 4 }}]

[lines.bus.devices.ks]
profile = "ksvario"
address = {KS}
unit_id = {KS}

[[lines.bus.devices.ks.poll]]
name = "process"
period = "200ms"
ranges = [{{ table = "input", start = 1004, count = 3 }}]

[lines.bus.devices.meter]
profile = "generic"
address = {METER}
unit_id = {METER}
tags = [{{ name = "temperature", table = "input", address = 8, type = "u16" }}]

[[lines.bus.devices.meter.poll]]
name = "temperature"
period = "200ms"
ranges = [{{ table = "input", start = 8, count = 1 }}]
"#,
        port = port.display()
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_simulated_port_carries_a_drive_a_controller_and_a_meter() {
    let dir = temp_dir("sim-bus");
    let link = SocatLink::new(&dir, "bus");
    let port = link.b.to_str().expect("utf-8 path").to_owned();
    let (drive, ks, meter) = (DRIVE.to_string(), KS.to_string(), METER.to_string());
    let _sim = start_sim(&[
        "--device",
        "altivar71",
        "--address",
        &drive,
        "--device",
        "ksvario",
        "--address",
        &ks,
        "--device",
        "meter",
        "--address",
        &meter,
        "--port",
        &port,
    ]);
    let cfg = dir.join("gateway.toml");
    std::fs::write(&cfg, config(&link.a)).expect("write config");
    let (passed, report) = check_config(&cfg);
    assert!(passed, "{report}");

    let gw = Gateway::run(&cfg);
    let mut drive_ctx = tcp::connect_slave(gw.modbus_tcp, Slave(DRIVE))
        .await
        .expect("connect");
    let mut ks_ctx = tcp::connect_slave(gw.modbus_tcp, Slave(KS))
        .await
        .expect("connect");
    let mut meter_ctx = tcp::connect_slave(gw.modbus_tcp, Slave(METER))
        .await
        .expect("connect");

    // The manuals' values (002: W3102..W3105 = 40/600/500/0; 001: 1004..1006 = 1066/140/4158)
    // and the meter's temperature register (raw 2931), each from its own unit.
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let d = drive_ctx
            .read_holding_registers(3102, 4)
            .await
            .expect("transport");
        let k = ks_ctx
            .read_input_registers(1004, 3)
            .await
            .expect("transport");
        let m = meter_ctx
            .read_input_registers(8, 1)
            .await
            .expect("transport");
        if d.as_deref() == Ok(&[40, 600, 500, 0][..])
            && k.as_deref() == Ok(&[1066, 140, 4158][..])
            && m.as_deref() == Ok(&[2931][..])
        {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the three devices never all answered: {d:?} {k:?} {m:?}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }

    // The line's status shows all three devices polled with success.
    let url = format!("http://{}/api/v1/lines/bus", gw.http.expect("HTTP"));
    let client = reqwest::Client::builder()
        .no_proxy()
        .build()
        .expect("client");
    let status: serde_json::Value = client
        .get(url)
        .send()
        .await
        .expect("GET the line")
        .json()
        .await
        .expect("JSON");
    let devices = status["devices"].as_array().expect("devices");
    assert_eq!(devices.len(), 3, "{status}");
    for device in devices {
        assert!(device["polls_ok"].as_u64() > Some(0), "{device}");
    }
}

#[test]
fn two_devices_at_one_address_are_refused() {
    let out = Command::new(gateway_bin())
        .args([
            "sim",
            "--device",
            "altivar71",
            "--address",
            "7",
            "--device",
            "meter",
            "--address",
            "7",
            "--port",
            "/dev/null",
        ])
        .output()
        .expect("gateway sim");
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("two devices at slave address 7"),
        "{stderr}"
    );

    let out = Command::new(gateway_bin())
        .args([
            "sim",
            "--device",
            "meter",
            "--address",
            "7",
            "--address",
            "8",
            "--port",
            "/dev/null",
        ])
        .output()
        .expect("gateway sim");
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("more --address than --device"), "{stderr}");
}
