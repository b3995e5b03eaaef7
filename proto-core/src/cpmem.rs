//! The CP memory areas (M, Q, I, T, C, DBs) and the Modbus slave address conversion (manual 003, 6.4.8).
