//! The 3964(R) tap of a Y-cable driven by a script of both partners' bytes, silences and line errors
//! (proto_core::fuzzing::fuzz_tap_3964).

#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| proto_core::fuzzing::fuzz_tap_3964(data));
