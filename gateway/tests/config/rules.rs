//! Checks that span several keys.

use super::*;

#[test]
fn duplicates_across_the_gateway() {
    let text = r#"
[lines.a]
port = "/dev/ttyS0"
protocol = "modbus-master-rtu"
[lines.a.devices.x]
profile = "altivar71"
address = 3
[lines.a.devices.y]
profile = "altivar71"
address = 3
unit_id = 4
[lines.b]
port = "/dev/ttyS0"
protocol = "3964r"
unit_id = 4
"#;
    let got = issues(text);
    assert_eq!(
        got,
        [
            ("lines.a.devices.y.address".to_owned(), "slave address 3 is already used by lines.a.devices.x on this line".to_owned()),
            ("lines.b.port".to_owned(), "port \"/dev/ttyS0\" is already used by lines.a".to_owned()),
            (
                "lines.b.unit_id".to_owned(),
                "unit id 4 is already used by lines.a.devices.y; unit ids must be unique in the gateway".to_owned()
            ),
        ]
    );
}

#[test]
fn the_diagnostic_unit_is_its_own_read_only_unit() {
    let text = r#"
[modbus_tcp]
diagnostic_unit = 4
write_ranges = [{ unit_id = 4, table = "holding", start = 0, count = 1 }]
[lines.a]
port = "/dev/ttyS0"
protocol = "modbus-master-rtu"
[lines.a.devices.x]
profile = "altivar71"
address = 3
unit_id = 4
"#;
    assert_eq!(
        issues(text),
        [
            (
                "modbus_tcp.diagnostic_unit".to_owned(),
                "unit id 4 is already used by lines.a.devices.x; unit ids must be unique in the gateway".to_owned()
            ),
            (
                "modbus_tcp.write_ranges[0].unit_id".to_owned(),
                "unit id 4 is the diagnostic unit, which is read-only".to_owned()
            ),
        ]
    );
    let ok = parse(
        &text
            .replace("diagnostic_unit = 4", "diagnostic_unit = 247")
            .replace(
                "write_ranges = [{ unit_id = 4, table = \"holding\", start = 0, count = 1 }]\n",
                "",
            ),
    );
    assert_eq!(ok.modbus_tcp.diagnostic_unit, Some(247));
    one_issue(
        "[modbus_tcp]\ndiagnostic_unit = 0\n",
        "modbus_tcp.diagnostic_unit",
        "must be between 1 and 255, found 0",
    );
}

#[test]
fn protocol_and_interface_rules() {
    one_issue(
        &one_line("3964r", "interface = \"rs485\""),
        "lines.a.interface",
        "not possible in two-wire",
    );
    one_issue(
        &one_line("modbus-master-rtu", "data_bits = 7"),
        "lines.a.data_bits",
        "8 data bits (003 6.4.2.1",
    );
    one_issue(
        &one_line("modbus-slave-rtu", "data_bits = 7"),
        "lines.a.data_bits",
        "8 data bits",
    );
    // Modbus ASCII: 7 data bits are the serial line standard.
    parse(&one_line("modbus-master-ascii", "data_bits = 7"));
    one_issue(
        &one_line(
            "ascii",
            "interface = \"rs485\"\nflow_control = \"xon-xoff\"",
        ),
        "lines.a.flow_control",
        "half-duplex RS485",
    );
    one_issue(
        &one_line("ascii", "flow_control = \"rts-cts\""),
        "lines.a.flow_control",
        "interface = \"rs232\" (000 5.4)",
    );
    parse(&one_line(
        "ascii",
        "interface = \"rs232\"\nflow_control = \"auto-v24\"",
    ));
    one_issue(
        &one_line("ascii", "flow_control = \"xon-xoff\"\nxoff_code = 0x11"),
        "lines.a.xoff_code",
        "different",
    );
    one_issue(
        &one_line("ascii", "data_bits = 7\nend_chars = [0x83]"),
        "lines.a.end_chars[0]",
        "0x83 does not fit in 7 data bits",
    );
    one_issue(
        &one_line("ascii", "prevent_overwrite = false"),
        "lines.a.prevent_overwrite",
        "only with receive_buffer = 1",
    );
    parse(&one_line(
        "ascii",
        "prevent_overwrite = false\nreceive_buffer = 1",
    ));
    one_issue(
        &one_line(
            "ascii",
            "end_criterion = \"fixed-length\"\nfixed_length = 600\nmax_telegram_len = 500",
        ),
        "lines.a.fixed_length",
        "longer than max_telegram_len",
    );
    // per-baud minimums: 003 6.2.1 (ASCII 300 baud: 130 ms), 003 6.3.3 (3964 300 baud: 60 ms)
    one_issue(
        &one_line("ascii", "baud = 300\ncharacter_delay = \"100ms\""),
        "lines.a.character_delay",
        "at 300 baud must be at least 130ms (003 6.2.1)",
    );
    one_issue(
        &one_line("3964r", "baud = 300\nack_delay = \"50ms\""),
        "lines.a.ack_delay",
        "at 300 baud must be at least 60ms (003 6.3.3)",
    );
    one_issue(
        &one_line("3964r", "devices = {}"),
        "lines.a.devices",
        "only on modbus-master-rtu, modbus-master-ascii and modbus-rtu-tap lines, not on a 3964r line",
    );
    one_issue(
        &one_line("modbus-master-rtu", "unit_id = 3"),
        "lines.a.unit_id",
        "unknown key",
    );
}

