//! Opening serial ports with line settings (see the crate documentation).
