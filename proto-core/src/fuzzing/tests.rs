//! The fuzz entry points on the committed seed corpus (`fuzz/seeds/<target>/`) and on a bounded,
//! deterministic set of mutations of it: what the fuzzer does, in miniature, on every `cargo test`.

use std::path::PathBuf;

use super::slave::run_slave_script;
use super::tap::{run_rtu_tap, run_tap_3964};
use super::telegram::{run_3964, run_telegram};
use super::*;
use crate::modbus::ascii::{self, AsciiEvent, AsciiFrameAssembler};
use crate::modbus::pdu::{Limits, Request, Response};
use crate::modbus::rtu;

/// Mutations tried per seed.
const MUTATIONS_PER_SEED: usize = 200;

/// The seed files of one target, sorted by name; the corpus must not be empty.
fn seeds(target: &str) -> Vec<(String, Vec<u8>)> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/seeds")
        .join(target);
    let mut seeds: Vec<(String, Vec<u8>)> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|entry| {
            let path = entry.expect("directory entry").path();
            let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            (path.display().to_string(), bytes)
        })
        .collect();
    seeds.sort();
    assert!(!seeds.is_empty(), "no seeds in {}", dir.display());
    seeds
}

/// xorshift64*: a small deterministic generator, so a failure reproduces.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn below(&mut self, n: usize) -> usize {
        usize::try_from(self.next() % u64::try_from(n.max(1)).unwrap_or(1)).unwrap_or(0)
    }

    fn byte(&mut self) -> u8 {
        self.next().to_le_bytes()[0]
    }
}

/// One to four of the fuzzer's usual mutations: flip a bit, set a byte (often to an interesting
/// value), insert, delete, duplicate a range, or splice in part of another seed.
fn mutate(rng: &mut Rng, seed: &[u8], other: &[u8]) -> Vec<u8> {
    const INTERESTING: [u8; 10] = [0x00, 0x01, 0x02, 0x7F, 0x80, 0xFF, b':', b'\r', b'\n', 0x10];
    let mut data = seed.to_vec();
    for _ in 0..=rng.below(4) {
        let len = data.len();
        match rng.below(7) {
            0 if len > 0 => {
                let at = rng.below(len);
                data[at] ^= 1 << rng.below(8);
            }
            1 if len > 0 => {
                let at = rng.below(len);
                data[at] = INTERESTING[rng.below(INTERESTING.len())];
            }
            2 => {
                let at = rng.below(len + 1);
                let byte = rng.byte();
                data.insert(at, byte);
            }
            3 if len > 0 => {
                let at = rng.below(len);
                data.remove(at);
            }
            4 if len > 0 => {
                let at = rng.below(len);
                let to = at + rng.below(len - at) + 1;
                let copy = data[at..to].to_vec();
                data.splice(to..to, copy);
            }
            5 if !other.is_empty() => {
                let at = rng.below(other.len());
                let to = at + rng.below(other.len() - at) + 1;
                let cut = rng.below(len + 1);
                data.splice(cut..cut, other[at..to].iter().copied());
            }
            _ => data.truncate(rng.below(len + 1)),
        }
    }
    data
}

/// Runs `target` on every seed and on mutations of it.
fn exercise(name: &str, target: fn(&[u8])) {
    let seeds = seeds(name);
    let mut rng = Rng(0x5EED_0000_0000_0001 ^ as_u64(name.len()));
    for (i, (path, seed)) in seeds.iter().enumerate() {
        target(seed);
        let other = &seeds[(i + 1) % seeds.len()].1;
        for _ in 0..MUTATIONS_PER_SEED {
            let input = mutate(&mut rng, seed, other);
            let outcome = std::panic::catch_unwind(|| target(&input));
            assert!(
                outcome.is_ok(),
                "{name}: input {input:02x?} (a mutation of {path}) panicked"
            );
        }
    }
}

#[test]
fn rtu_seeds_and_mutations() {
    exercise("rtu", fuzz_rtu);
}

#[test]
fn ascii_seeds_and_mutations() {
    exercise("ascii", fuzz_ascii);
}

#[test]
fn pdu_seeds_and_mutations() {
    exercise("pdu", fuzz_pdu);
}

#[test]
fn slave_seeds_and_mutations() {
    exercise("slave", fuzz_slave);
}

#[test]
fn proc3964_seeds_and_mutations() {
    exercise("proc3964", fuzz_3964);
}

#[test]
fn marks_seeds_and_mutations() {
    exercise("marks", fuzz_marks);
}

#[test]
fn rtu_tap_seeds_and_mutations() {
    exercise("rtu_tap", fuzz_rtu_tap);
}

#[test]
fn tap3964_seeds_and_mutations() {
    exercise("tap3964", fuzz_tap_3964);
}

