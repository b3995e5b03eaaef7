//! `gateway fleet status` and `gateway fleet watch`: the operator's view of the fleet, from any
//! machine that reaches the fabric.
//!
//! With `--connect ENDPOINT` the command is a zenoh client of that router (or gateway), multicast
//! scouting off: nothing but that connection. Without it, it is a peer that listens nowhere,
//! finds routers and gateways by multicast scouting and connects to `tcp/127.0.0.1:7447` (a
//! gateway or router on this machine, the gateway's default listen endpoint).
//!
//! `status` asks `<gateways>/status` (default `gw/*/status`, every gateway under the default
//! prefix) and prints one table: a row per gateway, per line and per device, with what each
//! answered (online, the STATUS word of the line's last event, how long ago). It exits 1 when
//! no gateway answered within `--timeout`. What it prints is bounded whatever the peers answer:
//! an answer over [`fleet::STATUS_MAX`] bytes is skipped, at most [`fleet::MEMBER_LIMIT`]
//! answers and [`ANSWERS_MAX_BYTES`] of them are kept (stderr says how many were left out),
//! every cell is escaped and cut to [`CELL_MAX`] bytes (the WHERE column to its parts' bounds),
//! and the table has at most [`ROWS_MAX`] rows (about 1 KiB each), so under 5 MiB; `--json`
//! prints the kept answers (at most [`ANSWERS_MAX_BYTES`], control characters escaped by JSON).
//!
//! `watch KEYEXPR` prints every sample under `KEYEXPR` as it comes, one line each:
//! `<receive time, RFC 3339 UTC> <key> <payload>` (the payload as text when it is UTF-8, else
//! as hex), and with `--liveliness` the tokens under `KEYEXPR` as they come (`+ key`) and go
//! (`- key`). It runs until SIGINT or SIGTERM.

use std::fmt::Write as _;
use std::time::{Duration, SystemTime};

use serde_json::Value;
use tokio_util::sync::CancellationToken;
use zenoh::sample::{Sample, SampleKind};

use super::fleet::{self, bounded_text};

/// The most bytes of status answers `fleet status` keeps (the rest are left out, counted).
pub const ANSWERS_MAX_BYTES: usize = 4 * 1024 * 1024;
/// The longest cell of the table (bytes, after escaping), but WHERE.
pub const CELL_MAX: usize = 64;
/// The most rows of the table (the rest are left out, counted in a last line).
pub const ROWS_MAX: usize = 4096;

/// Where `fleet` commands connect without `--connect`: a gateway or router on this machine.
pub const LOCAL_ENDPOINT: &str = "tcp/127.0.0.1:7447";

/// `gateway fleet ...`.
#[derive(Debug, clap::Subcommand)]
pub enum FleetCommand {
    /// Print one table of every gateway, line and device that answers; exit 1 if none does.
    Status {
        /// Connect as a zenoh client to this endpoint only (e.g. tcp/10.0.0.1:7447), multicast
        /// scouting off.
        #[arg(long, value_name = "ENDPOINT")]
        connect: Option<String>,
        /// The gateways' key prefixes, as a key expression.
        #[arg(long, value_name = "KEYEXPR", default_value = "gw/*")]
        gateways: String,
        /// How long to wait for the answers.
        #[arg(long, value_name = "DURATION", default_value = "3s", value_parser = humantime::parse_duration)]
        timeout: Duration,
        /// Print the answers as JSON (one array) instead of the table.
        #[arg(long)]
        json: bool,
    },
    /// Print the samples under KEYEXPR as they come, one line each with the time.
    Watch {
        /// The key expression (e.g. `gw/*/*/events`, `gw/**`).
        keyexpr: String,
        /// Connect as a zenoh client to this endpoint only, multicast scouting off.
        #[arg(long, value_name = "ENDPOINT")]
        connect: Option<String>,
        /// Also print liveliness tokens under KEYEXPR as they come (`+`) and go (`-`).
        #[arg(long)]
        liveliness: bool,
    },
}

