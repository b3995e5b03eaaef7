//! Unknown keys and the checks of single keys.

use super::*;

// === unknown keys ===

#[test]
fn unknown_keys_are_refused_with_their_path() {
    let cases: &[(&str, &str)] = &[
        ("[http]\nlisten = \"127.0.0.1:0\"\ncolour = 1\n", "http.colour"),
        ("[htpp]\nlisten = \"x\"\n", "htpp"),
        ("[zenoh]\nmode = \"peer\"\nlisen = []\n", "zenoh.lisen"),
        ("[gateway]\nnmae = \"x\"\n", "gateway.nmae"),
        ("[modbus_tcp]\nwrite_ranges = [{ unit_id = 1, table = \"coil\", start = 0, count = 1, x = 1 }]\n", "modbus_tcp.write_ranges[0].x"),
    ];
    for (text, path) in cases {
        let got = issues(text);
        assert!(
            got.iter()
                .any(|(p, m)| p == path && m.starts_with("unknown key")),
            "{text}: {got:#?}"
        );
    }
    one_issue(
        &one_line("ascii", "baudrate = 9600"),
        "lines.a.baudrate",
        "unknown key",
    );
    // a key of another protocol is unknown too
    one_issue(
        &one_line("ascii", "reply_timeout = \"1s\""),
        "lines.a.reply_timeout",
        "unknown key",
    );
    one_issue(
        &one_line("3964r", "interface = \"rs232\"\n[lines.a.rs485]\n"),
        "lines.a.rs485",
        "need interface = \"rs485\"",
    );
    one_issue(
        &one_line(
            "ascii",
            "interface = \"rs485\"\n[lines.a.rs485]\nrts_on_sent = true\n",
        ),
        "lines.a.rs485.rts_on_sent",
        "unknown key",
    );
    one_issue(
        &one_line(
            "modbus-slave-rtu",
            "[lines.a.coils]\nmemory = { start = 0, count = 8, plc = 1, x = 2 }\n",
        ),
        "lines.a.coils.memory.x",
        "unknown key",
    );
    let dev = one_line("modbus-master-rtu", "[lines.a.devices.d]\nprofile = \"generic\"\naddress = 1\nadress = 2\ntags = [{ name = \"t\", table = \"holding\", address = 0, scal = 2 }]\n");
    let got = issues(&dev);
    let paths: Vec<_> = got.iter().map(|(p, _)| p.as_str()).collect();
    assert_eq!(
        paths,
        ["lines.a.devices.d.tags[0].scal", "lines.a.devices.d.adress"],
        "{got:#?}"
    );
}

// === single-key checks ===

