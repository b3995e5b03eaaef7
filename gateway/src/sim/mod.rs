//! See the crate documentation.
//!
//! - [`master`]: a simulated serial Modbus master polling the gateway's slave line (demo).

pub mod master;
