//! The Modbus ASCII frame decoder and AsciiFrameAssembler (proto_core::fuzzing::fuzz_ascii).

#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| proto_core::fuzzing::fuzz_ascii(data));
