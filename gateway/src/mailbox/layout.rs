//! The register layout of a telegram mailbox (holding registers of the line's unit id).
//!
//! | address | block | meaning | access |
//! |---|---|---|---|
//! | 0 | receive | STATUS word of the line's newest event (7.2: bits 12..8 class, 7..0 number; 0 = none) | read |
//! | 1 | receive | SEQ: sequence number of the oldest unacknowledged telegram, 1..65535 (0 = none waiting) | read |
//! | 2 | receive | LEN: its length in bytes (0 = none waiting) | read |
//! | 3 | receive | WAITING: telegrams waiting, this one included | read |
//! | 4..515 | receive | DATA: the telegram, two bytes a register, high byte first, the last odd byte in the high byte, zero beyond LEN | read |
//! | 520..521 | counters | telegrams received (32 bit, high word first) | read |
//! | 522..523 | counters | overflows: telegrams dropped or refused because the mailbox was full | read |
//! | 524..525 | counters | telegrams sent (every client: Modbus TCP, REST, zenoh) | read |
//! | 526..527 | counters | sends failed | read |
//! | 528 | counters | queue depth configured | read |
//! | 529 | counters | overflow policy: 0 refuse, 1 drop the new telegram, 2 drop the oldest, 3 overwrite | read |
//! | 530 | counters | port open: 1, closed: 0 | read |
//! | 531 | counters | longest telegram the line sends, in bytes | read |
//! | 600 | acknowledge | ACK: write SEQ to release that telegram; reads the last acknowledged SEQ | read/write |
//! | 1000 | send | DONE: 1 when request RESULT_REQ was sent without error | read |
//! | 1001 | send | ERROR: 1 when request RESULT_REQ failed | read |
//! | 1002 | send | STATUS: the event that failed it (7.2 STATUS word), 0 when done | read |
//! | 1003 | send | BUSY: 1 while a request is being sent | read |
//! | 1004 | send | RESULT_REQ: the request DONE / ERROR / STATUS belong to | read |
//! | 1005..1007 | send | reserved, read as 0 | read |
//! | 1008 | send | REQ: write a value other than the current one to send DATA[..LEN] | read/write |
//! | 1009 | send | LEN: bytes to send, 0..1024 | read/write |
//! | 1010..1521 | send | DATA: the telegram to send, two bytes a register, high byte first | read/write |
//!
//! REQ, LEN and DATA are adjacent and in that order so that one FC 16 writes a short telegram
//! whole (the registers are written first, then a changed REQ starts the send). Any address not
//! in the table answers exception 02, a write to a read-only register 02, a LEN above 1024 03.

use proto_core::modbus::pdu::ExceptionCode;

/// STATUS word of the line's newest event.
pub const RX_STATUS: u16 = 0;
/// Sequence number of the oldest unacknowledged telegram (0 = none).
pub const RX_SEQ: u16 = 1;
/// Its length in bytes.
pub const RX_LEN: u16 = 2;
/// Telegrams waiting.
pub const RX_WAITING: u16 = 3;
/// First data register of the receive block.
pub const RX_DATA: u16 = 4;
/// Data registers of a block: 1024 bytes (7.2, 1E 41h: LEN "1 to 1024 bytes").
pub const DATA_REGISTERS: u16 = 512;
/// The most bytes a block holds.
pub const MAX_DATA_BYTES: usize = 2 * DATA_REGISTERS as usize;
/// One past the receive block.
pub const RX_END: u16 = RX_DATA + DATA_REGISTERS;

/// Telegrams received (u32, high word first).
pub const DIAG_RECEIVED: u16 = 520;
/// Overflows (u32).
pub const DIAG_OVERFLOWS: u16 = 522;
/// Telegrams sent (u32).
pub const DIAG_SENT: u16 = 524;
/// Sends failed (u32).
pub const DIAG_SEND_FAILED: u16 = 526;
/// Queue depth.
pub const DIAG_QUEUE_DEPTH: u16 = 528;
/// Overflow policy code.
pub const DIAG_OVERFLOW_POLICY: u16 = 529;
/// Port open.
pub const DIAG_PORT_OPEN: u16 = 530;
/// Longest telegram sent.
pub const DIAG_MAX_LEN: u16 = 531;
/// One past the counters.
pub const DIAG_END: u16 = 532;

/// The acknowledge register.
pub const ACK: u16 = 600;

