//! The demo and the example file, serde, every problem of a file at once, `gateway check`.

use super::*;

// === demo and example ===

#[test]
fn demo_follows_the_spec() {
    let c = gateway::plant::demo();
    assert_eq!(c.gateway.name, "demo");
    assert_eq!(
        c.modbus_tcp.listen,
        "127.0.0.1:5020".parse::<SocketAddr>().unwrap() // the demo's fixed address; not bound here
    );
    let names: Vec<_> = c.lines.keys().map(String::as_str).collect();
    // The demo's four fixed lines, and `hmi`, the slave line a simulated serial master polls.
    assert_eq!(names, ["ascii", "drive", "hmi", "ksvario", "r3964"]);
    let frame = |l: &LineConfig| {
        (
            l.serial.baud.get(),
            l.serial.data_bits.get(),
            l.serial.parity,
            l.serial.stop_bits.get(),
        )
    };
    for (name, baud) in [
        ("drive", 19200),
        ("ksvario", 19200),
        ("r3964", 9600),
        ("ascii", 9600),
    ] {
        let l = &c.lines[name];
        assert_eq!(
            frame(l),
            (baud, 8, Parity::Even, 1),
            "{name}: 8E1 at {baud}"
        );
        assert_eq!(l.serial.pty_name(), Some(name), "{name} runs on a demo pty");
    }
    // Two drives on one bus (multi-drop): slaves 2 and 3, served as unit ids 2 and 3.
    let drive: Vec<_> = c.lines["drive"].devices().collect();
    assert_eq!(drive.len(), 2);
    assert_eq!(
        (drive[0].1.profile, drive[0].1.address, drive[0].1.unit_id),
        (Profile::named("altivar71").expect("registered"), 2, 2)
    );
    assert_eq!(
        (drive[1].1.profile, drive[1].1.address, drive[1].1.unit_id),
        (Profile::named("altivar71").expect("registered"), 3, 3)
    );
    assert!(matches!(
        c.lines["drive"].protocol,
        ProtocolConfig::ModbusMasterRtu(_)
    ));
    let kv: Vec<_> = c.lines["ksvario"].devices().collect();
    assert_eq!(
        (kv[0].1.profile, kv[0].1.address, kv[0].1.unit_id),
        (Profile::named("ksvario").expect("registered"), 17, 17)
    );
    let ProtocolConfig::Proc3964(p) = &c.lines["r3964"].protocol else {
        panic!("r3964 is 3964R")
    };
    assert!(p.block_check);
    assert_eq!(p.priority, Priority::High);
    let ProtocolConfig::Ascii(a) = &c.lines["ascii"].protocol else {
        panic!("ascii line")
    };
    assert_eq!(a.end_criterion, EndCriterion::EndChars);
    assert_eq!(a.end_chars, [0x03]);
    // Two drives, the KS vario, and the meter of every tag type on the KS vario's bus.
    assert_eq!(c.device_count(), 4);
    let ks: Vec<_> = c.lines["ksvario"].devices().collect();
    assert_eq!(
        (
            ks[1].0.as_str(),
            ks[1].1.profile,
            ks[1].1.address,
            ks[1].1.unit_id
        ),
        ("meter", Profile::GENERIC, 30, 30)
    );
}

#[test]
fn demo_and_example_round_trip_through_serialize() {
    for c in [gateway::plant::demo(), parse(&EXAMPLE)] {
        let text = toml::to_string(&c).expect("serialize");
        assert_eq!(parse(&text), c, "round trip of\n{text}");
    }
}

/// Every key path of a TOML table; array elements are indexed, arrays of plain values are leaves.
fn key_paths(prefix: &str, table: &toml::Table, out: &mut BTreeSet<String>) {
    for (key, value) in table {
        let path = if prefix.is_empty() {
            key.clone()
        } else {
            format!("{prefix}.{key}")
        };
        match value {
            toml::Value::Table(t) => key_paths(&path, t, out),
            toml::Value::Array(items) if items.iter().any(toml::Value::is_table) => {
                for (i, item) in items.iter().enumerate() {
                    if let toml::Value::Table(t) = item {
                        key_paths(&format!("{path}[{i}]"), t, out);
                    }
                }
            }
            _ => {
                out.insert(path);
            }
        }
    }
}

