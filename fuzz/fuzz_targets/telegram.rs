//! The ASCII telegram driver driven by a script of line events
//! (proto_core::fuzzing::fuzz_telegram).

#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| proto_core::fuzzing::fuzz_telegram(data));
