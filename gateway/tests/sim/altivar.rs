//! The Altivar 61/71 simulator against 002's frames and rules, through the model.

use std::time::Duration;

use gateway::sim::altivar::AltivarSim;
use gateway::sim::{Faults, ModbusDevice};
use proto_core::profiles::altivar::{self as profile, DriveState};

use crate::{frame, hex};

/// One exchange of the manual: how to set the drive up, what the master sends, what the drive
/// answers (`None`: silence).
pub(crate) struct Vector {
    pub(crate) name: &'static str,
    pub(crate) setup: fn() -> AltivarSim,
    pub(crate) request: Vec<u8>,
    pub(crate) response: Option<Vec<u8>>,
}

fn drive_2() -> AltivarSim {
    AltivarSim::default()
}

fn drive_at(address: u8) -> AltivarSim {
    AltivarSim::new(address)
}

fn drive_4() -> AltivarSim {
    drive_at(4)
}

fn drive_12() -> AltivarSim {
    drive_at(12)
}

fn drive_12_chcf_protected() -> AltivarSim {
    let mut sim = drive_at(12);
    sim.set_protected(profile::CHCF, true);
    sim
}

fn drive_12_all_protected() -> AltivarSim {
    let mut sim = drive_12_chcf_protected();
    sim.set_protected(profile::COP, true);
    sim
}

fn drive_with_cards() -> AltivarSim {
    let mut sim = AltivarSim::default();
    sim.set_card_addresses(Some(54), Some(104));
    sim
}

/// 002 "Kommunikationsscanner": slave 20, scanner assigned as in the example, and the drive in
/// the state the example reads (values set, dynamics off so they stay).
fn drive_20_scanner() -> AltivarSim {
    let mut sim = drive_at(20);
    sim.set_dynamics(false);
    let nma = [3201, 8604, 3204, 3205, 3207, 3209, 9630, 7121];
    let nca = [8501, 8602, 3104, 3105, 9001, 9002, 0, 0];
    for (address, value) in profile::NMA
        .iter()
        .zip(nma)
        .chain(profile::NCA.iter().zip(nca))
    {
        assert!(sim.set_word(*address, value));
    }
    for (address, value) in [
        (profile::ETA, 0x0007),
        (profile::RFRD, 0x1388),
        (profile::LCR, 0x0064),
        (profile::OTR, 0x0045),
        (profile::ULN, 0x00F0),
        (profile::THD, 0x0065),
        (profile::THR, 0x0032),
        (profile::LFT, 0x0000),
    ] {
        assert!(sim.set_word(address, value));
    }
    sim
}

/// The 55-byte FC 43 answer of 002 "Identifikation".
fn identification_response() -> Vec<u8> {
    let mut bytes = hex("02 2B 0E 01 02 00 00 04");
    for (id, text) in [
        (0x00, "Telemecanique"),
        (0x01, "ATV71HU15M3"),
        (0x02, "0201"),
        (0x06, "MACHINE 4"),
    ] {
        bytes.push(id);
        bytes.push(u8::try_from(text.len()).unwrap());
        bytes.extend_from_slice(text.as_bytes());
    }
    bytes.extend_from_slice(&hex("6F 50"));
    assert_eq!(bytes.len(), 55);
    bytes
}

