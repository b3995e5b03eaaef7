//! End to end on the binary: a configuration change never leaves a journal the gateway cannot
//! open, never loses a waiting telegram, and never touches a file it did not write.
//!
//! - `PUT /api/v1/config/lines/{line}` (and `POST /config/validate`) with `journal` naming a
//!   directory, the CP memory file, or a file on a read-only file system (a read-only tmpfs
//!   mounted in the gateway's own mount namespace with `unshare`, since the tests may run as
//!   root, whom a read-only permission does not stop; where that cannot be had, a path under a
//!   regular file, ENOTDIR): 422 at `lines.r3964.journal`, the configuration file byte for
//!   byte, the CP memory file byte for byte and not renamed, the line running on. A SIGHUP with
//!   such a file keeps the running configuration; `gateway check` refuses it, `gateway run`
//!   exits 64.
//! - A line's `journal` path changed over REST with 57 telegrams waiting (each confirmed to the
//!   3964R partner with DLE): the same telegrams wait under the same numbers, the numbering goes
//!   on, a `kill -9` and restart find them in the new journal; the old journal keeps none.
//!
//! The partner is the gateway's own 3964R simulator on a socat pty pair.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use gateway_tests::{check_config, gateway_bin, start_sim, temp_dir, Gateway, SocatLink};
use serde_json::Value;
use tokio_modbus::client::{tcp, Writer};
use tokio_modbus::prelude::Slave;

/// The mailbox's Modbus TCP unit id and its acknowledge register (docs/mailbox.md).
const UNIT: u8 = 100;
const ACK: u16 = 600;
/// The CP memory's unit id (the slave line `hmi`).
const CP_UNIT: u8 = 50;
/// The REST API's token in these tests.
const TOKEN: &str = "journal-changes-token-0123456789";

/// The `[lines.r3964]` keys with `journal` (none when `None`) and the mailbox `depth`.
fn r3964(port: &Path, journal: Option<&Path>, depth: usize) -> String {
    let journal = journal
        .map(|j| format!("journal = \"{}\"\n", j.display()))
        .unwrap_or_default();
    format!(
        "port = \"{port}\"\nprotocol = \"3964r\"\nbaud = 9600\nparity = \"even\"\n\
         priority = \"high\"\nunit_id = {UNIT}\nreceive_buffer = {depth}\n{journal}",
        port = port.display(),
    )
}

