use std::time::{Duration, SystemTime};

use proto_core::event::ids;
use proto_core::modbus::pdu::{ExceptionCode, Request, Response};
use tokio::sync::mpsc;

use super::layout::*;
use super::*;
use crate::protocols::telegram::{Command, MailboxUnit, TelegramClient, TelegramSendError};

impl Mailbox {
    /// The last sequence number acknowledged (0 before the first).
    fn last_acknowledged(&self) -> u16 {
        self.lock().last_acked
    }
}

fn mailbox(depth: usize, overflow: Overflow) -> Arc<Mailbox> {
    Mailbox::new(
        "test",
        MailboxSettings {
            queue_depth: depth,
            overflow,
            ack: AckMode::Explicit,
        },
        250,
    )
}

fn journaled(path: &std::path::Path, depth: usize, overflow: Overflow) -> (Arc<Mailbox>, Restored) {
    Mailbox::with_journal(
        "test",
        MailboxSettings {
            queue_depth: depth,
            overflow,
            ack: AckMode::Explicit,
        },
        250,
        path,
    )
    .expect("journal")
}

fn waiting_of(mailbox: &Mailbox) -> Vec<(u16, Vec<u8>)> {
    mailbox
        .waiting()
        .iter()
        .map(|t| (t.seq, t.data.to_vec()))
        .collect()
}

#[test]
fn a_journaled_mailbox_comes_back_with_its_telegrams_and_numbers() {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("mb.journal");
    let before = {
        let (mb, restored) = journaled(&path, 3, Overflow::DropOldest);
        assert_eq!(restored, Restored::default());
        for text in ["a", "b", "c", "d", "e"] {
            mb.try_deliver(text.as_bytes().to_vec(), SystemTime::now())
                .expect("journaled");
        }
        mb.ack(3).expect("ack the oldest");
        waiting_of(&mb)
    };
    assert_eq!(before, [(4, b"d".to_vec()), (5, b"e".to_vec())]);
    let (mb, restored) = journaled(&path, 3, Overflow::DropOldest);
    assert_eq!((restored.telegrams, restored.last_seq), (2, 5));
    assert_eq!(waiting_of(&mb), before);
    assert_eq!(mb.last_acknowledged(), 3);
    // The numbering goes on; a repeated acknowledgement is still accepted.
    mb.ack(3).expect("repeated ack");
    assert_eq!(
        mb.try_deliver(b"f".to_vec(), SystemTime::now())
            .expect("journaled"),
        Delivery::Kept { seq: 6 }
    );
}

#[test]
fn a_number_given_to_a_dropped_telegram_is_not_given_again_after_a_restart() {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("mb.journal");
    {
        let (mb, _) = journaled(&path, 1, Overflow::DropNew);
        mb.try_deliver(b"kept".to_vec(), SystemTime::now())
            .expect("journaled");
        assert_eq!(
            mb.try_deliver(b"dropped".to_vec(), SystemTime::now())
                .expect("journaled"),
            Delivery::DroppedNew { seq: 2 }
        );
    }
    let (mb, restored) = journaled(&path, 1, Overflow::DropNew);
    assert_eq!(restored.last_seq, 2);
    assert_eq!(waiting_of(&mb), [(1, b"kept".to_vec())]);
    mb.ack(1).expect("ack");
    assert_eq!(
        mb.try_deliver(b"next".to_vec(), SystemTime::now())
            .expect("journaled"),
        Delivery::Kept { seq: 3 }
    );
}

fn deliver(mailbox: &Mailbox, text: &str) -> Delivery {
    mailbox.deliver(text.as_bytes().to_vec(), SystemTime::now())
}

fn read(mailbox: &Mailbox, address: u16, quantity: u16) -> Vec<u16> {
    mailbox
        .read_registers(address, quantity)
        .expect("a read inside the layout")
}

#[test]
fn sequence_numbers_start_at_one_and_skip_zero_when_they_wrap() {
    assert_eq!(next_seq(0), 1);
    assert_eq!(next_seq(41), 42);
    assert_eq!(next_seq(u16::MAX), 1);
}

