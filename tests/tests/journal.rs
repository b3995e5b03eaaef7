//! End to end on the binary: telegrams never lost.
//!
//! - A 3964R line with a `journal`: telegrams waiting when the gateway is killed (`kill -9`) wait
//!   again after the restart, with the same sequence numbers and bytes, and the numbering goes on.
//! - A journal whose last record is cut short: the line starts, reports the loss (05 01h in its
//!   diagnostic buffer and an error line in the log) and keeps what came before.
//! - A 3964R line without `unit_id`, read only over zenoh (`ack = "on-publish"` by default):
//!   a partner sending every 20 ms for 20 s is never refused (no 08 0Ah), and at least 99 % of
//!   its telegrams reach a zenoh subscriber.
//!
//! The partner is the gateway's own 3964R simulator on a socat pty pair.

use std::collections::BTreeSet;
use std::path::Path;
use std::time::{Duration, Instant};

use gateway_tests::{start_sim, temp_dir, zenoh_client, Gateway, SocatLink};
use serde_json::Value;
use tokio_modbus::client::{tcp, Writer};
use tokio_modbus::prelude::Slave;

/// The mailbox's Modbus TCP unit id and its acknowledge register (docs/mailbox.md).
const UNIT: u8 = 100;
const ACK: u16 = 600;
/// The mailbox depth of the journal tests: the partner fills it and is then refused.
const DEPTH: usize = 20;

fn journal_config(port: &Path, journal: &Path) -> String {
    format!(
        r#"
[gateway]
name = "journal"

[modbus_tcp]
listen = "127.0.0.1:0"

[lines.r3964]
port = "{port}"
protocol = "3964r"
baud = 9600
parity = "even"
priority = "high"
unit_id = {UNIT}
receive_buffer = {DEPTH}
journal = "{journal}"
"#,
        port = port.display(),
        journal = journal.display(),
    )
}

/// The partner: the gateway's 3964R simulator, sending one telegram every `every`.
fn partner(port: &Path, every: &str) -> gateway_tests::ChildGuard {
    start_sim(&[
        "--device",
        "3964r",
        "--port",
        port.to_str().expect("utf-8 path"),
        "--every",
        every,
    ])
}

async fn get_json(url: &str) -> Value {
    reqwest::get(url)
        .await
        .unwrap_or_else(|e| panic!("GET {url}: {e}"))
        .json()
        .await
        .unwrap_or_else(|e| panic!("GET {url}: not JSON: {e}"))
}

/// `(seq, hex)` of every waiting telegram of line `r3964`, oldest first.
async fn waiting(gw: &Gateway) -> Vec<(u64, String)> {
    let url = format!(
        "http://{}/api/v1/lines/r3964/telegrams",
        gw.http.expect("HTTP")
    );
    get_json(&url).await["telegrams"]
        .as_array()
        .expect("telegrams")
        .iter()
        .map(|t| {
            (
                t["seq"].as_u64().expect("seq"),
                t["hex"].as_str().expect("hex").to_owned(),
            )
        })
        .collect()
}