#[test]
fn example_contains_every_key() {
    let c = parse(&EXAMPLE);
    // Serializing writes every field of every struct; the example must have written them all.
    let written: toml::Table = toml::to_string(&c)
        .expect("serialize")
        .parse()
        .expect("reparse");
    let example: toml::Table = EXAMPLE.parse().expect("example is TOML");
    let (mut all, mut given) = (BTreeSet::new(), BTreeSet::new());
    key_paths("", &written, &mut all);
    key_paths("", &example, &mut given);
    let missing: Vec<_> = all.difference(&given).collect();
    assert!(
        missing.is_empty(),
        "keys missing from deploy/gateway.example.toml: {missing:#?}"
    );
    let extra: Vec<_> = given.difference(&all).collect();
    assert!(
        extra.is_empty(),
        "keys of the example that do not serialize back: {extra:#?}"
    );
    // and it shows every protocol and every profile
    let kinds: BTreeSet<_> = c
        .lines
        .values()
        .map(|l| l.protocol.kind().as_str())
        .collect();
    assert_eq!(kinds.len(), 5, "{kinds:?}");
    let profiles: BTreeSet<_> = c
        .lines
        .values()
        .flat_map(|l| l.devices().map(|(_, d)| d.profile.name()))
        .collect();
    assert!(
        profiles.contains("altivar71") && profiles.contains("generic"),
        "{profiles:?}"
    );
}

/// The example's commented keys made live as the comments beside them say ("remove the leading
/// `# `"), as (what, candidate texts): a key in a live table alone, or else together with the
/// commented keys of its comment run (`transparent_units` needs `transparent`); a key in a
/// commented-out table with its whole block, from the first `# [table]` line of its comment run to
/// the run's end.
fn example_with_comments_made_live() -> Vec<(String, Vec<String>)> {
    let lines: Vec<&str> = EXAMPLE.lines().collect();
    let is_key = |l: &str| {
        l.strip_prefix("# ").is_some_and(|rest| {
            rest.split_once(" = ").is_some_and(|(k, _)| {
                !k.is_empty() && k.chars().all(|c| c.is_ascii_lowercase() || c == '_')
            }) && rest.parse::<toml::Table>().is_ok() // not prose such as "value = raw * scale"
        })
    };
    let is_dead_header = |l: &str| {
        l.strip_prefix("# ").is_some_and(|r| {
            let r = r.split(" #").next().unwrap_or(r).trim_end();
            r.starts_with('[')
                && r.ends_with(']')
                && r.trim_matches(['[', ']'])
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '.')
        })
    };
    let live = |from: usize, to: usize, only: Option<usize>| -> String {
        let mut out: Vec<&str> = lines.clone();
        for (k, line) in out.iter_mut().enumerate().take(to).skip(from) {
            if only.is_none_or(|o| o == k) && (only.is_some() || line.starts_with('#')) {
                *line = line.strip_prefix("# ").unwrap_or(&line[1..]);
            }
        }
        out.join("\n")
    };
    let mut seen_blocks = BTreeSet::new();
    let mut out = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        if !is_key(line) {
            continue;
        }
        let mut start = i;
        while start > 0 && lines[start - 1].starts_with('#') {
            start -= 1;
        }
        let mut end = i;
        while end < lines.len() && lines[end].starts_with('#') {
            end += 1;
        }
        match (start..i).find(|&h| is_dead_header(lines[h])) {
            Some(h) => {
                if seen_blocks.insert(h) {
                    let what = format!("the block {} (line {})", lines[h], h + 1);
                    out.push((what, vec![live(h, end, None)]));
                }
            }
            None => {
                let keys_of_run = {
                    let mut out: Vec<&str> = lines.clone();
                    for line in out.iter_mut().take(end).skip(start) {
                        if is_key(line) {
                            *line = &line[2..];
                        }
                    }
                    out.join("\n")
                };
                let what = format!("{} (line {})", &line[2..], i + 1);
                out.push((what, vec![live(i, i + 1, Some(i)), keys_of_run]));
            }
        }
    }
    out
}

