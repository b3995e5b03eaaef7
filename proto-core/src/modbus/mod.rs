//! Modbus: the PDU codec, RTU and ASCII framing, and the master engine.

pub mod ascii;
pub mod master;
pub mod pdu;
pub mod rtu;
pub mod slave;
