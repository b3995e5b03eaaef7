//! Every default against the manual section it comes from.

use super::*;

#[test]
fn empty_file_takes_every_default() {
    let c = parse("");
    assert_eq!(c.gateway.name, "gateway");
    // 003 7.3: "a ring buffer for a maximum of 9 diagnostic entries".
    assert_eq!(c.gateway.diag_buffer_depth, 9);
    assert_eq!(
        c.modbus_tcp.listen,
        "0.0.0.0:502".parse::<SocketAddr>().unwrap()
    );
    assert_eq!(c.modbus_tcp.max_connections, 64);
    assert_eq!(c.modbus_tcp.idle_timeout, Duration::from_secs(60));
    assert_eq!(c.modbus_tcp.request_timeout, Duration::from_secs(5));
    assert!(c.modbus_tcp.allowed_networks.is_empty());
    assert!(!c.modbus_tcp.read_only);
    assert!(c.modbus_tcp.write_ranges.is_empty());
    assert!(c.lines.is_empty());
}

#[test]
fn serial_defaults_match_the_manual() {
    let c = parse(&one_line("ascii", ""));
    let s = &line(&c).serial;
    // 003 6.2.1 ff.: 9600 baud, 8 data bits, even parity, 1 stop bit; interface full duplex RS422.
    assert_eq!(s.baud.get(), 9600);
    assert_eq!(s.data_bits, DataBits::Eight);
    assert_eq!(s.parity, Parity::Even);
    assert_eq!(s.stop_bits, StopBits::One);
    assert_eq!(s.interface, Interface::Rs422);
    assert_eq!(s.rs485, None);
}

#[test]
fn modbus_master_rtu_defaults_match_the_manual() {
    let c = parse(&one_line("modbus-master-rtu", ""));
    let ProtocolConfig::ModbusMasterRtu(m) = &line(&c).protocol else {
        panic!("rtu")
    };
    // 003 6.4.2.1: reply monitoring time 2000 ms, normal operation, multiplier 1.
    assert_eq!(m.reply_timeout, ms(2000));
    assert_eq!(m.operating_mode, OperatingMode::Normal);
    assert_eq!(m.delay_multiplier, 1);
    assert_eq!(m.retries, 0);
    // Modbus over Serial Line V1.02 2.4.1: turnaround delay typically 100..200 ms.
    assert_eq!(m.turnaround_delay, ms(100));
    assert!(m.devices.is_empty());
}

#[test]
fn modbus_master_ascii_defaults_match_the_manual() {
    let c = parse(&one_line("modbus-master-ascii", ""));
    let ProtocolConfig::ModbusMasterAscii(m) = &line(&c).protocol else {
        panic!("ascii master")
    };
    // 003 6.4.2.2: character delay 1000 ms, response time-out 2000 ms, turnaround delay 0,
    // normal operation, 32-bit registers deactivated.
    assert_eq!(m.character_delay, ms(1000));
    assert_eq!(m.reply_timeout, ms(2000));
    assert_eq!(m.turnaround_delay, Duration::ZERO);
    assert_eq!(m.operating_mode, OperatingMode::Normal);
    assert!(!m.registers32);
}

#[test]
fn modbus_slave_defaults_match_the_manual() {
    let c = parse(&one_line("modbus-slave-rtu", ""));
    let ProtocolConfig::ModbusSlaveRtu(s) = &line(&c).protocol else {
        panic!("slave")
    };
    // 003 6.4.5.1: slave address 222, normal operation, multiplier 1.
    assert_eq!(s.address, 222);
    assert_eq!(s.operating_mode, OperatingMode::Normal);
    assert_eq!(s.delay_multiplier, 1);
    // 003 6.4.8.1 example: 0 -> M 1000.0, 1024 -> Q 100.0, 2048 -> T 100, 4064 -> C 200.
    assert_eq!((s.coils.memory.start, s.coils.memory.plc), (0, 1000));
    assert_eq!((s.coils.outputs.start, s.coils.outputs.plc), (1024, 100));
    assert_eq!((s.coils.timers.start, s.coils.timers.plc), (2048, 100));
    assert_eq!((s.coils.counters.start, s.coils.counters.plc), (4064, 200));
    // The example's last counter start address 4096 (C 202) lies inside the counter area.
    assert_eq!(
        u32::from(s.coils.counters.start) + s.coils.counters.count,
        4096 + 16
    );
    // 003 6.4.8.2 example: 0 -> M 1000.0, 1024 -> I 100.0.
    assert_eq!(
        (s.discrete_inputs.inputs.start, s.discrete_inputs.inputs.plc),
        (1024, 100)
    );
    // 003 6.4.8.3 example: base DB 800.
    assert_eq!(s.holding_db, 800);
    assert_eq!(s.input_db, 800);
    // 003 6.4.5 "Limits": by default nothing is writable.
    assert!(s.write_enable.is_empty());
    assert_eq!(s.unit_id, None);
}

#[test]
fn proc3964_defaults_match_the_manual() {
    let c = parse(&one_line("3964r", ""));
    let ProtocolConfig::Proc3964(p) = &line(&c).protocol else {
        panic!("3964")
    };
    // 003 6.3.3: with block check, priority high, ZVZ 220 ms, QVZ 2000 ms, 6 and 6 attempts.
    assert!(p.block_check);
    assert_eq!(p.priority, Priority::High);
    assert_eq!(p.character_delay, ms(220));
    assert_eq!(p.ack_delay, ms(2000));
    assert_eq!(p.setup_attempts, 6);
    assert_eq!(p.transmission_attempts, 6);
    // 003 6.3.1: at most 250 bytes a telegram.
    assert_eq!(p.max_telegram_len, 250);
    assert_eq!(p.receive_buffer, 250);
    assert_eq!(p.overflow, Overflow3964::Refuse);

    // 003 6.3.3: "2000ms (550ms at 3964 without block check)".
    let c = parse(&one_line("3964r", "block_check = false"));
    let ProtocolConfig::Proc3964(p) = &line(&c).protocol else {
        panic!("3964")
    };
    assert_eq!(p.ack_delay, ms(550));
    assert_eq!(p.character_delay, ms(220));
}