#[test]
fn range_checks() {
    let cases: &[(&str, &str, &str, &str)] = &[
        // (protocol, extra keys, path, message part)
        (
            "ascii",
            "baud = 14400",
            "lines.a.baud",
            "14400 baud is not supported",
        ),
        (
            "ascii",
            "data_bits = 6",
            "lines.a.data_bits",
            "between 7 and 8",
        ),
        (
            "ascii",
            "stop_bits = 3",
            "lines.a.stop_bits",
            "between 1 and 2",
        ),
        (
            "ascii",
            "parity = \"mark\"",
            "lines.a.parity",
            "unknown variant `mark`",
        ),
        (
            "ascii",
            "interface = \"rs999\"",
            "lines.a.interface",
            "unknown variant",
        ),
        (
            "modbus-master-rtu",
            "reply_timeout = \"4ms\"",
            "lines.a.reply_timeout",
            "between 5ms and 65500ms (003 6.4.2.1)",
        ),
        (
            "modbus-master-rtu",
            "reply_timeout = \"66s\"",
            "lines.a.reply_timeout",
            "found 66s",
        ),
        (
            "modbus-master-rtu",
            "reply_timeout = 2000",
            "lines.a.reply_timeout",
            "expected a duration",
        ),
        (
            "modbus-master-rtu",
            "delay_multiplier = 11",
            "lines.a.delay_multiplier",
            "between 1 and 10 (003 6.4.2.1)",
        ),
        (
            "modbus-master-rtu",
            "delay_multiplier = 0",
            "lines.a.delay_multiplier",
            "between 1 and 10",
        ),
        (
            "modbus-master-rtu",
            "operating_mode = \"quiet\"",
            "lines.a.operating_mode",
            "unknown variant",
        ),
        (
            "modbus-master-rtu",
            "turnaround_delay = \"66s\"",
            "lines.a.turnaround_delay",
            "between 0ms and 65535ms",
        ),
        (
            "modbus-master-ascii",
            "character_delay = \"6501ms\"",
            "lines.a.character_delay",
            "between 1ms and 6500ms (003 6.4.2.2)",
        ),
        (
            "modbus-master-ascii",
            "turnaround_delay = \"65536ms\"",
            "lines.a.turnaround_delay",
            "(003 6.4.2.2)",
        ),
        (
            "modbus-slave-rtu",
            "address = 0",
            "lines.a.address",
            "between 1 and 255 (003 6.4.5.1)",
        ),
        (
            "modbus-slave-rtu",
            "address = 256",
            "lines.a.address",
            "between 1 and 255",
        ),
        (
            "modbus-slave-rtu",
            "holding_db = 0",
            "lines.a.holding_db",
            "between 1 and 65408",
        ),
        (
            "modbus-slave-rtu",
            "unit_id = 0",
            "lines.a.unit_id",
            "between 1 and 255",
        ),
        (
            "3964r",
            "setup_attempts = 0",
            "lines.a.setup_attempts",
            "between 1 and 255 (003 6.3.3)",
        ),
        (
            "3964r",
            "transmission_attempts = 256",
            "lines.a.transmission_attempts",
            "between 1 and 255",
        ),
        (
            "3964r",
            "character_delay = \"10ms\"",
            "lines.a.character_delay",
            "between 20ms and 65535ms (003 6.3.3)",
        ),
        (
            "3964r",
            "ack_delay = \"2005ms\"",
            "lines.a.ack_delay",
            "multiple of 10ms (003 6.3.3)",
        ),
        (
            "3964r",
            "max_telegram_len = 1025",
            "lines.a.max_telegram_len",
            "between 1 and 1024",
        ),
        (
            "3964r",
            "priority = \"medium\"",
            "lines.a.priority",
            "unknown variant `medium`",
        ),
        (
            "3964r",
            "overflow = \"drop-newest\"",
            "lines.a.overflow",
            "unknown variant",
        ),
        (
            "ascii",
            "character_delay = \"1ms\"",
            "lines.a.character_delay",
            "between 2ms and 65535ms (003 6.2.1)",
        ),
        (
            "ascii",
            "fixed_length = 0",
            "lines.a.fixed_length",
            "between 1 and 1024 (003 6.2.1)",
        ),
        (
            "ascii",
            "end_chars = [3, 4, 5]",
            "lines.a.end_chars",
            "one or two end characters",
        ),
        (
            "ascii",
            "end_chars = []",
            "lines.a.end_chars",
            "one or two end characters",
        ),
        (
            "ascii",
            "end_chars = [256]",
            "lines.a.end_chars[0]",
            "between 0 and 255",
        ),
        (
            "ascii",
            "xon_wait = \"10ms\"",
            "lines.a.xon_wait",
            "between 20ms and 65535ms",
        ),
        (
            "ascii",
            "rts_hold_time = \"15ms\"",
            "lines.a.rts_hold_time",
            "multiple of 10ms (000 6.2.1)",
        ),
        (
            "ascii",
            "receive_buffer = 251",
            "lines.a.receive_buffer",
            "between 1 and 250 (003 6.2.1)",
        ),
        (
            "ascii",
            "end_criterion = \"never\"",
            "lines.a.end_criterion",
            "unknown variant",
        ),
        (
            "ascii",
            "flow_control = \"dtr-dsr\"",
            "lines.a.flow_control",
            "unknown variant",
        ),
        (
            "ascii",
            "unit_id = 300",
            "lines.a.unit_id",
            "between 1 and 255",
        ),
        (
            "ascii",
            "send_pause = 1",
            "lines.a.send_pause",
            "expected true or false",
        ),
        (
            "ascii",
            "interface = \"rs485\"\n[lines.a.rs485]\ndelay_before_send = \"101ms\"",
            "lines.a.rs485.delay_before_send",
            "between 0ms and 100ms",
        ),
        (
            "ascii",
            "interface = \"rs485\"\n[lines.a.rs485]\nrts_after_send = true",
            "lines.a.rs485.rts_after_send",
            "must differ",
        ),
    ];
    for (protocol, extra, path, needle) in cases {
        one_issue(&one_line(protocol, extra), path, needle);
    }
}

