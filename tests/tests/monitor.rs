//! End to end on the binary: the frame monitor of `gateway demo`'s lines.
//!
//! - `GET /api/v1/lines/drive/frames`: the drive line's requests and answers, oldest first, with
//!   verdicts and summaries; `?since=` pages; `?follow=true` streams the next frames as
//!   Server-Sent Events;
//! - `GET /api/v1/lines/drive/capture`: a pcapng file that the real tshark decodes with its own
//!   `mbrtu` dissector (link type 147 through the `user_dlts` preference, as docs/monitor.md
//!   says) into the function codes and register addresses the demo polls; `?seconds=1` records
//!   the next second; the 3964R line's capture decodes with deploy/wireshark/cp341_3964r.lua;
//! - zenoh `<prefix>/drive/frames`: one JSON sample per frame in a second zenoh session.

use std::collections::BTreeSet;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use gateway_tests::Gateway;
use serde_json::Value;

/// The `user_dlts` entry that hands link type 147 (USER0) to Wireshark's Modbus RTU dissector.
const MBRTU_USER_DLT: &str = r#"uat:user_dlts:"User 0 (DLT=147)","mbrtu","0","","0","""#;

/// What the demo polls on its drive line (gateway/src/plant/demo.toml): (slave, function,
/// start, quantity).
const DEMO_DRIVE_POLLS: &[(u64, u64, u64, u64)] = &[
    (2, 3, 3201, 9),
    (2, 3, 8602, 3),
    (2, 3, 3102, 4),
    (2, 3, 9001, 2),
    (3, 3, 3201, 9),
    (3, 3, 3102, 4),
];

fn base(gw: &Gateway) -> String {
    format!("http://{}", gw.http.expect("the demo serves HTTP"))
}

async fn frames(client: &reqwest::Client, url: &str) -> Value {
    let r = client.get(url).send().await.expect("GET frames");
    assert_eq!(r.status(), 200, "{url}");
    r.json().await.expect("JSON")
}

/// The drive line's frames once it has at least `n` of them.
async fn frames_eventually(client: &reqwest::Client, gw: &Gateway, n: usize) -> Value {
    let url = format!("{}/api/v1/lines/drive/frames", base(gw));
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let v = frames(client, &url).await;
        if v["frames"].as_array().is_some_and(|f| f.len() >= n) {
            return v;
        }
        assert!(Instant::now() < deadline, "fewer than {n} frames: {v:#}");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

fn hex(s: &str) -> Vec<u8> {
    (0..s.len() / 2)
        .map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).expect("hex"))
        .collect()
}

/// (slave, function, start, quantity) of a read request's bytes.
fn request(bytes: &[u8]) -> (u64, u64, u64, u64) {
    let word = |at: usize| u64::from(u16::from_be_bytes([bytes[at], bytes[at + 1]]));
    (u64::from(bytes[0]), u64::from(bytes[1]), word(2), word(4))
}

async fn capture(client: &reqwest::Client, url: &str, file: &Path) {
    let r = client.get(url).send().await.expect("GET capture");
    assert_eq!(r.status(), 200, "{url}");
    assert_eq!(
        r.headers()
            .get("content-type")
            .and_then(|v| v.to_str().ok()),
        Some("application/x-pcapng")
    );
    let body = r.bytes().await.expect("capture body");
    assert_eq!(
        &body[..4],
        &[0x0A, 0x0D, 0x0D, 0x0A],
        "a pcapng section header"
    );
    std::fs::write(file, &body).expect("write the capture");
}