/// Why a fleet command could not run.
#[derive(Debug, thiserror::Error)]
pub enum FleetError {
    /// A bad endpoint or key expression.
    #[error("{0}")]
    Usage(String),
    /// The session or a declaration failed.
    #[error("zenoh: {0}")]
    Zenoh(String),
}

/// Runs a fleet command; the process's exit code (0, 1 when `status` found no gateway, 64 on a
/// usage error, 70 when zenoh failed).
pub async fn run(command: FleetCommand, shutdown: CancellationToken) -> u8 {
    let result = match command {
        FleetCommand::Status {
            connect,
            gateways,
            timeout,
            json,
        } => status(connect.as_deref(), &gateways, timeout, json).await,
        FleetCommand::Watch {
            keyexpr,
            connect,
            liveliness,
        } => watch(connect.as_deref(), &keyexpr, liveliness, shutdown).await,
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("gateway fleet: {e}");
            match e {
                FleetError::Usage(_) => 64,
                FleetError::Zenoh(_) => 70,
            }
        }
    }
}

/// The session of a fleet command (see the module docs).
pub fn session_config(connect: Option<&str>) -> Result<zenoh::Config, FleetError> {
    let mut c = zenoh::Config::default();
    let mut set = |key: &str, value: &str| {
        c.insert_json5(key, value)
            .map_err(|e| FleetError::Usage(format!("zenoh config {key} = {value}: {e}")))
    };
    match connect {
        Some(endpoint) => {
            endpoint
                .parse::<zenoh::config::EndPoint>()
                .map_err(|e| FleetError::Usage(format!("bad endpoint {endpoint:?}: {e}")))?;
            set("mode", r#""client""#)?;
            set(
                "connect/endpoints",
                &serde_json::json!([endpoint]).to_string(),
            )?;
            set("scouting/multicast/enabled", "false")?;
        }
        None => {
            set("mode", r#""peer""#)?;
            set("listen/endpoints", "[]")?;
            set(
                "connect/endpoints",
                &serde_json::json!([LOCAL_ENDPOINT]).to_string(),
            )?;
            set("scouting/multicast/enabled", "true")?;
        }
    }
    Ok(c)
}

async fn open(connect: Option<&str>) -> Result<zenoh::Session, FleetError> {
    let config = session_config(connect)?;
    zenoh::open(config)
        .await
        .map_err(|e| FleetError::Zenoh(format!("session not opened: {e}")))
}

async fn status(
    connect: Option<&str>,
    gateways: &str,
    timeout: Duration,
    as_json: bool,
) -> Result<u8, FleetError> {
    let key = format!("{gateways}/status");
    zenoh::key_expr::KeyExpr::try_from(key.as_str())
        .map_err(|e| FleetError::Usage(format!("bad key expression {key:?}: {e}")))?;
    let session = open(connect).await?;
    let answers = collect_status(&session, &key, timeout).await?;
    let _ = session.close().await;
    if answers.is_empty() {
        eprintln!("gateway fleet: no gateway answered on {key} within {timeout:?}");
        return Ok(1);
    }
    if as_json {
        let list: Vec<Value> = answers.into_iter().map(|(_, v)| v).collect();
        println!("{}", Value::Array(list));
    } else {
        print!("{}", table(&answers));
    }
    Ok(0)
}

/// Every JSON answer on `key` within `timeout`, as `(reply key, status)`, by reply key.
pub async fn collect_status(
    session: &zenoh::Session,
    key: &str,
    timeout: Duration,
) -> Result<Vec<(String, Value)>, FleetError> {
    let replies = session
        .get(key)
        .timeout(timeout)
        .await
        .map_err(|e| FleetError::Zenoh(format!("query {key}: {e}")))?;
    let mut answers = Vec::new();
    let (mut kept_bytes, mut left_out) = (0usize, 0usize);
    while let Ok(reply) = replies.recv_async().await {
        match reply.result() {
            Ok(sample) => {
                let len = sample.payload().len();
                let key = bounded_text(sample.key_expr().as_str(), fleet::KEY_MAX + 7);
                if len > fleet::STATUS_MAX
                    || answers.len() >= fleet::MEMBER_LIMIT
                    || kept_bytes + len > ANSWERS_MAX_BYTES
                {
                    left_out += 1;
                    continue;
                }
                match serde_json::from_slice::<Value>(&sample.payload().to_bytes()) {
                    Ok(v) => {
                        kept_bytes += len;
                        answers.push((key, v));
                    }
                    Err(e) => {
                        eprintln!("gateway fleet: {key} answered something that is not JSON: {e}");
                    }
                }
            }
            Err(e) => eprintln!(
                "gateway fleet: an error reply: {}",
                bounded_text(&String::from_utf8_lossy(&e.payload().to_bytes()), 256)
            ),
        }
    }
    if left_out > 0 {
        eprintln!(
            "gateway fleet: {left_out} answers left out (over {} bytes each, over {} answers or \
             {ANSWERS_MAX_BYTES} bytes in all)",
            fleet::STATUS_MAX,
            fleet::MEMBER_LIMIT
        );
    }
    answers.sort_by(|a, b| a.0.cmp(&b.0));
    Ok(answers)
}

/// A row of the `fleet status` table, one cell per column of [`HEADER`].
type Row = [String; 8];

/// The columns of the `fleet status` table.
const HEADER: [&str; 8] = [
    "GATEWAY",
    "LINE",
    "DEVICE",
    "ONLINE",
    "STATUS",
    "LAST EVENT",
    "AGE",
    "WHERE",
];

/// The table of `fleet status`: a row per gateway, per line and per device.
pub fn table(answers: &[(String, Value)]) -> String {
    let mut rows: Vec<Row> = Vec::new();
    for (key, s) in answers {
        gateway_rows(key, s, &mut rows);
    }
    layout(rows)
}

/// The rows of one gateway's status answer: the gateway, then each line and its devices.
fn gateway_rows(key: &str, s: &Value, rows: &mut Vec<Row>) {
    let gw = text(s, "name").unwrap_or_else(|| key.trim_end_matches("/status").to_owned());
    let lines = s.get("lines").and_then(Value::as_array);
    let mut place = vec![];
    if let Some(h) = s.get("host").and_then(Value::as_str) {
        place.push(bounded_text(h, fleet::HOST_MAX));
    }
    if let Some(z) = s.pointer("/zenoh/zid").and_then(Value::as_str) {
        place.push(format!("zid {}", bounded_text(z, fleet::ZID_MAX)));
    }
    if let Some(u) = s.get("http").and_then(Value::as_str) {
        place.push(bounded_text(u, fleet::HTTP_MAX));
    }
    rows.push([
        gw.clone(),
        format!("({} lines)", lines.map_or(0, Vec::len)),
        "-".into(),
        "yes".into(),
        "-".into(),
        "-".into(),
        s.get("uptime_s")
            .and_then(Value::as_f64)
            .map_or_else(|| "-".into(), |u| format!("up {}", age(u))),
        place.join(" "),
    ]);
    for line in lines.into_iter().flatten() {
        line_rows(&gw, line, rows);
    }
}

/// The rows of one line of a gateway: the line, then each of its devices.
fn line_rows(gw: &str, line: &Value, rows: &mut Vec<Row>) {
    let name = text(line, "name").unwrap_or_default();
    let online = line
        .get("online")
        .or_else(|| line.get("port_open"))
        .and_then(Value::as_bool);
    let event = line.get("last_event").filter(|e| !e.is_null()).map(|e| {
        format!(
            "{} {}",
            text(e, "code").unwrap_or_default(),
            text(e, "class_name").unwrap_or_default()
        )
        .trim()
        .to_owned()
    });
    rows.push([
        gw.to_owned(),
        name.clone(),
        "-".into(),
        yes_no(online),
        line.get("status_word")
            .and_then(Value::as_u64)
            .map_or_else(|| "-".into(), |w| format!("{w:04X}")),
        event.unwrap_or_else(|| "-".into()),
        line.get("last_event_age_s")
            .and_then(Value::as_f64)
            .map_or_else(|| "-".into(), age),
        text(line, "protocol").unwrap_or_default(),
    ]);
    for d in line
        .get("devices")
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
    {
        rows.push([
            gw.to_owned(),
            name.clone(),
            text(d, "name").unwrap_or_default(),
            yes_no(d.get("online").and_then(Value::as_bool)),
            "-".into(),
            "-".into(),
            d.get("last_answer_age_s")
                .and_then(Value::as_f64)
                .map_or_else(|| "-".into(), age),
            d.get("address")
                .and_then(Value::as_u64)
                .map_or_else(String::new, |a| format!("address {a}")),
        ]);
    }
}

/// The rows as aligned text under [`HEADER`], at most [`ROWS_MAX`] of them.
fn layout(mut rows: Vec<Row>) -> String {
    let left_out = rows.len().saturating_sub(ROWS_MAX);
    rows.truncate(ROWS_MAX);
    let mut widths = HEADER.map(str::len);
    for row in &rows {
        for (w, cell) in widths.iter_mut().zip(row) {
            *w = (*w).max(cell.chars().count());
        }
    }
    let mut out = String::new();
    let mut put = |cells: &[&str]| {
        let mut line = String::new();
        for (i, (cell, w)) in cells.iter().zip(widths).enumerate() {
            if i + 1 == cells.len() {
                line.push_str(cell);
            } else {
                let _ = write!(line, "{cell:<w$}  ");
            }
        }
        out.push_str(line.trim_end());
        out.push('\n');
    };
    put(&HEADER);
    for row in &rows {
        put(&row.each_ref().map(String::as_str));
    }
    if left_out > 0 {
        let _ = writeln!(
            out,
            "... {left_out} more rows left out (at most {ROWS_MAX})"
        );
    }
    out
}

/// A text member of `v`, escaped and cut to [`CELL_MAX`].
fn text(v: &Value, key: &str) -> Option<String> {
    v.get(key)
        .and_then(Value::as_str)
        .map(|t| bounded_text(t, CELL_MAX))
}

fn yes_no(b: Option<bool>) -> String {
    match b {
        Some(true) => "yes".into(),
        Some(false) => "no".into(),
        None => "-".into(),
    }
}

/// An age in seconds as the table shows it: `850ms`, `12.3s`, `4m05s`, `2h03m`.
fn age(s: f64) -> String {
    if s < 1.0 {
        format!("{:.0}ms", s * 1000.0)
    } else if s < 60.0 {
        format!("{s:.1}s")
    } else if s < 3600.0 {
        let s = s as u64;
        format!("{}m{:02}s", s / 60, s % 60)
    } else {
        let s = s as u64;
        format!("{}h{:02}m", s / 3600, s % 3600 / 60)
    }
}

async fn watch(
    connect: Option<&str>,
    keyexpr: &str,
    liveliness: bool,
    shutdown: CancellationToken,
) -> Result<u8, FleetError> {
    zenoh::key_expr::KeyExpr::try_from(keyexpr)
        .map_err(|e| FleetError::Usage(format!("bad key expression {keyexpr:?}: {e}")))?;
    let session = open(connect).await?;
    let samples = session
        .declare_subscriber(keyexpr)
        .await
        .map_err(|e| FleetError::Zenoh(format!("subscriber on {keyexpr}: {e}")))?;
    let tokens = if liveliness {
        Some(
            session
                .liveliness()
                .declare_subscriber(keyexpr)
                .history(true)
                .await
                .map_err(|e| {
                    FleetError::Zenoh(format!("liveliness subscriber on {keyexpr}: {e}"))
                })?,
        )
    } else {
        None
    };
    eprintln!("gateway fleet: watching {keyexpr} (Ctrl-C stops)");
    loop {
        let token = async {
            match &tokens {
                Some(t) => t.recv_async().await.ok(),
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            () = shutdown.cancelled() => break,
            s = samples.recv_async() => match s {
                Ok(s) => println!("{}", sample_line(SystemTime::now(), &s)),
                Err(_) => break,
            },
            Some(t) = token => {
                let sign = if t.kind() == SampleKind::Put { '+' } else { '-' };
                println!("{} {sign} {}", super::publish::rfc3339(SystemTime::now()), t.key_expr());
            }
        }
    }
    let _ = session.close().await;
    Ok(0)
}

/// One line of `watch`: time, key, payload (text, or hex when it is not UTF-8), and the
/// attachment when there is one.
fn sample_line(received: SystemTime, sample: &Sample) -> String {
    let bytes = sample.payload().to_bytes();
    let mut line = format!(
        "{} {} {}",
        super::publish::rfc3339(received),
        sample.key_expr(),
        payload_text(&bytes)
    );
    if sample.kind() == SampleKind::Delete {
        line.push_str(" (delete)");
    }
    if let Some(a) = sample.attachment() {
        let _ = write!(line, " attachment {}", payload_text(&a.to_bytes()));
    }
    line
}

/// UTF-8 text without line breaks as it is; anything else as hex.
pub fn payload_text(bytes: &[u8]) -> String {
    match std::str::from_utf8(bytes) {
        Ok(t) if !t.contains(['\n', '\r']) => t.to_owned(),
        _ => bytes.iter().fold(String::from("0x"), |mut s, b| {
            let _ = write!(s, "{b:02x}");
            s
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn the_table_has_a_row_per_gateway_line_and_device() {
        let answers = vec![(
            "gw/a/status".to_owned(),
            json!({"name": "a", "host": "cab1", "uptime_s": 75.0,
                   "zenoh": {"zid": "f1"},
                   "lines": [{"name": "drive", "protocol": "modbus-master-rtu", "online": true,
                              "status_word": 2096,
                              "last_event": {"class": 8, "number": 48, "status_word": 2096,
                                             "code": "0830", "class_name": "modbus"},
                              "last_event_age_s": 2.5,
                              "devices": [{"name": "atv71", "address": 2, "online": false,
                                           "last_answer_age_s": 0.25}]}]}),
        )];
        let t = table(&answers);
        let rows: Vec<&str> = t.lines().collect();
        assert_eq!(rows.len(), 4, "{t}");
        assert!(rows[0].starts_with("GATEWAY"));
        assert!(
            rows[1].starts_with("a ")
                && rows[1].contains("up 1m15s")
                && rows[1].contains("cab1 zid f1"),
            "{t}"
        );
        assert!(
            rows[2].contains("drive")
                && rows[2].contains("0830")
                && rows[2].contains("0830 modbus")
                && rows[2].contains("2.5s"),
            "{t}"
        );
        assert!(
            rows[3].contains("atv71") && rows[3].contains(" no ") && rows[3].contains("250ms"),
            "{t}"
        );
    }

    #[test]
    fn payloads_print_as_text_or_hex() {
        assert_eq!(payload_text(b"{\"value\":1}"), "{\"value\":1}");
        assert_eq!(payload_text(&[0x02, 0xff]), "0x02ff");
        assert_eq!(payload_text(b"a\nb"), "0x610a62");
    }

    #[test]
    fn ages_read_well() {
        assert_eq!(age(0.85), "850ms");
        assert_eq!(age(12.34), "12.3s");
        assert_eq!(age(245.0), "4m05s");
        assert_eq!(age(7380.0), "2h03m");
    }

    #[test]
    fn connect_makes_a_client_without_scouting() {
        let c = session_config(Some("tcp/127.0.0.1:7000")).unwrap();
        assert_eq!(c.get_json("mode").unwrap(), "\"client\"");
        assert_eq!(c.get_json("scouting/multicast/enabled").unwrap(), "false");
        assert!(session_config(Some("nonsense")).is_err());
    }
}
