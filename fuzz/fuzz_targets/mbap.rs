//! The MBAP frame reader and header codec of the Modbus TCP server, with the PDU decoder behind
//! them (gateway::fuzzing::fuzz_mbap).
//!
//! The gateway crate pulls in the whole service (tokio, zenoh, ...), which would be compiled with
//! coverage instrumentation for nothing: this target compiles only the two source files it needs,
//! the MBAP codec and the entry point, at the module paths they expect. Should `mbap.rs` come to use
//! other gateway modules, this fails to build; depend on the gateway crate then.

#![no_main]

use libfuzzer_sys::fuzz_target;

#[allow(dead_code, unreachable_pub)]
#[path = "../../gateway/src/modbus_tcp/mbap.rs"]
mod mbap_source;

/// `crate::modbus_tcp::mbap`, as in the gateway.
mod modbus_tcp {
    pub(crate) use super::mbap_source as mbap;
}

#[allow(dead_code, unreachable_pub)]
#[path = "../../gateway/src/fuzzing.rs"]
mod fuzzing;

fuzz_target!(|data: &[u8]| fuzzing::fuzz_mbap(data));