#[test]
fn root_and_server_range_checks() {
    one_issue(
        "[gateway]\nname = \"Plant A\"\n",
        "gateway.name",
        "invalid name",
    );
    one_issue(
        "[gateway]\ndiag_buffer_depth = 0\n",
        "gateway.diag_buffer_depth",
        "between 1 and 1000 (003 7.3)",
    );
    one_issue(
        "[modbus_tcp]\nlisten = \"localhost\"\n",
        "modbus_tcp.listen",
        "invalid socket address",
    );
    one_issue(
        "[modbus_tcp]\nmax_connections = 0\n",
        "modbus_tcp.max_connections",
        "between 1 and 4096",
    );
    one_issue(
        "[modbus_tcp]\nidle_timeout = \"0s\"\n",
        "modbus_tcp.idle_timeout",
        "between 1s and",
    );
    one_issue(
        "[modbus_tcp]\nallowed_networks = [\"10.0.0.0/33\"]\n",
        "modbus_tcp.allowed_networks[0]",
        "invalid network",
    );
    one_issue(
        "[modbus_tcp]\nread_only = \"yes\"\n",
        "modbus_tcp.read_only",
        "expected true or false",
    );
    one_issue(
        "[lines.Drive]\nport = \"x\"\nprotocol = \"ascii\"\n",
        "lines.Drive",
        "invalid name",
    );
    one_issue(
        "[lines.a]\nprotocol = \"ascii\"\n",
        "lines.a.port",
        "missing required key",
    );
    one_issue(
        "[lines.a]\nport = \"x\"\n",
        "lines.a.protocol",
        "missing required key",
    );
    one_issue(
        "[lines.a]\nport = \"x\"\nprotocol = \"rk512\"\n",
        "lines.a.protocol",
        "unknown variant `rk512`",
    );
    one_issue(
        "[lines.a]\nport = \"pty:\"\nprotocol = \"ascii\"\n",
        "lines.a.port",
        "needs a name",
    );
    one_issue("lines = 3\n", "lines", "expected a table");
    one_issue("[[lines]]\nport = \"x\"\n", "lines", "not as [[lines]]");
}

