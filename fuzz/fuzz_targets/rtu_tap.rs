//! The Modbus RTU tap driven by a script of bus traffic, silences and line errors
//! (proto_core::fuzzing::fuzz_rtu_tap).

#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| proto_core::fuzzing::fuzz_rtu_tap(data));