#[test]
fn every_commented_key_of_the_example_is_valid_where_it_stands() {
    let found = example_with_comments_made_live();
    assert!(
        found.len() >= 16,
        "only {} commented keys or blocks",
        found.len()
    );
    let failed: Vec<String> = found
        .iter()
        .filter_map(|(what, texts)| {
            let errors: Vec<String> = texts
                .iter()
                .filter_map(|t| gateway::plant::parse(t).err().map(|e| e.to_string()))
                .collect();
            (errors.len() == texts.len()).then(|| format!("{what}: {}", errors.join(" / ")))
        })
        .collect();
    assert!(failed.is_empty(), "{failed:#?}");
}

#[test]
fn configs_changed_in_code_are_checked_by_the_same_rules() {
    let mut c = gateway::plant::demo();
    assert_eq!(c.check(), Ok(()));
    let ProtocolConfig::ModbusMasterRtu(m) = &mut c.lines.get_mut("drive").expect("drive").protocol
    else {
        panic!("drive is a Modbus master")
    };
    m.reply_timeout = ms(1);
    let kv = c.lines["ksvario"].clone();
    c.lines.insert("copy".to_owned(), kv);
    let got: Vec<_> = c
        .check()
        .expect_err("invalid")
        .issues
        .into_iter()
        .map(|i| i.path)
        .collect();
    assert_eq!(
        got,
        [
            "lines.drive.reply_timeout",
            "lines.ksvario.port",
            "lines.ksvario.devices.ksvario.unit_id",
            "lines.ksvario.devices.meter.unit_id"
        ],
    );
    assert_eq!(Config::default(), parse(""));
}

#[test]
fn serde_deserialize_uses_the_same_rules() {
    let c: Config = toml::from_str(&EXAMPLE).expect("example through serde");
    assert_eq!(c, parse(&EXAMPLE));
    let err = toml::from_str::<Config>("[gateway]\nnmae = \"x\"\n").expect_err("unknown key");
    assert!(
        err.to_string().contains("gateway.nmae: unknown key"),
        "{err}"
    );
}

// === all problems at once ===

#[test]
fn three_independent_mistakes_give_three_issues() {
    let text = r#"
[gateway]
name = "plant"

[modbus_tcp]
listen = "0.0.0.0:502"
max_conections = 10

[lines.drive]
port = "/dev/ttyS0"
protocol = "modbus-master-rtu"
baud = 19201

[lines.drive.devices.atv]
profile = "altivar71"
address = 2

[lines.kv]
port = "/dev/ttyS1"
protocol = "modbus-master-rtu"

[lines.kv.devices.ks]
profile = "ksvario"
address = 17
unit_id = 2
"#;
    let got = issues(text);
    let paths: Vec<_> = got.iter().map(|(p, _)| p.as_str()).collect();
    assert_eq!(
        paths,
        [
            "modbus_tcp.max_conections",
            "lines.drive.baud",
            "lines.kv.devices.ks.unit_id"
        ],
        "{got:#?}"
    );
    assert!(got[0].1.starts_with("unknown key"));
    assert!(got[1].1.contains("19201 baud is not supported"));
    assert!(got[2]
        .1
        .contains("unit id 2 is already used by lines.drive.devices.atv"));
    // Display: one line per issue, `path: message`.
    let shown = gateway::plant::parse(text)
        .expect_err("invalid")
        .to_string();
    let lines: Vec<_> = shown.lines().collect();
    assert_eq!(lines.len(), 3);
    assert!(
        lines[1].starts_with("lines.drive.baud: 19201 baud"),
        "{shown}"
    );
}

#[test]
fn several_problems_in_one_table_are_all_reported() {
    let got = issues(&one_line(
        "3964r",
        "priority = \"medium\"\nsetup_attempts = 0\nbcc = true\ncharacter_delay = \"225ms\"",
    ));
    let paths: Vec<_> = got.iter().map(|(p, _)| p.as_str()).collect();
    assert_eq!(
        paths,
        [
            "lines.a.character_delay",
            "lines.a.priority",
            "lines.a.setup_attempts",
            "lines.a.bcc"
        ],
        "{got:#?}"
    );
}

