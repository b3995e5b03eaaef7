//! The Modbus master engine (manual 003, 6.4.2 to 6.4.4 and the checks of 7.2), sans-IO.
