//! The memory side of the slave: the conversion tables of 003 6.4.8 (copied from the manual, as
//! checked in the project's vector notes), the write limits and the exception rules, each checked
//! over the line as well.

use super::*;

/// 003 6.4.8.1 (FC 01/05/15) "Address calculation", with the manual's example parameterization.
const COIL_TABLE: &[(u16, &str)] = &[
    (0, "M 1000.0"),
    (1, "M 1000.1"),
    (497, "M 1062.1"),
    (1024, "Q 100.0"),
    (1025, "Q 100.1"),
    (2010, "Q 223.2"),
    (2048, "T 100"),
    (2064, "T 101"),
    (3200, "T 172"),
    (4064, "C 200"),
    (4080, "C 201"),
    (4096, "C 202"),
];

/// 003 6.4.8.2 (FC 02) "Address calculation".
const INPUT_TABLE: &[(u16, &str)] = &[
    (0, "M 1000.0"),
    (1, "M 1000.1"),
    (497, "M 1062.1"),
    (1024, "I 100.0"),
    (1025, "I 100.1"),
    (2010, "I 223.2"),
];

/// 003 6.4.8.3 "Further values" (base DB 800): start_register, DB, DBW.
const REGISTER_TABLE: &[(u16, u16, u32)] = &[
    (0, 800, 0),
    (500, 800, 1000),
    (900, 801, 776),
    (1023, 801, 1022),
];

#[test]
fn conversion_tables_of_the_manual() {
    let map = AddressMap::manual_example();
    for &(start, want) in COIL_TABLE {
        let quantity = if want.starts_with('T') || want.starts_with('C') {
            16
        } else {
            1
        };
        let got = locate_bits(&map, BitTable::Coils, start, quantity, false).expect("mapped");
        assert_eq!(got.to_string(), want, "FC 01 start_addr {start}");
    }
    for &(start, want) in INPUT_TABLE {
        let got = locate_bits(&map, BitTable::Inputs, start, 1, false).expect("mapped");
        assert_eq!(got.to_string(), want, "FC 02 start_addr {start}");
    }
    for &(start, db, dbw) in REGISTER_TABLE {
        let got = locate_registers(&map, RegisterTable::Holding, start, 1).expect("mapped");
        assert_eq!((got.db, got.dbw()), (db, dbw), "start_register {start}");
        assert_eq!(got.to_string(), format!("DB{db}.DBW{dbw}"));
    }
    // 6.4.8.3 worked example: start_register 80 -> DB 800, DBW 160.
    assert_eq!(
        locate_registers(&map, RegisterTable::Holding, 80, 1),
        Ok(RegisterLocation { db: 800, word: 80 })
    );
}

#[test]
fn conversion_tables_over_the_line() {
    // A marker at places of the tables, read back with FC 01, 02 and 03.
    let mut mem = CpMemory::default();
    mem.m_mut()[1062] = 0b0000_0010; // M 1062.1
    mem.q_mut()[223] = 0b0000_0100; // Q 223.2
    mem.i_mut()[223] = 0b0000_0100; // I 223.2
    mem.timers_mut()[172] = 0x0001; // T 172: low byte bit 0 = coil 8
    mem.counters_mut()[202] = 0x8000; // C 202: high byte bit 7 = coil 7
    mem.db_mut(801).expect("DB 801")[388] = 0xBEEF; // DBW 776
    mem.db_mut(800).expect("DB 800")[500] = 0x1234; // DBW 1000
    let mut line = Line::new(222, AddressMap::manual_example(), mem);
    let cases: &[(&[u8], &[u8])] = &[
        (&[0x01, 0x01, 0xF1, 0x00, 0x01], &[0x01, 0x01, 0x01]),
        (&[0x01, 0x07, 0xDA, 0x00, 0x01], &[0x01, 0x01, 0x01]),
        (&[0x02, 0x07, 0xDA, 0x00, 0x01], &[0x02, 0x01, 0x01]),
        (&[0x02, 0x01, 0xF1, 0x00, 0x01], &[0x02, 0x01, 0x01]),
        (&[0x01, 0x0C, 0x80, 0x00, 0x10], &[0x01, 0x02, 0x00, 0x01]),
        (&[0x01, 0x10, 0x00, 0x00, 0x10], &[0x01, 0x02, 0x80, 0x00]),
        (&[0x03, 0x03, 0x84, 0x00, 0x01], &[0x03, 0x02, 0xBE, 0xEF]),
        (&[0x03, 0x01, 0xF4, 0x00, 0x01], &[0x03, 0x02, 0x12, 0x34]),
    ];
    for (request, answer) in cases {
        assert_eq!(
            line.exchange(&frame(222, request)),
            Some(frame(222, answer)),
            "request {request:02X?}"
        );
    }
    // The neighbours of the markers read as zero.
    assert_eq!(
        line.exchange(&frame(222, &[0x01, 0x01, 0xF0, 0x00, 0x01])),
        Some(frame(222, &[0x01, 0x01, 0x00]))
    );
}