/// Every Altivar frame of the vector list.
pub(crate) fn vectors() -> Vec<Vector> {
    let v = |name, setup, request: &str, response: Option<Vec<u8>>| Vector {
        name,
        setup,
        request: hex(request),
        response,
    };
    vec![
        v(
            "fc03 W3102..W3105",
            drive_2,
            "02 03 0C 1E 00 04 27 6C",
            Some(hex("02 03 08 00 28 02 58 01 F4 00 00 52 B0")),
        ),
        v(
            "fc03 %MW20..24 of the Controller Inside server",
            drive_with_cards,
            "36 03 00 14 00 05 C1 8A",
            Some(hex("36 03 0A 00 54 01 23 01 A3 1A D5 00 9E 21 4C")),
        ),
        v(
            "fc03 IP address of the Ethernet card server",
            drive_with_cards,
            "68 03 EA 66 00 04 99 37",
            Some(hex("68 03 08 00 8B 00 A0 00 45 00 F1 2E 0A")),
        ),
        v(
            "fc06 ACC = 13",
            drive_2,
            "02 06 23 29 00 0D 92 70",
            Some(hex("02 06 23 29 00 0D 92 70")),
        ),
        v(
            "fc08 echo",
            drive_4,
            "04 08 00 00 31 32 74 1B",
            Some(hex("04 08 00 00 31 32 74 1B")),
        ),
        v(
            "fc16 ACC, DEC = 20, 30",
            drive_2,
            "02 10 23 29 00 02 04 00 14 00 1E 73 A4",
            Some(hex("02 10 23 29 00 02 9B B7")),
        ),
        v(
            "fc43 identification",
            drive_2,
            "02 2B 0E 01 00 34 77",
            Some(identification_response()),
        ),
        v(
            "fc23 scanner",
            drive_20_scanner,
            "14 17 31 C5 00 08 31 D9 00 06 0C 00 0F 13 88 1F 40 01 F4 04 B0 02 58 56 3D",
            Some(hex(
                "14 17 10 00 07 13 88 00 64 00 45 00 F0 00 65 00 32 00 00 E4 90",
            )),
        ),
        v(
            "fc16 to read-only ETA",
            drive_4,
            "04 10 0C 81 00 01 02 00 01 8A D1",
            Some(hex("04 90 04 5D C2")),
        ),
        v(
            "fc03 from missing W8400",
            drive_12,
            "0C 03 20 D0 00 03 0E EF",
            Some(hex("0C 03 06 80 00 00 03 00 02 17 E4")),
        ),
        v(
            "fc03 from W8400, CHCF protected",
            drive_12_chcf_protected,
            "0C 03 20 D0 00 03 0E EF",
            Some(hex("0C 03 06 80 00 80 00 00 02 CE 24")),
        ),
        v(
            "fc03 from W8400, all protected",
            drive_12_all_protected,
            "0C 03 20 D0 00 03 0E EF",
            Some(hex("0C 83 02 51 32")),
        ),
    ]
}

#[test]
fn every_manual_frame_is_answered_byte_for_byte() {
    for vector in vectors() {
        let mut sim = (vector.setup)();
        assert_eq!(
            sim.handle_frame(&vector.request),
            vector.response,
            "{}",
            vector.name
        );
    }
}

#[test]
fn fc23_writes_through_the_scanner_before_reading() {
    let mut sim = drive_20_scanner();
    let request = hex("14 17 31 C5 00 08 31 D9 00 06 0C 00 0F 13 88 1F 40 01 F4 04 B0 02 58 56 3D");
    assert!(sim.handle_frame(&request).is_some());
    // NC1..NC6 went to CMD, LFRD, HSP, LSP, ACC, DEC.
    let written = [
        (8501, 0x000F),
        (8602, 0x1388),
        (3104, 0x1F40),
        (3105, 0x01F4),
        (9001, 0x04B0),
        (9002, 0x0258),
    ];
    for (address, value) in written {
        assert_eq!(sim.word(address), Some(value), "W{address}");
    }
    assert_eq!(sim.word(profile::NC[0]), Some(0x000F));
}

#[test]
fn scanner_defaults_read_eta_and_rfrd() {
    let mut sim = AltivarSim::default();
    // NMA1..8 (W12701) hold the factory assignment: ETA, RFRD, then 0.
    let reply = sim.handle_frame(&frame("02 03 31 9D 00 08")).unwrap();
    assert_eq!(
        reply,
        frame("02 03 10 0C 81 21 9C 00 00 00 00 00 00 00 00 00 00 00 00")
    );
    // NM1 = ETA, NM2 = RFRD, NM3..8 not assigned = 0.
    let eta = sim.word(profile::ETA).unwrap();
    let reply = sim.handle_frame(&frame("02 03 31 C5 00 03")).unwrap();
    let [high, low] = eta.to_be_bytes();
    assert_eq!(
        reply,
        with_crc_vec(&[0x02, 0x03, 0x06, high, low, 0x00, 0x00, 0x00, 0x00])
    );
}

fn with_crc_vec(bytes: &[u8]) -> Vec<u8> {
    crate::with_crc(bytes)
}