/// tshark's fields of every packet, tab-separated.
fn tshark_fields(file: &Path, extra: &[&str], fields: &[&str]) -> Vec<Vec<String>> {
    let mut cmd = Command::new(gateway_tests::tshark());
    cmd.arg("-r").arg(file).args(extra).args(["-T", "fields"]);
    for f in fields {
        cmd.args(["-e", f]);
    }
    let out = cmd.output().expect("tshark runs");
    assert!(
        out.status.success(),
        "tshark failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| l.split('\t').map(str::to_owned).collect())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_drive_line_frames_follow_and_capture_decode_with_tshark() {
    let gw = Gateway::demo(&[]);
    let client = reqwest::Client::new();
    let dir = gateway_tests::temp_dir("monitor-capture");

    // The ring: requests (tx) and answers (rx) with good CRCs, ordered by seq and by time.
    let all = frames_eventually(&client, &gw, 12).await;
    assert_eq!(all["line"], "drive");
    assert_eq!(all["capacity"], 256);
    let list = all["frames"].as_array().expect("frames");
    let mut requests = BTreeSet::new();
    for pair in list.windows(2) {
        assert_eq!(
            pair[1]["seq"].as_u64(),
            pair[0]["seq"].as_u64().map(|s| s + 1)
        );
        assert!(
            pair[0]["mono_first_us"].as_u64() <= pair[1]["mono_first_us"].as_u64(),
            "{pair:#?}"
        );
    }
    for f in list {
        assert_eq!(f["verdict"], "ok", "{f:#}");
        assert!(
            f["summary"]
                .as_str()
                .unwrap_or_default()
                .ends_with("CRC ok"),
            "{f:#}"
        );
        assert!(f["first_us"].as_u64() <= f["last_us"].as_u64());
        if f["direction"] == "tx" {
            let bytes = hex(f["bytes"].as_str().expect("hex bytes"));
            requests.insert(request(&bytes));
        }
    }
    assert!(!requests.is_empty());
    for r in &requests {
        assert!(
            DEMO_DRIVE_POLLS.contains(r),
            "{r:?} is not a poll of the demo"
        );
    }

    // `since` pages: only the frames after it.
    let last = list.last().expect("a frame")["seq"].as_u64().expect("seq");
    let page = frames(
        &client,
        &format!("{}/api/v1/lines/drive/frames?since={last}", base(&gw)),
    )
    .await;
    for f in page["frames"].as_array().expect("frames") {
        assert!(f["seq"].as_u64() > Some(last), "{f:#}");
    }

    // `follow`: Server-Sent Events of the frames after `since`, each once, in order.
    let mut sse = client
        .get(format!(
            "{}/api/v1/lines/drive/frames?follow=true&since={last}",
            base(&gw)
        ))
        .send()
        .await
        .expect("GET follow");
    assert_eq!(sse.status(), 200);
    assert_eq!(
        sse.headers()
            .get("content-type")
            .and_then(|v| v.to_str().ok()),
        Some("text/event-stream")
    );
    let mut text = String::new();
    let mut seqs = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(20);
    while seqs.len() < 4 {
        let chunk = tokio::time::timeout_at(deadline.into(), sse.chunk())
            .await
            .expect("frames keep coming")
            .expect("stream")
            .expect("not ended");
        text.push_str(&String::from_utf8_lossy(&chunk));
        while let Some(end) = text.find("\n\n") {
            let event: String = text.drain(..end + 2).collect();
            if !event.contains("event: frame") {
                continue;
            }
            let data = event
                .lines()
                .find_map(|l| l.strip_prefix("data: "))
                .expect("data line");
            let frame: Value = serde_json::from_str(data).expect("frame JSON");
            let id = event
                .lines()
                .find_map(|l| l.strip_prefix("id: "))
                .expect("id line");
            assert_eq!(frame["seq"].to_string(), id);
            seqs.push(frame["seq"].as_u64().expect("seq"));
        }
    }
    drop(sse);
    assert_eq!(seqs[0], last + 1, "follow starts right after since");
    assert!(seqs.windows(2).all(|w| w[1] == w[0] + 1), "{seqs:?}");

    // The capture of the ring decodes with tshark's own Modbus RTU dissector into the requests
    // the ring shows: sent frames on interface 1, answers on interface 0.
    let file = dir.join("drive.pcapng");
    capture(
        &client,
        &format!("{}/api/v1/lines/drive/capture", base(&gw)),
        &file,
    )
    .await;
    let rows = tshark_fields(
        &file,
        &["-o", MBRTU_USER_DLT],
        &[
            "frame.interface_id",
            "mbrtu.unit_id",
            "modbus.func_code",
            "modbus.reference_num",
            "modbus.word_cnt",
            "frame.comment",
        ],
    );
    assert!(rows.len() >= 12, "{rows:?}");
    let mut decoded = BTreeSet::new();
    for row in &rows {
        let [interface, unit, function, reference, count, comment] = &row[..] else {
            panic!("unexpected tshark row {row:?}");
        };
        assert!(comment.contains(" ok: slave "), "{row:?}");
        assert_eq!(function, "3", "{row:?}");
        if interface == "1" {
            let n = |s: &str| s.parse::<u64>().unwrap_or_else(|_| panic!("{row:?}"));
            decoded.insert((n(unit), n(function), n(reference), n(count)));
        } else {
            assert_eq!(interface, "0", "{row:?}");
        }
    }
    assert!(!decoded.is_empty());
    for r in &decoded {
        assert!(
            DEMO_DRIVE_POLLS.contains(r),
            "tshark decoded {r:?}, not a poll of the demo"
        );
    }
    assert!(
        decoded.contains(&(2, 3, 3201, 9)),
        "the status poll of the first drive: {decoded:?}"
    );

    // `seconds=1`: the frames of the next second, all after the request.
    let before = frames(&client, &format!("{}/api/v1/lines/drive/frames", base(&gw))).await;
    let next = before["next_seq"].as_u64().expect("next_seq");
    let timed = dir.join("timed.pcapng");
    capture(
        &client,
        &format!("{}/api/v1/lines/drive/capture?seconds=1", base(&gw)),
        &timed,
    )
    .await;
    let rows = tshark_fields(&timed, &["-o", MBRTU_USER_DLT], &["frame.comment"]);
    assert!(!rows.is_empty(), "the demo polls every 500 ms");
    for row in &rows {
        let seq: u64 = row[0]
            .strip_prefix('#')
            .and_then(|c| c.split(' ').next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("{row:?}"));
        assert!(seq >= next, "{seq} was before the capture began ({next})");
    }
    let r = client
        .get(format!(
            "{}/api/v1/lines/drive/capture?seconds=301",
            base(&gw)
        ))
        .send()
        .await
        .expect("GET");
    assert_eq!(r.status(), 400);

    // The 3964R line: its capture decodes with the Lua dissector (control characters and
    // telegrams with a good BCC).
    let r3964 = dir.join("r3964.pcapng");
    capture(
        &client,
        &format!("{}/api/v1/lines/r3964/capture", base(&gw)),
        &r3964,
    )
    .await;
    let lua = gateway_tests::lua_3964_dissector();
    let rows = tshark_fields(
        &r3964,
        &["-X", &lua],
        &[
            "cp341_3964r.kind",
            "cp341_3964r.control",
            "cp341_3964r.bcc_ok",
        ],
    );
    assert!(
        rows.iter().any(|r| r[0] == "telegram" && r[2] == "1"),
        "{rows:?}"
    );
    assert!(
        rows.iter().any(|r| r[0] == "control" && r[1] == "0x02"),
        "{rows:?}"
    );
    assert!(rows.iter().all(|r| r[2] != "0"), "{rows:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_zenoh_session_receives_the_drive_frames() {
    let gw = Gateway::demo(&[]);
    let port = gw.zenoh_port.expect("a zenoh port");
    let session = gateway_tests::zenoh_client(port).await;
    let sub = session
        .declare_subscriber("gw/demo/drive/frames")
        .await
        .expect("subscriber");
    let mut seqs = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(20);
    while seqs.len() < 4 {
        let sample = tokio::time::timeout_at(deadline.into(), sub.recv_async())
            .await
            .expect("frames on zenoh")
            .expect("sample");
        let frame: Value =
            serde_json::from_slice(&sample.payload().to_bytes()).expect("JSON payload");
        assert_eq!(frame["verdict"], "ok", "{frame:#}");
        assert!(["rx", "tx"].contains(&frame["direction"].as_str().unwrap_or_default()));
        seqs.push(frame["seq"].as_u64().expect("seq"));
    }
    assert!(seqs.windows(2).all(|w| w[1] > w[0]), "{seqs:?}");
    session.close().await.expect("close");
}