#[test]
fn a_bad_value_raises_no_follow_up_issues() {
    // The tag with a bad table stays known to the poll group; the bad range does not leave an
    // "empty poll group" behind; the bad profile does not leave a device without tags.
    let text = one_line(
        "modbus-master-rtu",
        r#"
[lines.a.devices.d]
profile = "generic"
address = 1
tags = [{ name = "t", table = "holdings", address = 0, type = "bool" }]
poll = [{ name = "p", period = "1s", tags = ["t"] },
        { name = "q", period = "1s", ranges = [{ table = "holding", start = 0, count = 0 }] }]
[lines.a.devices.e]
profile = "generik"
address = 2
"#,
    );
    let got = issues(&text);
    let paths: Vec<_> = got.iter().map(|(p, _)| p.as_str()).collect();
    assert_eq!(
        paths,
        [
            "lines.a.devices.d.tags[0].table",
            "lines.a.devices.d.poll[1].ranges[0].count",
            "lines.a.devices.e.profile"
        ],
        "{got:#?}"
    );
}

#[test]
fn syntax_errors_carry_line_and_column() {
    let got = issues("[gateway]\nname = \"x\"\ndiag_buffer_depth = = 3\n");
    assert_eq!(got.len(), 1);
    assert_eq!(got[0].0, "");
    assert!(
        got[0].1.starts_with("TOML syntax error at line 3, column"),
        "{}",
        got[0].1
    );
    // Two lines of the same name are a TOML duplicate key.
    let got = issues("[lines.a]\nport = \"x\"\nprotocol = \"ascii\"\n[lines.a]\nport = \"y\"\n");
    assert!(got[0].1.ends_with("duplicate key (at `a`)"), "{}", got[0].1);
    assert!(
        got[0].1.starts_with("TOML syntax error at line 4"),
        "{}",
        got[0].1
    );
}

// === files and `gateway check` ===

fn temp_file(name: &str, text: &str) -> PathBuf {
    let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    std::fs::write(&path, text).expect("write temp config");
    path
}

/// The Altivar profile's tags that the example polls by neither name nor range.
const UNPOLLED_ATV71: &str = "warning: lines.drive.devices.atv71.poll: 44 tags of the profile are read by no poll group (read on demand only, never published on change): SFr, tFr, HSP, LSP, M1EC, M1CT, LFT, CHCF, COP, CMD, LFRD, THR and 32 more";

#[test]
fn check_reports_counts_or_issues() {
    // The example's token file, here with a token of 16 characters (run reads it at start).
    let token = temp_file("config-check-ok-token", "0123456789abcdef\n");
    let example = EXAMPLE.replace(
        "# token_file = \"/etc/gateway/api-token\"",
        &format!("token_file = \"{}\"", token.display()),
    );
    assert_ne!(example, *EXAMPLE);
    let ok = temp_file("config-check-ok.toml", &example);
    let (text, code) = gateway::app::check_report(&ok);
    // The example's ports are not plugged in here: a warning each, in the words a change over
    // the REST API is refused with, not a problem.
    let ports = [
        (
            "drive",
            "/dev/serial/by-id/usb-FTDI_FT232R_USB_UART_A10K1234-if00-port0",
        ),
        ("meters", "/dev/ttyS1"),
        ("plc", "/dev/ttyS2"),
        ("r3964", "/dev/ttyS3"),
        ("scanner", "/dev/ttyS4"),
    ];
    let mut expected = vec!["ok: 5 lines, 3 devices".to_owned()];
    for (line, port) in ports {
        if !std::path::Path::new(port).exists() {
            expected.push(format!("warning: lines.{line}.port: no such serial port {port} (the line opens it with back-off until it appears)"));
        }
    }
    expected.push(UNPOLLED_ATV71.to_owned());
    // The CP memory's persistence file is opened by the start check as run opens it: where its
    // state directory does not exist yet (systemd makes it), a warning, not a problem.
    if !std::path::Path::new("/var/lib/gateway").exists() {
        expected.push("warning: cp_memory.persist_file: the directory /var/lib/gateway does not exist: the memory starts zeroed and every save fails (logged) until it exists (systemd's StateDirectory= makes it when the service starts)".to_owned());
    }
    assert_eq!((text.as_str(), code), (expected.join("\n").as_str(), 0));
    assert_eq!(gateway::app::check_command(&ok), 0);

    let bad = temp_file(
        "config-check-bad.toml",
        "[gateway]\nname = \"A\"\n[lines.a]\nport = \"x\"\n",
    );
    let (text, code) = gateway::app::check_report(&bad);
    assert_eq!(code, 1);
    assert_eq!(text.lines().collect::<Vec<_>>(), ["gateway.name: invalid name \"A\": use 1 to 64 characters of a-z, 0-9, '_' and '-' (names appear in metric labels and zenoh keys)", "lines.a.protocol: missing required key (modbus-master-rtu, modbus-master-ascii, modbus-slave-rtu, modbus-rtu-tap, 3964r, 3964r-tap or ascii)"]);
    assert_eq!(gateway::app::check_command(&bad), 1);

    let missing = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("no-such-config.toml");
    let err = gateway::plant::load(&missing).expect_err("missing file");
    assert!(err.issues[0].message.starts_with("cannot read"), "{err}");
}

