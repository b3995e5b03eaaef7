//! The 3964(R) deframer and one 3964(R) station driven by a script of line events
//! (proto_core::fuzzing::fuzz_3964).

#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| proto_core::fuzzing::fuzz_3964(data));
