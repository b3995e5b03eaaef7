//! A named constant for every event of the catalog (manual 003 7.2; identical list in 000 7.2).
//!
//! The names say what happened; the catalog ([`super::lookup`]) holds the manual's text.

use super::EventId;

// --- Class 00h "CP start-up" (7.2) ---

/// 00 03h PtP parameters accepted.
pub const PTP_PARAMS_ACCEPTED: EventId = EventId::new(0x00, 0x03);
/// 00 04h Parameters already on the CP (time stamps match).
pub const PARAMS_ALREADY_ON_CP: EventId = EventId::new(0x00, 0x04);
/// 00 07h CPU went to STOP.
pub const CPU_TO_STOP: EventId = EventId::new(0x00, 0x07);
/// 00 08h CPU went to RUN / START-UP.
pub const CPU_TO_RUN: EventId = EventId::new(0x00, 0x08);

// --- Class 01h "Hardware fault on CP" ---

/// 01 01h Operating system EPROM test failed.
pub const OS_EPROM_TEST_FAILED: EventId = EventId::new(0x01, 0x01);
/// 01 02h RAM test failed.
pub const RAM_TEST_FAILED: EventId = EventId::new(0x01, 0x02);
/// 01 03h Request interface of the CP defective.
pub const REQUEST_INTERFACE_DEFECTIVE: EventId = EventId::new(0x01, 0x03);
/// 01 10h Fault in the CP firmware.
pub const FIRMWARE_FAULT: EventId = EventId::new(0x01, 0x10);

// --- Class 02h "Initialization error" ---

/// 02 0Fh Invalid parameterization at the start of communication.
pub const INVALID_PARAMETERIZATION: EventId = EventId::new(0x02, 0x0F);

// --- Class 03h "Error parameterization of FBs" (not entered in the diagnostic buffer) ---

/// 03 01h Invalid source/destination data type, area or DB at the function block.
pub const INVALID_FB_PARAMETERS: EventId = EventId::new(0x03, 0x01);

// --- Class 04h "CP detected error in data traffic CP - CPU" ---

/// 04 03h Incorrect, unknown or illegal data type.
pub const ILLEGAL_DATA_TYPE: EventId = EventId::new(0x04, 0x03);
/// 04 07h Error during data transfer between CPU and CP.
pub const CPU_TRANSFER_ERROR: EventId = EventId::new(0x04, 0x07);
/// 04 08h Transfer to the CPU temporarily impossible, repeated.
pub const CPU_RECEIVE_RETRY: EventId = EventId::new(0x04, 0x08);
/// 04 09h Transfer to the CPU cancelled after 10 s of attempts.
pub const CPU_RECEIVE_ABORTED: EventId = EventId::new(0x04, 0x09);
/// 04 0Ah Transfer to the CPU cancelled by RESET.
pub const CPU_TRANSFER_RESET: EventId = EventId::new(0x04, 0x0A);

// --- Class 05h "Error while processing CPU request" ---

/// 05 01h Request aborted by a CP restart.
pub const REQUEST_ABORTED_BY_RESTART: EventId = EventId::new(0x05, 0x01);
/// 05 02h Request not permitted in this operating mode.
pub const REQUEST_NOT_PERMITTED: EventId = EventId::new(0x05, 0x02);
/// 05 14h Start address or DB number out of range.
pub const START_ADDRESS_OUT_OF_RANGE: EventId = EventId::new(0x05, 0x14);
/// 05 17h Transfer length too great (> 1 KiB) or too short.
pub const TRANSFER_LENGTH_INVALID: EventId = EventId::new(0x05, 0x17);
/// 05 18h Modbus master: send length too great (> 4 KiB) or too small.
pub const MODBUS_SEND_LENGTH_INVALID: EventId = EventId::new(0x05, 0x18);

// --- Class 07h "Send error" ---

/// 07 01h First repetition of a send.
pub const SEND_REPETITION: EventId = EventId::new(0x07, 0x01);
/// 07 02h 3964(R): connection setup answered with NAK or another code.
pub const SEND_SETUP_REJECTED: EventId = EventId::new(0x07, 0x02);
/// 07 03h 3964(R): no answer to STX within the acknowledgement delay time (QVZ).
pub const SEND_SETUP_TIMEOUT: EventId = EventId::new(0x07, 0x03);
/// 07 04h 3964(R): partner sent characters during the send.
pub const SEND_ABORTED_BY_PARTNER: EventId = EventId::new(0x07, 0x04);
/// 07 06h 3964(R): frame rejected at the end of the connection.
pub const SEND_END_REJECTED: EventId = EventId::new(0x07, 0x06);
/// 07 07h 3964(R): no answer to DLE ETX within the acknowledgement delay time.
pub const SEND_END_TIMEOUT: EventId = EventId::new(0x07, 0x07);
/// 07 08h ASCII driver: waiting time for XON or CTS = ON elapsed.
pub const SEND_FLOW_CONTROL_TIMEOUT: EventId = EventId::new(0x07, 0x08);
/// 07 09h Setup attempts exhausted.
pub const SEND_SETUP_ATTEMPTS_EXHAUSTED: EventId = EventId::new(0x07, 0x09);
/// 07 0Ah Transmission attempts exhausted.
pub const SEND_ATTEMPTS_EXHAUSTED: EventId = EventId::new(0x07, 0x0A);

