//! The demo and the example file, serde, every problem of a file at once, `gateway check`.

use super::*;

// === demo and example ===

#[test]
fn demo_follows_the_spec() {
    let c = config::demo();
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
    let drive: Vec<_> = c.lines["drive"].devices().collect();
    assert_eq!(drive.len(), 1);
    assert_eq!(
        (drive[0].1.profile, drive[0].1.address, drive[0].1.unit_id),
        (Profile::Altivar71, 2, 2)
    );
    assert!(matches!(
        c.lines["drive"].protocol,
        ProtocolConfig::ModbusMasterRtu(_)
    ));
    let kv: Vec<_> = c.lines["ksvario"].devices().collect();
    assert_eq!(
        (kv[0].1.profile, kv[0].1.address, kv[0].1.unit_id),
        (Profile::Ksvario, 17, 17)
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
    assert_eq!(c.device_count(), 2);
}

#[test]
fn demo_and_example_round_trip_through_serialize() {
    for c in [config::demo(), parse(EXAMPLE)] {
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
    let c = parse(EXAMPLE);
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
        .flat_map(|l| l.devices().map(|(_, d)| format!("{:?}", d.profile)))
        .collect();
    assert!(
        profiles.contains("Altivar71") && profiles.contains("Generic"),
        "{profiles:?}"
    );
}

#[test]
fn configs_changed_in_code_are_checked_by_the_same_rules() {
    let mut c = config::demo();
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
            "lines.ksvario.devices.ksvario.unit_id"
        ],
    );
    assert_eq!(Config::default(), parse(""));
}

#[test]
fn serde_deserialize_uses_the_same_rules() {
    let c: Config = toml::from_str(EXAMPLE).expect("example through serde");
    assert_eq!(c, parse(EXAMPLE));
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
    let shown = config::parse(text).expect_err("invalid").to_string();
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

#[test]
fn check_reports_counts_or_issues() {
    let ok = temp_file("config-check-ok.toml", EXAMPLE);
    let (text, code) = gateway::app::check_report(&ok);
    assert_eq!((text.as_str(), code), ("ok: 5 lines, 2 devices", 0));
    assert_eq!(gateway::app::check_command(&ok), 0);

    let bad = temp_file(
        "config-check-bad.toml",
        "[gateway]\nname = \"A\"\n[lines.a]\nport = \"x\"\n",
    );
    let (text, code) = gateway::app::check_report(&bad);
    assert_eq!(code, 1);
    assert_eq!(text.lines().collect::<Vec<_>>(), ["gateway.name: invalid name \"A\": use 1 to 64 characters of a-z, 0-9, '_' and '-' (names appear in metric labels and zenoh keys)", "lines.a.protocol: missing required key (modbus-master-rtu, modbus-master-ascii, modbus-slave-rtu, 3964r or ascii)"]);
    assert_eq!(gateway::app::check_command(&bad), 1);

    let missing = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("no-such-config.toml");
    let err = config::load(&missing).expect_err("missing file");
    assert!(err.issues[0].message.starts_with("cannot read"), "{err}");
}

#[test]
fn load_reads_the_example() {
    let path = temp_file("config-load-example.toml", EXAMPLE);
    assert_eq!(config::load(&path).expect("example loads"), parse(EXAMPLE));
    assert_eq!(
        config::parse(config::demo_toml()).expect("demo parses"),
        config::demo()
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