/// DONE of the send block.
pub const TX_DONE: u16 = 1000;
/// ERROR of the send block.
pub const TX_ERROR: u16 = 1001;
/// STATUS of the send block.
pub const TX_STATUS: u16 = 1002;
/// BUSY of the send block.
pub const TX_BUSY: u16 = 1003;
/// The request the result belongs to.
pub const TX_RESULT_REQ: u16 = 1004;
/// The request register.
pub const TX_REQ: u16 = 1008;
/// The length register.
pub const TX_LEN: u16 = 1009;
/// First data register of the send block.
pub const TX_DATA: u16 = 1010;
/// One past the send block.
pub const TX_END: u16 = TX_DATA + DATA_REGISTERS;

/// The register a read address names.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Reg {
    RxStatus,
    RxSeq,
    RxLen,
    RxWaiting,
    /// Receive data register `n` (bytes 2n, 2n + 1).
    RxData(usize),
    /// A 32-bit counter's high (true) or low word.
    Received(bool),
    Overflows(bool),
    Sent(bool),
    SendFailed(bool),
    QueueDepth,
    OverflowPolicy,
    PortOpen,
    MaxLen,
    Ack,
    TxDone,
    TxError,
    TxStatus,
    TxBusy,
    TxResultReq,
    TxReserved,
    TxReq,
    TxLen,
    /// Send data register `n`.
    TxData(usize),
}

/// The register at `address`, `None` where the layout has none.
pub(crate) fn reg(address: u16) -> Option<Reg> {
    let index = |start: u16| usize::from(address - start);
    Some(match address {
        RX_STATUS => Reg::RxStatus,
        RX_SEQ => Reg::RxSeq,
        RX_LEN => Reg::RxLen,
        RX_WAITING => Reg::RxWaiting,
        RX_DATA..RX_END => Reg::RxData(index(RX_DATA)),
        520 => Reg::Received(true),
        521 => Reg::Received(false),
        522 => Reg::Overflows(true),
        523 => Reg::Overflows(false),
        524 => Reg::Sent(true),
        525 => Reg::Sent(false),
        526 => Reg::SendFailed(true),
        527 => Reg::SendFailed(false),
        DIAG_QUEUE_DEPTH => Reg::QueueDepth,
        DIAG_OVERFLOW_POLICY => Reg::OverflowPolicy,
        DIAG_PORT_OPEN => Reg::PortOpen,
        DIAG_MAX_LEN => Reg::MaxLen,
        ACK => Reg::Ack,
        TX_DONE => Reg::TxDone,
        TX_ERROR => Reg::TxError,
        TX_STATUS => Reg::TxStatus,
        TX_BUSY => Reg::TxBusy,
        TX_RESULT_REQ => Reg::TxResultReq,
        1005..TX_REQ => Reg::TxReserved,
        TX_REQ => Reg::TxReq,
        TX_LEN => Reg::TxLen,
        TX_DATA..TX_END => Reg::TxData(index(TX_DATA)),
        _ => return None,
    })
}

/// The registers of a read: every address must be in the layout (else 02).
pub(crate) fn read_span(address: u16, quantity: u16) -> Result<Vec<Reg>, ExceptionCode> {
    (u32::from(address)..u32::from(address) + u32::from(quantity))
        .map(|a| {
            u16::try_from(a)
                .ok()
                .and_then(reg)
                .ok_or(ExceptionCode::IllegalDataAddress)
        })
        .collect()
}

/// What a write does.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum WritePlan {
    /// Acknowledge this sequence number.
    Ack(u16),
    /// Write the send block's registers from `offset` (0 = REQ, 1 = LEN, 2.. = DATA).
    SendBlock { offset: usize, values: Vec<u16> },
}

/// Checks a write of `values` at `address` against the layout: the acknowledge register alone,
/// or registers of REQ, LEN and DATA only (02 otherwise); a LEN above 1024 is 03.
pub(crate) fn plan_write(address: u16, values: &[u16]) -> Result<WritePlan, ExceptionCode> {
    let end = u32::from(address) + u32::try_from(values.len()).unwrap_or(u32::MAX);
    if address == ACK {
        return match values {
            [seq] => Ok(WritePlan::Ack(*seq)),
            _ => Err(ExceptionCode::IllegalDataAddress),
        };
    }
    if values.is_empty() || address < TX_REQ || end > u32::from(TX_END) {
        return Err(ExceptionCode::IllegalDataAddress);
    }
    let offset = usize::from(address - TX_REQ);
    let len_index = usize::from(TX_LEN - TX_REQ);
    if let Some(&len) = len_index.checked_sub(offset).and_then(|i| values.get(i)) {
        if usize::from(len) > MAX_DATA_BYTES {
            return Err(ExceptionCode::IllegalDataValue);
        }
    }
    Ok(WritePlan::SendBlock {
        offset,
        values: values.to_vec(),
    })
}