// --- Class 08h "Receive error" ---

/// 08 01h First repetition expected (the CP answered NAK).
pub const RECEIVE_REPETITION: EventId = EventId::new(0x08, 0x01);
/// 08 02h 3964(R): error during connection setup.
pub const RECEIVE_SETUP_ERROR: EventId = EventId::new(0x08, 0x02);
/// 08 05h 3964(R): code other than DLE or ETX after DLE.
pub const RECEIVE_LOGICAL_ERROR: EventId = EventId::new(0x08, 0x05);
/// 08 06h Character delay time (ZVZ) exceeded.
pub const CHARACTER_DELAY_EXCEEDED: EventId = EventId::new(0x08, 0x06);
/// 08 08h 3964(R): block check character (BCC) wrong.
pub const BCC_ERROR: EventId = EventId::new(0x08, 0x08);
/// 08 0Ah No free receive buffer.
pub const NO_FREE_RECEIVE_BUFFER: EventId = EventId::new(0x08, 0x0A);
/// 08 0Ch Transmission error: parity, stop bit or overrun.
pub const CHARACTER_ERROR: EventId = EventId::new(0x08, 0x0C);
/// 08 0Dh BREAK: receive line interrupted.
pub const LINE_BREAK: EventId = EventId::new(0x08, 0x0D);
/// 08 15h Transmission attempts of CP and partner differ.
pub const ATTEMPTS_MISMATCH: EventId = EventId::new(0x08, 0x15);
/// 08 16h Received frame longer than agreed or than the receive buffer.
pub const FRAME_TOO_LONG: EventId = EventId::new(0x08, 0x16);
/// 08 18h (Modbus) ASCII driver: DSR = OFF or CTS = OFF.
pub const DSR_OR_CTS_OFF: EventId = EventId::new(0x08, 0x18);
/// 08 30h Modbus master: no reply within the reply monitoring time.
pub const MODBUS_NO_REPLY: EventId = EventId::new(0x08, 0x30);
/// 08 31h Modbus master RTU: first reply character is not the addressed slave.
pub const MODBUS_WRONG_SLAVE_CHAR: EventId = EventId::new(0x08, 0x31);
/// 08 32h Modbus master: receive buffer overflow during the reply.
pub const MODBUS_RECEIVE_OVERFLOW: EventId = EventId::new(0x08, 0x32);
/// 08 33h Modbus master ASCII: wrong start character (not ':').
pub const MODBUS_ASCII_WRONG_START: EventId = EventId::new(0x08, 0x33);
/// 08 34h Modbus master ASCII: start character inside a frame.
pub const MODBUS_ASCII_START_IN_FRAME: EventId = EventId::new(0x08, 0x34);

// --- Class 0Eh "Loadable driver - general processing errors" ---