#[test]
fn slave_memory_rules() {
    one_issue(
        &one_line(
            "modbus-slave-rtu",
            "[lines.a.coils]\noutputs = { start = 1000, count = 100, plc = 100 }",
        ),
        "lines.a.coils.outputs.start",
        "overlaps the memory area",
    );
    one_issue(
        &one_line(
            "modbus-slave-rtu",
            "[lines.a.coils]\ntimers = { start = 2048, count = 20, plc = 100 }",
        ),
        "lines.a.coils.timers.count",
        "multiple of 16 (003 6.4.8.1)",
    );
    one_issue(
        &one_line(
            "modbus-slave-rtu",
            "[lines.a.discrete_inputs]\ninputs = { start = 1024, count = 1024, plc = 65530 }",
        ),
        "lines.a.discrete_inputs.inputs.plc",
        "runs past PLC address 65535",
    );
    one_issue(
        &one_line(
            "modbus-slave-rtu",
            "write_enable = [{ table = \"input\", start = 0, count = 1 }]",
        ),
        "lines.a.write_enable[0].table",
        "003 6.4.5 Limits",
    );
    // switching an area off removes it from the overlap check
    parse(&one_line("modbus-slave-rtu", "[lines.a.coils]\nmemory = { start = 0, count = 0, plc = 0 }\noutputs = { start = 0, count = 2048, plc = 100 }"));
}

#[test]
fn device_rules() {
    let dev = |keys: &str| {
        one_line(
            "modbus-master-rtu",
            &format!("[lines.a.devices.d]\naddress = 1\n{keys}\n"),
        )
    };
    one_issue(
        &dev("profile = \"generic\""),
        "lines.a.devices.d.tags",
        "needs a tag list",
    );
    one_issue(
        &dev("profile = \"altivar71\"\nbridge_gap = 20\nlimits = { read_registers = 20 }"),
        "lines.a.devices.d.bridge_gap",
        "below the read limit of 20 registers",
    );
    one_issue(
        &dev("profile = \"altivar71\"\noffline_backoff_min = \"2m\""),
        "lines.a.devices.d.offline_backoff_min",
        "longer than offline_backoff_max",
    );
    let generic = |tags: &str, poll: &str| {
        dev(&format!(
            "profile = \"generic\"\ntags = [{tags}]\npoll = [{poll}]"
        ))
    };
    let t = "{ name = \"t\", table = \"holding\", address = 0 }";
    one_issue(
        &generic(&format!("{t}, {t}"), ""),
        "lines.a.devices.d.tags[1].name",
        "defined twice",
    );
    one_issue(
        &generic(
            "{ name = \"t\", table = \"coil\", address = 0, type = \"u16\" }",
            "",
        ),
        "lines.a.devices.d.tags[0].type",
        "a coil tag must be bool",
    );
    one_issue(
        &generic(
            "{ name = \"t\", table = \"input\", address = 0, type = \"bool\" }",
            "",
        ),
        "lines.a.devices.d.tags[0].type",
        "must be u16, i16",
    );
    one_issue(
        &generic(
            "{ name = \"t\", table = \"input\", address = 0, writable = true }",
            "",
        ),
        "lines.a.devices.d.tags[0].writable",
        "cannot be written",
    );
    one_issue(
        &generic(
            "{ name = \"t\", table = \"holding\", address = 65535, type = \"f32\" }",
            "",
        ),
        "lines.a.devices.d.tags[0].address",
        "past address 65535",
    );
    one_issue(
        &generic(t, "{ name = \"p\", period = \"1s\", tags = [\"nope\"] }"),
        "lines.a.devices.d.poll[0].tags[0]",
        "no tag \"nope\"",
    );
    one_issue(
        &generic(t, "{ name = \"p\", period = \"1s\" }"),
        "lines.a.devices.d.poll[0]",
        "needs tags or ranges",
    );
    one_issue(
        &generic(t, "{ name = \"p\", period = \"1s\", tags = [\"t\"] }, { name = \"p\", period = \"2s\", tags = [\"t\"] }"),
        "lines.a.devices.d.poll[1].name",
        "defined twice",
    );
    // the Altivar serves holding registers only (002: functions 3, 6, 8, 16, 23, 43)
    one_issue(
        &dev("profile = \"altivar71\"\npoll = [{ name = \"p\", period = \"1s\", ranges = [{ table = \"coil\", start = 0, count = 1 }] }]"),
        "lines.a.devices.d.poll[0].ranges[0].table",
        "the altivar71 profile has no coil table",
    );
    // profile tag names may be polled
    parse(&dev("profile = \"altivar71\"\npoll = [{ name = \"p\", period = \"1s\", tags = [\"eta\", \"rfrd\"] }]"));
    let c = parse(&generic(
        t,
        "{ name = \"p\", period = \"250ms\", tags = [\"t\"] }",
    ));
    let (_, d) = line(&c).devices().next().expect("device");
    assert_eq!(d.poll[0].period, ms(250));
    assert_eq!(d.tags[0].table, ModbusTable::Holding);
}