/// Waits until `n` telegrams wait.
async fn until_waiting(gw: &Gateway, n: usize) -> Vec<(u64, String)> {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let w = waiting(gw).await;
        if w.len() >= n {
            return w;
        }
        assert!(
            Instant::now() < deadline,
            "only {} of {n} telegrams waiting within 30 s; output:\n{}",
            w.len(),
            gw.output()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// Acknowledges `seq` over Modbus TCP.
async fn ack(gw: &Gateway, seq: u64) {
    let mut ctx = tcp::connect_slave(gw.modbus_tcp, Slave(UNIT))
        .await
        .expect("connect");
    ctx.write_single_register(ACK, u16::try_from(seq).expect("seq"))
        .await
        .expect("transport")
        .expect("acknowledge");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn telegrams_waiting_at_a_kill_wait_again_with_their_numbers() {
    let dir = temp_dir("journal-kill");
    let link = SocatLink::new(&dir, "r3964");
    let journal = dir.join("r3964.journal");
    let config = dir.join("gateway.toml");
    std::fs::write(&config, journal_config(&link.a, &journal)).expect("config");
    let _partner = partner(&link.b, "30ms");

    let mut gw = Gateway::run(&config);
    let before = until_waiting(&gw, DEPTH).await;
    assert_eq!(
        before.iter().map(|t| t.0).collect::<Vec<_>>(),
        (1..=DEPTH as u64).collect::<Vec<_>>()
    );
    // The mailbox is full: the partner is refused (NAK), nothing more is taken.
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert_eq!(waiting(&gw).await, before);
    gw.kill();

    let gw = Gateway::run(&config);
    assert!(
        gw.output().contains("mailbox restored from its journal"),
        "{}",
        gw.output()
    );
    let after = until_waiting(&gw, DEPTH).await;
    assert_eq!(after, before, "the same telegrams under the same numbers");

    // The numbering goes on: acknowledged, the oldest makes room for number 21.
    ack(&gw, 1).await;
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let w = waiting(&gw).await;
        if w.len() == DEPTH && w.last().map(|t| t.0) == Some(DEPTH as u64 + 1) {
            assert_eq!(w.first().map(|t| t.0), Some(2));
            break;
        }
        assert!(Instant::now() < deadline, "no telegram 21: {w:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_journal_cut_short_starts_the_line_and_reports_the_loss() {
    let dir = temp_dir("journal-cut");
    let link = SocatLink::new(&dir, "r3964");
    let journal = dir.join("r3964.journal");
    let config = dir.join("gateway.toml");
    std::fs::write(&config, journal_config(&link.a, &journal)).expect("config");
    let mut partner = partner(&link.b, "30ms");

    let mut gw = Gateway::run(&config);
    let before = until_waiting(&gw, DEPTH).await;
    gw.kill();
    // No telegram may come in while the file is cut.
    partner.kill();

    // The last record (telegram 20) loses its last 3 bytes, as by a crash during its write.
    let len = std::fs::metadata(&journal).expect("journal").len();
    let file = std::fs::OpenOptions::new()
        .write(true)
        .open(&journal)
        .expect("open the journal");
    file.set_len(len - 3).expect("cut");
    drop(file);

    let mut gw = Gateway::run(&config);
    // The line starts (and logs) before the gateway announces Modbus TCP.
    let output = gw.output();
    let line = output
        .lines()
        .find(|l| l.contains("ERROR") && l.contains("unreadable"))
        .unwrap_or_else(|| panic!("no loss reported:\n{output}"));
    assert!(
        line.contains("cut short") && line.contains("r3964.journal"),
        "{line}"
    );
    let after = waiting(&gw).await;
    assert_eq!(
        after,
        before[..DEPTH - 1],
        "everything before the cut record"
    );

    // The loss is the line's event 05 01h, in its diagnostic buffer.
    let diag = get_json(&format!(
        "http://{}/api/v1/lines/r3964/diag",
        gw.http.expect("HTTP")
    ))
    .await;
    let words: Vec<u64> = diag["entries"]
        .as_array()
        .expect("entries")
        .iter()
        .filter_map(|e| e["status_word"].as_u64())
        .collect();
    assert!(words.contains(&0x0501), "{diag}");
    // The journal is whole again: a restart reads it without a loss.
    gw.kill();
    let gw = Gateway::run(&config);
    assert_eq!(waiting(&gw).await, before[..DEPTH - 1]);
    assert!(!gw.output().contains("unreadable"), "{}", gw.output());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_line_read_only_over_zenoh_acknowledges_on_publication() {
    let dir = temp_dir("on-publish");
    let link = SocatLink::new(&dir, "r3964");
    let config = dir.join("gateway.toml");
    let port = link.a.clone();
    let gw = Gateway::run_on_free_zenoh_port(&config, |zenoh_port| {
        format!(
            r#"
[gateway]
name = "onpub"

[modbus_tcp]
listen = "127.0.0.1:0"

[zenoh]
mode = "peer"
listen = ["tcp/127.0.0.1:{zenoh_port}"]
connect = []
multicast_scouting = false

[lines.r3964]
port = "{port}"
protocol = "3964r"
baud = 9600
parity = "even"
priority = "high"
receive_buffer = 5
"#,
            port = port.display()
        )
    });
    let session = zenoh_client(gw.zenoh_port.expect("zenoh port")).await;
    let rx = session
        .declare_subscriber("gw/onpub/r3964/rx")
        .await
        .expect("subscribe");
    // The subscription reaches the gateway before the partner starts.
    tokio::time::sleep(Duration::from_millis(500)).await;
    let mut partner = partner(&link.b, "20ms");
    let started = Instant::now();
    let mut counters = BTreeSet::new();
    let mut seqs = Vec::new();
    while started.elapsed() < Duration::from_secs(20) {
        let Ok(Ok(sample)) =
            tokio::time::timeout(Duration::from_millis(200), rx.recv_async()).await
        else {
            continue;
        };
        let text = String::from_utf8_lossy(&sample.payload().to_bytes()).into_owned();
        // "3964R 000123": the partner's counter is the last word.
        let counter: u64 = text
            .rsplit(' ')
            .next()
            .and_then(|w| w.parse().ok())
            .unwrap_or_else(|| panic!("no counter in {text:?}"));
        counters.insert(counter);
        let att: Value =
            serde_json::from_slice(&sample.attachment().expect("attachment").to_bytes())
                .expect("JSON attachment");
        seqs.push(att["seq"].as_u64().expect("seq"));
    }
    partner.kill();
    let sent = *counters.last().expect("telegrams");
    assert!(
        sent >= 500,
        "the partner sent only {sent} telegrams in 20 s"
    );
    assert!(
        counters.len() as f64 >= 0.99 * sent as f64,
        "{} of {sent} telegrams reached the subscriber",
        counters.len()
    );
    // In order, each once.
    assert!(seqs.windows(2).all(|w| w[1] == w[0] + 1), "{seqs:?}");
    // Never refused: no 08 0Ah on the line.
    let metrics = reqwest::get(format!("http://{}/metrics", gw.http.expect("HTTP")))
        .await
        .expect("metrics")
        .text()
        .await
        .expect("text");
    assert!(
        !metrics
            .lines()
            .any(|l| l.starts_with("gateway_events_total") && l.contains("event=\"080A\"")),
        "08 0Ah raised:\n{}",
        metrics
            .lines()
            .filter(|l| l.starts_with("gateway_events_total"))
            .collect::<Vec<_>>()
            .join("\n")
    );
    let status = get_json(&format!(
        "http://{}/api/v1/lines/r3964/telegrams",
        gw.http.expect("HTTP")
    ))
    .await;
    assert_eq!(status["dropped"], 0, "{status}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_zenoh_put_on_ack_acknowledges_the_oldest_telegram() {
    let dir = temp_dir("zenoh-ack");
    let link = SocatLink::new(&dir, "r3964");
    let config = dir.join("gateway.toml");
    let port = link.a.clone();
    let gw = Gateway::run_on_free_zenoh_port(&config, |zenoh_port| {
        format!(
            r#"
[gateway]
name = "zack"

[modbus_tcp]
listen = "127.0.0.1:0"

[zenoh]
mode = "peer"
listen = ["tcp/127.0.0.1:{zenoh_port}"]
connect = []
multicast_scouting = false
writes = true

[lines.r3964]
port = "{port}"
protocol = "3964r"
baud = 9600
parity = "even"
priority = "high"
receive_buffer = 5
ack = "explicit"
"#,
            port = port.display()
        )
    });
    let _partner = partner(&link.b, "30ms");
    let full = until_waiting(&gw, 5).await;
    assert_eq!(full.first().map(|t| t.0), Some(1));
    let session = zenoh_client(gw.zenoh_port.expect("zenoh port")).await;
    // A wrong number is refused (the query form answers why); nothing is released.
    let replies = session
        .get("gw/zack/r3964/ack")
        .payload("3")
        .await
        .expect("get");
    let reply = replies.recv_async().await.expect("a reply");
    let answer: Value =
        serde_json::from_slice(&reply.result().expect("an answer").payload().to_bytes())
            .expect("JSON");
    assert_eq!(answer["ok"], false, "{answer}");
    assert_eq!(waiting(&gw).await.first().map(|t| t.0), Some(1));
    // The oldest's number, put as text: released, the next one shows.
    session.put("gw/zack/r3964/ack", "1").await.expect("put");
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let w = waiting(&gw).await;
        if w.first().map(|t| t.0) == Some(2) {
            break;
        }
        assert!(Instant::now() < deadline, "not acknowledged: {w:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}
