//! End to end on the binary: a `3964r-tap` line reading both directions of a 3964R point-to-point
//! link through a Y-cable, one socat pty link per direction. The test plays both partners on the
//! links' other ends, with real gaps between STX, DLE, the telegram and the acknowledgement as
//! partners answer what they received (003 6.3.1):
//!
//! ```text
//!   A: STX          telegram "A-1"            (exchange 1: B acknowledges)
//!   B:      DLE                      DLE
//!   B: STX          telegram DLE "B-2"        (exchange 2: the DLE is doubled on the wire)
//!   A:      DLE                      DLE
//!   A: STX          telegram "A-3"            (exchange 3: B refuses it with NAK)
//!   B:      DLE                      NAK
//!   A: STX          telegram "A-3"            (exchange 4: A repeats it, B acknowledges)
//!   B:      DLE                      DLE
//! ```
//!
//! It checks what every view shows (REST telegrams with their side, line status with the NAK's
//! event, `/metrics`, `/frames`, the pcapng capture decoded by the real tshark with
//! deploy/wireshark/cp341_3964r.lua, zenoh `<line>/rx`), that every send is refused (REST,
//! zenoh, Modbus TCP) and that nothing is ever written to either port, and what `gateway check`
//! says of the config and of one with `port_b = port`.

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use gateway_tests::{check_config, free_port, temp_dir, Gateway, SocatLink};
use proto_core::proc3964::frame::encode;
use proto_core::proc3964::{Variant, DLE, NAK, STX};
use serde_json::Value;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_modbus::client::{tcp, Reader, Writer};
use tokio_modbus::prelude::{ExceptionCode, Slave};
use tokio_serial::SerialStream;

/// The line's name and the gateway's (zenoh keys `gw/<gateway>/<line>/..`).
const LINE: &str = "link";
const GATEWAY: &str = "yt";
/// The mailbox's Modbus TCP unit id.
const UNIT: u8 = 44;
/// The serial speed of both directions.
const BAUD: u32 = 9600;
/// Between one partner's bytes and the other's answer: a partner answers what it received, a few
/// character times later (1 ms a character at 9600 Bd), well within the character delay time
/// (220 ms) and the acknowledgement delay time (2 s) of 003 6.3.3.
const STEP: Duration = Duration::from_millis(20);

/// The mailbox layout (gateway/src/mailbox/layout.rs): the receive block, the counters and the
/// send block.
const RX_SEQ: u16 = 1;
const DIAG: u16 = 520;
const ACK: u16 = 600;
const TX_REQ: u16 = 1008;

/// The telegrams of the exchanges, user data.
const A1: &[u8] = b"A-1";
const B2: &[u8] = b"\x10B-2";
const A3: &[u8] = b"A-3";

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn config(port: &Path, port_b: &Path, zenoh_port: u16) -> String {
    format!(
        r#"
[gateway]
name = "{GATEWAY}"

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

[lines.{LINE}]
protocol = "3964r-tap"
port = "{port}"
port_b = "{port_b}"
baud = {BAUD}
block_check = true
character_delay = "220ms"
ack_delay = "2s"
max_telegram_len = 64
receive_buffer = 16
unit_id = {UNIT}
"#,
        port = port.display(),
        port_b = port_b.display(),
    )
}

fn open_partner(path: &Path) -> SerialStream {
    SerialStream::open(&tokio_serial::new(path.to_str().expect("utf-8 path"), BAUD))
        .expect("a partner's end of its link")
}

/// The two partners on their links' ends, and the line's frame monitor to pace them by.
struct Partners {
    a: SerialStream,
    b: SerialStream,
    client: reqwest::Client,
    /// `GET /api/v1/lines/<line>/frames`.
    frames_url: String,
    /// Frames the monitor has shown so far (one per step).
    frames: u64,
}

// === impl Partners ===

