//! Modbus ASCII framing (manual 003, 6.4.2.2 and 6.4.4): ':' start, hex, LRC, CR LF.
