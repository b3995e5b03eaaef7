//! `gateway scan` end to end: the real binary scanning a socat pty link with a simulated bus of
//! Altivar drives (`gateway sim --also-address`) at the other end.

use std::process::{Command, Output};

use gateway_tests::{check_config, gateway_bin, start_sim, temp_dir, Gateway, SocatLink};

/// The drives on the simulated bus.
const DRIVES: [u8; 3] = [2, 5, 9];

fn scan(port: &std::path::Path, extra: &[&str]) -> Output {
    Command::new(gateway_bin())
        .args([
            "scan",
            "--port",
            port.to_str().expect("utf-8 path"),
            "--baud",
            "19200",
            "--parity",
            "even",
            "--from",
            "1",
            "--to",
            "12",
            "--timeout",
            "60ms",
        ])
        .args(extra)
        .output()
        .expect("gateway scan")
}

fn bus(link: &SocatLink) -> gateway_tests::ChildGuard {
    start_sim(&[
        "--device",
        "altivar71",
        "--port",
        link.b.to_str().expect("utf-8 path"),
        "--address",
        "2",
        "--also-address",
        "5,9",
    ])
}

#[test]
fn a_scan_finds_exactly_the_drives_with_their_identity_and_its_toml_passes_check() {
    let dir = temp_dir("scan");
    let link = SocatLink::new(&dir, "bus");
    let _bus = bus(&link);

    // The simulator needs a moment to open its end: scan until all three answer (at most a few
    // times), then look at that scan.
    let mut out = scan(&link.a, &[]);
    for _ in 0..5 {
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        if text.lines().count() == DRIVES.len() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(300));
        out = scan(&link.a, &[]);
    }
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "{stdout}\n{stderr}");
    let found: Vec<u8> = stdout
        .lines()
        .map(|line| {
            line.split_whitespace()
                .next()
                .and_then(|a| a.parse().ok())
                .unwrap_or_else(|| panic!("a line not starting with an address: {line:?}"))
        })
        .collect();
    assert_eq!(found, DRIVES, "{stdout}\n{stderr}");
    for line in stdout.lines() {
        // The drive's FC 43 identity (002 "Identifikation"; the simulator's defaults).
        assert!(
            line.contains("\"Telemecanique\"")
                && line.contains("\"ATV71HU15M3\"")
                && line.contains("\"0201\""),
            "{line}"
        );
    }
    // Not a terminal: no progress on stderr.
    assert!(!stderr.contains("scanning address"), "{stderr}");

    // --toml: a valid document with a device block holding `address` for each drive...
    let out = scan(&link.a, &["--toml"]);
    let doc = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "{doc}");
    let parsed: toml::Table = toml::from_str(&doc).unwrap_or_else(|e| panic!("{e}\n{doc}"));
    let devices = parsed
        .get("devices")
        .and_then(toml::Value::as_table)
        .unwrap_or_else(|| panic!("no devices table:\n{doc}"))
        .clone();
    let mut addresses: Vec<i64> = devices
        .values()
        .filter_map(|d| d.get("address").and_then(toml::Value::as_integer))
        .collect();
    addresses.sort_unstable();
    assert_eq!(addresses, [2, 5, 9], "{doc}");

    // ...that `gateway check` accepts as the devices of a line.
    let mut line = toml::Table::new();
    line.insert("port".into(), link.a.to_str().expect("utf-8 path").into());
    line.insert("protocol".into(), "modbus-master-rtu".into());
    line.insert("baud".into(), 19200.into());
    line.insert("parity".into(), "even".into());
    line.insert("devices".into(), toml::Value::Table(devices));
    let mut lines = toml::Table::new();
    lines.insert("bus".into(), toml::Value::Table(line));
    let mut config = toml::Table::new();
    config.insert("lines".into(), toml::Value::Table(lines));
    let cfg = dir.join("scanned.toml");
    std::fs::write(&cfg, toml::to_string(&config).expect("serialize")).expect("write config");
    let (passed, report) = check_config(&cfg);
    assert!(passed, "{report}\n{doc}");

    // With --line the blocks are ready to append to a config file as they are.
    let out = scan(&link.a, &["--toml", "--line", "bus"]);
    let blocks = String::from_utf8_lossy(&out.stdout).into_owned();
    let text = format!(
        "[lines.bus]\nport = \"{}\"\nprotocol = \"modbus-master-rtu\"\nbaud = 19200\n{blocks}",
        link.a.display()
    );
    let cfg = dir.join("appended.toml");
    std::fs::write(&cfg, &text).expect("write config");
    let (passed, report) = check_config(&cfg);
    assert!(passed, "{report}\n{text}");
}

#[test]
fn a_port_a_running_gateway_holds_is_refused() {
    let dir = temp_dir("scan-busy");
    let link = SocatLink::new(&dir, "bus");
    let _bus = bus(&link);
    let cfg = dir.join("gateway.toml");
    std::fs::write(
        &cfg,
        format!(
            r#"
[modbus_tcp]
listen = "127.0.0.1:0"

[lines.drive]
port = "{}"
protocol = "modbus-master-rtu"
baud = 19200
parity = "even"

[lines.drive.devices.atv71]
profile = "altivar71"
address = 2
"#,
            link.a.display()
        ),
    )
    .expect("write config");
    let gw = Gateway::run(&cfg);
    // Its log (stderr, read by another thread than the announcement) says the port is open.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while !gw.output().contains("port open") {
        assert!(std::time::Instant::now() < deadline, "{}", gw.output());
        std::thread::sleep(std::time::Duration::from_millis(50));
    }

    let out = scan(&link.a, &[]);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "{stderr}");
    assert!(
        out.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    assert!(
        stderr.contains("in use by another process") && stderr.contains("running gateway"),
        "{stderr}"
    );
}