#[test]
fn device_range_checks() {
    let dev = |keys: &str| {
        one_line(
            "modbus-master-rtu",
            &format!("[lines.a.devices.d]\n{keys}\n"),
        )
    };
    one_issue(
        &dev("profile = \"altivar71\"\naddress = 0"),
        "lines.a.devices.d.address",
        "broadcast",
    );
    one_issue(
        &dev("profile = \"altivar71\"\naddress = 248"),
        "lines.a.devices.d.address",
        "between 1 and 247",
    );
    one_issue(
        &dev("profile = \"altivar71\""),
        "lines.a.devices.d.address",
        "missing required key",
    );
    one_issue(
        &dev("address = 1"),
        "lines.a.devices.d.profile",
        "missing required key",
    );
    one_issue(
        &dev("profile = \"atv\"\naddress = 1"),
        "lines.a.devices.d.profile",
        "unknown variant `atv`",
    );
    one_issue(
        &dev("profile = \"altivar71\"\naddress = 1\nunit_id = 0"),
        "lines.a.devices.d.unit_id",
        "between 1 and 255",
    );
    // limits may only lower the profile's (002: FC03 max. 63 words)
    one_issue(
        &dev("profile = \"altivar71\"\naddress = 1\nlimits = { read_registers = 64 }"),
        "lines.a.devices.d.limits.read_registers",
        "between 1 and 63 (the altivar71 profile, 002 Modbus-Funktionen)",
    );
    one_issue(
        &dev("profile = \"altivar71\"\naddress = 1\nlimits = { write_registers = 0 }"),
        "lines.a.devices.d.limits.write_registers",
        "between 1 and 61",
    );
    one_issue(
        &dev("profile = \"ksvario\"\naddress = 1\nlimits = { rw_read_registers = 1 }"),
        "lines.a.devices.d.limits.rw_read_registers",
        "between 0 and 0",
    );
    let c = parse(&dev(
        "profile = \"altivar71\"\naddress = 1\nlimits = { read_registers = 20 }",
    ));
    let (_, d) = line(&c).devices().next().expect("device");
    assert_eq!(d.limits.read_registers, 20);
    assert_eq!(d.limits.write_registers, 61);
    one_issue(
        &dev("profile = \"altivar71\"\naddress = 1\noffline_backoff_min = \"5ms\""),
        "lines.a.devices.d.offline_backoff_min",
        "between 10ms and 3600s",
    );
    // 003 6.4.2.1: a reply monitoring time is 5..65500 ms, and so is a probe's floor.
    one_issue(
        &dev("profile = \"altivar71\"\naddress = 1\nprobe_timeout_min = \"4ms\""),
        "lines.a.devices.d.probe_timeout_min",
        "between 5ms and",
    );
    one_issue(
        &dev("profile = \"altivar71\"\naddress = 1\nfull_probe_every = 0"),
        "lines.a.devices.d.full_probe_every",
        "between 1 and 1000",
    );
    one_issue(
        &dev("profile = \"altivar71\"\naddress = 1\npoll = [{ name = \"p\", period = \"1ms\", ranges = [{ table = \"holding\", start = 0, count = 1 }] }]"),
        "lines.a.devices.d.poll[0].period",
        "between 10ms and",
    );
    one_issue(
        &dev("profile = \"altivar71\"\naddress = 1\npoll = [{ name = \"p\", ranges = [{ table = \"holding\", start = 0, count = 1 }] }]"),
        "lines.a.devices.d.poll[0].period",
        "missing required key",
    );
    one_issue(
        &dev("profile = \"altivar71\"\naddress = 1\npoll = [{ name = \"p\", period = \"1s\", ranges = [{ table = \"holding\", start = 65535, count = 2 }] }]"),
        "lines.a.devices.d.poll[0].ranges[0].count",
        "runs past address 65535",
    );
    let tag = |keys: &str| {
        dev(&format!(
            "profile = \"generic\"\naddress = 1\ntags = [{{ {keys} }}]"
        ))
    };
    one_issue(
        &tag("name = \"t\", table = \"holding\", address = 0, type = \"u128\""),
        "lines.a.devices.d.tags[0].type",
        "unknown variant `u128`",
    );
    one_issue(
        &tag("name = \"t\", table = \"holding\", address = 0, decimals = 10"),
        "lines.a.devices.d.tags[0].decimals",
        "between 0 and 9",
    );
    one_issue(
        &tag("name = \"t\", table = \"holding\", address = 0, scale = \"x\""),
        "lines.a.devices.d.tags[0].scale",
        "expected a finite number",
    );
    one_issue(
        &tag("name = \"t\", table = \"holding\", address = 0, word_order = \"middle\""),
        "lines.a.devices.d.tags[0].word_order",
        "unknown variant",
    );
    one_issue(
        &tag("name = \"t\", address = 0"),
        "lines.a.devices.d.tags[0].table",
        "missing required key",
    );
    one_issue(
        &tag("name = \"T 1\", table = \"holding\", address = 0"),
        "lines.a.devices.d.tags[0].name",
        "invalid name",
    );
    one_issue(
        &tag("name = \"t\", table = \"holding\", address = 70000"),
        "lines.a.devices.d.tags[0].address",
        "between 0 and 65535",
    );
}

