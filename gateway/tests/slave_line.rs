//! The Modbus slave RTU line and the CP memory, with real parts: the line on one end of a pty
//! pair, the tokio-modbus RTU client on the other as the outside serial master (an HMI), the
//! gateway's Modbus TCP server on 127.0.0.1 port 0 with a tokio-modbus TCP client as SCADA.
//!
//! The memory layout is the manual's example (003 6.4.8): FC 01/05/15 0.. -> M 1000.0,
//! 1024.. -> Q 100.0, 2048.. -> T 100, 4064.. -> C 200; FC 02 0.. -> M 1000.0, 1024.. -> I 100.0;
//! FC 03/06/16 from DB 800 and, here, FC 04 from a second base, DB 801.

#[path = "slave_line/support.rs"]
mod support;

use std::time::Duration;

use gateway::cpmem::{spawn_persistence, LoadStatus, PersistSettings, SharedCpMemory};
use gateway::image::{ProcessImage, Quality, Table};
use gateway::line::EVENT_PORT_SETUP;
use gateway::protocols::modbus_slave::partner::{spawn_sim_master, SimMasterSettings};
use gateway::protocols::{spawn_modbus_slave_line, SlaveLineSettings};
use gateway::serial::PortSettings;
use proto_core::cpmem::{AddressMap, MemoryLayout, OperatingMode, SlaveParams};
use proto_core::event::ids;
use proto_core::modbus::rtu::{decode_frame, encode_frame};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_modbus::prelude::*;
use tokio_util::sync::CancellationToken;

use support::{
    bits, eventually, filled_memory, pty, temp_path, test_map, within, Rig, Tcp, ADDRESS,
};

// === the outside serial master ===

#[tokio::test]
async fn the_outside_master_reads_every_area() {
    let mut rig = Rig::start(filled_memory()).await;
    let c = &mut rig.client;

    // FC 01, M: coils 0..15 are M 1000.0 .. M 1001.7.
    let m = c.read_coils(0, 16).await.unwrap().unwrap();
    assert_eq!(m, bits(&[0b1010_0101, 0x0F], 16));
    // FC 01, Q: coil 1025 is Q 100.1.
    let q = c.read_coils(1024, 8).await.unwrap().unwrap();
    assert_eq!(q, bits(&[0b0000_0110], 8));
    // FC 01, T in the 16-bit grid: T 100 = 8001h, memory byte order (high byte first).
    let t = c.read_coils(2048, 16).await.unwrap().unwrap();
    assert_eq!(t, bits(&[0x80, 0x01], 16));
    // FC 01, C: C 200 and C 201 in one request.
    let cc = c.read_coils(4064, 32).await.unwrap().unwrap();
    assert_eq!(cc, bits(&[0x00, 0x03, 0xFF, 0x00], 32));
    // FC 02, M through the inputs table, I from 1024.
    let dm = c.read_discrete_inputs(0, 8).await.unwrap().unwrap();
    assert_eq!(dm, bits(&[0b1010_0101], 8));
    let di = c.read_discrete_inputs(1024, 16).await.unwrap().unwrap();
    assert_eq!(di, bits(&[0x81, 0x40], 16));
    // FC 03 from DB 800; register 512 + 388 is DB 801.DBW776.
    let h = c.read_holding_registers(0, 3).await.unwrap().unwrap();
    assert_eq!(h, vec![0x1111, 0x2222, 0x3333]);
    let h801 = c.read_holding_registers(900, 1).await.unwrap().unwrap();
    assert_eq!(h801, vec![0x0388]);
    // FC 04 from its own base, DB 801.
    let i = c.read_input_registers(0, 2).await.unwrap().unwrap();
    assert_eq!(i, vec![0xA0A0, 0xB1B1]);

    let counters = rig.line.slave_counters().expect("a slave line");
    assert_eq!((counters.answered, counters.exceptions), (9, 0));
    assert!(counters.last_request.is_some());
    let status = rig.line.status();
    assert_eq!((status.commands_answered, status.commands_failed), (9, 0));
    assert_eq!(status.port_opens, 1);
    rig.stop().await;
}