#[test]
fn ascii_end_character_2_zero_is_none() {
    // 003 6.2.1: "End character 1:3 (03h=ETX) End character 2:0", where 0 is the screen's "none".
    let c = parse(&one_line(
        "ascii",
        "end_criterion = \"end-chars\"\nend_chars = [0x03, 0]",
    ));
    let ProtocolConfig::Ascii(a) = &line(&c).protocol else {
        panic!("ascii")
    };
    assert_eq!(a.end_chars, [0x03]);
    // End character 1 = 0 is a real NUL.
    let c = parse(&one_line(
        "ascii",
        "end_criterion = \"end-chars\"\nend_chars = [0, 0x0A]",
    ));
    let ProtocolConfig::Ascii(a) = &line(&c).protocol else {
        panic!("ascii")
    };
    assert_eq!(a.end_chars, [0x00, 0x0A]);
}

#[test]
fn ascii_defaults_match_the_manual() {
    let c = parse(&one_line("ascii", ""));
    let ProtocolConfig::Ascii(a) = &line(&c).protocol else {
        panic!("ascii")
    };
    // 000 6.2.1: end after the character delay time is the default.
    assert_eq!(a.end_criterion, EndCriterion::CharDelay);
    // 003 6.2.1: ZVZ 4 ms, frame length 240, end character 1 = 03h (ETX), transmission pause on.
    assert_eq!(a.character_delay, ms(4));
    assert_eq!(a.fixed_length, 240);
    assert_eq!(a.end_chars, [0x03]);
    assert!(a.send_pause);
    // 003 6.2.1: flow control none, XON 11h, XOFF 13h, wait for XON 20 000 ms.
    assert_eq!(a.flow_control, FlowControl::None);
    assert_eq!((a.xon_code, a.xoff_code), (0x11, 0x13));
    assert_eq!(a.xon_wait, ms(20_000));
    // 000 6.2.1: RTS off delay 10 ms, data output wait 10 ms.
    assert_eq!(a.rts_hold_time, ms(10));
    assert_eq!(a.data_output_wait, ms(10));
    // 003 6.2.1: 250 buffered telegrams, prevent overwriting on.
    assert_eq!(a.receive_buffer, 250);
    assert!(a.prevent_overwrite);
    // At most 1024 bytes a telegram.
    assert_eq!(a.max_telegram_len, 1024);
}

#[test]
fn ascii_character_delay_default_rises_to_the_baud_minimum() {
    // 003 6.2.1: at 1200 baud the shortest ZVZ is 32 ms, above the 4 ms default.
    let c = parse(&one_line("ascii", "baud = 1200"));
    let ProtocolConfig::Ascii(a) = &line(&c).protocol else {
        panic!("ascii")
    };
    assert_eq!(a.character_delay, ms(32));
}

#[test]
fn device_defaults_come_from_the_profile() {
    let text = format!(
        "{}[lines.a.devices.atv]\nprofile = \"altivar71\"\naddress = 5\n\
         [lines.a.devices.kv]\nprofile = \"ksvario\"\naddress = 17\n",
        one_line("modbus-master-rtu", "")
    );
    let c = parse(&text);
    let devices: Vec<_> = line(&c).devices().collect();
    let (_, atv) = devices[0];
    // unit id defaults to the slave address.
    assert_eq!(atv.unit_id, 5);
    // 002 "Modbus-Funktionen": FC03 63 words, FC16 61, FC23 20 / 20.
    assert_eq!(atv.limits.read_registers, 63);
    assert_eq!(atv.limits.write_registers, 61);
    assert_eq!(
        atv.limits.read_write.map(|rw| (rw.read, rw.write)),
        Some((20, 20))
    );
    assert_eq!(atv.offline_backoff_min, Duration::from_secs(1));
    assert_eq!(atv.offline_backoff_max, Duration::from_secs(5));
    assert_eq!(atv.probe_timeout_min, Duration::from_millis(100));
    assert_eq!(atv.full_probe_every, 12);
    assert_eq!(atv.bridge_gap, 0);
    let (_, kv) = devices[1];
    // 001 3.1: at most 120 integer values a message.
    assert_eq!(kv.limits.read_registers, 120);
    assert_eq!(kv.profile, Profile::named("ksvario").expect("registered"));
}

#[test]
fn tag_defaults_follow_the_table() {
    let text = format!(
        "{}[lines.a.devices.d]\nprofile = \"generic\"\naddress = 1\n\
         tags = [{{ name = \"c\", table = \"coil\", address = 3 }}, {{ name = \"h\", table = \"holding\", address = 4 }}]\n",
        one_line("modbus-master-rtu", "")
    );
    let c = parse(&text);
    let (_, d) = line(&c).devices().next().expect("device");
    assert_eq!(d.tags[0].data_type, DataType::Bool);
    assert_eq!(d.tags[1].data_type, DataType::U16);
    assert_eq!(d.tags[1].byte_order(), ByteOrder::Abcd);
    assert_eq!(d.tags[1].scale, 1.0);
    assert_eq!(
        d.tags[1].decimals, None,
        "absent: the places scale and offset imply"
    );
    assert!(!d.tags[1].writable);
}
