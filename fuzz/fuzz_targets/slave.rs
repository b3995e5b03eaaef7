//! The Modbus slave RTU engine fed a script of bytes, pauses, timeouts and line faults
//! (proto_core::fuzzing::fuzz_slave).

#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| proto_core::fuzzing::fuzz_slave(data));
