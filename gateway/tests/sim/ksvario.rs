//! The KS vario simulator against 001's frames and rules, through the model.

use gateway::sim::ksvario::{Datum, KsVarioSim};
use gateway::sim::ModbusDevice;
use proto_core::profiles::ksvario::FLOAT_NOT_DEFINED;

use crate::{frame, with_crc};

/// One exchange of the manual: what the master sends (without CRC) and what the controller
/// answers (without CRC), in order on one controller.
pub(crate) fn vectors() -> Vec<(&'static str, Vec<u8>, Vec<u8>)> {
    vec![
        // 001 4 "Beispiel für eine Übertragung": FC 04 at 1004 = 1066, 140, 4158.
        (
            "fc04 1004..1006",
            frame("11 04 03 EC 00 03"),
            frame("11 04 06 04 2A 00 8C 10 3E"),
        ),
        // 001 4.2.1: ti1 / ti2 of channel 1.
        (
            "fc03 0498h",
            frame("11 03 04 98 00 02"),
            frame("11 03 04 00 B4 01 4D"),
        ),
        // 001 4.2.2: SetpInterface of channel 30 = 123.
        (
            "fc06 15990",
            frame("11 06 3E 76 00 7B"),
            frame("11 06 3E 76 00 7B"),
        ),
        // 001 4.4: 3415 = 222, 3416 = 333 in the integer format.
        (
            "fc16 integer 3415",
            frame("11 10 0D 57 00 02 04 00 DE 01 4D"),
            frame("11 10 0D 57 00 02"),
        ),
        // 001 4.5: the same in the float format at 9AAEh.
        (
            "fc16 float 9AAEh",
            frame("11 10 9A AE 00 04 08 43 5E 00 00 43 A6 80 00"),
            frame("11 10 9A AE 00 04"),
        ),
        // Read back in the three formats: one value behind all three addresses.
        (
            "fc03 integer 3415",
            frame("11 03 0D 57 00 02"),
            frame("11 03 04 00 DE 01 4D"),
        ),
        (
            "fc03 fix point 3415",
            frame("11 03 4D 57 00 02"),
            frame("11 03 04 08 AC 0D 02"),
        ),
        (
            "fc03 float 3415",
            frame("11 03 9A AE 00 04"),
            frame("11 03 08 43 5E 00 00 43 A6 80 00"),
        ),
    ]
}

#[test]
fn every_manual_frame_is_answered_byte_for_byte() {
    let mut sim = KsVarioSim::default();
    for (name, request, response) in vectors() {
        assert_eq!(sim.handle_frame(&request), Some(response), "{name}");
    }
}