#[test]
fn write_ranges_must_name_a_served_unit() {
    one_issue("[modbus_tcp]\nwrite_ranges = [{ unit_id = 9, table = \"holding\", start = 0, count = 1 }]\n", "modbus_tcp.write_ranges[0].unit_id", "no device or line is served as unit id 9");
    one_issue(
        "[modbus_tcp]\nwrite_ranges = [{ unit_id = 9, table = \"input\", start = 0, count = 1 }]\n[lines.a]\nport = \"x\"\nprotocol = \"ascii\"\nunit_id = 9\n",
        "modbus_tcp.write_ranges[0].table",
        "only \"holding\" and \"coil\"",
    );
    let c = parse(&EXAMPLE);
    assert!(c.modbus_tcp.allows_write(2, ModbusTable::Holding, 8501, 1));
    assert!(!c.modbus_tcp.allows_write(2, ModbusTable::Holding, 8502, 1));
    assert!(!c.modbus_tcp.allows_write(2, ModbusTable::Holding, 9001, 3));
    assert!(c.modbus_tcp.allows("10.1.2.3".parse().unwrap()));
    assert!(!c.modbus_tcp.allows("192.168.1.1".parse().unwrap()));
}

#[test]
fn publishing_policy_rules_inherit_the_section_and_are_checked() {
    let c = parse(
        r#"
[zenoh.publish]
deadband = 2
heartbeat = "5s"
[[zenoh.publish.tags]]
key = "drive/*/SFr"
deadband_percent = 1.5
[[zenoh.publish.tags]]
key = "ksvario/**"
heartbeat = "0s"
"#,
    );
    let p = &c.zenoh.expect("zenoh section").publish;
    let secs = Duration::from_secs;
    assert_eq!(p.default.deadband.0, 2.0);
    assert_eq!(p.default.heartbeat, secs(5));
    assert_eq!(p.tags[0].policy.deadband.0, 2.0, "inherited");
    assert_eq!(p.tags[0].policy.deadband_percent.0, 1.5);
    assert_eq!(p.tags[0].policy.heartbeat, secs(5), "inherited");
    assert_eq!(p.tags[1].policy.heartbeat, secs(0), "off for this rule");
    assert_eq!(p.policy("drive", "atv71", "SFr"), p.tags[0].policy);
    assert_eq!(p.policy("drive", "atv71", "ETA"), p.default);

    let got = issues(
        r#"
[zenoh.publish]
deadband = -1
deadband_percent = 101
heartbeat = "50ms"
[[zenoh.publish.tags]]
key = "drive/**/"
"#,
    );
    let paths: Vec<&str> = got.iter().map(|(p, _)| p.as_str()).collect();
    assert_eq!(
        paths,
        [
            "zenoh.publish.deadband",
            "zenoh.publish.deadband_percent",
            "zenoh.publish.heartbeat",
            "zenoh.publish.tags[0].key",
        ],
        "{got:#?}"
    );
    assert!(got[2].1.contains("at least 100ms"), "{got:#?}");
}

