//! The MBAP frame reader and header codec of the Modbus TCP server, with the PDU decoder behind
//! them (gateway::fuzzing::fuzz_mbap).

#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| gateway::fuzzing::fuzz_mbap(data));
