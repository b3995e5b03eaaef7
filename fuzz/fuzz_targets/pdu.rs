//! The PDU codec: requests, and responses decoded against a request (proto_core::fuzzing::fuzz_pdu).

#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| proto_core::fuzzing::fuzz_pdu(data));
