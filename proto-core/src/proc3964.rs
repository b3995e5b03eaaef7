//! The 3964(R) procedure (manual 003, 6.3), sans-IO.