#[test]
fn manual_frames_are_answered_byte_for_byte() {
    // Frames of the vector notes (from 002), served from CP memory: register 3102 = DB(base + 6)
    // word 30, register 9001 = DB(base + 17) word 297.
    let base = 800;
    let layout = MemoryLayout {
        data_blocks: vec![(base + 6, 512), (base + 17, 512)],
        ..MemoryLayout::default()
    };
    let mut mem = CpMemory::new(&layout);
    mem.db_mut(base + 6).expect("DB")[30..34].copy_from_slice(&[40, 600, 500, 0]);
    let map = AddressMap::manual_example()
        .with_limits(open_limits())
        .expect("valid");
    let mut line = Line::new(2, map, mem);

    let read = [0x02, 0x03, 0x0C, 0x1E, 0x00, 0x04, 0x27, 0x6C];
    let answer = [
        0x02, 0x03, 0x08, 0x00, 0x28, 0x02, 0x58, 0x01, 0xF4, 0x00, 0x00, 0x52, 0xB0,
    ];
    assert_eq!(line.exchange(&read).as_deref(), Some(&answer[..]));

    let write = [0x02, 0x06, 0x23, 0x29, 0x00, 0x0D, 0x92, 0x70];
    assert_eq!(line.exchange(&write).as_deref(), Some(&write[..]));
    assert_eq!(line.memory().db(base + 17).expect("DB")[297], 13);
    let write16 = [
        0x02, 0x10, 0x23, 0x29, 0x00, 0x02, 0x04, 0x00, 0x14, 0x00, 0x1E, 0x73, 0xA4,
    ];
    let answer16 = [0x02, 0x10, 0x23, 0x29, 0x00, 0x02, 0x9B, 0xB7];
    assert_eq!(line.exchange(&write16).as_deref(), Some(&answer16[..]));
    assert_eq!(
        &line.memory().db(base + 17).expect("DB")[297..299],
        &[20, 30]
    );

    // FC 08 diagnostic code 0000h is echoed (6.4.8.7).
    let mut line4 = Line::new(4, AddressMap::manual_example(), CpMemory::default());
    let echo = [0x04, 0x08, 0x00, 0x00, 0x31, 0x32, 0x74, 0x1B];
    assert_eq!(line4.exchange(&echo).as_deref(), Some(&echo[..]));
}

#[test]
fn writes_need_limits() {
    let mut line = Line::new(222, AddressMap::manual_example(), CpMemory::default());
    // By default nothing is writable (6.4.5 "Limits"): every write answers 02.
    let writes: &[&[u8]] = &[
        &[0x05, 0x00, 0x00, 0xFF, 0x00],
        &[0x06, 0x00, 0x00, 0x12, 0x34],
        &[0x0F, 0x04, 0x00, 0x00, 0x03, 0x01, 0x05],
        &[0x10, 0x00, 0x00, 0x00, 0x01, 0x02, 0x12, 0x34],
    ];
    for pdu in writes {
        assert_eq!(
            line.exchange(&frame(222, pdu)),
            Some(exception(222, pdu[0], 0x02)),
            "{pdu:02X?}"
        );
    }
    assert_eq!(line.memory(), &CpMemory::default(), "nothing written");

    // Enable MB 1000 and DB 800 only.
    let limits = WriteLimits {
        memory: Some((1000, 1000)),
        outputs: None,
        data_blocks: Some((800, 800)),
    };
    let map = AddressMap::manual_example()
        .with_limits(limits)
        .expect("valid");
    let mut line = Line::new(222, map, CpMemory::default());
    assert_eq!(
        line.exchange(&frame(222, writes[0])),
        Some(frame(222, writes[0]))
    );
    assert_eq!(line.memory().m()[1000], 0x01);
    // M 1001.0 is outside the limit; the outputs are not enabled.
    assert_eq!(
        line.exchange(&frame(222, &[0x05, 0x00, 0x08, 0xFF, 0x00])),
        Some(exception(222, 0x05, 0x02))
    );
    assert_eq!(
        line.exchange(&frame(222, writes[2])),
        Some(exception(222, 0x0F, 0x02))
    );
    assert_eq!(
        line.exchange(&frame(222, writes[1])),
        Some(frame(222, writes[1]))
    );
    assert_eq!(line.memory().db(800).expect("DB 800")[0], 0x1234);
    // DB 801 (register 512) is not enabled.
    assert_eq!(
        line.exchange(&frame(222, &[0x06, 0x02, 0x00, 0x00, 0x01])),
        Some(exception(222, 0x06, 0x02))
    );
    assert_eq!(line.memory().db(801).expect("DB 801")[0], 0);

    // Timers and counters are read-only (FC 01 only, 6.4.5), whatever the limits.
    let all = AddressMap::manual_example()
        .with_limits(open_limits())
        .expect("valid");
    let mut line = Line::new(222, all, CpMemory::default());
    assert_eq!(
        line.exchange(&frame(222, &[0x05, 0x08, 0x00, 0xFF, 0x00])),
        Some(exception(222, 0x05, 0x02))
    );
}

