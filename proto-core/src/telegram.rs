//! The ASCII telegram driver (manual 003, 6.2), sans-IO.