#[test]
fn a_tap_line_lists_devices_without_poll_groups() {
    let tap = |keys: &str, device: &str| {
        one_line(
            "modbus-rtu-tap",
            &format!(
                "{keys}\n[lines.a.devices.d]\naddress = 2\nprofile = \"altivar71\"\n{device}\n"
            ),
        )
    };
    // The keys with their defaults.
    let c = parse(&tap("", ""));
    let ProtocolConfig::ModbusRtuTap(t) = &line(&c).protocol else {
        panic!("a tap line");
    };
    assert_eq!(t.answer_timeout, ms(1000));
    assert_eq!(t.expected_cycle, ms(1000));
    assert_eq!(t.delay_multiplier, 1);
    assert!(t.inter_character_check);
    assert_eq!(line(&c).devices().count(), 1);
    let c = parse(&tap(
        "answer_timeout = \"300ms\"\nexpected_cycle = \"5s\"\ninter_character_check = false\ndelay_multiplier = 2",
        "unit_id = 7",
    ));
    let ProtocolConfig::ModbusRtuTap(t) = &line(&c).protocol else {
        panic!("a tap line");
    };
    assert_eq!((t.answer_timeout, t.expected_cycle), (ms(300), ms(5000)));
    assert!(!t.inter_character_check);
    assert_eq!(t.devices.get("d").map(|d| d.unit_id), Some(7));

    // It polls nothing and runs no scanner: refused with the path.
    one_issue(
        &tap(
            "",
            "poll = [{ name = \"fast\", period = \"1s\", tags = [\"ETA\"] }]",
        ),
        "lines.a.devices.d.poll",
        "only listens",
    );
    one_issue(
        &tap("", "scanner = { enabled = true }"),
        "lines.a.devices.d.scanner",
        "only listens",
    );
    one_issue(
        &tap("answer_timeout = \"1ms\"", ""),
        "lines.a.answer_timeout",
        "",
    );
    one_issue(
        &tap("data_bits = 7", ""),
        "lines.a.data_bits",
        "8 data bits",
    );
    // A slave line lists no devices.
    one_issue(
        &one_line(
            "modbus-slave-rtu",
            "[lines.a.devices.d]\naddress = 2\nprofile = \"altivar71\"\n",
        ),
        "lines.a.devices",
        "modbus-rtu-tap",
    );
}

#[test]
fn a_3964r_tap_line_reads_two_different_ports() {
    let tap = |keys: &str| one_line("3964r-tap", &format!("port_b = \"/dev/ttyS1\"\n{keys}"));
    // The keys with their defaults: the 3964R procedure's (003 6.3.3).
    let c = parse(&tap(""));
    let ProtocolConfig::Proc3964Tap(t) = &line(&c).protocol else {
        panic!("a 3964(R) tap line");
    };
    assert_eq!(t.port_b, "/dev/ttyS1");
    assert!(t.block_check);
    assert_eq!((t.character_delay, t.ack_delay), (ms(220), ms(2000)));
    assert_eq!((t.max_telegram_len, t.receive_buffer), (250, 250));
    assert_eq!(t.unit_id, None);
    assert_eq!(line(&c).second_port(), Some("/dev/ttyS1"));
    let c = parse(&tap(
        "block_check = false\nunit_id = 41\nreceive_buffer = 10",
    ));
    let ProtocolConfig::Proc3964Tap(t) = &line(&c).protocol else {
        panic!("a 3964(R) tap line");
    };
    assert_eq!(
        (t.block_check, t.ack_delay, t.unit_id),
        (false, ms(550), Some(41))
    );
    assert_eq!(line(&c).unit_id(), Some(41));

    // port_b: required, another port than port, and no other line's.
    one_issue(&one_line("3964r-tap", ""), "lines.a.port_b", "missing");
    one_issue(
        &one_line("3964r-tap", "port_b = \"/dev/ttyS0\""),
        "lines.a.port_b",
        "another port than port",
    );
    one_issue(
        &format!(
            "{}[lines.b]\nport = \"/dev/ttyS1\"\nprotocol = \"3964r\"\n",
            tap("")
        ),
        "lines.b.port",
        "already used by lines.a",
    );
    // A tap sends nothing: the keys of sending are unknown; a full-duplex link; the times'
    // minimum at the baud rate.
    one_issue(&tap("sends = true"), "lines.a.sends", "unknown key");
    one_issue(
        &tap("priority = \"low\""),
        "lines.a.priority",
        "unknown key",
    );
    one_issue(
        &tap("interface = \"rs485\""),
        "lines.a.interface",
        "full-duplex",
    );
    one_issue(
        &tap("baud = 300\ncharacter_delay = \"20ms\""),
        "lines.a.character_delay",
        "at 300 baud must be at least 60ms (003 6.3.3)",
    );
}