#[test]
fn the_oldest_telegram_stays_until_its_number_is_acknowledged() {
    let mb = mailbox(8, Overflow::Refuse);
    assert_eq!(read(&mb, RX_SEQ, 3), [0, 0, 0], "nothing waits");
    assert_eq!(deliver(&mb, "ABC"), Delivery::Kept { seq: 1 });
    assert_eq!(deliver(&mb, "second"), Delivery::Kept { seq: 2 });
    // SEQ, LEN, WAITING, then the data two bytes a register, high byte first.
    assert_eq!(read(&mb, RX_SEQ, 5), [1, 3, 2, 0x4142, 0x4300]);
    assert_eq!(
        mb.ack(2),
        Err(AckError::WrongSeq {
            given: 2,
            expected: Some(1)
        })
    );
    assert!(mb.ack(0).is_err());
    assert_eq!(mb.ack(1), Ok(()));
    assert_eq!(
        mb.ack(1),
        Ok(()),
        "repeating the last acknowledgement is harmless"
    );
    assert_eq!(read(&mb, RX_SEQ, 3), [2, 6, 1]);
    assert_eq!(read(&mb, ACK, 1), [1]);
    assert_eq!(mb.ack(2), Ok(()));
    assert_eq!(read(&mb, RX_SEQ, 4), [0, 0, 0, 0], "old data does not show");
    assert_eq!(mb.counters().acknowledged, 2);
    assert_eq!(mb.counters().received, 2);
}

#[test]
fn a_full_queue_follows_its_policy() {
    let refuse = mailbox(2, Overflow::Refuse);
    deliver(&refuse, "a");
    assert!(refuse.accepts());
    deliver(&refuse, "b");
    assert!(
        !refuse.accepts(),
        "refuse: the line leaves the next one with the driver"
    );

    let new = mailbox(2, Overflow::DropNew);
    deliver(&new, "a");
    deliver(&new, "b");
    assert!(new.accepts());
    assert_eq!(deliver(&new, "c"), Delivery::DroppedNew { seq: 3 });
    assert_eq!(
        new.waiting().iter().map(|t| t.seq).collect::<Vec<_>>(),
        [1, 2]
    );

    let oldest = mailbox(2, Overflow::DropOldest);
    deliver(&oldest, "a");
    deliver(&oldest, "b");
    assert_eq!(
        deliver(&oldest, "c"),
        Delivery::DroppedOldest { seq: 3, dropped: 1 }
    );
    let waiting: Vec<_> = oldest.waiting().iter().map(|t| t.seq).collect();
    assert_eq!(waiting, [2, 3]);

    // Overwriting allowed (003 6.2.1, one buffer): the new telegram replaces the held one.
    let overwrite = mailbox(1, Overflow::Overwrite);
    deliver(&overwrite, "a");
    assert!(overwrite.accepts());
    assert_eq!(
        deliver(&overwrite, "b"),
        Delivery::Overwritten {
            seq: 2,
            replaced: 1
        }
    );
    let held: Vec<_> = overwrite.waiting().iter().map(|t| t.seq).collect();
    assert_eq!(held, [2]);
    assert_eq!(
        oldest.ack(1),
        Err(AckError::WrongSeq {
            given: 1,
            expected: Some(2)
        }),
        "a dropped telegram cannot be acknowledged"
    );
}

#[test]
fn depth_is_clamped_to_the_manuals_range() {
    assert_eq!(mailbox(0, Overflow::Refuse).settings().queue_depth, 1);
    assert_eq!(mailbox(1000, Overflow::Refuse).settings().queue_depth, 250);
}

#[test]
fn subscribers_see_every_telegram_with_its_number() {
    let mb = mailbox(1, Overflow::DropNew);
    let mut rx = mb.subscribe();
    deliver(&mb, "a");
    deliver(&mb, "b");
    let first = rx.try_recv().expect("first");
    let second = rx
        .try_recv()
        .expect("second, dropped from the queue but observed");
    assert_eq!((first.seq, &*first.data), (1, &b"a"[..]));
    assert_eq!((second.seq, &*second.line), (2, "test"));
}

#[test]
fn counters_status_and_settings_are_registers() {
    let mb = mailbox(5, Overflow::DropOldest);
    for _ in 0..3 {
        deliver(&mb, "x");
    }
    mb.count_overflow();
    mb.count_send(true, 4);
    mb.count_send(false, 4);
    mb.set_status_word(ids::NO_FREE_RECEIVE_BUFFER.status_word());
    mb.set_port_open(true);
    assert_eq!(read(&mb, RX_STATUS, 1), [0x080A]);
    assert_eq!(
        read(&mb, DIAG_RECEIVED, DIAG_END - DIAG_RECEIVED),
        [0, 3, 0, 1, 0, 1, 0, 1, 5, 2, 1, 250]
    );
    for (address, quantity) in [
        (RX_END, 1),
        (RX_END - 1, 2),
        (DIAG_END, 1),
        (ACK, 2),
        (0, 600),
    ] {
        assert_eq!(
            mb.read_registers(address, quantity),
            Err(ExceptionCode::IllegalDataAddress),
            "{address}+{quantity}"
        );
    }
}

/// A mailbox unit whose line is played by the test: sends arrive on the returned receiver.
fn unit(max_len: usize) -> (MailboxUnit, mpsc::Receiver<Command>) {
    let (tx, rx) = mpsc::channel(4);
    let mb = Mailbox::new("test", MailboxSettings::default(), max_len);
    let client = TelegramClient::new(Arc::from("test"), tx, 4);
    (MailboxUnit::new(mb, client), rx)
}