#[test]
fn load_reads_the_example() {
    let path = temp_file("config-load-example.toml", &EXAMPLE);
    assert_eq!(
        gateway::plant::load(&path).expect("example loads"),
        parse(&EXAMPLE)
    );
    assert_eq!(
        gateway::plant::parse(gateway::plant::demo_toml()).expect("demo parses"),
        gateway::plant::demo()
    );
}

#[test]
fn check_and_load_report_what_the_cp_memory_cannot_serve_with_the_readers_issues() {
    // A write enable inside a byte of M (003 6.4.5 "Limits": the write limits are whole bytes),
    // and a bad baud rate that the reader finds: both in one answer, each with its path.
    let text = one_line(
        "modbus-slave-rtu",
        "baud = 12345\nwrite_enable = [{ table = \"coil\", start = 3, count = 8 }]",
    );
    let path = temp_file("config-check-cpmem.toml", &text);
    let err = gateway::app::load_config(&path).expect_err("refused");
    let paths: Vec<&str> = err.issues.iter().map(|i| i.path.as_str()).collect();
    assert_eq!(paths, ["lines.a.baud", "lines.a.write_enable[0]"], "{err}");
    assert!(err.issues[1].message.contains("whole bytes"), "{err}");
    let (shown, code) = gateway::app::check_report(&path);
    assert_eq!((shown, code), (err.to_string(), 1));
    // The reader alone knows the keys, not the CP memory's limits.
    let paths: Vec<String> = issues(&text).into_iter().map(|(p, _)| p).collect();
    assert_eq!(paths, ["lines.a.baud"]);
}

#[test]
fn check_refuses_what_run_refuses_the_api_token() {
    // A variable that is not set, then a token file shorter than 16 characters: run exits 64 on
    // both (`run_issues`), so check reports them at the key that names the token.
    let unset = "[http]\ntoken_env = \"GATEWAY_TEST_TOKEN_THAT_IS_NEVER_SET\"\n";
    let path = temp_file("config-check-token-env.toml", unset);
    let (text, code) = gateway::app::check_report(&path);
    assert_eq!(code, 1, "{text}");
    assert_eq!(
        text,
        "http.token_env: the API token variable GATEWAY_TEST_TOKEN_THAT_IS_NEVER_SET is not set"
    );
    let run = gateway::app::run_issues(&gateway::app::load_config(&path).expect("loads"));
    assert_eq!(run.len(), 1);

    let token = temp_file("config-check-short-token", "short-token\n");
    let short = format!("[http]\ntoken_file = \"{}\"\n", token.display());
    let path = temp_file("config-check-token-file.toml", &short);
    let (text, code) = gateway::app::check_report(&path);
    assert_eq!(code, 1, "{text}");
    assert!(
        text.starts_with("http.token_file: the API token from "),
        "{text}"
    );
    assert!(
        text.ends_with("is too short (at least 16 characters)"),
        "{text}"
    );

    std::fs::write(&token, "0123456789abcdef\n").expect("token file");
    assert_eq!(
        gateway::app::check_report(&path),
        ("ok: 0 lines, 0 devices".to_owned(), 0)
    );
}