#[test]
fn one_value_store_behind_three_formats() {
    let mut sim = KsVarioSim::default();
    // The float write alone changes the integer data 3415 and 3416.
    sim.handle_frame(&frame("11 10 9A AE 00 04 08 43 5E 00 00 43 A6 80 00"))
        .unwrap();
    assert_eq!(sim.datum(3415), Some(Datum::Value(222.0)));
    assert_eq!(sim.datum(3416), Some(Datum::Value(333.0)));
    // A fix point write: ti1 of channel 1 = 123.4.
    assert_eq!(
        sim.handle_frame(&frame("11 06 44 98 04 D2")),
        Some(frame("11 06 44 98 04 D2"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 03 04 98 00 01")),
        Some(frame("11 03 02 00 7B"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 03 44 98 00 01")),
        Some(frame("11 03 02 04 D2"))
    );
}

#[test]
fn special_values_in_reads() {
    let mut sim = KsVarioSim::default();
    // A gap after the first datum reads 31000 (integer) or 1.5E37 (float).
    assert_eq!(
        sim.handle_frame(&frame("11 04 03 EC 00 04")),
        Some(frame("11 04 08 04 2A 00 8C 10 3E 79 18"))
    );
    let mut expect = vec![0x11, 0x03, 0x08];
    expect.extend_from_slice(&4158f32.to_be_bytes());
    expect.extend_from_slice(&FLOAT_NOT_DEFINED.to_be_bytes());
    // Float address of 1006: 2 x 1006 + 8000h = 87DCh.
    assert_eq!(
        sim.handle_frame(&frame("11 03 87 DC 00 04")),
        Some(with_crc(&expect))
    );
    // Switched off: 32000; beyond the integer range: 8000h (the float still carries it).
    assert!(sim.set_datum(0x0498, Datum::Off));
    assert_eq!(
        sim.handle_frame(&frame("11 03 04 98 00 01")),
        Some(frame("11 03 02 7D 00"))
    );
    assert!(sim.set_datum(0x0498, Datum::Value(40000.0)));
    assert_eq!(
        sim.handle_frame(&frame("11 03 04 98 00 01")),
        Some(frame("11 03 02 80 00"))
    );
    assert_eq!(sim.read_register(0x8000 + 2 * 0x0498), 0x471C);
}

#[test]
fn exceptions_follow_the_manual() {
    let mut sim = KsVarioSim::default();
    // 4.2.1: the first datum undefined -> 02.
    assert_eq!(
        sim.handle_frame(&frame("11 03 00 00 00 01")),
        Some(frame("11 83 02"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 04 03 EB 00 02")),
        Some(frame("11 84 02"))
    );
    // 4.2.2 / 4.5: FC 06 to a float address is refused.
    assert_eq!(
        sim.handle_frame(&frame("11 06 9A AE 43 5E")),
        Some(frame("11 86 02"))
    );
    // 4.2.2: a value outside the limits -> 03, datum unchanged (ti1 0..9999; transfer range
    // -30000..32000).
    assert_eq!(
        sim.handle_frame(&frame("11 06 04 98 27 10")),
        Some(frame("11 86 03"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 06 3E 76 7D 01")),
        Some(frame("11 86 03"))
    );
    assert_eq!(sim.datum(0x0498), Some(Datum::Value(180.0)));
    // 4.2.2: a datum that cannot be written -> 03.
    assert_eq!(
        sim.handle_frame(&frame("11 06 03 EC 00 01")),
        Some(frame("11 86 03"))
    );
    // 4.4: the first datum undefined 02, read-only 03; out of range stops, earlier data stay.
    assert_eq!(
        sim.handle_frame(&frame("11 10 00 00 00 01 02 00 01")),
        Some(frame("11 90 02"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 10 03 EC 00 01 02 00 01")),
        Some(frame("11 90 03"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 10 04 98 00 02 04 00 C8 27 10")),
        Some(frame("11 90 03"))
    );
    assert_eq!(sim.datum(0x0498), Some(Datum::Value(200.0)));
    assert_eq!(sim.datum(0x0499), Some(Datum::Value(333.0)));
    // 4.4: gaps after the first datum are skipped without an error.
    assert_eq!(
        sim.handle_frame(&frame("11 10 04 98 00 03 06 00 05 00 0A 00 14")),
        Some(frame("11 10 04 98 00 03"))
    );
    assert_eq!(sim.datum(0x0498), Some(Datum::Value(5.0)));
    assert_eq!(sim.datum(0x0499), Some(Datum::Value(10.0)));
    // Functions 001 4.2 does not list -> 01; a quantity above 120 -> 03.
    assert_eq!(
        sim.handle_frame(&frame("11 17 04 98 00 01 04 98 00 01 02 00 01")),
        Some(frame("11 97 01"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 01 00 00 00 01")),
        Some(frame("11 81 01"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 03 04 76 00 79")),
        Some(frame("11 83 03"))
    );
    // A float block must start on a float and cover whole floats.
    assert_eq!(
        sim.handle_frame(&frame("11 03 9A AF 00 02")),
        Some(frame("11 83 02"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 03 9A AE 00 03")),
        Some(frame("11 83 03"))
    );
}

#[test]
fn other_address_bad_crc_and_too_long_are_silent() {
    let mut sim = KsVarioSim::default();
    assert_eq!(sim.handle_frame(&frame("12 04 03 EC 00 03")), None);
    let mut bad = frame("11 04 03 EC 00 03");
    if let Some(last) = bad.last_mut() {
        *last ^= 0x01;
    }
    assert_eq!(sim.handle_frame(&bad), None);
    // 001 3.1: a message longer than the 250-byte buffer is not answered. FC 16 of 121 registers
    // is 251 bytes; 120 registers (249 bytes) fit. From SetpInterface of channel 1 (0476h) the
    // block covers ti1 / ti2 (written 0, inside their limits) and gaps (skipped).
    let block = |count: u16| {
        let mut bytes = vec![0x11, 0x10, 0x04, 0x76];
        bytes.extend_from_slice(&count.to_be_bytes());
        bytes.push(u8::try_from(2 * count).unwrap_or(u8::MAX));
        bytes.extend(std::iter::repeat_n(0u8, usize::from(2 * count)));
        with_crc(&bytes)
    };
    assert_eq!(block(121).len(), 251);
    assert_eq!(sim.handle_frame(&block(121)), None);
    assert_eq!(
        sim.handle_frame(&block(120)),
        Some(frame("11 10 04 76 00 78"))
    );
    assert_eq!(sim.datum(0x0498), Some(Datum::Value(0.0)));
    // The counters saw all of it (001 4.3.6..4.3.15).
    let counters = sim.counters();
    assert_eq!(
        counters.bus_messages, 2,
        "two good frames: the other slave's and the 120-register write"
    );
    assert_eq!(counters.comm_errors, 1);
    assert_eq!(counters.overruns, 1);
    assert_eq!(counters.buffer_full, 1);
    assert_eq!(counters.slave_messages, 1);
    assert_eq!(
        sim.handle_frame(&frame("11 08 00 12 00 00")),
        Some(frame("11 08 00 12 00 01"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 08 00 42 00 00")),
        Some(frame("11 08 00 42 00 01"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 08 00 0C 00 00")),
        Some(frame("11 08 00 0C 00 01"))
    );
    // 0B counts this request too: 2 + three FC 08.
    assert_eq!(
        sim.handle_frame(&frame("11 08 00 0B 00 00")),
        Some(frame("11 08 00 0B 00 06"))
    );
}

#[test]
fn broadcast_writes_are_applied_silently() {
    let mut sim = KsVarioSim::default();
    assert_eq!(
        sim.handle_frame(&frame("00 10 9A AE 00 04 08 43 5E 00 00 43 A6 80 00")),
        None
    );
    assert_eq!(sim.handle_frame(&frame("00 06 3E 76 00 7B")), None);
    assert_eq!(
        sim.handle_frame(&frame("11 03 0D 57 00 02")),
        Some(frame("11 03 04 00 DE 01 4D"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 03 3E 76 00 01")),
        Some(frame("11 03 02 00 7B"))
    );
    // Reads and diagnostics are not broadcast (001 4.2.1, 4.3): no answer, no effect.
    assert_eq!(sim.handle_frame(&frame("00 03 0D 57 00 02")), None);
    assert_eq!(sim.handle_frame(&frame("00 08 00 04 00 00")), None);
    assert!(!sim.is_listen_only());
}

#[test]
fn listen_only_until_restart() {
    let mut sim = KsVarioSim::default();
    // 001 4.3.2: a restart outside listen-only mode is answered (echo 00 00).
    assert_eq!(
        sim.handle_frame(&frame("11 08 00 01 00 00")),
        Some(frame("11 08 00 01 00 00"))
    );
    // 4.3.4: switching to listen-only is never answered; nothing is carried out afterwards.
    assert_eq!(sim.handle_frame(&frame("11 08 00 04 00 00")), None);
    assert!(sim.is_listen_only());
    assert_eq!(sim.handle_frame(&frame("11 04 03 EC 00 03")), None);
    assert_eq!(sim.handle_frame(&frame("11 06 3E 76 00 7B")), None);
    assert_eq!(sim.datum(15990), Some(Datum::Value(0.0)));
    assert_eq!(sim.handle_frame(&frame("11 08 00 00 12 34")), None);
    // 4.3.2: the restart ends listen-only mode without an answer, and clears the counters.
    assert_eq!(sim.handle_frame(&frame("11 08 00 01 00 00")), None);
    assert!(!sim.is_listen_only());
    assert_eq!(
        sim.handle_frame(&frame("11 04 03 EC 00 03")),
        Some(frame("11 04 06 04 2A 00 8C 10 3E"))
    );
    assert_eq!(sim.counters().slave_messages, 1);
}

#[test]
fn diagnostics_sub_functions() {
    let mut sim = KsVarioSim::default();
    // 00 echoes any data.
    assert_eq!(
        sim.handle_frame(&frame("11 08 00 00 A5 5A")),
        Some(frame("11 08 00 00 A5 5A"))
    );
    // 02 the diagnostic register; 0A clears; 0D counts exceptions.
    assert_eq!(
        sim.handle_frame(&frame("11 08 00 02 00 00")),
        Some(frame("11 08 00 02 00 00"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 03 00 00 00 01")),
        Some(frame("11 83 02"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 08 00 0D 00 00")),
        Some(frame("11 08 00 0D 00 01"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 08 00 0E 00 00")),
        Some(frame("11 08 00 0E 00 05"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 08 00 0A 00 00")),
        Some(frame("11 08 00 0A 00 00"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 08 00 0E 00 00")),
        Some(frame("11 08 00 0E 00 01"))
    );
    for sub in [0x0F, 0x10, 0x11, 0x40, 0x41] {
        assert_eq!(
            sim.handle_frame(&frame(&format!("11 08 00 {sub:02X} 00 00"))),
            Some(frame(&format!("11 08 00 {sub:02X} 00 00"))),
            "sub-function {sub:02X}"
        );
    }
    // Counters as fix point (x 10) and float (001 4.3 "Anfrage im Integerformat / Floatformat").
    assert_eq!(
        sim.handle_frame(&frame("11 08 40 0E 00 00")),
        Some(frame("11 08 40 0E 00 46"))
    );
    let mut float = vec![0x11, 0x08, 0x80, 0x0E];
    float.extend_from_slice(&8f32.to_be_bytes());
    assert_eq!(
        sim.handle_frame(&frame("11 08 80 0E 00 00")),
        Some(with_crc(&float))
    );
    // Unknown sub-function 01; data other than 00 00 03.
    assert_eq!(
        sim.handle_frame(&frame("11 08 00 03 00 00")),
        Some(frame("11 88 01"))
    );
    assert_eq!(
        sim.handle_frame(&frame("11 08 00 0B 00 01")),
        Some(frame("11 88 03"))
    );
}