#[test]
fn impossible_tag_types_are_refused_with_their_path() {
    let tag = |keys: &str| {
        one_line(
            "modbus-master-rtu",
            &format!(
                "[lines.a.devices.d]\nprofile = \"generic\"\naddress = 1\ntags = [{{ name = \"t\", {keys} }}]\n"
            ),
        )
    };
    let at = |key: &str| format!("lines.a.devices.d.tags[0].{key}");
    one_issue(
        &tag("table = \"coil\", address = 0, type = \"string\", registers = 2"),
        &at("type"),
        "a coil tag must be bool",
    );
    one_issue(
        &tag("table = \"discrete\", address = 0, type = \"string\", registers = 2"),
        &at("type"),
        "a discrete tag must be bool",
    );
    one_issue(
        &tag("table = \"holding\", address = 0, type = \"u64\", registers = 3"),
        &at("registers"),
        "a u64 value occupies 4 registers, not 3",
    );
    one_issue(
        &tag("table = \"holding\", address = 0, type = \"string\""),
        &at("registers"),
        "a string tag needs registers",
    );
    one_issue(
        &tag("table = \"holding\", address = 0, bit = 16"),
        &at("bit"),
        "between 0 and 15",
    );
    one_issue(
        &tag("table = \"coil\", address = 0, bit = 3"),
        &at("bit"),
        "a coil is a bit already",
    );
    one_issue(
        &tag("table = \"holding\", address = 0, type = \"u16\", bit = 3"),
        &at("type"),
        "a bit of a register is a bool",
    );
    one_issue(
        &tag("table = \"holding\", address = 0, type = \"u16\", byte_order = \"BADC\""),
        &at("byte_order"),
        "only ABCD (high-first) applies",
    );
    one_issue(
        &tag("table = \"holding\", address = 0, type = \"string\", registers = 2, byte_order = \"CDAB\""),
        &at("byte_order"),
        "a string's order is",
    );
    one_issue(
        &tag("table = \"holding\", address = 0, scale = 0"),
        &at("scale"),
        "scale 0",
    );
    one_issue(
        &tag("table = \"holding\", address = 0, type = \"u32\", byte_order = \"ABCD\", word_order = \"low-first\""),
        &at("word_order"),
        "not both",
    );
    // Every name of the four orders, the aliases, and the older key name are accepted.
    for (order, expected) in [
        ("ABCD", ByteOrder::Abcd),
        ("high-first", ByteOrder::Abcd),
        ("ABCDEFGH", ByteOrder::Abcd),
        ("CDAB", ByteOrder::Cdab),
        ("low-first", ByteOrder::Cdab),
        ("GHEFCDAB", ByteOrder::Cdab),
        ("BADC", ByteOrder::Badc),
        ("BADCFEHG", ByteOrder::Badc),
        ("DCBA", ByteOrder::Dcba),
        ("HGFEDCBA", ByteOrder::Dcba),
    ] {
        for key in ["byte_order", "word_order"] {
            let c = parse(&tag(&format!(
                "table = \"holding\", address = 0, type = \"f64\", {key} = \"{order}\""
            )));
            let (_, d) = line(&c).devices().next().expect("device");
            assert_eq!(d.tags[0].byte_order(), expected, "{key} = {order}");
        }
    }
    // A bit tag is a bool of a register; `type` may be left out.
    let c = parse(&tag("table = \"input\", address = 4, bit = 15"));
    let (_, d) = line(&c).devices().next().expect("device");
    assert_eq!(
        (d.tags[0].data_type, d.tags[0].bit),
        (DataType::Bool, Some(15))
    );
}

#[test]
fn scanner_keys_are_checked() {
    let dev = |keys: &str| {
        one_line(
            "modbus-master-rtu",
            &format!("[lines.a.devices.d]\n{keys}\n"),
        )
    };
    // Absent: off; a table with only `enabled = true`: the factory words and 100 ms.
    let c = parse(&dev("profile = \"altivar71\"\naddress = 1"));
    assert_eq!(
        line(&c).devices().next().map(|(_, d)| d.scanner),
        Some(None)
    );
    let c = parse(&dev(
        "profile = \"altivar71\"\naddress = 1\nscanner = { enabled = true }",
    ));
    assert_eq!(
        line(&c).devices().next().and_then(|(_, d)| d.scanner),
        Some(ScannerConfig {
            enabled: true,
            inputs: 2,
            outputs: 2,
            period: ms(100),
        })
    );
    // 002: NM1..NM8 and NC1..NC8.
    one_issue(
        &dev("profile = \"altivar71\"\naddress = 1\nscanner = { outputs = 9 }"),
        "lines.a.devices.d.scanner.outputs",
        "between 1 and 8",
    );
    one_issue(
        &dev("profile = \"ksvario\"\naddress = 1\nscanner = { enabled = true }"),
        "lines.a.devices.d.scanner",
        "altivar71",
    );
    // The words must fit one FC 23 of the device.
    one_issue(
        &dev(
            "profile = \"altivar71\"\naddress = 1\nlimits = { rw_write_registers = 1 }\n\
             scanner = { enabled = true, outputs = 2 }",
        ),
        "lines.a.devices.d.scanner",
        "do not fit one FC 23",
    );
    one_issue(
        &dev("profile = \"altivar71\"\naddress = 1\nscanner = { enable = true }"),
        "lines.a.devices.d.scanner.enable",
        "unknown key",
    );
}
