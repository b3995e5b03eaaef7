//! Transparent forwarding end to end: the real binary, a real Modbus TCP client (tokio-modbus)
//! and a simulated bus of two Altivar drives (`gateway sim --also-address`) on a socat pty link.
//! The line declares the drive at address 2; the drive at address 5 is reached only through
//! `transparent = true`.

use std::time::{Duration, Instant};

use gateway_tests::{check_config, start_sim, temp_dir, Gateway, SocatLink};
use tokio_modbus::client::{tcp, Context, Reader, Writer};
use tokio_modbus::prelude::{ExceptionCode, Slave};

fn config(port: &std::path::Path) -> String {
    format!(
        r#"
[gateway]
name = "transparent"

[modbus_tcp]
listen = "127.0.0.1:0"
# ACC (W9001) of both drives may be written, nothing else.
write_ranges = [
  {{ unit_id = 2, table = "holding", start = 9001, count = 1 }},
  {{ unit_id = 5, table = "holding", start = 9001, count = 1 }},
]

[lines.drive]
port = "{port}"
protocol = "modbus-master-rtu"
baud = 19200
parity = "even"
reply_timeout = "200ms"
transparent = true
transparent_units = [1, 100]

[lines.drive.devices.atv71]
profile = "altivar71"
address = 2
unit_id = 2

[[lines.drive.devices.atv71.poll]]
name = "settings"
period = "100ms"
ranges = [{{ table = "holding", start = 3102, count = 4 }}]
"#,
        port = port.display()
    )
}

async fn connect(gw: &Gateway, unit: u8) -> Context {
    tcp::connect_slave(gw.modbus_tcp, Slave(unit))
        .await
        .expect("connect")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_undeclared_unit_reaches_the_slave_of_its_address_under_the_write_policy() {
    let dir = temp_dir("transparent");
    let link = SocatLink::new(&dir, "bus");
    let _bus = start_sim(&[
        "--device",
        "altivar71",
        "--port",
        link.b.to_str().expect("utf-8 path"),
        "--address",
        "2",
        "--also-address",
        "5",
    ]);
    let cfg = dir.join("gateway.toml");
    std::fs::write(&cfg, config(&link.a)).expect("write config");
    let (passed, report) = check_config(&cfg);
    assert!(passed, "{report}");
    let mut gw = Gateway::run(&cfg);

    // FC 03 to unit 5, which no device declares: the drive at address 5 answers (002, the
    // manual's FC 03 example), on demand.
    let mut forwarded = connect(&gw, 5).await;
    let deadline = Instant::now() + Duration::from_secs(10);
    let settings = loop {
        match forwarded
            .read_holding_registers(3102, 4)
            .await
            .expect("transport")
        {
            Ok(values) => break values,
            Err(e) => assert!(Instant::now() < deadline, "unit 5 answers {e:?}"),
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    assert_eq!(settings, vec![40, 600, 500, 0]);

    // FC 06 to unit 5: written in the drive at address 5, and only there.
    let mut declared = connect(&gw, 2).await;
    let before = declared
        .read_holding_registers(9001, 1)
        .await
        .expect("transport")
        .expect("W9001 of the declared drive");
    let value = if before == [21] { 22 } else { 21 };
    forwarded
        .write_single_register(9001, value)
        .await
        .expect("transport")
        .expect("FC 06 to unit 5");
    assert_eq!(
        forwarded
            .read_holding_registers(9001, 1)
            .await
            .expect("transport")
            .expect("read back"),
        vec![value]
    );
    assert_eq!(
        declared
            .read_holding_registers(9001, 1)
            .await
            .expect("transport")
            .expect("W9001 of the declared drive"),
        before,
        "the write to unit 5 reached the drive at address 2"
    );

    // The write policy is the one of every unit: W9002 is outside `write_ranges`, so the
    // gateway answers 02 itself, the drive keeps its value, and the refusal is audited.
    let dec = forwarded
        .read_holding_registers(9002, 1)
        .await
        .expect("transport")
        .expect("W9002");
    assert_eq!(
        forwarded
            .write_single_register(9002, dec[0].wrapping_add(1))
            .await
            .expect("transport"),
        Err(ExceptionCode::IllegalDataAddress)
    );
    assert_eq!(
        forwarded
            .read_holding_registers(9002, 1)
            .await
            .expect("transport")
            .expect("W9002"),
        dec
    );
    let audit = gw.wait_for("unit 5 function 06 address 9002", Duration::from_secs(5));
    assert!(audit.contains("refused"), "{audit}");

    // A unit outside transparent_units is nobody's: 0A, as before.
    let mut outside = connect(&gw, 150).await;
    assert_eq!(
        outside
            .read_holding_registers(3102, 1)
            .await
            .expect("transport"),
        Err(ExceptionCode::GatewayPathUnavailable)
    );

    // A forwarded address without a device: 0B "gateway target device failed to respond".
    let mut absent = connect(&gw, 7).await;
    assert_eq!(
        absent
            .read_holding_registers(3102, 1)
            .await
            .expect("transport"),
        Err(ExceptionCode::GatewayTargetDevice)
    );

    // The declared drive kept being polled all along.
    assert_eq!(
        declared
            .read_holding_registers(3102, 4)
            .await
            .expect("transport")
            .expect("polled settings"),
        vec![40, 600, 500, 0]
    );
}

#[test]
fn check_refuses_two_transparent_lines_claiming_one_unit_id() {
    let dir = temp_dir("transparent-check");
    let line = |name: &str, units: &str, device: &str| {
        format!(
            r#"
[lines.{name}]
port = "/dev/ttyGW-{name}"
protocol = "modbus-master-rtu"
baud = 19200
transparent = true
transparent_units = {units}
{device}"#
        )
    };
    let device = |line: &str, address: u8| {
        format!(
            r#"
[lines.{line}.devices.atv]
profile = "altivar71"
address = {address}
"#
        )
    };

    // 10..=20 and 20..=30 share unit 20, which no device claims: refused, with the ids named.
    let cfg = dir.join("overlap.toml");
    let text = line("a", "[10, 20]", "") + &line("b", "[20, 30]", "");
    std::fs::write(&cfg, text).expect("write config");
    let (passed, report) = check_config(&cfg);
    assert!(!passed, "{report}");
    assert!(
        report.contains("lines.b.transparent_units") && report.contains("unit ids 20 "),
        "{report}"
    );

    // The same ranges with a device at unit 20: the device wins, nothing is shared.
    let cfg = dir.join("claimed.toml");
    let text = line("a", "[10, 20]", &device("a", 20)) + &line("b", "[20, 30]", "");
    std::fs::write(&cfg, text).expect("write config");
    let (passed, report) = check_config(&cfg);
    assert!(passed, "{report}");

    // A backwards range, and transparent_units without transparent.
    let cfg = dir.join("bad.toml");
    let text = line("a", "[30, 20]", "")
        + "\n[lines.c]\nport = \"/dev/ttyGW-c\"\nprotocol = \"modbus-master-rtu\"\nbaud = 19200\ntransparent_units = [1, 5]\n";
    std::fs::write(&cfg, text).expect("write config");
    let (passed, report) = check_config(&cfg);
    assert!(!passed, "{report}");
    assert!(report.contains("lines.a.transparent_units"), "{report}");
    assert!(
        report.contains("lines.c.transparent_units") && report.contains("transparent = true"),
        "{report}"
    );
}