#[test]
fn other_address_and_bad_crc_are_silent() {
    let mut sim = AltivarSim::default();
    assert_eq!(sim.handle_frame(&hex("03 03 0C 1E 00 04 26 BD")), None);
    assert_eq!(sim.handle_frame(&frame("03 03 0C 1E 00 04")), None);
    assert_eq!(sim.counters().frames, 0);
    // The first vector with its CRC damaged.
    assert_eq!(sim.handle_frame(&hex("02 03 0C 1E 00 04 27 6D")), None);
    let counters = sim.counters();
    assert_eq!((counters.frames, counters.crc_errors), (1, 1));
    // M1CT / M1EC read the counters (6010 = 0x177A): 2 frames now, 1 CRC error.
    let reply = sim.handle_frame(&frame("02 03 17 7A 00 02")).unwrap();
    assert_eq!(reply, frame("02 03 04 00 01 00 02"));
    // FC 08 / 0C and 0E.
    assert_eq!(
        sim.handle_frame(&frame("02 08 00 0C 00 00")),
        Some(frame("02 08 00 0C 00 01"))
    );
    assert_eq!(
        sim.handle_frame(&frame("02 08 00 0E 00 00")),
        Some(frame("02 08 00 0E 00 03"))
    );
    assert_eq!(
        sim.handle_frame(&frame("02 08 00 0A 00 00")),
        Some(frame("02 08 00 0A 00 00"))
    );
    assert_eq!(sim.counters().crc_errors, 0);
    // An unknown sub-function is an illegal function.
    assert_eq!(
        sim.handle_frame(&frame("02 08 00 04 00 00")),
        Some(frame("02 88 01"))
    );
}

#[test]
fn broadcast_writes_are_applied_silently() {
    let mut sim = AltivarSim::default();
    // FC 06 ACC = 13 and FC 16 DEC = 45 to address 0: no answer, values changed.
    assert_eq!(sim.handle_frame(&frame("00 06 23 29 00 0D")), None);
    assert_eq!(sim.handle_frame(&frame("00 10 23 2A 00 01 02 00 2D")), None);
    assert_eq!(
        sim.handle_frame(&frame("02 03 23 29 00 02")),
        Some(frame("02 03 04 00 0D 00 2D"))
    );
    // A broadcast read is ignored, and broadcasts are not counted in M1CT.
    assert_eq!(sim.handle_frame(&frame("00 03 23 29 00 02")), None);
    assert_eq!(sim.counters().frames, 1);
    // A broadcast write to read-only ETA changes nothing.
    let eta = sim.word(profile::ETA);
    assert_eq!(sim.handle_frame(&frame("00 06 0C 81 00 01")), None);
    assert_eq!(sim.word(profile::ETA), eta);
}

#[test]
fn limits_and_unsupported_functions() {
    let mut sim = AltivarSim::default();
    // 002 "Modbus-Funktionen": FC03 at most 63 words, FC16 61, FC23 20 / 20.
    assert!(
        sim.handle_frame(&frame("02 03 0C 1E 00 3F"))
            .unwrap()
            .get(1)
            == Some(&0x03)
    );
    assert_eq!(
        sim.handle_frame(&frame("02 03 0C 1E 00 40")),
        Some(frame("02 83 03"))
    );
    let mut fc16 = hex("02 10 23 29 00 3E 7C");
    fc16.extend(std::iter::repeat_n(0u8, 124));
    assert_eq!(
        sim.handle_frame(&crate::with_crc(&fc16)),
        Some(frame("02 90 03"))
    );
    assert_eq!(
        sim.handle_frame(&frame("02 17 0C 1E 00 15 23 29 00 01 02 00 0D")),
        Some(frame("02 97 03"))
    );
    // No FC 04, 01, 05 on the drive.
    assert_eq!(
        sim.handle_frame(&frame("02 04 0C 1E 00 01")),
        Some(frame("02 84 01"))
    );
    assert_eq!(
        sim.handle_frame(&frame("02 01 00 00 00 01")),
        Some(frame("02 81 01"))
    );
    // Writes: missing word 02, out of range 03 (ACC 1..9999), read-only 04.
    assert_eq!(
        sim.handle_frame(&frame("02 06 20 D0 00 01")),
        Some(frame("02 86 02"))
    );
    assert_eq!(
        sim.handle_frame(&frame("02 06 23 29 27 10")),
        Some(frame("02 86 03"))
    );
    assert_eq!(
        sim.handle_frame(&frame("02 06 21 9C 00 01")),
        Some(frame("02 86 04"))
    );
    // A refused block changes nothing: DEC (W9002) then the missing W9003.
    assert_eq!(
        sim.handle_frame(&frame("02 10 23 2A 00 02 04 00 63 00 01")),
        Some(frame("02 90 02"))
    );
    assert_eq!(sim.word(profile::DEC), Some(30));
}

