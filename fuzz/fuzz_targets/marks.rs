//! The PARMRK mark decoder (proto_core::fuzzing::fuzz_marks).

#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| proto_core::fuzzing::fuzz_marks(data));
