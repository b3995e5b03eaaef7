//! End to end on the binary: the REST API of `gateway run` (socat links, simulator processes) and
//! of `gateway demo`, with a real HTTP client (reqwest).
//!
//! - a PUT that changes one line's baud rate restarts that line only: the other lines keep their
//!   task (start time), their port (`port_opens`), their counters, and an open Modbus TCP client
//!   keeps reading on the same connection; `/readyz` stays 200 all through the restart;
//! - every line route: status, diagnostics (newest first, catalog texts), clearing them, queued
//!   telegrams (read, acknowledge), sending, tags (read, write through to the device), RS232
//!   signals on a pseudo-terminal (a clear error), health, readiness, OpenAPI, metrics;
//! - changes need the token (no token 401, a wrong one 401, the right one 200; none configured
//!   403), the token is never returned; a configuration with three mistakes gets all three;
//! - SIGKILL in the middle of a series of PUTs leaves a configuration file that loads, the old
//!   or the new one.

use std::time::{Duration, Instant};

use gateway_tests::start_sim;
use reqwest::{Method, StatusCode};
use serde_json::{json, Value};
use tokio_modbus::client::{tcp, Reader};
use tokio_modbus::prelude::Slave;

#[path = "rest/support.rs"]
mod support;

#[path = "rest/as_written.rs"]
mod as_written;
#[path = "rest/config.rs"]
mod config;
#[path = "rest/routes.rs"]
mod routes;

use support::{check, path, sample, Plant};