impl Partners {
    /// `side` transmits `bytes`; returns once the gateway has read them. A partner answers what
    /// it has received; the tap orders the two ports' bytes by when it reads them, so each step
    /// waits (besides the pause of a real partner) until the monitor shows its frame: on a
    /// loaded machine a pause alone could let both partners' bytes be read in one go.
    async fn transmit(&mut self, side: &str, bytes: &[u8]) {
        let port = if side == "a" {
            &mut self.a
        } else {
            &mut self.b
        };
        port.write_all(bytes).await.expect("write to the link");
        port.flush().await.expect("flush");
        tokio::time::sleep(STEP).await;
        let url = format!("{}?since={}", self.frames_url, self.frames);
        let deadline = Instant::now() + Duration::from_secs(10);
        loop {
            let page = get_json(&self.client, &url).await;
            if page["frames"].as_array().is_some_and(|f| !f.is_empty()) {
                break;
            }
            assert!(
                Instant::now() < deadline,
                "the gateway did not read {bytes:02x?} of partner {side}: {page:#}"
            );
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        self.frames += 1;
    }

    /// One exchange of 003 6.3.1: `sender` requests with STX, the other partner answers DLE,
    /// `sender` sends the telegram, the other acknowledges with `ack` (DLE, or NAK to refuse it).
    async fn exchange(&mut self, sender: &str, data: &[u8], ack: u8) {
        let receiver = if sender == "a" { "b" } else { "a" };
        self.transmit(sender, &[STX]).await;
        self.transmit(receiver, &[DLE]).await;
        self.transmit(sender, &encode(data, Variant::P3964R)).await;
        self.transmit(receiver, &[ack]).await;
    }
}

async fn get_json(client: &reqwest::Client, url: &str) -> Value {
    let r = client.get(url).send().await.expect("GET");
    assert_eq!(r.status(), 200, "{url}");
    r.json().await.expect("JSON")
}

/// What the monitor shows of the four exchanges: (direction, verdict, bytes on the wire, user
/// data of a telegram).
fn expected_frames() -> Vec<(&'static str, &'static str, Vec<u8>, &'static [u8])> {
    let telegram = |data: &[u8]| encode(data, Variant::P3964R);
    let mut out = Vec::new();
    for (sender, receiver, data, ack) in [
        ("a", "b", A1, DLE),
        ("b", "a", B2, DLE),
        ("a", "b", A3, NAK),
        ("a", "b", A3, DLE),
    ] {
        out.push((sender, "control", vec![STX], &[][..]));
        out.push((receiver, "control", vec![DLE], &[]));
        out.push((sender, "ok", telegram(data), data));
        out.push((receiver, "control", vec![ack], &[]));
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_3964r_tap_line_shows_both_partners_telegrams_and_refuses_every_send() {
    let dir = temp_dir("tap3964");
    // One link per direction: partner A writes on `a_link.b`, the gateway reads `a_link.a`.
    let a_link = SocatLink::new(&dir, "txd-a");
    let b_link = SocatLink::new(&dir, "txd-b");

    // `gateway check` accepts the config; `port_b = port` is refused at `lines.link.port_b`.
    let cfg = dir.join("gateway.toml");
    let zenoh_port = free_port();
    std::fs::write(&cfg, config(&a_link.a, &b_link.a, zenoh_port)).expect("write config");
    let (passed, report) = check_config(&cfg);
    assert!(passed, "{report}");
    let same = dir.join("same-port.toml");
    std::fs::write(&same, config(&a_link.a, &a_link.a, zenoh_port)).expect("write config");
    let (passed, report) = check_config(&same);
    assert!(!passed, "port_b = port was accepted:\n{report}");
    assert!(report.contains(&format!("lines.{LINE}.port_b")), "{report}");

    // (The zenoh port is chosen again should another process take it before the gateway.)
    let gw = Gateway::run_on_free_zenoh_port(&cfg, |port| config(&a_link.a, &b_link.a, port));
    let zenoh_port = gw.zenoh_port.expect("zenoh port");
    let http = format!("http://{}", gw.http.expect("HTTP"));
    let client = reqwest::Client::new();
    let partner_a = open_partner(&a_link.b);
    let partner_b = open_partner(&b_link.b);

    // Both ports open (the line opens them together) before the partners talk.
    let line_url = format!("{http}/api/v1/lines/{LINE}");
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let status = get_json(&client, &line_url).await;
        if status["state"] == "running" {
            assert_eq!(status["protocol"], "3964r-tap", "{status}");
            assert_eq!(
                status["port"],
                a_link.a.to_str().expect("utf-8"),
                "{status}"
            );
            assert_eq!(
                status["port_b"],
                b_link.a.to_str().expect("utf-8"),
                "{status}"
            );
            break;
        }
        assert!(
            Instant::now() < deadline,
            "the line never ran: {status:#}\n{}",
            gw.output()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }

    // A zenoh subscriber on the line's received telegrams, declared before they come; the
    // refused send below is a round trip to the gateway on the same session, after which the
    // gateway knows the subscription.
    let session = gateway_tests::zenoh_client(zenoh_port).await;
    let rx = session
        .declare_subscriber(format!("gw/{GATEWAY}/{LINE}/rx"))
        .await
        .expect("subscribe");

    // zenoh: a send (a get on `<line>/tx` with the telegram) is answered with the refusal.
    let replies = session
        .get(format!("gw/{GATEWAY}/{LINE}/tx"))
        .payload(b"from zenoh".to_vec())
        .timeout(Duration::from_secs(10))
        .await
        .expect("get");
    let reply = tokio::time::timeout(Duration::from_secs(10), replies.recv_async())
        .await
        .expect("a reply")
        .expect("reply");
    let sample = reply.result().expect("a reply sample");
    let result: Value = serde_json::from_slice(&sample.payload().to_bytes()).expect("JSON");
    assert_eq!(result["ok"], Value::Bool(false), "{result}");
    assert!(
        result["error"]
            .as_str()
            .is_some_and(|e| e.contains("only listens")),
        "{result}"
    );

    // The partners talk.
    let played = Instant::now();
    let mut partners = Partners {
        a: partner_a,
        b: partner_b,
        client: client.clone(),
        frames_url: format!("{http}/api/v1/lines/{LINE}/frames"),
        frames: 0,
    };
    partners.exchange("a", A1, DLE).await;
    partners.exchange("b", B2, DLE).await;
    partners.exchange("a", A3, NAK).await;
    partners.exchange("a", A3, DLE).await;
    let played = played.elapsed();

    // REST: the three acknowledged telegrams in order, each with its sender; the refused one
    // only once (its repetition).
    let telegrams_url = format!("{http}/api/v1/lines/{LINE}/telegrams");
    let deadline = Instant::now() + Duration::from_secs(10);
    let queue = loop {
        let queue = get_json(&client, &telegrams_url).await;
        if queue["telegrams"].as_array().is_some_and(|t| t.len() >= 3) {
            break queue;
        }
        assert!(
            Instant::now() < deadline,
            "fewer than 3 telegrams: {queue:#}\n{}",
            gw.output()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    let seen: Vec<(&str, &str)> = queue["telegrams"]
        .as_array()
        .expect("telegrams")
        .iter()
        .map(|t| {
            (
                t["side"].as_str().unwrap_or("?"),
                t["hex"].as_str().unwrap_or("?"),
            )
        })
        .collect();
    let (a1, b2, a3) = (hex(A1), hex(B2), hex(A3));
    assert_eq!(
        seen,
        [("a", a1.as_str()), ("b", b2.as_str()), ("a", a3.as_str())],
        "{queue:#}"
    );
    assert_eq!(queue["capacity"], 16, "{queue:#}");
    assert_eq!(queue["dropped"], 0, "{queue:#}");

    // The line's status: the NAK to A's telegram is 07 06h from A's view, its repetition 07 01h;
    // three telegrams received.
    let status = get_json(&client, &line_url).await;
    let count = |code: &str| {
        status["event_counts"]
            .as_array()
            .expect("event_counts")
            .iter()
            .find(|c| c["event"]["code"] == code)
            .and_then(|c| c["count"].as_u64())
            .unwrap_or(0)
    };
    assert_eq!(count("0706"), 1, "{status:#}");
    assert_eq!(count("0701"), 1, "{status:#}");
    assert_eq!(status["port_opens"], 1, "{status:#}");
    assert_eq!(status["counters"]["frames_sent"], 0, "{status:#}");
    assert_eq!(status["counters"]["bytes_sent"], 0, "{status:#}");
    assert_eq!(status["counters"]["frames_received"], 3, "{status:#}");
    // A telegram line counts the user bytes of its telegrams (the mailbox's counts).
    let user_bytes = A1.len() + B2.len() + A3.len();
    assert_eq!(
        status["counters"]["bytes_received"].as_u64(),
        u64::try_from(user_bytes).ok(),
        "{status:#}"
    );
    // The diagnostic buffer has the NAK's event, and the log says whose telegram it was.
    let diag = get_json(&client, &format!("{line_url}/diag")).await;
    assert!(
        diag["entries"]
            .as_array()
            .expect("entries")
            .iter()
            .any(|e| e["code"] == "0706"),
        "{diag:#}"
    );
    assert!(
        gw.output().contains("partner a: NAK to its telegram"),
        "{}",
        gw.output()
    );

    // /metrics: the NAK counted once under its reason, nothing else discarded.
    let metrics = client
        .get(format!("{http}/metrics"))
        .send()
        .await
        .expect("GET /metrics")
        .text()
        .await
        .expect("text");
    let discarded = |reason: &str| {
        let series =
            format!("gateway_frames_discarded_total{{line=\"{LINE}\",reason=\"{reason}\"}}");
        metrics
            .lines()
            .find_map(|l| l.strip_prefix(series.as_str()))
            .map(str::trim)
            .unwrap_or_else(|| panic!("no {series} in /metrics:\n{metrics}"))
            .to_owned()
    };
    assert_eq!(discarded("nak"), "1", "{metrics}");
    for reason in [
        "missing_dle",
        "bad_bcc",
        "bad_telegram",
        "conflict",
        "stray",
    ] {
        assert_eq!(discarded(reason), "0", "{reason}\n{metrics}");
    }
    // The bytes on the wire, both ports'.
    let wire_bytes: usize = expected_frames().iter().map(|f| f.2.len()).sum();
    let bytes = format!("gateway_bytes_total{{direction=\"rx\",line=\"{LINE}\"}} {wire_bytes}");
    assert!(
        metrics.lines().any(|l| l == bytes),
        "no {bytes}:\n{metrics}"
    );
    let telegrams = format!("gateway_telegrams_total{{direction=\"rx\",line=\"{LINE}\"}} 3");
    assert!(
        metrics.lines().any(|l| l == telegrams),
        "no {telegrams}:\n{metrics}"
    );

    // /frames: every frame under the side that sent it, in order on the wire; B's telegram
    // (data beginning with DLE, doubled) is one frame.
    let frames = get_json(&client, &format!("{http}/api/v1/lines/{LINE}/frames")).await;
    let got: Vec<(String, String, String)> = frames["frames"]
        .as_array()
        .expect("frames")
        .iter()
        .map(|f| {
            (
                f["direction"].as_str().unwrap_or("?").to_owned(),
                f["verdict"].as_str().unwrap_or("?").to_owned(),
                f["bytes"].as_str().unwrap_or("?").to_owned(),
            )
        })
        .collect();
    let want: Vec<(String, String, String)> = expected_frames()
        .into_iter()
        .map(|(d, v, b, _)| (d.to_owned(), v.to_owned(), hex(&b).to_uppercase()))
        .collect();
    // (The monitor's hex is upper case.)
    assert_eq!(got, want, "{frames:#}");
    assert!(
        hex(&encode(B2, Variant::P3964R)).starts_with("1010"),
        "B's DLE is doubled on the wire"
    );

    // /capture: the real tshark with the Lua dissector decodes both interfaces and the
    // telegrams.
    let r = client
        .get(format!("{http}/api/v1/lines/{LINE}/capture"))
        .send()
        .await
        .expect("GET capture");
    assert_eq!(r.status(), 200);
    let pcap = dir.join("tap.pcapng");
    std::fs::write(&pcap, r.bytes().await.expect("capture body")).expect("write the capture");
    let lua = gateway_tests::lua_3964_dissector();
    let out = Command::new(gateway_tests::tshark())
        .arg("-r")
        .arg(&pcap)
        .args(["-X", &lua, "-T", "fields"])
        .args(["-e", "frame.interface_name"])
        .args(["-e", "cp341_3964r.kind"])
        .args(["-e", "cp341_3964r.control"])
        .args(["-e", "cp341_3964r.data"])
        .args(["-e", "cp341_3964r.length"])
        .args(["-e", "cp341_3964r.bcc_ok"])
        .output()
        .expect("tshark runs");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "tshark failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rows: Vec<Vec<&str>> = text.lines().map(|l| l.split('\t').collect()).collect();
    let want: Vec<Vec<String>> = expected_frames()
        .into_iter()
        .map(|(side, _, bytes, data)| {
            let interface = format!("{LINE} {side}");
            if let [control] = bytes[..] {
                vec![
                    interface,
                    "control".into(),
                    format!("0x{control:02x}"),
                    String::new(),
                    String::new(),
                    String::new(),
                ]
            } else {
                vec![
                    interface,
                    "telegram".into(),
                    String::new(),
                    hex(data),
                    data.len().to_string(),
                    "1".into(),
                ]
            }
        })
        .collect();
    assert_eq!(rows, want, "tshark:\n{text}");

    // zenoh: the subscriber got the telegrams with their side in the attachment.
    let mut zenoh_seen = Vec::new();
    while zenoh_seen.len() < 3 {
        let sample = tokio::time::timeout(Duration::from_secs(10), rx.recv_async())
            .await
            .unwrap_or_else(|_| panic!("only {zenoh_seen:?} on zenoh"))
            .expect("sample");
        let attachment: Value =
            serde_json::from_slice(&sample.attachment().expect("attachment").to_bytes())
                .expect("JSON attachment");
        assert!(attachment["seq"].as_u64().is_some(), "{attachment}");
        zenoh_seen.push((
            attachment["side"].as_str().unwrap_or("?").to_owned(),
            sample.payload().to_bytes().to_vec(),
        ));
    }
    assert_eq!(
        zenoh_seen,
        [
            ("a".to_owned(), A1.to_vec()),
            ("b".to_owned(), B2.to_vec()),
            ("a".to_owned(), A3.to_vec()),
        ]
    );

    // REST: a send is refused with 409.
    let r = client
        .post(format!("{http}/api/v1/lines/{LINE}/send"))
        .json(&serde_json::json!({ "text": "from REST" }))
        .send()
        .await
        .expect("POST send");
    let code = r.status();
    let body = r.text().await.unwrap_or_default();
    assert_eq!(code.as_u16(), 409, "{body}");
    assert!(body.contains("only listens"), "{body}");

    // Modbus TCP: the mailbox reads (the oldest telegram, A's first), a write to the send block
    // is exception 01.
    let mut scada = tcp::connect_slave(gw.modbus_tcp, Slave(UNIT))
        .await
        .expect("connect");
    let head = scada
        .read_holding_registers(0, 6)
        .await
        .expect("transport")
        .expect("the receive block");
    assert_eq!(head[usize::from(RX_SEQ)], 1, "{head:?}");
    assert_eq!(head[2], 3, "LEN of A's first telegram: {head:?}");
    assert_eq!(head[3], 3, "telegrams waiting: {head:?}");
    assert_eq!(&head[4..6], &[0x412D, 0x3100], "{head:?}");
    let counters = scada
        .read_holding_registers(DIAG, 11)
        .await
        .expect("transport")
        .expect("the counters");
    // Received 3, overflows 0, sent 0, send failures 0; depth 16, drop-oldest (2), port open.
    assert_eq!(
        &counters[..10],
        &[0, 3, 0, 0, 0, 0, 0, 0, 16, 2],
        "{counters:?}"
    );
    assert_eq!(counters[10], 1, "port open: {counters:?}");
    // Reading goes on as on every mailbox: acknowledging A's first telegram shows B's.
    scada
        .write_single_register(ACK, 1)
        .await
        .expect("transport")
        .expect("acknowledge");
    let head = scada
        .read_holding_registers(0, 6)
        .await
        .expect("transport")
        .expect("the receive block");
    assert_eq!(
        &head[1..6],
        &[2, 4, 2, 0x1042, 0x2D32],
        "B's telegram: {head:?}"
    );
    let send = scada
        .write_multiple_registers(TX_REQ, &[1, 2, 0x4142])
        .await
        .expect("transport");
    assert_eq!(send, Err(ExceptionCode::IllegalFunction));
    let send = scada
        .write_single_register(TX_REQ, 2)
        .await
        .expect("transport");
    assert_eq!(send, Err(ExceptionCode::IllegalFunction));

    // zenoh: a put on `<line>/tx` too; its result says no.
    let result = session
        .declare_subscriber(format!("gw/{GATEWAY}/{LINE}/tx/result"))
        .await
        .expect("subscribe");
    session
        .put(format!("gw/{GATEWAY}/{LINE}/tx"), b"put".to_vec())
        .await
        .expect("put");
    let sample = tokio::time::timeout(Duration::from_secs(10), result.recv_async())
        .await
        .expect("a result")
        .expect("sample");
    let result: Value = serde_json::from_slice(&sample.payload().to_bytes()).expect("JSON");
    assert_eq!(result["ok"], Value::Bool(false), "{result}");
    session.close().await.expect("close");

    // Nothing was ever written to either port.
    for (name, partner) in [("A", &mut partners.a), ("B", &mut partners.b)] {
        let mut buf = [0u8; 64];
        let silent = tokio::time::timeout(Duration::from_millis(300), partner.read(&mut buf)).await;
        assert!(
            silent.is_err(),
            "the tap wrote to partner {name}'s link: {silent:?}"
        );
    }
    let status = get_json(&client, &line_url).await;
    assert_eq!(status["counters"]["bytes_sent"], 0, "{status:#}");
    eprintln!("the partners' four exchanges took {played:?}");
}
