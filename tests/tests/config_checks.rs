//! One check, three doors: `gateway check`, `POST /api/v1/config/validate` and
//! `PUT /api/v1/config...` refuse the same configurations that `gateway run` would not start,
//! with the same problems at the same paths, and a refused change never reaches the file. SIGHUP
//! re-reads the file and applies it as a REST replace does, or keeps the running configuration
//! and says why; a SIGHUP during start does not kill the process. `gateway check` catches what
//! people get wrong (overlapping tags, keys without effect, missing ports), each at its path.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use gateway_tests::{check_config, free_port, gateway_bin, temp_dir, Gateway, SocatLink};
use serde_json::Value;

/// The REST API's token in these tests.
const TOKEN: &str = "doors-admin-token-0123456789";

/// A gateway with one ASCII line on `port`, the token in `dir`, `config_dirs` = `dir`, and
/// `extra` appended (more keys of `[http]` first, then other sections).
fn config_text(dir: &Path, port: &Path, http: &str, extra: &str) -> String {
    format!(
        r#"[gateway]
name = "doors"
config_dirs = ["{dir}"]

[modbus_tcp]
listen = "127.0.0.1:0"

[http]
{http}

[lines.ascii]
port = "{port}"
protocol = "ascii"
end_criterion = "end-chars"
end_chars = [0x03]
{extra}"#,
        dir = dir.display(),
        port = port.display(),
    )
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

/// Sends `body` (TOML) with the token; the status and the JSON answer.
async fn send(
    http: &reqwest::Client,
    method: reqwest::Method,
    url: &str,
    body: &str,
) -> (u16, Value) {
    let reply = http
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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_config_that_would_not_start_is_refused_at_every_door_and_never_persisted() {
    let dir = temp_dir("doors");
    let link = SocatLink::new(&dir, "ascii");
    let token = dir.join("admin.token");
    std::fs::write(&token, format!("{TOKEN}\n")).expect("token file");
    // The same token again, under another name.
    let twin = dir.join("ops.token");
    std::fs::write(&twin, format!("{TOKEN}\n")).expect("second token file");
    let token_key = format!("token_file = \"{}\"", token.display());
    let file = dir.join("gateway.toml");
    std::fs::write(&file, config_text(&dir, &link.a, &token_key, "")).expect("config");
    let original = std::fs::read(&file).expect("config bytes");
    let gw = Gateway::run(&file);
    let base = format!("http://{}/api/v1", gw.http.expect("http"));
    let http = reqwest::Client::new();

    let missing = dir.join("missing.token");
    let zenoh_file = dir.join("missing-zenoh.json5");
    let cases: Vec<(&str, String, Vec<&str>)> = vec![
        (
            "a token file that does not exist",
            config_text(&dir, &link.a, &format!("token_file = \"{}\"", missing.display()), ""),
            vec!["http.token_file"],
        ),
        (
            "/etc/shadow as the token file",
            config_text(&dir, &link.a, "token_file = \"/etc/shadow\"", ""),
            vec!["http.token_file"],
        ),
        (
            "a token variable that is not set",
            config_text(
                &dir,
                &link.a,
                "token_env = \"GATEWAY_DOORS_TEST_UNSET_TOKEN\"",
                "",
            ),
            vec!["http.token_env"],
        ),
        (
            "two equal tokens",
            config_text(
                &dir,
                &link.a,
                &format!(
                    "{token_key}\n\n[http.tokens.ops]\nrole = \"operator\"\ntoken_file = \"{}\"",
                    twin.display()
                ),
                "",
            ),
            vec!["http.tokens"],
        ),
        (
            "a zenoh config file that does not exist",
            config_text(
                &dir,
                &link.a,
                &token_key,
                &format!(
                    "\n[zenoh]\nconfig_file = \"{}\"\nlisten = [\"tcp/127.0.0.1:{}\"]\n",
                    zenoh_file.display(),
                    free_port()
                ),
            ),
            vec!["zenoh.config_file"],
        ),
        (
            "Modbus/TCP Security files that do not exist",
            config_text(
                &dir,
                &link.a,
                &token_key,
                &format!(
                    "\n[modbus_tcp.tls]\nlisten = \"127.0.0.1:0\"\ncert = \"{d}/no.crt\"\nkey = \"{d}/no.key\"\nca = \"{d}/no-ca.crt\"\n",
                    d = dir.display()
                ),
            ),
            vec!["modbus_tcp.tls.cert"],
        ),
        (
            "two problems at once",
            config_text(
                &dir,
                &link.a,
                &format!("token_file = \"{}\"", missing.display()),
                &format!(
                    "\n[zenoh]\nconfig_file = \"{}\"\nlisten = [\"tcp/127.0.0.1:{}\"]\n",
                    zenoh_file.display(),
                    free_port()
                ),
            ),
            vec!["http.token_file", "zenoh.config_file"],
        ),
    ];
    for (what, text, paths) in &cases {
        // PUT /config: 422 with every problem at its path, the file untouched byte for byte.
        let (status, body) =
            send(&http, reqwest::Method::PUT, &format!("{base}/config"), text).await;
        assert_eq!(status, 422, "{what}: {body:#}");
        let put = issues(&body);
        let got: Vec<&str> = put.iter().map(|(p, _)| p.as_str()).collect();
        assert_eq!(&got, paths, "{what}: {body:#}");
        assert_eq!(
            std::fs::read(&file).expect("config bytes"),
            original,
            "{what}: the file changed"
        );
        // POST /config/validate says the same.
        let (status, body) = send(
            &http,
            reqwest::Method::POST,
            &format!("{base}/config/validate"),
            text,
        )
        .await;
        assert_eq!(status, 422, "{what}: {body:#}");
        assert_eq!(issues(&body), put, "{what}: validate and PUT differ");
        // gateway check: exit 1, the same problems (a file outside the directories is the
        // API's refusal; the host's own file may name it, and check reads it).
        let candidate = dir.join("candidate.toml");
        std::fs::write(&candidate, text).expect("candidate");
        let (ok, stdout) = check_config(&candidate);
        assert!(!ok, "{what}: check passed:\n{stdout}");
        // The refusals; a warning (e.g. a line nothing acknowledges) refuses nothing.
        let lines: Vec<&str> = stdout
            .lines()
            .filter(|l| !l.starts_with("warning: "))
            .collect();
        if *what == "/etc/shadow as the token file" {
            assert!(
                put[0].1.contains("outside [gateway] config_dirs"),
                "{what}: {put:?}"
            );
            assert!(
                lines.iter().any(|l| l.starts_with("http.token_file: ")),
                "{what}: {stdout}"
            );
        } else {
            let expected: Vec<String> = put.iter().map(|(p, m)| format!("{p}: {m}")).collect();
            assert_eq!(lines, expected, "{what}: check and PUT differ");
        }
    }
    let (_, body) = send(
        &http,
        reqwest::Method::POST,
        &format!("{base}/config/validate"),
        &cases[0].1,
    )
    .await;
    assert!(
        issues(&body)[0].1.contains("missing.token"),
        "the message names the file: {body:#}"
    );

    // One line's door: a port that does not exist is refused there, in the words `check` warns
    // with (the host's file may name a port that is not plugged in yet).
    let line = "port = \"/dev/gateway-doors-no-such-port\"\nprotocol = \"ascii\"\n";
    let (status, body) = send(
        &http,
        reqwest::Method::PUT,
        &format!("{base}/config/lines/ascii"),
        line,
    )
    .await;
    assert_eq!(status, 422, "{body:#}");
    let refused = issues(&body);
    assert_eq!(
        refused,
        [(
            "lines.ascii.port".to_owned(),
            "no such serial port /dev/gateway-doors-no-such-port".to_owned()
        )]
    );
    assert_eq!(std::fs::read(&file).expect("config bytes"), original);
    let candidate = dir.join("candidate.toml");
    std::fs::write(
        &candidate,
        config_text(
            &dir,
            Path::new("/dev/gateway-doors-no-such-port"),
            &token_key,
            "",
        ),
    )
    .expect("candidate");
    let (ok, stdout) = check_config(&candidate);
    assert!(ok, "{stdout}");
    assert!(
        stdout.contains(&format!("warning: {}: {}", refused[0].0, refused[0].1)),
        "{stdout}"
    );
}

// === SIGHUP ===

fn hangup(pid: u32) {
    let status = Command::new("kill")
        .args(["-HUP", &pid.to_string()])
        .status()
        .expect("kill -HUP");
    assert!(status.success());
}

/// Two ASCII lines on their own links; line `a` at `baud_a`, `http` keys in `[http]`.
fn two_lines(a: &Path, b: &Path, baud_a: u32, http: &str) -> String {
    format!(
        r#"[gateway]
name = "hup"

[modbus_tcp]
listen = "127.0.0.1:0"

[http]
{http}

[lines.a]
port = "{a}"
protocol = "ascii"
baud = {baud_a}

[lines.b]
port = "{b}"
protocol = "ascii"
"#,
        a = a.display(),
        b = b.display(),
    )
}

async fn get(http: &reqwest::Client, url: &str) -> Value {
    http.get(url)
        .send()
        .await
        .expect("GET")
        .json()
        .await
        .expect("JSON")
}

/// The `started` time of line `name` in `GET /status`.
async fn started(http: &reqwest::Client, base: &str, name: &str) -> Value {
    let status = get(http, &format!("{base}/status")).await;
    status["lines"]
        .as_array()
        .expect("lines")
        .iter()
        .find(|l| l["name"] == name)
        .map(|l| l["started"].clone())
        .unwrap_or_else(|| panic!("no line {name} in {status:#}"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sighup_applies_a_changed_file_and_keeps_the_running_one_when_check_refuses_it() {
    let dir = temp_dir("sighup");
    let (link_a, link_b) = (SocatLink::new(&dir, "a"), SocatLink::new(&dir, "b"));
    let file = dir.join("gateway.toml");
    let ok_http = "insecure_allow_unauthenticated_changes = true";
    std::fs::write(&file, two_lines(&link_a.a, &link_b.a, 9600, ok_http)).expect("config");
    let mut gw = Gateway::run(&file);
    let base = format!("http://{}/api/v1", gw.http.expect("http"));
    let http = reqwest::Client::new();
    let b_started = started(&http, &base, "b").await;
    let a_started = started(&http, &base, "a").await;

    // A changed file: line a's baud rate; only line a restarts.
    std::fs::write(&file, two_lines(&link_a.a, &link_b.a, 19200, ok_http)).expect("config");
    hangup(gw.pid());
    let applied = gw.wait_for(
        "SIGHUP: configuration file applied",
        Duration::from_secs(20),
    );
    assert!(applied.contains(r#"lines_restarted=["a"]"#), "{applied}");
    let config = get(&http, &format!("{base}/config")).await;
    assert_eq!(config["lines"]["a"]["baud"], 19200, "{config:#}");
    // Line b's baud rate is not in the file: GET shows the file's keys, not the default.
    assert_eq!(config["lines"]["b"].get("baud"), None, "{config:#}");
    assert_eq!(
        started(&http, &base, "b").await,
        b_started,
        "line b was restarted"
    );
    assert_ne!(
        started(&http, &base, "a").await,
        a_started,
        "line a was not restarted"
    );

    // A file check refuses (a token variable that is not set, and line b changed): not applied,
    // the process runs on with the configuration in force, and the log says why.
    std::fs::write(
        &file,
        two_lines(
            &link_a.a,
            &link_b.a,
            38400,
            "token_env = \"GATEWAY_SIGHUP_TEST_UNSET_TOKEN\"",
        ),
    )
    .expect("config");
    hangup(gw.pid());
    let refused = gw.wait_for(
        "SIGHUP: configuration file refused",
        Duration::from_secs(20),
    );
    assert!(
        refused.contains(
            "http.token_env: the API token variable GATEWAY_SIGHUP_TEST_UNSET_TOKEN is not set"
        ),
        "{refused}"
    );
    let config = get(&http, &format!("{base}/config")).await;
    assert_eq!(config["lines"]["a"]["baud"], 19200, "{config:#}");
    assert!(config["http"]["token_env"].is_null(), "{config:#}");
    // A file that is not even TOML: the same.
    std::fs::write(&file, "[lines.a\nport = ").expect("config");
    hangup(gw.pid());
    let refused = gw.wait_for(
        "SIGHUP: configuration file refused",
        Duration::from_secs(20),
    );
    assert!(refused.contains("TOML syntax error"), "{refused}");
    assert_eq!(started(&http, &base, "b").await, b_started);

    // SIGTERM stops as before.
    let status = gw.stop(Duration::from_secs(15)).expect("stopped");
    assert!(status.success(), "{status:?}");
    assert!(gw.output().contains("stopped gracefully"));
}

/// `gateway demo` started by hand: its output lines as they come.
struct Started {
    child: std::process::Child,
    lines: mpsc::Receiver<String>,
    seen: Vec<String>,
}

impl Started {
    fn wait_for(&mut self, needle: &str, timeout: Duration) -> String {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(line) => {
                    self.seen.push(line.clone());
                    if line.contains(needle) {
                        return line;
                    }
                }
                Err(_) => panic!(
                    "no {needle:?} within {timeout:?}:\n{}",
                    self.seen.join("\n")
                ),
            }
        }
    }
}

impl Drop for Started {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn a_sighup_during_start_does_not_kill_and_the_demo_has_nothing_to_re_read() {
    // zenoh is not used here: port 0, nothing to choose and race for.
    let zenoh = "tcp/127.0.0.1:0".to_owned();
    let mut child = Command::new(gateway_bin())
        .args([
            "demo",
            "--modbus-tcp",
            "127.0.0.1:0",
            "--http",
            "127.0.0.1:0",
            "--zenoh-listen",
            &zenoh,
        ])
        .env("RUST_LOG", "info")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start the demo");
    let (tx, lines) = mpsc::channel();
    for stream in [
        Box::new(child.stdout.take().expect("stdout")) as Box<dyn std::io::Read + Send>,
        Box::new(child.stderr.take().expect("stderr")),
    ] {
        let tx = tx.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(stream).lines().map_while(Result::ok) {
                let _ = tx.send(line);
            }
        });
    }
    drop(tx);
    let mut demo = Started {
        child,
        lines,
        seen: Vec::new(),
    };
    // Its first line comes while it starts (virtual lines, simulators, listeners); a SIGHUP now
    // is remembered, not fatal.
    let first = demo.wait_for("", Duration::from_secs(30));
    hangup(demo.child.id());
    demo.wait_for("modbus-tcp listening on ", Duration::from_secs(60));
    // The remembered SIGHUP is handled as the gateway comes up: its line may come before the
    // listening line or after it.
    let reread = "SIGHUP: no configuration file to re-read";
    if !demo.seen.iter().any(|l| l.contains(reread)) {
        demo.wait_for(reread, Duration::from_secs(20));
    }
    assert!(
        demo.child.try_wait().expect("status").is_none(),
        "the demo stopped (first line: {first})"
    );
    // And once it runs.
    hangup(demo.child.id());
    demo.wait_for(
        "SIGHUP: no configuration file to re-read",
        Duration::from_secs(20),
    );
    std::thread::sleep(Duration::from_millis(300));
    assert!(demo.child.try_wait().expect("status").is_none());
    // SIGTERM stops it, with exit code 0.
    Command::new("kill")
        .args(["-TERM", &demo.child.id().to_string()])
        .status()
        .expect("kill -TERM");
    let deadline = Instant::now() + Duration::from_secs(20);
    let status = loop {
        if let Some(status) = demo.child.try_wait().expect("status") {
            break status;
        }
        assert!(Instant::now() < deadline, "the demo did not stop");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(status.success(), "{status:?}");
}

// === what check catches ===

/// `gateway check` on `text`: exit code and stdout.
fn check_text(dir: &Path, name: &str, text: &str) -> (i32, String) {
    let path: PathBuf = dir.join(name);
    std::fs::write(&path, text).expect("config");
    let out = Command::new(gateway_bin())
        .args(["check", "--config", path.to_str().expect("utf-8")])
        .output()
        .expect("gateway check");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    )
}

#[test]
fn check_names_overlapping_tags_keys_without_effect_and_missing_ports() {
    let dir = temp_dir("check-catches");
    // An f64 at input 2 over a u64 at input 0..3: an error naming both.
    let overlap = r#"
[lines.m]
port = "/dev/null"
protocol = "modbus-master-rtu"
[lines.m.devices.meter]
profile = "generic"
address = 1
tags = [
  { name = "count", table = "input", address = 0, type = "u64" },
  { name = "ready", table = "input", address = 0, bit = 3 },
  { name = "pos", table = "input", address = 2, type = "f64" },
]
"#;
    let (code, out) = check_text(&dir, "overlap.toml", overlap);
    assert_eq!(code, 1, "{out}");
    assert_eq!(
        out.trim_end(),
        "lines.m.devices.meter.tags[2].address: tag \"pos\" (f64 at input 2..5) overlaps tag \
         \"count\" (u64 at input 0..3): two values cannot share registers (a bit of a register \
         is a bool tag with `bit`)"
    );

    // end_chars with the character-delay criterion, a save interval without a file: warnings
    // at their paths; a port that is not there on an rs232 line: a warning naming it.
    let ignored = r#"
[cp_memory]
save_interval = "5s"
[lines.t]
port = "/dev/gateway-check-no-such-port"
interface = "rs232"
protocol = "ascii"
unit_id = 101
end_chars = [0x03]
"#;
    let (code, out) = check_text(&dir, "ignored.toml", ignored);
    assert_eq!(code, 0, "{out}");
    assert_eq!(
        out.lines().collect::<Vec<_>>(),
        [
            "ok: 1 lines, 0 devices",
            "warning: lines.t.port: no such serial port /dev/gateway-check-no-such-port (the line opens it with back-off until it appears)",
            "warning: lines.t.end_chars: has no effect: end_chars is read only with end_criterion = \"end-chars\", and end_criterion is \"char-delay\" (its default)",
            "warning: cp_memory.save_interval: has no effect: the CP memory is saved only with persist_file",
        ]
    );
}

/// `gateway check ... | head -1` and the like: when the reader of its output has gone, a printing
/// command ends as Unix tools do (SIGPIPE), not with a panic message on stderr.
#[test]
fn check_into_a_closed_pipe_ends_quietly() {
    let dir = temp_dir("check-closed-pipe");
    let path = dir.join("ok.toml");
    std::fs::write(
        &path,
        "[lines.t]\nport = \"/dev/gateway-check-no-such-port\"\nprotocol = \"ascii\"\n",
    )
    .expect("config");
    // The reader (`true`) has exited long before the gateway, started 300 ms later, prints.
    let script =
        "(sleep 0.3; exec \"$0\" check --config \"$1\") | true; echo \"status=${PIPESTATUS[0]}\"";
    let out = Command::new("bash")
        .args(["-c", script])
        .arg(gateway_bin())
        .arg(&path)
        .output()
        .expect("bash");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "stderr: {stderr}");
    assert!(!stderr.contains("Broken pipe"), "stderr: {stderr}");
    // 128 + SIGPIPE (13): ended by the signal, as `grep` would be.
    assert_eq!(stdout.trim(), "status=141", "stderr: {stderr}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn run_says_port_not_found_for_a_missing_port() {
    let dir = temp_dir("port-not-found");
    let file = dir.join("gateway.toml");
    std::fs::write(
        &file,
        "[modbus_tcp]\nlisten = \"127.0.0.1:0\"\n[lines.a]\nport = \"/dev/gateway-run-no-such-port\"\n\
         interface = \"rs232\"\nprotocol = \"ascii\"\n",
    )
    .expect("config");
    let mut gw = Gateway::run(&file);
    let line = gw.wait_for("event=02 0Fh", Duration::from_secs(20));
    assert!(
        line.contains("port not found: /dev/gateway-run-no-such-port"),
        "{line}"
    );
    let http = reqwest::Client::new();
    let status = get(
        &http,
        &format!("http://{}/api/v1/lines/a", gw.http.expect("http")),
    )
    .await;
    let error = status["port_error"].as_str().unwrap_or_default();
    assert!(
        error.starts_with("port not found: /dev/gateway-run-no-such-port"),
        "{status:#}"
    );
    assert_eq!(status["last_event"]["code"], "020F", "{status:#}");
    assert_eq!(status["last_event"]["detail"], error, "{status:#}");
}