#[tokio::test]
async fn check_opens_an_rs485_port_and_reports_a_refused_rs485_mode() {
    // A pseudo-terminal has no RS485 driver: the line would report 02 0Fh forever.
    let (_device, line_end) = tokio_serial::SerialStream::pair().expect("pty pair");
    let pty = tokio_serial::SerialPort::name(&line_end).expect("pty path");
    drop(line_end);
    let text = format!(
        "[lines.a]\nport = \"{pty}\"\nprotocol = \"modbus-master-rtu\"\ninterface = \"rs485\"\n"
    );
    let path = temp_file("config-check-rs485-pty.toml", &text);
    let (shown, code) = gateway::app::check_report(&path);
    assert_eq!(code, 1, "{shown}");
    assert!(
        shown.starts_with(&format!(
            "lines.a.interface: port {pty} refused RS485 mode: "
        )),
        "{shown}"
    );
    // What to set instead: the interface, or the adapter's or driver's RS485 support.
    assert!(
        shown.ends_with("(a pseudo-terminal has no RS485 driver); with an adapter that switches its transmitter itself (automatic send/receive, as most USB-RS485 adapters do) set interface = \"rs422\" (the port as it is, no kernel RS485 mode); on a UART with a transceiver on RTS, switch the driver's RS485 support on (device tree linux,rs485-enabled-at-boot-time, or a driver with TIOCSRS485)"),
        "{shown}"
    );
    // The port was closed again: it opens (exclusively) once more.
    let again = gateway::serial::PortSettings::new(pty.as_str(), 9600);
    gateway::serial::probe(&again).expect("the port is free again");

    // A port that is not there is a warning (the line opens it with back-off), on every
    // interface, in the words a change over the REST API is refused with.
    for interface in ["rs485", "rs422", "rs232"] {
        let missing = text
            .replace(&pty, "/dev/gateway-test-no-such-port")
            .replace("\"rs485\"", &format!("{interface:?}"));
        let path = temp_file("config-check-rs485-missing.toml", &missing);
        let (shown, code) = gateway::app::check_report(&path);
        assert_eq!(code, 0, "{shown}");
        assert_eq!(
            shown.lines().collect::<Vec<_>>(),
            [
                "ok: 1 lines, 0 devices",
                "warning: lines.a.port: no such serial port /dev/gateway-test-no-such-port (the line opens it with back-off until it appears)"
            ],
            "{interface}"
        );
    }
}

#[test]
fn tag_names_compare_without_case_and_check_warns_about_tags_no_poll_group_reads() {
    // `LEVEL` in a poll group is the tag `level`, `ETA` the Altivar profile's `eta`.
    let device = "[lines.a.devices.d]\nprofile = \"generic\"\naddress = 1\n\
        tags = [\n  { name = \"level\", table = \"holding\", address = 10 },\n  \
        { name = \"flow\", table = \"holding\", address = 11, writable = true },\n  \
        { name = \"spare\", table = \"holding\", address = 50 },\n]\n\
        [[lines.a.devices.d.poll]]\nname = \"fast\"\nperiod = \"1s\"\ntags = [\"LEVEL\"]\n\
        [[lines.a.devices.d.poll]]\nname = \"slow\"\nperiod = \"10s\"\nranges = [{ table = \"holding\", start = 11, count = 1 }]\n";
    let text = one_line("modbus-master-rtu", device);
    let c = parse(&text);
    assert_eq!(line(&c).devices().count(), 1);
    let path = temp_file("config-check-unpolled.toml", &text);
    let (shown, code) = gateway::app::check_report(&path);
    assert_eq!(code, 0, "{shown}");
    assert_eq!(
        shown,
        "ok: 1 lines, 1 devices\nwarning: lines.a.devices.d.tags[2]: tag \"spare\" is read by no poll group: it is read from the device only on demand and never published on change"
    );

    let altivar = one_line(
        "modbus-master-rtu",
        "[lines.a.devices.atv]\nprofile = \"altivar71\"\naddress = 2\n\
         [[lines.a.devices.atv.poll]]\nname = \"s\"\nperiod = \"1s\"\ntags = [\"ETA\", \"acc\", \"SFr\"]\n",
    );
    parse(&altivar);
}