fn write(unit: &MailboxUnit, address: u16, values: &[u16]) -> Result<Response, ExceptionCode> {
    unit.answer(Request::WriteMultipleRegisters {
        address,
        values: values.to_vec(),
    })
}

fn send_block(unit: &MailboxUnit) -> Vec<u16> {
    read(unit.mailbox(), TX_DONE, 5)
}

async fn settle(unit: &MailboxUnit, req: u16) {
    for _ in 0..100 {
        if send_block(unit)[4] == req && send_block(unit)[3] == 0 {
            return;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    panic!("request {req} did not finish: {:?}", send_block(unit));
}

#[tokio::test]
async fn the_send_block_sends_on_a_new_request_and_shows_the_result() {
    let (unit, mut line) = unit(250);
    // REQ, LEN, DATA in one write.
    let answer = write(&unit, TX_REQ, &[1, 3, 0x4142, 0x4300]);
    assert_eq!(
        answer,
        Ok(Response::WriteMultipleRegisters {
            address: TX_REQ,
            quantity: 4
        })
    );
    assert_eq!(send_block(&unit), [0, 0, 0, 1, 0], "BUSY");
    let Some(Command::Send { data, reply }) = line.recv().await else {
        panic!("a send");
    };
    assert_eq!(data, b"ABC");

    // A new request while busy is refused; the same value again starts nothing.
    assert_eq!(
        write(&unit, TX_REQ, &[2]),
        Err(ExceptionCode::ServerDeviceBusy)
    );
    assert_eq!(
        read(unit.mailbox(), TX_REQ, 1),
        [1],
        "the refused write changed nothing"
    );
    assert!(write(&unit, TX_REQ, &[1]).is_ok());
    // DATA may be prepared while busy.
    assert!(write(&unit, TX_LEN, &[2, 0x5859]).is_ok());

    reply.send(Ok(())).expect("the mailbox waits");
    settle(&unit, 1).await;
    assert_eq!(send_block(&unit), [1, 0, 0, 0, 1], "DONE for request 1");

    // The next request fails at the line: ERROR and the event's STATUS word.
    assert!(unit
        .answer(Request::WriteSingleRegister {
            address: TX_REQ,
            value: 2
        })
        .is_ok());
    let Some(Command::Send { data, reply }) = line.recv().await else {
        panic!("a send");
    };
    assert_eq!(data, b"XY");
    let _ = reply.send(Err(TelegramSendError::Failed {
        event: ids::SEND_ATTEMPTS_EXHAUSTED,
        first: ids::SEND_END_TIMEOUT,
    }));
    settle(&unit, 2).await;
    assert_eq!(send_block(&unit), [0, 1, 0x070A, 0, 2]);
    assert!(line.try_recv().is_err(), "nothing else was sent");
}

#[tokio::test]
async fn a_length_the_line_cannot_send_ends_in_error_without_sending() {
    let (unit, mut line) = unit(4);
    assert!(write(&unit, TX_REQ, &[1, 0]).is_ok());
    assert_eq!(send_block(&unit), [0, 1, 0x1E41, 0, 1], "LEN 0: 1E 41h");
    assert!(write(&unit, TX_REQ, &[2, 5]).is_ok());
    assert_eq!(send_block(&unit), [0, 1, 0x0517, 0, 2], "LEN 5 > 4: 05 17h");
    assert_eq!(
        write(&unit, TX_LEN, &[1025]),
        Err(ExceptionCode::IllegalDataValue)
    );
    assert_eq!(unit.mailbox().counters().send_failed, 2);
    assert!(line.try_recv().is_err());
}

#[tokio::test]
async fn a_full_line_queue_is_busy_and_changes_nothing() {
    let (unit, _line) = unit(250);
    let client = unit.client().clone();
    for _ in 0..4 {
        client.try_send(b"fill".to_vec()).expect("room");
    }
    assert_eq!(
        write(&unit, TX_REQ, &[1, 1, 0x4100]),
        Err(ExceptionCode::ServerDeviceBusy)
    );
    assert_eq!(read(unit.mailbox(), TX_REQ, 3), [0, 0, 0]);
}

#[test]
fn acknowledge_by_write_and_fetch_the_next_in_one_exchange() {
    let (unit, _line) = unit(250);
    deliver(unit.mailbox(), "one");
    deliver(unit.mailbox(), "two");
    assert_eq!(
        unit.answer(Request::WriteSingleRegister {
            address: ACK,
            value: 2
        }),
        Err(ExceptionCode::IllegalDataValue),
        "not the oldest"
    );
    assert_eq!(
        unit.answer(Request::WriteSingleRegister {
            address: ACK,
            value: 1
        }),
        Ok(Response::WriteSingleRegister {
            address: ACK,
            value: 1
        })
    );
    // FC 23: acknowledge 2, read the receive block header: nothing left.
    assert_eq!(
        unit.answer(Request::ReadWriteMultipleRegisters {
            read_address: RX_STATUS,
            read_quantity: 4,
            write_address: ACK,
            values: vec![2],
        }),
        Ok(Response::ReadWriteMultipleRegisters(vec![0, 0, 0, 0]))
    );
    // A bad read part changes nothing.
    deliver(unit.mailbox(), "three");
    assert_eq!(
        unit.answer(Request::ReadWriteMultipleRegisters {
            read_address: RX_END,
            read_quantity: 1,
            write_address: ACK,
            values: vec![3],
        }),
        Err(ExceptionCode::IllegalDataAddress)
    );
    assert_eq!(unit.mailbox().len(), 1);
    assert_eq!(
        unit.answer(Request::ReadInputRegisters {
            address: 0,
            quantity: 1
        }),
        Err(ExceptionCode::IllegalFunction)
    );
    assert_eq!(
        write(&unit, RX_SEQ, &[1]),
        Err(ExceptionCode::IllegalDataAddress)
    );
}

#[tokio::test]
async fn a_line_without_sends_refuses_the_send_block_and_its_client_refuses_every_send() {
    use crate::unit::UnitService;

    let (tx, mut line) = mpsc::channel(4);
    let mb = Mailbox::new("quiet", MailboxSettings::default(), 250);
    let client = TelegramClient::new(Arc::from("quiet"), tx, 4).with_sends(false);
    assert!(matches!(
        client.try_send(b"AB".to_vec()),
        Err(TelegramSendError::NotAllowed { .. })
    ));
    let unit = MailboxUnit::new(mb, client);
    let fc16 = |address: u16, values: &[u16]| Request::WriteMultipleRegisters {
        address,
        values: values.to_vec(),
    };
    // Any write touching REQ..TX_DATA's end: refused before it is served.
    for request in [
        fc16(TX_REQ, &[1, 2, 0x4142]),
        fc16(TX_REQ - 1, &[0, 1]),
        fc16(TX_REQ + 2, &[0x4142]),
        fc16(TX_REQ + 513, &[0x4142]),
    ] {
        assert_eq!(
            unit.refuses(&request),
            Some(ExceptionCode::IllegalFunction),
            "{request:?}"
        );
    }
    // Reads and the acknowledgement are not sends.
    for request in [
        Request::ReadHoldingRegisters {
            address: TX_REQ,
            quantity: 2,
        },
        Request::WriteSingleRegister {
            address: 600,
            value: 1,
        },
        fc16(TX_REQ + 514, &[0x4142]),
    ] {
        assert_eq!(unit.refuses(&request), None, "{request:?}");
    }
    // Served anyway (a path that skipped the check), the line client still refuses: 01.
    assert_eq!(
        write(&unit, TX_REQ, &[1, 2, 0x4142]),
        Err(ExceptionCode::IllegalFunction)
    );
    assert!(line.try_recv().is_err(), "nothing reached the line");
}

#[test]
fn what_a_line_carries_waits_again_under_its_numbers_and_the_numbering_goes_on() {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("old.journal");
    let (old, _) = journaled(&path, 5, Overflow::Refuse);
    for i in 0..5u8 {
        old.try_deliver(vec![i], SystemTime::now())
            .expect("journaled");
    }
    old.ack(1).expect("ack");
    let carried = old.carry();
    assert_eq!(
        carried.telegrams.iter().map(|t| t.seq).collect::<Vec<_>>(),
        [2, 3, 4, 5]
    );
    assert_eq!((carried.last_seq, carried.last_acked), (5, 1));
    assert_eq!(carried.journal.as_deref(), Some(path.as_path()));
    // In memory, with a smaller depth: all wait; a full mailbox refuses until fewer wait.
    let new = Mailbox::with_carried(
        "test",
        MailboxSettings {
            queue_depth: 2,
            overflow: Overflow::Refuse,
            ack: AckMode::Explicit,
        },
        250,
        carried,
    );
    assert_eq!(
        waiting_of(&new),
        [(2, vec![1]), (3, vec![2]), (4, vec![3]), (5, vec![4])]
    );
    assert!(!new.accepts());
    assert_eq!(new.last_acknowledged(), 1);
    for seq in 2..=4 {
        new.ack(seq).expect("ack");
    }
    assert!(new.accepts());
    assert_eq!(
        new.deliver(vec![9], SystemTime::now()),
        Delivery::Kept { seq: 6 }
    );
}
