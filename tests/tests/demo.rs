//! End to end on the binary: `gateway demo` serves the simulated Altivar 71 (unit 2) and KS vario
//! (unit 17) over Modbus TCP; tokio-modbus and mbpoll read and write them.

use std::process::Command;
use std::time::Duration;

use gateway_tests::Gateway;
use tokio_modbus::client::{tcp, Context, Reader, Writer};
use tokio_modbus::prelude::{ExceptionCode, Slave, SlaveContext};

/// How long the first polls may take after start-up on a loaded machine.
const FIRST_POLL: Duration = Duration::from_secs(20);

async fn connect(gw: &Gateway, unit: u8) -> Context {
    tcp::connect_slave(gw.modbus_tcp, Slave(unit))
        .await
        .expect("connect to the gateway")
}

/// Reads until the first poll has filled the image (the gateway answers 0x0B before that).
async fn read_holding_eventually(ctx: &mut Context, addr: u16, count: u16) -> Vec<u16> {
    let deadline = tokio::time::Instant::now() + FIRST_POLL;
    loop {
        match ctx
            .read_holding_registers(addr, count)
            .await
            .expect("transport")
        {
            Ok(values) => return values,
            Err(e) if tokio::time::Instant::now() < deadline => {
                eprintln!("not yet: {e:?}");
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
            Err(e) => panic!("holding {addr}+{count}: exception {e:?}"),
        }
    }
}

async fn read_input_eventually(ctx: &mut Context, addr: u16, count: u16) -> Vec<u16> {
    let deadline = tokio::time::Instant::now() + FIRST_POLL;
    loop {
        match ctx
            .read_input_registers(addr, count)
            .await
            .expect("transport")
        {
            Ok(values) => return values,
            Err(_) if tokio::time::Instant::now() < deadline => {
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
            Err(e) => panic!("input {addr}+{count}: exception {e:?}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn demo_serves_both_devices_and_writes_through() {
    let gw = Gateway::demo(&[]);

    // Altivar 71, unit 2: SFr, tFr, HSP, LSP (002, the manual's FC03 example).
    let mut drive = connect(&gw, 2).await;
    assert_eq!(
        read_holding_eventually(&mut drive, 3102, 4).await,
        vec![40, 600, 500, 0]
    );

    // The second Altivar on the same bus (multi-drop, slave 3), unit 3: the same settings.
    let mut drive_b = connect(&gw, 3).await;
    assert_eq!(
        read_holding_eventually(&mut drive_b, 3102, 4).await,
        vec![40, 600, 500, 0]
    );

    // KS vario, unit 17: FC04 1004..1006 (001 chapter 4 example).
    let mut ks = connect(&gw, 17).await;
    assert_eq!(
        read_input_eventually(&mut ks, 1004, 3).await,
        vec![1066, 140, 4158]
    );

    // A write of ACC (W9001) goes through to the drive and is answered with the drive's echo.
    drive
        .write_single_register(9001, 13)
        .await
        .expect("transport")
        .expect("write W9001");
    // Read W9001 together with W9003, which nobody polls: the gateway asks the drive itself, so
    // the value comes from the simulator, not from the cache.
    let values = drive
        .read_holding_registers(9001, 3)
        .await
        .expect("transport")
        .expect("read W9001..9003");
    assert_eq!(values[0], 13, "W9001 after the write: {values:?}");
    // And the cached read agrees.
    assert_eq!(
        drive
            .read_holding_registers(9001, 1)
            .await
            .expect("transport")
            .expect("read W9001"),
        vec![13]
    );

    // Each drive on the bus answers its own address: a write to the second drive leaves the
    // first one's value alone.
    drive_b
        .write_single_register(9001, 21)
        .await
        .expect("transport")
        .expect("write W9001 of the second drive");
    let both = (
        drive_b
            .read_holding_registers(9001, 3)
            .await
            .expect("transport")
            .expect("read the second drive"),
        drive
            .read_holding_registers(9001, 3)
            .await
            .expect("transport")
            .expect("read the first drive"),
    );
    assert_eq!((both.0[0], both.1[0]), (21, 13), "{both:?}");

    // ETA (W3201) is read-only on the drive: the drive's own exception 04 comes back.
    let refused = drive
        .write_single_register(3201, 1)
        .await
        .expect("transport");
    assert_eq!(refused, Err(ExceptionCode::ServerDeviceFailure));

    // An unknown unit answers 0x0A.
    drive.set_slave(Slave(99));
    let unknown = drive.read_holding_registers(0, 1).await.expect("transport");
    assert_eq!(unknown, Err(ExceptionCode::GatewayPathUnavailable));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigterm_stops_the_demo_gracefully() {
    let mut gw = Gateway::demo(&[]);
    let mut drive = connect(&gw, 2).await;
    read_holding_eventually(&mut drive, 3102, 4).await;
    let status = gw
        .terminate(Duration::from_secs(15))
        .expect("the gateway did not stop within 15 s of SIGTERM");
    assert!(status.success(), "exit status {status:?}");
    gw.wait_for("stopped gracefully", Duration::from_secs(5));
}

/// Runs mbpoll once against the gateway (`-0`: the device's own addresses); `write` values come
/// after the host, as mbpoll wants them.
fn mbpoll(gw: &Gateway, args: &[&str], write: &[&str]) -> String {
    let port = gw.modbus_tcp.port().to_string();
    let mut cmd = Command::new("mbpoll");
    cmd.args(["-m", "tcp", "-p", &port, "-0", "-1", "-o", "3"])
        .args(args)
        .arg(gw.modbus_tcp.ip().to_string())
        .args(write);
    let out = cmd.output().unwrap_or_else(|e| {
        panic!("mbpoll is needed for this test (apt install mbpoll; .ci/run installs it): {e}")
    });
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "mbpoll {args:?} failed: {stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

/// The values mbpoll prints as `[addr]: value` lines.
fn mbpoll_values(out: &str) -> Vec<i64> {
    out.lines()
        .filter_map(|l| l.trim().strip_prefix('[').and_then(|r| r.split_once("]:")))
        .map(|(_, v)| {
            v.split_whitespace()
                .next()
                .expect("value")
                .parse()
                .expect("number")
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mbpoll_reads_the_demo() {
    let gw = Gateway::demo(&[]);
    // Wait for the first polls through tokio-modbus, then ask mbpoll.
    let mut drive = connect(&gw, 2).await;
    read_holding_eventually(&mut drive, 3102, 4).await;
    let mut ks = connect(&gw, 17).await;
    read_input_eventually(&mut ks, 1004, 3).await;

    let out = mbpoll(&gw, &["-a", "2", "-t", "4", "-r", "3102", "-c", "4"], &[]);
    assert_eq!(mbpoll_values(&out), vec![40, 600, 500, 0], "{out}");
    let out = mbpoll(&gw, &["-a", "17", "-t", "3", "-r", "1004", "-c", "3"], &[]);
    assert_eq!(mbpoll_values(&out), vec![1066, 140, 4158], "{out}");
    // mbpoll writes DEC (W9002) and reads it back.
    mbpoll(&gw, &["-a", "2", "-t", "4", "-r", "9002"], &["25"]);
    let out = mbpoll(&gw, &["-a", "2", "-t", "4", "-r", "9002", "-c", "1"], &[]);
    assert_eq!(mbpoll_values(&out), vec![25], "{out}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_demo_hmi_polls_the_slave_line_and_tcp_shares_its_memory() {
    let gw = Gateway::demo(&[]);
    let mut cp = connect(&gw, 50).await;
    // The simulated serial master writes its cycle counter into holding register 10 (DB 800,
    // DBW 20) of the gateway's slave line: over TCP the value moves.
    let first = read_holding_eventually(&mut cp, 10, 1).await[0];
    let deadline = tokio::time::Instant::now() + FIRST_POLL;
    loop {
        let now = cp
            .read_holding_registers(10, 1)
            .await
            .expect("transport")
            .expect("read DBW 20")[0];
        if now != first {
            break;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "the serial master's counter never moved from {first}"
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    // A write over TCP lands in the same memory (write-enabled in the demo) and reads back.
    cp.write_multiple_registers(100, &[1234, 5678])
        .await
        .expect("transport")
        .expect("write DB 800");
    assert_eq!(
        cp.read_holding_registers(100, 2).await.expect("transport"),
        Ok(vec![1234, 5678])
    );
    // M 1000.0.. through FC05/FC01 (coils 0..1023 are write-enabled in the demo).
    cp.write_single_coil(3, true)
        .await
        .expect("transport")
        .expect("write M 1000.3");
    let bits = cp
        .read_coils(0, 8)
        .await
        .expect("transport")
        .expect("read M 1000.0..7");
    assert!(bits[3], "{bits:?}");
}

#[test]
fn gateway_check_accepts_the_example_and_lists_every_mistake() {
    let root = gateway_tests::repo_root();
    // The example as shipped, from the repository root as an operator types it.
    let out = Command::new(gateway_tests::gateway_bin())
        .args(["check", "--config", "deploy/gateway.example.toml"])
        .current_dir(&root)
        .output()
        .expect("gateway check");
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{text}");
    assert!(text.starts_with("ok: "), "{text}");
    // The example as installed with its REST token: the token file exists and holds 16
    // characters or more (run refuses to start without it, and so does check), and its line is
    // uncommented.
    let dir = gateway_tests::temp_dir("check");
    let token = dir.join("api-token");
    std::fs::write(&token, "0123456789abcdef\n").expect("write token");
    let shipped =
        std::fs::read_to_string(root.join("deploy/gateway.example.toml")).expect("example");
    let text = shipped
        .replace(
            "# token_file = \"/etc/gateway/api-token\"",
            &format!("token_file = \"{}\"", token.display()),
        )
        // The templates stay where they are shipped.
        .replace(
            "template_dirs = [\"templates\"]",
            &format!(
                "template_dirs = [{:?}]",
                root.join("deploy/templates").display().to_string()
            ),
        );
    assert_ne!(text, shipped, "the example's commented token_file line");
    let example = dir.join("gateway.example.toml");
    std::fs::write(&example, text).expect("write example");
    let out = Command::new(gateway_tests::gateway_bin())
        .args(["check", "--config", example.to_str().expect("path")])
        .output()
        .expect("gateway check");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );

    let bad = dir.join("bad.toml");
    std::fs::write(
        &bad,
        "[modbus_tcp]\nlisten = \"nowhere\"\n\n[lines.a]\nport = \"/dev/ttyS1\"\nprotocol = \"modbus-master-rtu\"\nbaud = 12345\ncolour = \"red\"\n",
    )
    .expect("write");
    let out = Command::new(gateway_tests::gateway_bin())
        .args(["check", "--config", bad.to_str().expect("path")])
        .output()
        .expect("gateway check");
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{text}");
    for path in ["modbus_tcp.listen", "lines.a.baud", "lines.a.colour"] {
        assert!(text.contains(path), "{path} missing from:\n{text}");
    }
}

#[test]
fn run_refuses_a_missing_or_short_api_token_with_the_config_exit_code() {
    // 64 (EX_USAGE): the systemd unit does not restart on it (RestartPreventExitStatus=64), and
    // check reports the same problem.
    let dir = gateway_tests::temp_dir("short-token");
    let token = dir.join("api-token");
    std::fs::write(&token, "too-short\n").expect("write token");
    for (name, http) in [
        (
            "env",
            "token_env = \"GATEWAY_TEST_TOKEN_NEVER_SET\"".to_owned(),
        ),
        ("file", format!("token_file = \"{}\"", token.display())),
    ] {
        let cfg = dir.join(format!("{name}.toml"));
        std::fs::write(
            &cfg,
            format!("[modbus_tcp]\nlisten = \"127.0.0.1:0\"\n[http]\nlisten = \"127.0.0.1:0\"\n{http}\n"),
        )
        .expect("write config");
        let out = Command::new(gateway_tests::gateway_bin())
            .args(["run", "--config", cfg.to_str().expect("path")])
            .env_remove("GATEWAY_TEST_TOKEN_NEVER_SET")
            .output()
            .expect("gateway run");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(64), "{name}: {stderr}");
        assert!(stderr.contains(&format!("http.token_{name}: ")), "{stderr}");
        let (passed, report) = gateway_tests::check_config(&cfg);
        assert!(!passed, "{report}");
        assert!(report.contains(&format!("http.token_{name}: ")), "{report}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_paced_demo_serves_its_devices_with_cable_timing() {
    // Every line on a paced link: bytes take their character time, as on a cable.
    let gw = Gateway::demo(&["--paced"]);
    let mut drive = connect(&gw, 2).await;
    assert_eq!(
        read_holding_eventually(&mut drive, 3102, 4).await,
        vec![40, 600, 500, 0]
    );
    let mut ks = connect(&gw, 17).await;
    assert_eq!(
        read_input_eventually(&mut ks, 1004, 3).await,
        vec![1066, 140, 4158]
    );
    drive
        .write_single_register(9001, 21)
        .await
        .expect("transport")
        .expect("write ACC");
    let values = drive
        .read_holding_registers(9001, 3)
        .await
        .expect("transport")
        .expect("read");
    assert_eq!(values[0], 21);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slave_line_moved_to_another_unit_id_serves_there_and_its_old_mirror_stops() {
    // The demo's HMI line: the gateway as a serial slave, its CP memory on unit 50, where the
    // simulated HMI writes its cycle counter into holding register 10.
    let gw = Gateway::demo(&[]);
    let http = gw.http.expect("the demo serves HTTP");
    let mut old_unit = connect(&gw, 50).await;
    read_holding_eventually(&mut old_unit, 10, 1).await;

    let client = reqwest::Client::builder()
        .no_proxy()
        .build()
        .expect("HTTP client");
    let url = format!("http://{http}/api/v1/config/lines/hmi");
    let mut line: serde_json::Value = client
        .get(&url)
        .send()
        .await
        .expect("GET the line")
        .json()
        .await
        .expect("JSON");
    assert_eq!(line["unit_id"], 50, "{line:#}");
    line["unit_id"] = serde_json::json!(51);
    let put = client.put(&url).json(&line).send().await.expect("PUT");
    assert_eq!(put.status(), reqwest::StatusCode::OK);

    // The mirror under unit 50 is stopped, not left writing into the image for nobody.
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    while !gw.output().contains("CP memory mirror stopped") {
        assert!(
            tokio::time::Instant::now() < deadline,
            "the old mirror was not stopped:\n{}",
            gw.output()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // Unit 51 serves the memory, the HMI's counter still moving; unit 50 is no unit any more.
    let mut new_unit = connect(&gw, 51).await;
    let before = read_holding_eventually(&mut new_unit, 10, 1).await;
    let deadline = tokio::time::Instant::now() + FIRST_POLL;
    loop {
        let now = read_holding_eventually(&mut new_unit, 10, 1).await;
        if now != before {
            break;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "the HMI counter stands still on unit 51"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let gone = old_unit
        .read_holding_registers(10, 1)
        .await
        .expect("transport");
    assert_eq!(gone, Err(ExceptionCode::GatewayPathUnavailable));
}

/// The demo's diagnostic unit (docs/diagnostics.md).
const DIAGNOSTIC_UNIT: &str = "247";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mbpoll_reads_the_gateway_health_from_the_diagnostic_unit() {
    let gw = Gateway::demo(&[]);
    // Wait for the first polls of the KS vario, then ask mbpoll.
    let mut ks = connect(&gw, 17).await;
    read_input_eventually(&mut ks, 1004, 3).await;

    // The header through FC 04: version 1, 5 lines, 4 devices (two drives, the KS vario and
    // the meter on its bus), block sizes and addresses.
    let out = mbpoll(
        &gw,
        &["-a", DIAGNOSTIC_UNIT, "-t", "3", "-r", "0", "-c", "9"],
        &[],
    );
    let header = mbpoll_values(&out);
    assert_eq!(header, [1, 5, 4, 16, 32, 8, 16, 176, 10], "{out}");

    // The block of line `drive` (the second line by name: ascii, drive, hmi, ksvario, r3964),
    // through FC 03: STATUS word, port open, devices online and polled, frames sent/received.
    let drive = 16 + 32;
    let out = mbpoll(
        &gw,
        &[
            "-a",
            DIAGNOSTIC_UNIT,
            "-t",
            "4",
            "-r",
            &drive.to_string(),
            "-c",
            "32",
        ],
        &[],
    );
    let block = mbpoll_values(&out);
    assert_eq!(block.len(), 32, "{out}");
    assert_eq!(block[1], 1, "port open: {out}");
    assert_eq!(block[3], 2, "two drives on the bus: {out}");
    let u32_at = |i: usize| (block[i] << 16) | block[i + 1];
    assert!(
        u32_at(4) > 0 && u32_at(6) > 0,
        "frames sent and received: {out}"
    );
    // Class 00h: the line took its parameters (00 03h) at least once.
    assert!(u32_at(12) >= 1, "class 00h count: {out}");
    // The events per class add up to what the STATUS word's class shows at least once.
    let class = block[0] >> 8;
    let classes = [0x00, 0x01, 0x02, 0x03, 0x04, 0x05, 0x07, 0x08, 0x0E, 0x1E];
    let i = classes
        .iter()
        .position(|c| *c == class)
        .expect("a catalog class");
    assert!(u32_at(12 + 2 * i) >= 1, "class {class:02X}h counted: {out}");

    // The KS vario's device block (the third device): online, a fresh value, no exception,
    // line 3, unit id 17, slave 17.
    let out = mbpoll(
        &gw,
        &[
            "-a",
            DIAGNOSTIC_UNIT,
            "-t",
            "3",
            "-r",
            &(176 + 2 * 8).to_string(),
            "-c",
            "6",
        ],
        &[],
    );
    let device = mbpoll_values(&out);
    assert_eq!(device[0], 1, "online: {out}");
    assert!(device[1] < 100, "age under 10 s in 100 ms steps: {out}");
    assert_eq!(device[2..], [0, 3, 17, 17], "{out}");

    // Read-only: a write is an illegal function, a read past the end an illegal address.
    let mut diag = connect(&gw, 247).await;
    assert_eq!(
        diag.write_single_register(0, 2).await.expect("transport"),
        Err(ExceptionCode::IllegalFunction)
    );
    assert_eq!(
        diag.read_holding_registers(176 + 4 * 8 - 1, 2)
            .await
            .expect("transport"),
        Err(ExceptionCode::IllegalDataAddress)
    );
}

/// How long the demo runs in the quiet test: long enough for every periodic part of the demo
/// (polls, the partners' telegrams, the mailbox consumer, zenoh publications, rate-limited
/// warnings with their 10 s interval) to come round several times.
const QUIET_RUN: Duration = Duration::from_secs(60);

/// A log line above INFO (the log's level field, padded: ` WARN `, `ERROR `).
fn above_info(line: &str) -> bool {
    line.contains(" WARN ") || line.contains("ERROR ")
}

#[test]
fn the_demo_runs_a_minute_and_stops_without_a_warning() {
    let mut gw = Gateway::demo(&[]);
    std::thread::sleep(QUIET_RUN);
    let status = gw.stop(Duration::from_secs(15));
    assert!(
        status.is_some_and(|s| s.success()),
        "exit {status:?}:\n{}",
        gw.output()
    );
    let output = gw.output();
    // One warning on purpose, at start-up: the demo's REST API takes changes without a token.
    // At the stop, each telegram line says what it loses: the demo keeps its newest telegrams
    // waiting for a client and has no journal (docs/mailbox.md). Nothing else above INFO: not
    // at start-up, not while it runs, not when it stops.
    let above: Vec<&str> = output
        .lines()
        .filter(|l| above_info(l) && !l.contains("telegrams waiting were not journaled"))
        .collect();
    assert!(
        above.len() == 1 && above[0].contains("INSECURE"),
        "{} lines above INFO, one expected (INSECURE):\n{}\n\nwhole output:\n{output}",
        above.len(),
        above.join("\n")
    );
}

/// The harness's answer to a zenoh port another process took between choosing it and the
/// gateway binding it: the gateway refuses to start ("Address already in use") and the next port
/// is tried.
#[test]
fn a_demo_whose_zenoh_port_was_taken_starts_again_on_another() {
    let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
    let taken_port = taken.local_addr().expect("addr").port();
    let Err(output) = Gateway::try_demo(taken_port, &[]) else {
        panic!("the demo started on a taken port");
    };
    assert!(output.contains("Address already in use"), "{output}");

    let mut ports = [taken_port, gateway_tests::free_port()].into_iter();
    let mut gw = Gateway::on_zenoh_ports(
        || ports.next().unwrap_or_else(gateway_tests::free_port),
        |port| Gateway::try_demo(port, &[]),
    );
    assert_ne!(gw.zenoh_port, Some(taken_port));
    assert!(gw.zenoh_port.is_some());
    assert!(gw
        .stop(Duration::from_secs(10))
        .is_some_and(|s| s.success()));
}