/// The KS vario simulator's process values (input registers 1004..1006).
const KS_VALUES: [u16; 3] = [1066, 140, 4158];

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_baud_rate_change_restarts_only_its_line() {
    let mut plant = Plant::start("rest-baud").await;
    let api = plant.api.clone();

    // A SCADA client on unit 17 (the KS vario line), reading on one connection throughout.
    let mut ks = tcp::connect_slave(plant.gw.modbus_tcp, Slave(17))
        .await
        .expect("connect");
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let r = ks.read_input_registers(1004, 3).await.expect("transport");
        if r.as_deref() == Ok(&KS_VALUES[..]) {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the KS vario never answered: {r:?}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let accepted_before = sample(
        &api.metrics().await,
        "gateway_modbus_tcp_connections_accepted_total",
    );
    assert_eq!(accepted_before, Some(1.0));

    let before = api.get_ok("/api/v1/status").await;
    let line = |status: &Value, name: &str| -> Value {
        status["lines"]
            .as_array()
            .and_then(|l| l.iter().find(|l| l["name"] == name))
            .cloned()
            .unwrap_or_else(|| panic!("no line {name} in {status:#}"))
    };
    let (ks_before, ascii_before, drive_before) = (
        line(&before, "ksvario"),
        line(&before, "ascii"),
        line(&before, "drive"),
    );
    assert_eq!(ks_before["port_opens"], 1, "{ks_before:#}");
    assert_eq!(before["modbus_tcp"]["connections"], 1);

    // The drive line goes to 9600 baud.
    let mut drive = api.get_ok("/api/v1/config/lines/drive").await;
    assert_eq!(drive["baud"], 19200);
    drive["baud"] = json!(9600);
    assert_eq!(api.get("/readyz").await.status, StatusCode::OK);
    // Readiness is watched all through the restart: a line that had opened its port, restarted
    // on the same port, does not make the gateway unready while its new task reopens it.
    let watch = tokio::sync::watch::channel(false);
    let readiness = {
        let (api, mut stop) = (api.clone(), watch.1.clone());
        tokio::spawn(async move {
            let mut seen = Vec::new();
            while !*stop.borrow_and_update() {
                let a = api.get("/readyz").await;
                if a.status != StatusCode::OK {
                    seen.push(a.body);
                }
                tokio::select! {
                    _ = stop.changed() => {}
                    () = tokio::time::sleep(Duration::from_millis(2)) => {}
                }
            }
            seen
        })
    };
    let put_at = Instant::now();
    let answer = api
        .change(Method::PUT, "/api/v1/config/lines/drive", Some(&drive))
        .await;
    let put_took = put_at.elapsed();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let _ = watch.0.send(true);
    let unready = readiness.await.expect("readiness watcher");
    assert!(
        unready.is_empty(),
        "/readyz answered 503 during the restart of a line: {unready:#?}"
    );
    assert_eq!(answer.status, StatusCode::OK, "{:#}", answer.body);
    let applied = &answer.body["applied"];
    assert_eq!(applied["lines_restarted"], json!(["drive"]), "{applied:#}");
    assert_eq!(applied["lines_started"], json!([]));
    assert_eq!(applied["lines_stopped"], json!([]));
    assert_eq!(applied["servers_restarted"], json!([]));
    assert_eq!(answer.body["persisted"], true);
    eprintln!("PUT /config/lines/drive (restart of one line) answered in {put_took:?}");

    // The drive's simulator follows to 9600 baud.
    plant.drive_sim.kill();
    plant.drive_sim = start_sim(&[
        "--device",
        "altivar71",
        "--port",
        path(&plant.drive.b),
        "--baud",
        "9600",
    ]);

    // The KS vario connection keeps reading, on the same connection, all the while.
    for _ in 0..10 {
        let r = ks
            .read_input_registers(1004, 3)
            .await
            .expect("same connection");
        assert_eq!(r.as_deref(), Ok(&KS_VALUES[..]));
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let after = api
        .wait_for(
            "/api/v1/status",
            Duration::from_secs(20),
            "drive reopened",
            |s| {
                let d = line(s, "drive");
                d["port_opens"] == 1 && d["state"] == "running" && d["devices_online"] == 1
            },
        )
        .await;
    let (ks_after, ascii_after, drive_after) = (
        line(&after, "ksvario"),
        line(&after, "ascii"),
        line(&after, "drive"),
    );
    // Untouched: same task, same port, counters going on from where they were.
    for (b, a) in [(&ks_before, &ks_after), (&ascii_before, &ascii_after)] {
        assert_eq!(a["started"], b["started"], "{} restarted", a["name"]);
        assert_eq!(
            a["port_opens"], b["port_opens"],
            "{} reopened its port",
            a["name"]
        );
        for counter in ["frames_received", "bytes_received", "events"] {
            let (x, y) = (
                b["counters"][counter].as_u64().expect("counter"),
                a["counters"][counter].as_u64().expect("counter"),
            );
            assert!(y >= x, "{} {counter} went back from {x} to {y}", a["name"]);
        }
    }
    let polls = |l: &Value| l["devices"][0]["polls_ok"].as_u64().expect("polls_ok");
    assert!(
        polls(&ks_after) > polls(&ks_before),
        "the KS vario is still polled"
    );
    // Restarted: a new task, its port opened once since.
    assert_ne!(drive_after["started"], drive_before["started"]);
    assert_eq!(after["modbus_tcp"]["connections"], 1);
    assert_eq!(
        sample(
            &api.metrics().await,
            "gateway_modbus_tcp_connections_accepted_total"
        ),
        accepted_before,
        "the Modbus TCP client kept its connection"
    );

    // The drive answers at its new speed.
    let mut atv = tcp::connect_slave(plant.gw.modbus_tcp, Slave(2))
        .await
        .expect("connect");
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let r = atv
            .read_holding_registers(3102, 4)
            .await
            .expect("transport");
        if r.as_deref() == Ok(&[40, 600, 500, 0][..]) {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the drive never answered at 9600: {r:?}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }

    // The file holds the new configuration, the previous one is kept; both load.
    let saved = std::fs::read_to_string(&plant.config).expect("config file");
    assert!(drive_section(&saved).contains("baud = 9600"), "{saved}");
    assert!(check(&plant.config).0);
    let prev = plant.dir.join("gateway.toml.prev");
    let (ok, text) = check(&prev);
    assert!(ok, "{text}");
    assert_eq!(
        std::fs::read_to_string(&prev).expect("prev"),
        plant.config_text,
        "the previous version is the file before the change"
    );
    assert_eq!(api.get_ok("/api/v1/config/lines/drive").await["baud"], 9600);
}

/// The `[lines.drive]` table of a saved configuration (up to the next table).
fn drive_section(text: &str) -> &str {
    let start = text.find("[lines.drive]").unwrap_or(text.len());
    let rest = text.get(start + 1..).unwrap_or("");
    let end = rest.find("\n[").map_or(text.len(), |e| start + 1 + e);
    text.get(start..end).unwrap_or("")
}