/// 0E 31h Modbus slave: time-out during the data transfer to the CPU.
pub const SLAVE_CPU_TIMEOUT: EventId = EventId::new(0x0E, 0x31);
/// 0E 38h Modbus slave: access to M, Q, T, C or I failed (FC 01/02).
pub const SLAVE_BIT_AREA_ERROR: EventId = EventId::new(0x0E, 0x38);
/// 0E 39h Modbus slave: access to a data block failed (FC 03/04/06/16).
pub const SLAVE_DB_ERROR: EventId = EventId::new(0x0E, 0x39);
/// 0E 40h Modbus master: LEN at SEND too small (minimum 2 bytes).
pub const MASTER_LEN_TOO_SMALL: EventId = EventId::new(0x0E, 0x40);
/// 0E 41h Modbus master: LEN at SEND too small for the function code (minimum 6 bytes).
pub const MASTER_LEN_TOO_SMALL_FOR_FUNCTION: EventId = EventId::new(0x0E, 0x41);
/// 0E 42h Modbus master: illegal function code.
pub const MASTER_ILLEGAL_FUNCTION: EventId = EventId::new(0x0E, 0x42);
/// 0E 43h Modbus master: broadcast not permitted with this function code.
pub const MASTER_BROADCAST_NOT_PERMITTED: EventId = EventId::new(0x0E, 0x43);
/// 0E 44h Modbus master: amount of bits out of range.
pub const MASTER_BIT_COUNT_OUT_OF_RANGE: EventId = EventId::new(0x0E, 0x44);
/// 0E 45h Modbus master: amount of registers out of range.
pub const MASTER_REGISTER_COUNT_OUT_OF_RANGE: EventId = EventId::new(0x0E, 0x45);
/// 0E 46h Modbus master: FC 15/16 amount of bits or registers out of range.
pub const MASTER_WRITE_COUNT_OUT_OF_RANGE: EventId = EventId::new(0x0E, 0x46);
/// 0E 47h Modbus master: FC 15/16 LEN too small for the amount of bits or registers.
pub const MASTER_WRITE_LEN_TOO_SMALL: EventId = EventId::new(0x0E, 0x47);
/// 0E 48h Modbus master: FC 05 value is neither FF00h nor 0000h.
pub const MASTER_COIL_VALUE_INVALID: EventId = EventId::new(0x0E, 0x48);
/// 0E 49h Modbus master: FC 08 diagnostic code other than 0000h.
pub const MASTER_DIAGNOSTIC_CODE_INVALID: EventId = EventId::new(0x0E, 0x49);
/// 0E 4Ah Modbus master ASCII: 32-bit registers with a function code other than 03/06/16.
pub const MASTER_32BIT_FUNCTION_INVALID: EventId = EventId::new(0x0E, 0x4A);
/// 0E 4Fh Modbus master: illegal R_TYP at SEND.
pub const MASTER_ILLEGAL_R_TYP: EventId = EventId::new(0x0E, 0x4F);
/// 0E 50h Modbus master: reply from another slave address.
pub const MODBUS_WRONG_SLAVE: EventId = EventId::new(0x0E, 0x50);
/// 0E 51h Modbus master: reply with another function code.
pub const MODBUS_WRONG_FUNCTION: EventId = EventId::new(0x0E, 0x51);
/// 0E 52h Modbus master: fewer characters than the byte count or function code demand.
pub const MODBUS_BYTE_UNDERFLOW: EventId = EventId::new(0x0E, 0x52);
/// 0E 53h Modbus master: more characters than the byte count or function code demand.
pub const MODBUS_BYTE_OVERFLOW: EventId = EventId::new(0x0E, 0x53);
/// 0E 54h Modbus master: byte count in the reply too small.
pub const MODBUS_BYTE_COUNT_TOO_SMALL: EventId = EventId::new(0x0E, 0x54);
/// 0E 55h Modbus master: byte count in the reply wrong.
pub const MODBUS_BYTE_COUNT_WRONG: EventId = EventId::new(0x0E, 0x55);
/// 0E 56h Modbus master: echoed request data differ.
pub const MODBUS_ECHO_WRONG: EventId = EventId::new(0x0E, 0x56);
/// 0E 57h Modbus master: CRC (ASCII: LRC) of the reply wrong.
pub const MODBUS_CHECKSUM_ERROR: EventId = EventId::new(0x0E, 0x57);
/// 0E 58h Modbus master ASCII: character in the reply is not a hex digit.
pub const MODBUS_ASCII_INVALID_CHARACTER: EventId = EventId::new(0x0E, 0x58);
/// 0E 61h Modbus master: exception 01 illegal function.
pub const MODBUS_EXCEPTION_ILLEGAL_FUNCTION: EventId = EventId::new(0x0E, 0x61);
/// 0E 62h Modbus master: exception 02 illegal data address.
pub const MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS: EventId = EventId::new(0x0E, 0x62);
/// 0E 63h Modbus master: exception 03 illegal data value.
pub const MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE: EventId = EventId::new(0x0E, 0x63);
/// 0E 64h Modbus master: exception 04 failure in associated device.
pub const MODBUS_EXCEPTION_DEVICE_FAILURE: EventId = EventId::new(0x0E, 0x64);
/// 0E 65h Modbus master: exception 05 acknowledge.
pub const MODBUS_EXCEPTION_ACKNOWLEDGE: EventId = EventId::new(0x0E, 0x65);
/// 0E 66h Modbus master: exception 06 busy, rejected message.
pub const MODBUS_EXCEPTION_BUSY: EventId = EventId::new(0x0E, 0x66);
/// 0E 67h Modbus master: exception 07 negative acknowledgement.
pub const MODBUS_EXCEPTION_NEGATIVE_ACK: EventId = EventId::new(0x0E, 0x67);

// --- Class 1Eh "Error during communication between CP and CPU via backplane bus" ---

/// 1E 0Dh Request aborted by restart or reset.
pub const BACKPLANE_REQUEST_ABORTED: EventId = EventId::new(0x1E, 0x0D);
/// 1E 0Eh Static error of SFC 59 RD_REC (read data record).
pub const BACKPLANE_READ_RECORD_ERROR: EventId = EventId::new(0x1E, 0x0E);
/// 1E 0Fh Static error of SFC 58 WR_REC (write data record).
pub const BACKPLANE_WRITE_RECORD_ERROR: EventId = EventId::new(0x1E, 0x0F);
/// 1E 41h LEN of the function block out of 1..1024 bytes.
pub const BACKPLANE_LEN_ILLEGAL: EventId = EventId::new(0x1E, 0x41);