#[tokio::test]
async fn the_outside_master_writes_m_q_and_db() {
    let mut rig = Rig::start(filled_memory()).await;
    let c = &mut rig.client;

    // FC 05: coil 13 is M 1001.5.
    c.write_single_coil(13, true).await.unwrap().unwrap();
    // FC 15: coils 1032..1034 are Q 101.0 .. Q 101.2.
    c.write_multiple_coils(1032, &[true, false, true])
        .await
        .unwrap()
        .unwrap();
    // FC 06 and FC 16 into DB 800.
    c.write_single_register(7, 0xBEEF).await.unwrap().unwrap();
    c.write_multiple_registers(100, &[1, 2, 3])
        .await
        .unwrap()
        .unwrap();

    let (m, q, db) = rig.memory.read(|m| {
        (
            m.m()[1001],
            m.q()[101],
            m.db(800).map(|d| (d[7], d[100..103].to_vec())),
        )
    });
    assert_eq!(m, 0x0F | 1 << 5);
    assert_eq!(q, 0b101);
    assert_eq!(db, Some((0xBEEF, vec![1, 2, 3])));
    // And back over the same line.
    let back = c.read_coils(8, 8).await.unwrap().unwrap();
    assert_eq!(back, bits(&[0x2F], 8));
    let counters = rig.line.slave_counters().expect("a slave line");
    assert_eq!((counters.answered, counters.writes), (5, 4));
    rig.stop().await;
}

#[tokio::test]
async fn a_write_outside_the_limits_is_refused_with_an_exception() {
    let mut rig = Rig::start(filled_memory()).await;
    let before = rig.memory.snapshot();
    let c = &mut rig.client;
    // DB 801 (register 512..) is outside the DB limit 800..800.
    let db = c.write_single_register(512, 1).await.unwrap();
    assert_eq!(db, Err(ExceptionCode::IllegalDataAddress));
    // Coil 1016 is M 1127.0, outside MB 1000..1100.
    let m = c.write_multiple_coils(1016, &[true; 8]).await.unwrap();
    assert_eq!(m, Err(ExceptionCode::IllegalDataAddress));
    // Timers are read-only (003 6.4.5).
    let t = c.write_single_coil(2048, true).await.unwrap();
    assert_eq!(t, Err(ExceptionCode::IllegalDataAddress));
    // A read of 128 registers is beyond the slave's 1..127 (003 6.4.8.3).
    let n = c.read_holding_registers(0, 128).await.unwrap();
    assert_eq!(n, Err(ExceptionCode::IllegalDataValue));
    // DB 802 (register 1024..) does not exist: exception and event 0E 39h.
    let missing = c.read_holding_registers(1024, 1).await.unwrap();
    assert_eq!(missing, Err(ExceptionCode::IllegalDataAddress));

    assert_eq!(rig.memory.snapshot(), before, "nothing was written");
    let counters = rig.line.slave_counters().expect("a slave line");
    assert_eq!((counters.answered, counters.exceptions), (0, 5));
    let status = rig.line.status();
    assert_eq!(status.event_counts.get(&ids::SLAVE_DB_ERROR), Some(&1));
    assert_eq!(status.status_word, ids::SLAVE_DB_ERROR.status_word());
    assert_eq!(status.commands_failed, 5);
    assert_eq!(
        status.diagnostics.first().map(|e| e.id),
        Some(ids::SLAVE_DB_ERROR)
    );
    rig.stop().await;
}

#[tokio::test]
async fn a_broadcast_is_applied_without_an_answer() {
    let mut rig = Rig::start(filled_memory()).await;
    let c = &mut rig.client;
    c.set_slave(Slave::broadcast());
    // No answer: the client is still waiting when the timeout cuts it off.
    let silent = tokio::time::timeout(
        Duration::from_millis(300),
        c.write_multiple_registers(20, &[99, 98]),
    )
    .await;
    assert!(silent.is_err(), "a broadcast was answered: {silent:?}");
    let memory = rig.memory.clone();
    eventually("the broadcast write", || {
        memory.read(|m| m.db(800).map(|d| d[20..22].to_vec())) == Some(vec![99, 98])
    })
    .await;
    // A broadcast read is not carried out and not answered either.
    let read =
        tokio::time::timeout(Duration::from_millis(300), c.read_holding_registers(0, 1)).await;
    assert!(read.is_err(), "a broadcast read was answered: {read:?}");

    let counters = rig.line.slave_counters().expect("a slave line");
    assert_eq!(
        (
            counters.broadcasts_applied,
            counters.broadcasts_refused,
            counters.answered,
            counters.exceptions
        ),
        (1, 1, 0, 0)
    );
    // The line still answers its own address afterwards.
    c.set_slave(Slave(ADDRESS));
    let back = c.read_holding_registers(20, 2).await.unwrap().unwrap();
    assert_eq!(back, vec![99, 98]);
    rig.stop().await;
}