#[test]
fn check_refuses_a_zenoh_file_or_a_cp_memory_file_that_run_cannot_read() {
    let missing = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("no-such-zenoh.json5");
    let text = format!("[zenoh]\nconfig_file = \"{}\"\n", missing.display());
    let path = temp_file("config-check-zenoh-file.toml", &text);
    let (shown, code) = gateway::app::check_report(&path);
    assert_eq!(code, 1, "{shown}");
    assert!(shown.starts_with("zenoh.config_file: "), "{shown}");
    assert_eq!(shown.lines().count(), 1, "{shown}");
    // Disabled, the session is never built: nothing to refuse.
    let off = temp_file(
        "config-check-zenoh-off.toml",
        &format!("{text}enabled = false\n"),
    );
    assert_eq!(gateway::app::check_report(&off).1, 0);

    // A path below a regular file can never be read (ENOTDIR); a missing file starts zeroed.
    let slave = one_line("modbus-slave-rtu", "");
    let blocked = temp_file(
        "config-check-cpmem-file.toml",
        &format!(
            "[cp_memory]\npersist_file = \"{}/memory.bin\"\n{slave}",
            path.display()
        ),
    );
    let (shown, code) = gateway::app::check_report(&blocked);
    assert_eq!(code, 1, "{shown}");
    assert!(
        shown.starts_with("cp_memory.persist_file: cannot read "),
        "{shown}"
    );
    let fresh = temp_file(
        "config-check-cpmem-fresh.toml",
        &format!(
            "[cp_memory]\npersist_file = \"{}\"\n{slave}",
            PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
                .join("no-such-memory.bin")
                .display()
        ),
    );
    assert_eq!(gateway::app::check_report(&fresh).1, 0);
}

/// The example with the commented block that begins at `start` uncommented, up to the next
/// empty line followed by prose, or the end.
fn uncommented(start: &str) -> String {
    let at = EXAMPLE.find(start).expect("the block");
    let (head, rest) = EXAMPLE.split_at(at);
    let end = rest.find("\n\n# A ").map_or(rest.len(), |e| e + 1);
    let (block, tail) = rest.split_at(end);
    let block: String = block
        .lines()
        .map(|l| l.strip_prefix("# ").unwrap_or(l))
        .map(|l| if l == "#" { "" } else { l })
        .collect::<Vec<_>>()
        .join("\n");
    format!("{head}{block}\n{tail}")
}

/// The example's tap line is commented out (its adapter is not plugged in here): with the
/// comment marks removed it is a valid tap line with its keys at their defaults.
#[test]
fn the_examples_commented_tap_line_is_valid() {
    let c = parse(&uncommented("# [lines.tap]"));
    let tap = c.lines.get("tap").expect("the tap line");
    let ProtocolConfig::ModbusRtuTap(t) = &tap.protocol else {
        panic!("a tap line: {tap:?}");
    };
    assert_eq!(t.answer_timeout, gateway::protocols::DEFAULT_ANSWER_TIMEOUT);
    assert_eq!(t.expected_cycle, gateway::protocols::DEFAULT_EXPECTED_CYCLE);
    assert_eq!(t.delay_multiplier, 1);
    assert!(t.inter_character_check);
    assert_eq!(
        tap.devices()
            .map(|(n, d)| (n.as_str(), d.unit_id))
            .collect::<Vec<_>>(),
        [("pump", 5)]
    );
}

/// The example's 3964(R) tap of a Y-cable, commented out as the Modbus tap is: uncommented it is
/// a valid line on two ports with the procedure's defaults, and `check` passes.
#[test]
fn the_examples_commented_3964r_tap_line_is_valid() {
    let text = uncommented("# [lines.y_link]");
    let c = parse(&text);
    let tap = c.lines.get("y_link").expect("the 3964(R) tap line");
    let ProtocolConfig::Proc3964Tap(t) = &tap.protocol else {
        panic!("a 3964(R) tap line: {tap:?}");
    };
    assert_eq!(tap.serial.port, "/dev/ttyS5");
    assert_eq!(t.port_b, "/dev/ttyS6");
    assert!(t.block_check);
    assert_eq!(
        t.character_delay,
        gateway::protocols::DEFAULT_3964_CHARACTER_DELAY
    );
    assert_eq!(t.ack_delay, gateway::protocols::DEFAULT_3964_ACK_DELAY);
    assert_eq!(
        t.max_telegram_len,
        gateway::protocols::DEFAULT_3964_MAX_TELEGRAM_LEN
    );
    assert_eq!(
        t.receive_buffer,
        gateway::protocols::DEFAULT_3964_RECEIVE_BUFFER
    );
    assert_eq!(tap.unit_id(), Some(102));
    assert_eq!(c.check(), Ok(()));
}
