//! Modbus RTU framing (manual 003, 6.4.3 "Message structure"; Modbus over Serial Line V1.02, 2.5.1).
