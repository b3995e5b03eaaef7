//! End to end on the binary with separate simulator processes on socat pty links: a device that
//! stops answering gives 0x0B while the other line keeps answering.

use std::time::{Duration, Instant};

use gateway_tests::{check_config, device_sim, temp_dir, two_device_lines, Gateway, SocatLink};
use tokio_modbus::client::{tcp, Reader};
use tokio_modbus::prelude::{ExceptionCode, Slave};

/// The reply monitoring time configured for both lines.
const REPLY_TIMEOUT: Duration = Duration::from_millis(500);

fn config(drive: &std::path::Path, ks: &std::path::Path) -> String {
    let lines = two_device_lines(drive, ks, "500ms", Some(("1s", "2s")));
    format!(
        r#"
[gateway]
name = "e2e"

[modbus_tcp]
listen = "127.0.0.1:0"
{lines}"#
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stopped_simulator_answers_0x0b_while_the_other_line_keeps_answering() {
    let dir = temp_dir("stopped-sim");
    let drive = SocatLink::new(&dir, "drive");
    let ks = SocatLink::new(&dir, "ks");
    let mut drive_sim = device_sim("altivar71", &drive.b);
    let _ks_sim = device_sim("ksvario", &ks.b);
    let cfg = dir.join("gateway.toml");
    std::fs::write(&cfg, config(&drive.a, &ks.a)).expect("write config");

    let (passed, report) = check_config(&cfg);
    assert!(passed, "{report}");

    let gw = Gateway::run(&cfg);
    let mut drive_ctx = tcp::connect_slave(gw.modbus_tcp, Slave(2))
        .await
        .expect("connect");
    let mut ks_ctx = tcp::connect_slave(gw.modbus_tcp, Slave(17))
        .await
        .expect("connect");

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
        if d.as_deref() == Ok(&[40, 600, 500, 0][..]) && k.as_deref() == Ok(&[1066, 140, 4158][..])
        {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "both devices never answered: {d:?} {k:?}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }

    // The drive's simulator disappears: the next poll gets no reply within the reply monitoring
    // time, the drive goes offline, and its unit answers 0x0B.
    drive_sim.kill();
    let stopped = Instant::now();
    let answered_0b = loop {
        let d = drive_ctx
            .read_holding_registers(3102, 4)
            .await
            .expect("transport");
        if d == Err(ExceptionCode::GatewayTargetDevice) {
            break stopped.elapsed();
        }
        assert!(
            stopped.elapsed() < Duration::from_secs(10),
            "unit 2 still answers {d:?}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    eprintln!("unit 2 answered 0x0B {answered_0b:?} after its simulator was killed");
    // One poll period, the reply monitoring time and scheduling slack on a shared machine.
    assert!(
        answered_0b < REPLY_TIMEOUT + Duration::from_millis(200) + Duration::from_millis(1500),
        "0x0B only after {answered_0b:?}"
    );

    // The KS vario line is not disturbed.
    for _ in 0..10 {
        let k = ks_ctx
            .read_input_registers(1004, 3)
            .await
            .expect("transport");
        assert_eq!(k, Ok(vec![1066, 140, 4158]));
        tokio::time::sleep(Duration::from_millis(50)).await;
    }

    // The drive comes back: a new simulator on the same link, and the unit answers again without
    // a restart of the gateway.
    let _drive_sim = device_sim("altivar71", &drive.b);
    let deadline = Instant::now() + Duration::from_secs(15);
    loop {
        let d = drive_ctx
            .read_holding_registers(3102, 4)
            .await
            .expect("transport");
        if d == Ok(vec![40, 600, 500, 0]) {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the drive never came back: {d:?}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}