/// The gateway: state files under `state`, the token in `dir`, the 3964R line on `port` with
/// `journal`, and (when `hmi` is given) a Modbus slave line serving the CP memory, persisted to
/// `state/cp-memory.bin`.
fn config(
    dir: &Path,
    state: &Path,
    port: &Path,
    journal: Option<&Path>,
    depth: usize,
    hmi: Option<&Path>,
) -> String {
    let hmi = hmi
        .map(|hmi| {
            format!(
                r#"
[cp_memory]
persist_file = "{state}/cp-memory.bin"
save_interval = "100ms"

[lines.hmi]
port = "{hmi}"
protocol = "modbus-slave-rtu"
address = 222
unit_id = {CP_UNIT}
write_enable = [{{ table = "holding", start = 0, count = 512 }}]
"#,
                state = state.display(),
                hmi = hmi.display(),
            )
        })
        .unwrap_or_default();
    format!(
        r#"[gateway]
name = "jchanges"
state_dirs = ["{state}"]

[modbus_tcp]
listen = "127.0.0.1:0"

[http]
token_file = "{dir}/admin.token"
{hmi}
[lines.r3964]
{line}"#,
        state = state.display(),
        dir = dir.display(),
        line = r3964(port, journal, depth),
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
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let w = waiting(gw).await;
        if w.len() >= n {
            return w;
        }
        assert!(
            Instant::now() < deadline,
            "only {} of {n} telegrams waiting within 60 s; output:\n{}",
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

/// Sends `body` (TOML) with the token; the status and the JSON answer.
async fn send(method: reqwest::Method, url: &str, body: &str) -> (u16, Value) {
    let reply = reqwest::Client::new()
        .request(method, url)
        .bearer_auth(TOKEN)
        .header("content-type", "application/toml")
        .body(body.to_owned())
        .send()
        .await
        .expect("request");
    let status = reply.status().as_u16();
    (status, reply.json().await.expect("JSON answer"))
}

/// `(path, message)` of every issue of a 422 answer.
fn issues(body: &Value) -> Vec<(String, String)> {
    body["error"]["issues"]
        .as_array()
        .unwrap_or_else(|| panic!("no issues in {body:#}"))
        .iter()
        .map(|i| {
            (
                i["path"].as_str().unwrap_or_default().to_owned(),
                i["message"].as_str().unwrap_or_default().to_owned(),
            )
        })
        .collect()
}

/// The names in `dir`, sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .expect("list")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// Starts `gateway run` in a mount namespace of its own where `ro` is a read-only tmpfs
/// (`unshare -m`, then `mount -o ro`, then `exec` of the gateway: the same process). `None`
/// when this machine does not allow it (not root, no `unshare`).
fn run_with_read_only(config: &Path, ro: &Path) -> Option<Gateway> {
    let probe = Command::new("unshare")
        .args(["-m", "--propagation", "private", "sh", "-c"])
        .arg("mount -t tmpfs -o ro tmpfs \"$0\"")
        .arg(ro)
        .status()
        .is_ok_and(|s| s.success());
    if !probe {
        return None;
    }
    let mut command = Command::new("unshare");
    command
        .args(["-m", "--propagation", "private", "sh", "-c"])
        .arg("mount -t tmpfs -o ro tmpfs \"$0\" && exec \"$@\"")
        .arg(ro)
        .arg(gateway_bin())
        .args(Gateway::run_args(config))
        .env("RUST_LOG", "info");
    Some(Gateway::try_start_command(command).unwrap_or_else(|out| panic!("no start:\n{out}")))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_journal_the_gateway_cannot_open_is_refused_at_every_door_and_no_file_is_touched() {
    let dir = temp_dir("journal-doors");
    std::fs::write(dir.join("admin.token"), format!("{TOKEN}\n")).expect("token");
    let state = dir.join("state");
    std::fs::create_dir(&state).expect("state dir");
    let link = SocatLink::new(&dir, "r3964");
    let hmi = SocatLink::new(&dir, "hmi");
    let journal = state.join("r3964.journal");
    let file = dir.join("gateway.toml");
    std::fs::write(
        &file,
        config(&dir, &state, &link.a, Some(&journal), 20, Some(&hmi.a)),
    )
    .expect("config");
    let original = std::fs::read(&file).expect("config bytes");
    let ro = state.join("ro");
    std::fs::create_dir(&ro).expect("ro dir");
    // What the check says of the read-only path: "cannot create" on the read-only file system;
    // where no mount is possible (a chroot, a container) the path lies under a regular file,
    // which the check cannot open either ("Not a directory").
    let (mut gw, read_only, read_only_says) = match run_with_read_only(&file, &ro) {
        Some(gw) => (gw, ro.join("r3964.journal"), "cannot create"),
        None => {
            // Not allowed to mount here: a path under a regular file cannot be created either.
            let plain = state.join("plain");
            std::fs::write(&plain, b"a regular file").expect("plain");
            eprintln!("no read-only mount possible here: a path under a file (ENOTDIR) instead");
            (
                Gateway::run(&file),
                plain.join("r3964.journal"),
                "Not a directory",
            )
        }
    };
    let base = format!("http://{}/api/v1", gw.http.expect("HTTP"));
    let _partner = partner(&link.b, "30ms");
    let before = until_waiting(&gw, 3).await;

    // The CP memory file, written by the gateway: a write to the memory is saved within 100 ms.
    let mut ctx = tcp::connect_slave(gw.modbus_tcp, Slave(CP_UNIT))
        .await
        .expect("connect");
    ctx.write_single_register(0, 0x1234)
        .await
        .expect("transport")
        .expect("write the CP memory");
    let cp_file = state.join("cp-memory.bin");
    let deadline = Instant::now() + Duration::from_secs(20);
    while !cp_file.exists() {
        assert!(Instant::now() < deadline, "no CP memory file saved");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    let cp_bytes = std::fs::read(&cp_file).expect("CP memory file");
    assert!(cp_bytes.starts_with(b"GWCPMEM1"));

    let a_dir = state.join("a-directory");
    std::fs::create_dir(&a_dir).expect("mkdir");
    // A copy of it that no key names: refused for what it is, not for whose it is.
    let cp_copy = state.join("cp-copy.bin");
    std::fs::write(&cp_copy, &cp_bytes).expect("copy");
    let cases = [
        ("a directory", a_dir.clone(), "is a directory"),
        (
            "the CP memory file",
            cp_file.clone(),
            "the file cp_memory.persist_file names too",
        ),
        (
            "a copy of the CP memory file",
            cp_copy.clone(),
            "is not a journal",
        ),
        ("a read-only file system", read_only.clone(), read_only_says),
    ];
    for (what, path, says) in &cases {
        let line = r3964(&link.a, Some(path), 20);
        for (method, url) in [
            (reqwest::Method::PUT, format!("{base}/config/lines/r3964")),
            (reqwest::Method::POST, format!("{base}/config/validate")),
        ] {
            let body = if method == reqwest::Method::PUT {
                line.clone()
            } else {
                config(&dir, &state, &link.a, Some(path), 20, Some(&hmi.a))
            };
            let (status, answer) = send(method.clone(), &url, &body).await;
            assert_eq!(status, 422, "{what} ({method}): {answer:#}");
            let refused = issues(&answer);
            assert_eq!(refused.len(), 1, "{what}: {refused:?}");
            assert_eq!(refused[0].0, "lines.r3964.journal", "{what}");
            assert!(
                refused[0].1.contains(says) && refused[0].1.contains(&path.display().to_string()),
                "{what}: {refused:?}"
            );
            eprintln!("{what} ({method}): 422 {}", refused[0].1);
        }
        assert_eq!(
            std::fs::read(&file).expect("config bytes"),
            original,
            "{what}: the configuration file changed"
        );
    }
    // Nothing was renamed, created or written in the state directory; the CP memory file is the
    // gateway's own, byte for byte.
    let mut expected = vec![
        "a-directory".to_owned(),
        "cp-copy.bin".to_owned(),
        "cp-memory.bin".to_owned(),
        "r3964.journal".to_owned(),
        "ro".to_owned(),
    ];
    if read_only.parent() != Some(ro.as_path()) {
        expected.push("plain".to_owned());
        expected.sort();
    }
    assert_eq!(names(&state), expected);
    assert!(names(&a_dir).is_empty());
    assert_eq!(std::fs::read(&cp_file).expect("CP memory file"), cp_bytes);
    assert_eq!(std::fs::read(&cp_copy).expect("copy"), cp_bytes);
    // The line ran on: the same telegrams wait, under the same numbers, and more came.
    let after = until_waiting(&gw, before.len() + 1).await;
    assert_eq!(after[..before.len()], before[..]);

    // SIGHUP with such a file: refused, the running configuration stays.
    std::fs::write(
        &file,
        config(&dir, &state, &link.a, Some(&a_dir), 20, Some(&hmi.a)),
    )
    .expect("config");
    let hup = Command::new("kill")
        .args(["-HUP", &gw.pid().to_string()])
        .status()
        .expect("kill -HUP");
    assert!(hup.success());
    let refused = gw.wait_for(
        "SIGHUP: configuration file refused",
        Duration::from_secs(30),
    );
    assert!(
        refused.contains("lines.r3964.journal") && refused.contains("is a directory"),
        "{refused}"
    );
    let config_now = reqwest::get(format!("{base}/config"))
        .await
        .expect("GET /config")
        .text()
        .await
        .expect("text");
    assert!(
        config_now.contains(&journal.display().to_string())
            && !config_now.contains(&a_dir.display().to_string()),
        "the journal in force: {config_now}"
    );

    // `gateway check` refuses the file at the key; `gateway run` exits 64 before a port opens.
    let (ok, stdout) = check_config(&file);
    assert!(!ok, "{stdout}");
    assert!(
        stdout
            .lines()
            .any(|l| l.starts_with("lines.r3964.journal: ") && l.contains("is a directory")),
        "{stdout}"
    );
    gw.stop(Duration::from_secs(20));
    let run = Command::new(gateway_bin())
        .args(Gateway::run_args(&file))
        .output()
        .expect("gateway run");
    assert_eq!(
        run.status.code(),
        Some(64),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(
        String::from_utf8_lossy(&run.stderr).contains("lines.r3964.journal"),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(names(&a_dir).is_empty());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_changed_journal_path_carries_the_waiting_telegrams_and_their_numbers() {
    const DEPTH: usize = 57;
    let dir = temp_dir("journal-move");
    std::fs::write(dir.join("admin.token"), format!("{TOKEN}\n")).expect("token");
    let state = dir.join("state");
    std::fs::create_dir(&state).expect("state dir");
    let link = SocatLink::new(&dir, "r3964");
    let old: PathBuf = state.join("old.journal");
    let new: PathBuf = state.join("new.journal");
    let file = dir.join("gateway.toml");
    std::fs::write(
        &file,
        config(&dir, &state, &link.a, Some(&old), DEPTH, None),
    )
    .expect("config");
    let mut gw = Gateway::run(&file);
    let base = format!("http://{}/api/v1", gw.http.expect("HTTP"));
    let _partner = partner(&link.b, "20ms");
    // 57 telegrams wait, each confirmed to the partner (the mailbox is full: it is refused now).
    let before = until_waiting(&gw, DEPTH).await;
    assert_eq!(
        before.iter().map(|t| t.0).collect::<Vec<_>>(),
        (1..=DEPTH as u64).collect::<Vec<_>>()
    );

    let put = Instant::now();
    let (status, answer) = send(
        reqwest::Method::PUT,
        &format!("{base}/config/lines/r3964"),
        &r3964(&link.a, Some(&new), DEPTH),
    )
    .await;
    assert_eq!(status, 200, "{answer:#}");
    eprintln!(
        "PUT of a new journal path with {DEPTH} telegrams waiting answered in {:?}",
        put.elapsed()
    );
    assert_eq!(
        waiting(&gw).await,
        before,
        "the same telegrams under the same numbers"
    );
    let carried = gw.wait_for("carried over", Duration::from_secs(10));
    assert!(
        carried.contains("waiting=57") && carried.contains("new.journal"),
        "{carried}"
    );
    // The old journal holds none of them any more (a header and the counters only).
    let old_bytes = std::fs::read(&old).expect("old journal");
    assert!(old_bytes.starts_with(b"GWMBXJ01"));
    assert!(old_bytes.len() < 64, "{} bytes", old_bytes.len());

    // The numbering goes on: acknowledged, the oldest makes room for number 58.
    ack(&gw, 1).await;
    let deadline = Instant::now() + Duration::from_secs(30);
    let now = loop {
        let w = waiting(&gw).await;
        if w.last().map(|t| t.0) == Some(DEPTH as u64 + 1) {
            assert_eq!(w.first().map(|t| t.0), Some(2));
            assert_eq!(w[..DEPTH - 1], before[1..]);
            break w;
        }
        assert!(Instant::now() < deadline, "no telegram 58: {w:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    };

    // The new journal is the one that keeps them: killed and started again, they wait.
    gw.kill();
    let gw = Gateway::run(&file);
    assert_eq!(until_waiting(&gw, DEPTH).await, now);

    // Without a journal (in memory): carried again, and the journal emptied.
    let (status, answer) = send(
        reqwest::Method::PUT,
        &format!(
            "http://{}/api/v1/config/lines/r3964",
            gw.http.expect("HTTP")
        ),
        &r3964(&link.a, None, DEPTH),
    )
    .await;
    assert_eq!(status, 200, "{answer:#}");
    assert_eq!(waiting(&gw).await, now);
    assert!(std::fs::read(&new).expect("new journal").len() < 64);
}
