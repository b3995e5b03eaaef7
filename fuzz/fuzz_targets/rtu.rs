//! The RTU frame decoder and the frame length rules (proto_core::fuzzing::fuzz_rtu).

#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| proto_core::fuzzing::fuzz_rtu(data));
