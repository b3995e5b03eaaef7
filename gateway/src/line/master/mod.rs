//! The Modbus master line.
//!
//! - `build`: from the config's master sections (RTU and ASCII) to the line's settings and its
//!   polled devices, and the start of the line.

pub(crate) mod build;
