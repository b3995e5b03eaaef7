//! See the crate documentation.
pub mod telegram;