#[test]
fn identification_refusals_use_the_drive_format() {
    let mut sim = AltivarSim::default();
    // 002 "Negative Antwort für die Identifizierungsfunktion": AB 0E code.
    assert_eq!(
        sim.handle_frame(&frame("02 2B 0E 01 03")),
        Some(frame("02 AB 0E 02"))
    );
    assert_eq!(
        sim.handle_frame(&frame("02 2B 0E 05 00")),
        Some(frame("02 AB 0E 01"))
    );
    assert_eq!(
        sim.handle_frame(&frame("02 2B 0D 01 00")),
        Some(frame("02 AB 0E 01"))
    );
    // From object 02 on: revision and name.
    let reply = sim.handle_frame(&frame("02 2B 0E 01 02")).unwrap();
    assert_eq!(reply.get(..8), Some(&hex("02 2B 0E 01 02 00 00 02")[..]));
}

#[test]
fn the_drive_follows_cmd_and_lfrd() {
    let mut sim = AltivarSim::default();
    // CHCF = 3 (I/O profile): bit 0 of CMD runs. CMD = 000F, LFRD = 1200 rpm.
    assert_eq!(
        sim.handle_frame(&frame("02 10 21 35 00 01 02 00 0F")),
        Some(frame("02 10 21 35 00 01"))
    );
    assert_eq!(
        sim.handle_frame(&frame("02 06 21 9A 04 B0")),
        Some(frame("02 06 21 9A 04 B0"))
    );
    sim.tick(Duration::from_secs(1));
    let rfrd = sim.word(profile::RFRD).unwrap() as i16;
    assert!(rfrd > 0 && rfrd < 1200, "ramping: {rfrd}");
    for _ in 0..5 {
        sim.tick(Duration::from_secs(1));
        assert!(sim.handle_frame(&frame("02 03 0C 81 00 01")).is_some());
    }
    assert_eq!(sim.word(profile::RFRD), Some(1200));
    let eta = sim.word(profile::ETA).unwrap();
    assert_eq!(DriveState::from_eta(eta), DriveState::OperationEnabled);
    assert_ne!(eta & profile::eta::TARGET_REACHED, 0);
    assert!(sim.word(profile::LCR).unwrap() > 0);
    // The scanner's NM2 reads RFRD.
    assert_eq!(
        sim.handle_frame(&frame("02 03 31 C6 00 01")),
        Some(frame("02 03 02 04 B0"))
    );
    // No request for the 10 s time-out: the drive faults (SLF) and coasts down.
    sim.tick(Duration::from_secs(11));
    let eta = sim.word(profile::ETA).unwrap();
    assert_eq!(DriveState::from_eta(eta), DriveState::Fault);
    assert_ne!(sim.word(profile::LFT), Some(0));
    // Fault reset (rising edge of bit 7), then run again.
    sim.handle_frame(&frame("02 06 21 35 00 80")).unwrap();
    sim.tick(Duration::from_millis(100));
    assert_eq!(
        DriveState::from_eta(sim.word(profile::ETA).unwrap()),
        DriveState::SwitchedOn
    );
}

#[test]
fn injected_faults() {
    let request = hex("02 03 0C 1E 00 04 27 6C");
    let good = hex("02 03 08 00 28 02 58 01 F4 00 00 52 B0");
    let mut sim = AltivarSim::default();
    sim.set_faults(Faults {
        silent: true,
        ..Faults::default()
    });
    assert_eq!(sim.handle_frame(&request), None);
    sim.set_faults(Faults {
        bad_crc: true,
        ..Faults::default()
    });
    let reply = sim.handle_frame(&request).unwrap();
    assert_eq!(reply.get(..11), good.get(..11));
    assert_ne!(reply, good);
    sim.set_faults(Faults {
        wrong_address: true,
        ..Faults::default()
    });
    let reply = sim.handle_frame(&request).unwrap();
    assert_eq!(
        reply,
        crate::with_crc(&[&[0x03][..], good.get(1..11).unwrap()].concat())
    );
    let delay = Duration::from_millis(300);
    sim.set_faults(Faults {
        delay,
        ..Faults::default()
    });
    assert_eq!(sim.faults().delay, delay);
    assert_eq!(sim.handle_frame(&request), Some(good));
}

#[test]
fn an_assigned_scanner_output_reads_back_the_word_it_names() {
    // NC1 is a copy of CMD (NCA1's factory assignment): read back, it shows CMD as it is now,
    // whoever wrote it.
    let mut sim = AltivarSim::default();
    assert!(sim.set_word(profile::CMD, 0x0006));
    assert_eq!(sim.word(profile::NC[0]), Some(0x0006));
    // NC3 is not assigned: it keeps what was written to it.
    assert_eq!(sim.word(profile::NC[2]), Some(0));
}