/// Bytes that are not a request for this slave get no answer and are counted, never lost
/// silently: a bad CRC (event 0E 57h) and a good frame for another address on the bus.
#[tokio::test]
async fn bad_frames_and_other_addresses_get_no_answer() {
    let (mut outside, path, _keep) = pty();
    let params = SlaveParams::new(ADDRESS, OperatingMode::Normal, 1, test_map()).unwrap();
    let shutdown = CancellationToken::new();
    let line = spawn_modbus_slave_line(
        SlaveLineSettings::new("hmi", PortSettings::new(path, 19200), params),
        filled_memory(),
        shutdown.clone(),
    );
    eventually("the port to open", || line.status().port_open).await;
    // FC 03, register 0, quantity 1.
    let pdu = [0x03, 0x00, 0x00, 0x00, 0x01];
    let mut bad = Vec::new();
    encode_frame(ADDRESS, &pdu, &mut bad);
    *bad.last_mut().unwrap() ^= 0xFF;
    let mut other = Vec::new();
    encode_frame(17, &pdu, &mut other);
    for frame in [&bad, &other] {
        outside.write_all(frame).await.unwrap();
        // A pause longer than t3.5 so that each frame ends on its own.
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let mut buf = [0u8; 64];
    let silent = tokio::time::timeout(Duration::from_millis(200), outside.read(&mut buf)).await;
    assert!(silent.is_err(), "answered: {silent:?}");
    let counters = line.slave_counters().expect("a slave line");
    assert_eq!(counters.discarded.get("bad_crc"), Some(&1), "{counters:?}");
    assert_eq!(counters.other_address, 1);
    assert_eq!(
        line.status().event_counts.get(&ids::MODBUS_CHECKSUM_ERROR),
        Some(&1)
    );

    // A good frame right after is answered: DB 800 word 0.
    let mut good = Vec::new();
    encode_frame(ADDRESS, &pdu, &mut good);
    outside.write_all(&good).await.unwrap();
    let mut answer = Vec::new();
    while answer.len() < 7 {
        let n = within("the answer", outside.read(&mut buf)).await.unwrap();
        answer.extend_from_slice(&buf[..n]);
    }
    let frame = decode_frame(&answer).expect("a good answer frame");
    assert_eq!(
        (frame.address, frame.pdu),
        (ADDRESS, &[0x03, 0x02, 0x11, 0x11][..])
    );
    shutdown.cancel();
    within("the line to stop", line.join()).await;
}

// === the same memory over Modbus TCP ===

#[tokio::test]
async fn a_serial_write_reads_back_over_tcp_and_a_tcp_write_over_serial() {
    let mut rig = Rig::start(filled_memory()).await;
    let mut tcp = Tcp::start(rig.line.cp_memory().expect("a slave line").unit()).await;

    // Serial -> TCP.
    rig.client
        .write_single_register(42, 4242)
        .await
        .unwrap()
        .unwrap();
    rig.client
        .write_single_coil(1024 + 7, true)
        .await
        .unwrap()
        .unwrap();
    let reg = tcp.client.read_holding_registers(42, 1).await.unwrap();
    assert_eq!(reg, Ok(vec![4242]));
    let coil = tcp.client.read_coils(1024, 8).await.unwrap();
    assert_eq!(coil, Ok(bits(&[0b1000_0110], 8)));

    // TCP -> serial.
    tcp.client
        .write_multiple_registers(300, &[7, 8, 9])
        .await
        .unwrap()
        .unwrap();
    tcp.client
        .write_single_coil(3, false)
        .await
        .unwrap()
        .unwrap();
    let regs = rig.client.read_holding_registers(300, 3).await.unwrap();
    assert_eq!(regs, Ok(vec![7, 8, 9]));
    let m = rig.client.read_coils(0, 8).await.unwrap();
    assert_eq!(m, Ok(bits(&[0b1010_0101 & !(1 << 3)], 8)));

    // The same limits over TCP: DB 801 is not writable, timers are read-only.
    let refused = tcp.client.write_single_register(512, 1).await.unwrap();
    assert_eq!(refused, Err(ExceptionCode::IllegalDataAddress));
    let refused = tcp.client.write_single_coil(2048, true).await.unwrap();
    assert_eq!(refused, Err(ExceptionCode::IllegalDataAddress));
    // A wide read answers the whole range (125: the Modbus TCP limit, below the CP's 127).
    let wide = tcp.client.read_holding_registers(0, 125).await.unwrap();
    assert_eq!(
        wide,
        Ok(rig.memory.read(|m| m.db(800).unwrap()[..125].to_vec()))
    );

    tcp.stop().await;
    rig.stop().await;
}

/// Rows of the conversion tables of 003 6.4.8 (the manual's example parameterization), read over
/// Modbus TCP: a single bit or word is set in the memory and must show at the row's address.
#[tokio::test]
async fn conversion_table_rows_over_tcp() {
    let memory = SharedCpMemory::new(MemoryLayout::default());
    let mut tcp = Tcp::start(gateway::cpmem::CpMemoryUnit::new(
        memory.clone(),
        AddressMap::manual_example(),
    ))
    .await;
    // (start_addr, area, byte, bit) for the bit areas.
    let byte_rows = [
        (0u16, 'M', 1000usize, 0u8),
        (1, 'M', 1000, 1),
        (497, 'M', 1062, 1),
        (1024, 'Q', 100, 0),
        (1025, 'Q', 100, 1),
        (2010, 'Q', 223, 2),
    ];
    for (start, area, byte, bit) in byte_rows {
        memory.update(|m| {
            *m = proto_core::cpmem::CpMemory::default();
            let bytes = if area == 'M' { m.m_mut() } else { m.q_mut() };
            bytes[byte] = 1 << bit;
        });
        let got = tcp.client.read_coils(start, 1).await.unwrap();
        assert_eq!(got, Ok(vec![true]), "FC 01 {start} -> {area} {byte}.{bit}");
    }
    // FC 02 1024 -> I 100.0.
    memory.update(|m| m.i_mut()[100] = 1);
    let got = tcp.client.read_discrete_inputs(1024, 1).await.unwrap();
    assert_eq!(got, Ok(vec![true]), "FC 02 1024 -> I 100.0");
    // Timers and counters: coil 0 of a word is bit 0 of its high byte.
    for (start, timer, number) in [
        (2048u16, true, 100usize),
        (2064, true, 101),
        (3200, true, 172),
        (4064, false, 200),
        (4080, false, 201),
        (4096, false, 202),
    ] {
        memory.update(|m| {
            *m = proto_core::cpmem::CpMemory::default();
            let words = if timer {
                m.timers_mut()
            } else {
                m.counters_mut()
            };
            words[number] = 0x0100;
        });
        let got = tcp.client.read_coils(start, 16).await.unwrap().unwrap();
        let mut expected = vec![false; 16];
        expected[0] = true;
        assert_eq!(got, expected, "FC 01 {start} -> number {number}");
    }
    // Registers: start_register -> DB, DBW (word = DBW / 2).
    for (register, db, dbw) in [
        (0u16, 800u16, 0usize),
        (500, 800, 1000),
        (900, 801, 776),
        (1023, 801, 1022),
    ] {
        let value = register ^ 0x5A5A;
        memory.update(|m| m.db_mut(db).unwrap()[dbw / 2] = value);
        let got = tcp
            .client
            .read_holding_registers(register, 1)
            .await
            .unwrap();
        assert_eq!(got, Ok(vec![value]), "FC 03 {register} -> DB{db}.DBW{dbw}");
    }
    tcp.stop().await;
}

// === the image, persistence, the port, the demo's master ===

#[tokio::test]
async fn serial_writes_show_in_the_image_under_the_unit_id() {
    let memory = filled_memory();
    let image = ProcessImage::default();
    memory.mirror_to(image.clone(), 9, test_map());
    let read = image.read_words(9, Table::HoldingRegisters, 0, 3).unwrap();
    assert_eq!(
        (read.values, read.quality),
        (vec![0x1111, 0x2222, 0x3333], Quality::Good)
    );

    let mut rig = Rig::start(memory).await;
    let mut changes = image.subscribe();
    rig.client
        .write_single_register(5, 555)
        .await
        .unwrap()
        .unwrap();
    let change = within("the image change", changes.recv()).await.unwrap();
    assert_eq!(
        (change.unit, change.table, change.start, change.values),
        (9, Table::HoldingRegisters, 5, vec![555])
    );
    rig.client
        .write_single_coil(1024, true)
        .await
        .unwrap()
        .unwrap();
    eventually("the coil in the image", || {
        image
            .read_bits(9, Table::Coils, 1024, 1)
            .is_ok_and(|r| r.values == [true])
    })
    .await;
    rig.stop().await;
}

#[tokio::test]
async fn the_memory_survives_a_restart() {
    let path = temp_path("persist.bin");
    let (memory, report) = SharedCpMemory::open(MemoryLayout::default(), &path).unwrap();
    assert_eq!(report.status, LoadStatus::NoFile);
    let shutdown = CancellationToken::new();
    let saver = spawn_persistence(
        memory.clone(),
        PersistSettings {
            path: path.clone(),
            interval: Duration::from_millis(50),
        },
        shutdown.clone(),
    );
    let mut rig = Rig::start(memory).await;
    rig.client
        .write_multiple_registers(10, &[0xCAFE, 0xF00D])
        .await
        .unwrap()
        .unwrap();
    rig.client
        .write_single_coil(1024 + 9, true)
        .await
        .unwrap()
        .unwrap();
    eventually("a periodic save", || path.exists()).await;
    rig.stop().await;
    shutdown.cancel();
    within("the last save", saver).await.unwrap();

    let (again, report) = SharedCpMemory::open(MemoryLayout::default(), &path).unwrap();
    assert_eq!(report.status, LoadStatus::Loaded);
    assert!(report.differences.is_empty(), "{:?}", report.differences);
    assert_eq!(
        again.read(|m| (m.db(800).map(|d| d[10..12].to_vec()), m.q()[101])),
        (Some(vec![0xCAFE, 0xF00D]), 0b10)
    );

    // A damaged file is moved aside and the memory starts zeroed.
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[12] ^= 0xFF;
    std::fs::write(&path, &bytes).unwrap();
    let (zeroed, report) = SharedCpMemory::open(MemoryLayout::default(), &path).unwrap();
    let LoadStatus::Corrupt { moved_to, .. } = report.status else {
        panic!("damage not found: {report:?}");
    };
    assert!(moved_to.exists() && !path.exists());
    assert_eq!(zeroed.snapshot(), proto_core::cpmem::CpMemory::default());
    std::fs::remove_file(moved_to).unwrap();
}

#[tokio::test]
async fn a_port_that_cannot_open_is_an_event_and_retried() {
    let params = SlaveParams::default();
    let mut settings = SlaveLineSettings::new(
        "hmi",
        PortSettings::new("/dev/does-not-exist-gw-slave", 9600),
        params,
    );
    settings.reopen_min = Duration::from_millis(20);
    settings.reopen_max = Duration::from_millis(40);
    let shutdown = CancellationToken::new();
    let line = spawn_modbus_slave_line(
        settings,
        SharedCpMemory::new(MemoryLayout::default()),
        shutdown.clone(),
    );
    eventually("two failed opens", || {
        line.status()
            .event_counts
            .get(&EVENT_PORT_SETUP)
            .is_some_and(|n| *n >= 2)
    })
    .await;
    let status = line.status();
    assert!(!status.port_open);
    assert!(status
        .port_error
        .is_some_and(|e| e.contains("/dev/does-not-exist-gw-slave")));
    shutdown.cancel();
    within("the line to stop", line.join()).await;
}

/// The demo's simulated HMI polls the slave line: reads of every area, the cycle counter written
/// into a DB word, so the values and the counters move.
#[tokio::test]
async fn the_simulated_master_moves_values_and_counters() {
    let (outside, path, _keep) = pty();
    let params = SlaveParams::new(ADDRESS, OperatingMode::Normal, 1, test_map()).unwrap();
    let memory = filled_memory();
    let shutdown = CancellationToken::new();
    let line = spawn_modbus_slave_line(
        SlaveLineSettings::new("hmi", PortSettings::new(path, 9600), params.clone()),
        memory.clone(),
        shutdown.clone(),
    );
    eventually("the port to open", || line.status().port_open).await;
    let mut settings = SimMasterSettings::for_slave(&params, Some(50));
    settings.period = Duration::from_millis(20);
    let master = spawn_sim_master(outside, settings, shutdown.clone());

    eventually("three cycles", || master.counts().last_counter >= 3).await;
    let counts = master.counts();
    assert_eq!((counts.exceptions, counts.failures), (0, 0), "{counts:?}");
    // Each cycle: 8 reads and the counter write, all answered.
    assert!(counts.responses >= 3 * 9, "{counts:?}");
    let written = memory.read(|m| m.db(800).unwrap()[50]);
    assert!(
        u64::from(written) >= counts.last_counter,
        "{written} {counts:?}"
    );
    let served = line.slave_counters().expect("a slave line");
    assert!(
        served.answered >= counts.responses && served.writes >= 3,
        "{served:?}"
    );

    shutdown.cancel();
    within("the master to stop", master.join()).await;
    within("the line to stop", line.join()).await;
}