#[test]
fn exception_rules() {
    let mut line = Line::new(222, AddressMap::manual_example(), CpMemory::default());
    let cases: &[(&[u8], u8, &str)] = &[
        (&[0x07], 0x01, "FC 07 is not served by the slave driver"),
        (
            &[0x08, 0x00, 0x01, 0x00, 0x00],
            0x01,
            "only diagnostic code 0000h (6.4.8.7)",
        ),
        (&[0x2B, 0x0E, 0x01, 0x00], 0x01, "FC 43 is not served"),
        (&[0x03, 0x00, 0x00, 0x00, 0x80], 0x03, "128 registers > 127"),
        (&[0x01, 0x00, 0x00, 0x07, 0xF9], 0x03, "2041 bits > 2040"),
        (
            &[0x03, 0x01, 0xFF, 0x00, 0x02],
            0x02,
            "crosses from DB 800 into DB 801",
        ),
        (
            &[0x03, 0x04, 0x00, 0x00, 0x01],
            0x02,
            "DB 802 does not exist (event 0E 39h)",
        ),
        (
            &[0x01, 0x08, 0x08, 0x00, 0x10],
            0x02,
            "timer access off the 16-bit grid",
        ),
        (
            &[0x01, 0x08, 0x00, 0x00, 0x08],
            0x03,
            "timer count not a multiple of 16",
        ),
        (
            &[0x01, 0x03, 0xFC, 0x00, 0x08],
            0x02,
            "from the M row into the Q row",
        ),
        (
            &[0x05, 0x00, 0x00, 0x12, 0x34],
            0x03,
            "FC 05 value neither FF00h nor 0000h",
        ),
    ];
    for (pdu, code, why) in cases {
        assert_eq!(
            line.exchange(&frame(222, pdu)),
            Some(exception(222, pdu[0], *code)),
            "{why}"
        );
    }
    let seen = line.events();
    assert!(seen.contains(&SlaveEvent::Diagnostic(ids::SLAVE_DB_ERROR)));
    let exceptions = seen.iter().filter(|e| {
        matches!(
            e,
            SlaveEvent::Request {
                outcome: Outcome::Exception(_),
                ..
            }
        )
    });
    assert_eq!(exceptions.count(), cases.len());

    // A bit area smaller than the map reaches: 0E 38h.
    let small = MemoryLayout {
        m_bytes: 1000,
        ..MemoryLayout::default()
    };
    let mut line = Line::new(222, AddressMap::manual_example(), CpMemory::new(&small));
    assert_eq!(
        line.exchange(&frame(222, &[0x01, 0x00, 0x00, 0x00, 0x01])),
        Some(exception(222, 0x01, 0x02))
    );
    assert!(line
        .events()
        .contains(&SlaveEvent::Diagnostic(ids::SLAVE_BIT_AREA_ERROR)));
    assert_eq!(
        ExceptionCode::from(AccessError::BeyondAreaEnd { area: Area::M }),
        ExceptionCode::IllegalDataAddress
    );
}

#[test]
fn bit_tables_can_be_parameterized() {
    let coils = [
        BitMapping {
            area: Area::Q,
            modbus_start: 0,
            plc_start: 0,
        },
        BitMapping {
            area: Area::C,
            modbus_start: 100,
            plc_start: 0,
        },
    ];
    let inputs = [BitMapping {
        area: Area::I,
        modbus_start: 0,
        plc_start: 10,
    }];
    let map = AddressMap::new(&coils, &inputs, 1, 2, WriteLimits::NONE).expect("valid");
    let layout = MemoryLayout {
        data_blocks: vec![(1, 4), (2, 4)],
        ..MemoryLayout::default()
    };
    let mut mem = CpMemory::new(&layout);
    mem.i_mut()[10] = 0x81;
    mem.counters_mut()[0] = 0xFFFF;
    mem.db_mut(2).expect("DB 2")[3] = 7;
    let mut line = Line::new(5, map, mem);
    assert_eq!(
        line.exchange(&frame(5, &[0x02, 0x00, 0x00, 0x00, 0x08])),
        Some(frame(5, &[0x02, 0x01, 0x81]))
    );
    assert_eq!(
        line.exchange(&frame(5, &[0x01, 0x00, 0x64, 0x00, 0x10])),
        Some(frame(5, &[0x01, 0x02, 0xFF, 0xFF]))
    );
    // FC 04 reads its own base DB; DB 2 has only 4 words.
    assert_eq!(
        line.exchange(&frame(5, &[0x04, 0x00, 0x03, 0x00, 0x01])),
        Some(frame(5, &[0x04, 0x02, 0x00, 0x07]))
    );
    assert_eq!(
        line.exchange(&frame(5, &[0x04, 0x00, 0x03, 0x00, 0x02])),
        Some(exception(5, 0x04, 0x02))
    );
    // FC 01 at 0 is Q 0.0 in this map.
    assert_eq!(
        line.exchange(&frame(5, &[0x01, 0x00, 0x00, 0x00, 0x01])),
        Some(frame(5, &[0x01, 0x01, 0x00]))
    );
}
