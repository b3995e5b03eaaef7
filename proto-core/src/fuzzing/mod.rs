//! Entry points for the fuzz targets in `fuzz/` (cargo-fuzz), one a decoder or engine.
//!
//! Each `fuzz_*` function takes arbitrary bytes, feeds them to the code under test and checks the
//! properties that must hold for every input: no panic, no endless loop, and the invariants named
//! in the function's doc (round trips, lengths, nothing dropped without being counted). A broken
//! invariant panics, which the fuzzer reports as a crash with the input that caused it.
//!
//! The unit tests (`tests.rs`) run every function on the committed seed corpus
//! (`fuzz/seeds/<target>/`) and on a bounded number of deterministic mutations of it, so that the
//! stable toolchain's `cargo test` exercises the same code the fuzzer does.
//!
//! Compiled with `cfg(fuzzing)` (set by cargo-fuzz), the `fuzzing` feature, or for tests.

mod marks;
mod modbus;
mod slave;
mod tap;
mod telegram;

pub use marks::fuzz_marks;
pub use modbus::{fuzz_ascii, fuzz_pdu, fuzz_rtu};
pub use slave::fuzz_slave;
pub use tap::{fuzz_rtu_tap, fuzz_tap_3964};
pub use telegram::{fuzz_3964, fuzz_telegram};

/// `n` as a `u64` (saturating; `usize` is at most 64 bits on every target we build for).
fn as_u64(n: usize) -> u64 {
    u64::try_from(n).unwrap_or(u64::MAX)
}

#[cfg(test)]
mod tests;
