//! The Modbus slave engine (manual 003, 6.4.5 to 6.4.8), sans-IO.
