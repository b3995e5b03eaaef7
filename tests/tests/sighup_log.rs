//! End to end on the binary: a burst of SIGHUPs writes a bounded number of log lines plus one
//! line saying how many were left out, and the configuration file is still read again (its last
//! change is the one in force).

use std::process::Command;
use std::time::{Duration, Instant};

use gateway_tests::{temp_dir, Gateway};

/// SIGHUPs sent in the burst.
const SIGHUPS: u32 = 200;

fn config(max_connections: u32) -> String {
    format!(
        r#"
[gateway]
name = "hangups"

[modbus_tcp]
listen = "127.0.0.1:0"
max_connections = {max_connections}
"#
    )
}

fn hangup(pid: u32) {
    let status = Command::new("kill")
        .args(["-HUP", &pid.to_string()])
        .status()
        .expect("kill -HUP");
    assert!(status.success());
}

fn sighup_lines(output: &str) -> Vec<&str> {
    output.lines().filter(|l| l.contains("SIGHUP")).collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_of_sighups_writes_a_bounded_log_and_the_last_change_is_applied() {
    let dir = temp_dir("sighup_log");
    let file = dir.join("gateway.toml");
    std::fs::write(&file, config(64)).expect("write config");
    let mut gw = Gateway::run(&file);
    let pid = gw.pid();

    // The file changes between SIGHUPs; the last value written is 1 + SIGHUPS.
    for n in 1..=SIGHUPS {
        std::fs::write(&file, config(1 + n)).expect("write config");
        hangup(pid);
    }
    // The window of the limit is 10 s: then one line tells how many were left out.
    let told = gw.wait_for("log lines about SIGHUPs left out", Duration::from_secs(30));
    let left_out: u64 = told
        .split("left_out=")
        .nth(1)
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no count in {told:?}"));

    let output = gw.output();
    let lines = sighup_lines(&output);
    // At most 6 INFO and 6 WARN lines in the window, and the one line with the count.
    assert!(
        lines.len() <= 13,
        "{} SIGHUP lines for {SIGHUPS} SIGHUPs:\n{}",
        lines.len(),
        lines.join("\n")
    );
    // Some SIGHUPs were left out of the log (the kernel may merge SIGHUPs that arrive while one
    // is pending, so the exact number received is not known here), and said so.
    assert!(left_out > 0, "{told}");
    let written = lines.len() - 1;
    eprintln!("{SIGHUPS} SIGHUPs sent: {written} lines written, {left_out} left out");

    // The configuration in force is the file's last version.
    let http = gw.http.expect("http");
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let config: serde_json::Value = reqwest::get(format!("http://{http}/api/v1/config"))
            .await
            .expect("GET config")
            .json()
            .await
            .expect("JSON");
        if config["modbus_tcp"]["max_connections"] == serde_json::json!(1 + SIGHUPS) {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the last change was not applied: {:#}",
            config["modbus_tcp"]
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    // A SIGHUP after the window is logged again.
    hangup(pid);
    gw.wait_for(
        "SIGHUP received: reading the configuration",
        Duration::from_secs(10),
    );
    let after = gw.output();
    assert_eq!(
        sighup_lines(&after)
            .iter()
            .filter(|l| l.contains("SIGHUP received"))
            .count(),
        sighup_lines(&output)
            .iter()
            .filter(|l| l.contains("SIGHUP received"))
            .count()
            + 1
    );
}