/// Register `n` of a data block holding `data`: bytes 2n (high) and 2n + 1 (low), zero beyond.
pub(crate) fn data_word(data: &[u8], n: usize) -> u16 {
    let byte = |i: usize| data.get(i).copied().unwrap_or(0);
    u16::from_be_bytes([byte(2 * n), byte(2 * n + 1)])
}

/// The bytes of `len` bytes held in data registers, high byte first.
pub(crate) fn data_bytes(words: &[u16], len: usize) -> Vec<u8> {
    words
        .iter()
        .flat_map(|w| w.to_be_bytes())
        .take(len)
        .collect()
}

/// High (true) or low word of a 32-bit counter (saturating at `u32::MAX`).
pub(crate) fn counter_word(value: u64, high: bool) -> u16 {
    let value = u32::try_from(value).unwrap_or(u32::MAX);
    let [a, b, c, d] = value.to_be_bytes();
    if high {
        u16::from_be_bytes([a, b])
    } else {
        u16::from_be_bytes([c, d])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_block_and_only_them() {
        assert_eq!(reg(0), Some(Reg::RxStatus));
        assert_eq!(reg(4), Some(Reg::RxData(0)));
        assert_eq!(reg(515), Some(Reg::RxData(511)));
        assert_eq!(reg(516), None);
        assert_eq!(reg(519), None);
        assert_eq!(reg(520), Some(Reg::Received(true)));
        assert_eq!(reg(531), Some(Reg::MaxLen));
        assert_eq!(reg(532), None);
        assert_eq!(reg(599), None);
        assert_eq!(reg(600), Some(Reg::Ack));
        assert_eq!(reg(601), None);
        assert_eq!(reg(999), None);
        assert_eq!(reg(1006), Some(Reg::TxReserved));
        assert_eq!(reg(1010), Some(Reg::TxData(0)));
        assert_eq!(reg(1521), Some(Reg::TxData(511)));
        assert_eq!(reg(1522), None);
        assert_eq!(reg(u16::MAX), None);
        assert_eq!(read_span(0, 4).map(|r| r.len()), Ok(4));
        assert_eq!(
            read_span(514, 4),
            Err(ExceptionCode::IllegalDataAddress),
            "a read into the gap after the receive data"
        );
        assert_eq!(
            read_span(u16::MAX, 2),
            Err(ExceptionCode::IllegalDataAddress)
        );
    }

    #[test]
    fn writes_go_to_the_acknowledge_register_or_the_send_block_only() {
        assert_eq!(plan_write(ACK, &[7]), Ok(WritePlan::Ack(7)));
        assert_eq!(
            plan_write(ACK, &[7, 8]),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            plan_write(RX_SEQ, &[1]),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            plan_write(TX_DONE, &[1]),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            plan_write(TX_BUSY, &[0; 6]),
            Err(ExceptionCode::IllegalDataAddress),
            "a write that starts on a read-only register"
        );
        assert_eq!(
            plan_write(TX_REQ, &[1, 3, 0x4142, 0x4300]),
            Ok(WritePlan::SendBlock {
                offset: 0,
                values: vec![1, 3, 0x4142, 0x4300]
            })
        );
        assert_eq!(
            plan_write(TX_LEN, &[1025]),
            Err(ExceptionCode::IllegalDataValue)
        );
        assert!(plan_write(TX_LEN, &[1024]).is_ok());
        assert!(plan_write(TX_END - 1, &[0]).is_ok());
        assert_eq!(
            plan_write(TX_END - 1, &[0, 0]),
            Err(ExceptionCode::IllegalDataAddress)
        );
    }

    #[test]
    fn data_is_two_bytes_a_register_high_byte_first() {
        let data = b"ABC";
        assert_eq!(data_word(data, 0), 0x4142);
        assert_eq!(data_word(data, 1), 0x4300);
        assert_eq!(data_word(data, 2), 0);
        assert_eq!(data_bytes(&[0x4142, 0x4300], 3), b"ABC");
        assert_eq!(
            data_bytes(&[0x4142], 3),
            b"AB",
            "never more than the registers"
        );
        assert_eq!(counter_word(0x0001_0002, true), 1);
        assert_eq!(counter_word(0x0001_0002, false), 2);
        assert_eq!(counter_word(u64::MAX, false), 0xFFFF);
    }
}