#[test]
fn telegram_seeds_and_mutations() {
    exercise("telegram", fuzz_telegram);
}

#[test]
fn the_3964_seeds_receive_and_send_their_telegrams() {
    for (path, seed) in seeds("proc3964") {
        let report = run_3964(&seed).expect("valid setup");
        if path.ends_with("-received") {
            let expected = usize::from(!path.contains("bad-bcc"));
            assert_eq!(report.received.len(), expected, "{path}: {report:?}");
        } else if path.ends_with("-sent") {
            assert_eq!((report.sent, report.failed), (1, 0), "{path}: {report:?}");
        }
    }
}

#[test]
fn the_telegram_seeds_receive_and_send_their_telegrams() {
    for (path, seed) in seeds("telegram") {
        let report = run_telegram(&seed).expect("valid setup");
        if path.ends_with("-received") {
            assert_eq!(report.received.len(), 1, "{path}: {report:?}");
        } else {
            assert_eq!((report.sent, report.failed), (1, 0), "{path}: {report:?}");
        }
    }
}

#[test]
fn seeds_reach_the_interesting_paths() {
    // The RTU seeds are frames with good CRCs, the ASCII seeds good frames, so the fuzzer starts
    // past the checksums.
    for (path, seed) in seeds("rtu") {
        assert!(rtu::decode_frame(&seed).is_ok(), "{path}");
    }
    for (path, seed) in seeds("ascii") {
        let mut assembler = AsciiFrameAssembler::new();
        let mut events = Vec::new();
        assembler.feed(&seed, &mut events);
        let frames = events
            .iter()
            .filter_map(|e| match e {
                AsciiEvent::Frame(frame) => Some(frame),
                _ => None,
            })
            .filter(|frame| ascii::decode_frame(frame).is_ok())
            .count();
        assert!(frames > 0, "{path}: no good frame");
    }
    // Each PDU seed is a request and its answer.
    for (path, seed) in seeds("pdu") {
        let (&n, rest) = seed.split_first().expect("not empty");
        let (request, response) = rest.split_at(usize::from(n));
        let request = Request::decode_with(request, &Limits::CP_MASTER_RTU).unwrap_or_else(|e| {
            panic!("{path}: request {e}");
        });
        assert!(
            Response::decode_for(&request, response).is_ok(),
            "{path}: response"
        );
    }
}

#[test]
fn the_slave_script_answers_a_request() {
    // Slave 2, multiplier 1, 9600 Bd; receive FC 03 for 1 register at 0 (DB 800 word 0), then
    // follow the deadlines: one answer.
    let mut frame = Vec::new();
    rtu::encode_frame(2, &[0x03, 0x00, 0x00, 0x00, 0x01], &mut frame);
    let mut input = vec![
        2,
        0xA0,
        u8::try_from((frame.len() - 1) << 2).expect("small"),
    ];
    input.extend_from_slice(&frame);
    input.push(0x02);
    assert_eq!(run_slave_script(&input), 1);
    // The same request from another address is ignored.
    input[0] = 3;
    assert_eq!(run_slave_script(&input), 0);
}

/// The tap seeds are exchanges the taps understand: every RTU seed pairs its request with each
/// answer of the vectors and misses the last; the 3964(R) seeds deliver both partners' telegrams,
/// a repetition after a NAK, and the winner of a conflict.
#[test]
fn the_tap_seeds_pair_and_deliver_what_they_carry() {
    for (path, seed) in seeds("rtu_tap") {
        let c = run_rtu_tap(&seed).expect("a setup");
        assert_eq!(c.missing_answers, 1, "{path}: {c:?}");
        assert_eq!((c.bad_crc, c.discarded), (0, 0), "{path}: {c:?}");
        assert_eq!(c.frames, 2 * c.pairs + 1, "{path}: {c:?}");
    }
    assert!(seeds("rtu_tap")
        .iter()
        .any(|(_, seed)| run_rtu_tap(seed).is_some_and(|c| c.pairs >= 2)));
    for (path, seed) in seeds("tap3964") {
        let c = run_tap_3964(&seed).expect("a setup");
        let expected = if path.ends_with("-both-sides") {
            ([1, 1], 0, 0, 0)
        } else if path.ends_with("-nak-repeated") {
            ([1, 0], 1, 1, 0)
        } else {
            ([1, 0], 0, 0, 1)
        };
        assert_eq!(
            (c.telegrams, c.naks, c.repetitions, c.conflicts),
            expected,
            "{path}: {c:?}"
        );
        assert_eq!(
            (c.stray_bytes, c.bad_bcc, c.missing_dle),
            (0, 0, 0),
            "{path}: {c:?}"
        );
    }
}
