//! Checksums: CRC-16/Modbus (RTU), LRC (Modbus ASCII), BCC (3964R).
