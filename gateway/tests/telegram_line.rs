//! Telegram lines against the telegram simulators on the other end of real pty pairs: two
//! proto-core engines of ours talking (3964R and ASCII, both ways), the mailbox read and
//! acknowledged through a real Modbus TCP server by a tokio-modbus client, the send block, the
//! overflow of a full mailbox, and the RS232 signals a pty refuses. Real I/O timing is involved,
//! so these tests run on the real clock.

mod telegram_line {
    pub(crate) mod support;
}

use std::time::Duration;

use gateway::mailbox::{layout, Overflow};
use gateway::protocols::telegram::{spawn_telegram_line, TelegramProtocol, TelegramSendError};
use gateway::serial::Interface;
use gateway::signals::{Output, Signal, SignalError};
use proto_core::event::ids;
use proto_core::telegram::{AsciiParams, AsciiSettings, FlowControl, Interface as EngineInterface};
use tokio_modbus::prelude::*;
use tokio_util::sync::CancellationToken;

use telegram_line::support::*;

fn protocols() -> [TelegramProtocol; 2] {
    [
        TelegramProtocol::P3964(gateway_3964r()),
        TelegramProtocol::Ascii(gateway_ascii()),
    ]
}

// === two engines of ours over a pty pair ===

#[tokio::test]
async fn line_and_partner_exchange_telegrams_both_ways() {
    for protocol in protocols() {
        let name = protocol.name();
        let sim = partner(&protocol).every(ms(20)).limit(3);
        let mut pair = start_pair("t", protocol, mailbox(16, Overflow::Refuse), sim);
        let mailbox = pair.line.mailbox().expect("a telegram line");

        // The partner's own telegrams arrive in order, numbered from 1.
        eventually("three telegrams from the partner", || mailbox.len() == 3).await;
        let waiting = mailbox.waiting();
        let seqs: Vec<u16> = waiting.iter().map(|t| t.seq).collect();
        assert_eq!(seqs, [1, 2, 3], "{name}");
        let expected: Vec<Vec<u8>> = (1..=3)
            .map(|n| match name {
                "ASCII" => format!("ASCII {n:06}\x03").into_bytes(),
                _ => format!("3964R {n:06}").into_bytes(),
            })
            .collect();
        let got: Vec<Vec<u8>> = waiting.iter().map(|t| t.data.to_vec()).collect();
        assert_eq!(got, expected, "{name}");
        for seq in 1..=3 {
            mailbox.ack(seq).expect("the oldest");
        }

        // A telegram of ours reaches the partner, which echoes it back into the mailbox.
        let ours = b"HELLO PARTNER\x03".to_vec();
        let client = pair.line.telegram_client().expect("a telegram line");
        tokio::time::timeout(Duration::from_secs(10), client.send(ours.clone()))
            .await
            .expect("in time")
            .expect("sent");
        assert_eq!(pair.partner_received().await, ours, "{name}");
        eventually("the echo", || mailbox.len() == 1).await;
        let echo = mailbox.head().expect("echo");
        assert_eq!((echo.seq, echo.data.to_vec()), (4, ours), "{name}");

        let status = pair.line.telegram_status().expect("a telegram line");
        assert!(status.line.port_open);
        assert_eq!(status.counters.received, 4);
        assert_eq!(status.counters.sent, 1);
        assert_eq!(status.counters.overflows, 0);
        assert_eq!(status.protocol, name);
        pair.stop().await;
    }
}

#[tokio::test]
async fn a_telegram_longer_than_the_line_allows_is_refused_with_its_event() {
    let sim = partner(&TelegramProtocol::P3964(gateway_3964r())).every(Duration::ZERO);
    let pair = start_pair(
        "t",
        TelegramProtocol::P3964(gateway_3964r()),
        mailbox(4, Overflow::Refuse),
        sim,
    );
    let client = pair.line.telegram_client().expect("a telegram line");
    let err = client
        .send(vec![b'x'; 251])
        .await
        .expect_err("250 bytes at most");
    assert!(matches!(err, TelegramSendError::Refused(_)), "{err:?}");
    assert_eq!(err.event(), ids::TRANSFER_LENGTH_INVALID);
    let err = client.send(Vec::new()).await.expect_err("empty");
    assert_eq!(err.event(), ids::BACKPLANE_LEN_ILLEGAL);
    assert_eq!(
        pair.line
            .telegram_status()
            .expect("a telegram line")
            .counters
            .send_failed,
        2
    );
    pair.stop().await;
}

// === the mailbox over Modbus TCP ===

/// Reads and acknowledges `count` telegrams through the mailbox registers, as a SCADA client
/// would, and checks that they come in order with nothing lost.
async fn read_through_the_mailbox(protocol: TelegramProtocol, count: u16) {
    let name = protocol.name();
    let sim = partner(&protocol)
        .every(ms(1))
        .limit(u64::from(count))
        .echo(false);
    let pair = start_pair("t", protocol, mailbox(64, Overflow::Refuse), sim);
    let server = Server::start(&pair.line);
    let mut client = server.client().await;
    let deadline = tokio::time::Instant::now() + Duration::from_secs(60);
    let mut expected: u16 = 1;
    while expected <= count {
        assert!(
            tokio::time::Instant::now() < deadline,
            "{name}: only {} telegrams in 60 s",
            expected - 1
        );
        // STATUS, SEQ, LEN, WAITING and the first 16 data registers in one read.
        let head = read(&mut client, layout::RX_STATUS, 20).await;
        let (seq, len) = (head[1], usize::from(head[2]));
        if seq == 0 {
            tokio::time::sleep(ms(1)).await;
            continue;
        }
        let events = || {
            pair.line
                .telegram_status()
                .expect("a telegram line")
                .line
                .event_counts
        };
        assert_eq!(
            seq,
            expected,
            "{name}: in order, none lost; events {:?}",
            events()
        );
        let data = bytes(&head[4..], len);
        let text = match name {
            "ASCII" => format!("ASCII {expected:06}\x03"),
            _ => format!("3964R {expected:06}"),
        };
        assert_eq!(
            data,
            text.as_bytes(),
            "{name}: telegram {expected}; events {:?}",
            events()
        );
        client
            .write_single_register(layout::ACK, seq)
            .await
            .expect("transport")
            .expect("the right number is accepted");
        expected += 1;
    }
    let status = pair.line.telegram_status().expect("a telegram line");
    assert_eq!(status.counters.received, u64::from(count), "{name}");
    assert_eq!(status.counters.acknowledged, u64::from(count), "{name}");
    assert_eq!(status.counters.overflows, 0, "{name}");
    assert_eq!(status.waiting, 0);
    // The counters as registers: received (u32) and overflows (u32).
    let diag = read(&mut client, layout::DIAG_RECEIVED, 4).await;
    assert_eq!(diag, [0, count, 0, 0], "{name}");
    pair.stop().await;
}

#[tokio::test]
async fn a_thousand_3964r_telegrams_through_the_mailbox_in_order_none_lost() {
    read_through_the_mailbox(TelegramProtocol::P3964(gateway_3964r()), 1000).await;
}

#[tokio::test]
async fn a_thousand_ascii_telegrams_through_the_mailbox_in_order_none_lost() {
    read_through_the_mailbox(TelegramProtocol::Ascii(gateway_ascii()), 1000).await;
}

#[tokio::test]
async fn a_wrong_acknowledgement_is_exception_03_and_releases_nothing() {
    let protocol = TelegramProtocol::Ascii(gateway_ascii());
    let sim = partner(&protocol).every(ms(10)).limit(2);
    let pair = start_pair("t", protocol, mailbox(8, Overflow::DropNew), sim);
    let server = Server::start(&pair.line);
    let mut client = server.client().await;
    let mailbox = pair.line.mailbox().expect("a telegram line");
    eventually("two telegrams", || mailbox.len() == 2).await;
    let answer = client
        .write_single_register(layout::ACK, 2)
        .await
        .expect("transport");
    assert_eq!(answer, Err(ExceptionCode::IllegalDataValue));
    assert_eq!(mailbox.len(), 2);
    // FC 23: acknowledge 1 and read the next one's header in one exchange.
    let header = client
        .read_write_multiple_registers(layout::RX_STATUS, 4, layout::ACK, &[1])
        .await
        .expect("transport")
        .expect("no exception");
    assert_eq!(&header[1..], [2, 13, 1], "SEQ 2, 13 bytes, 1 waiting");
    let outside = client
        .read_holding_registers(layout::RX_END, 1)
        .await
        .expect("transport");
    assert_eq!(outside, Err(ExceptionCode::IllegalDataAddress));
    pair.stop().await;
}

#[tokio::test]
async fn a_telegram_written_into_the_send_block_arrives_and_done_is_set() {
    for protocol in protocols() {
        let name = protocol.name();
        let sim = partner(&protocol).every(Duration::ZERO);
        let mut pair = start_pair("t", protocol, mailbox(8, Overflow::Refuse), sim);
        let server = Server::start(&pair.line);
        let mut client = server.client().await;
        let telegram = b"SET 42\x03";
        // REQ = 1, LEN, DATA in one FC 16.
        let mut values = vec![1, telegram.len() as u16];
        values.extend(words(telegram));
        client
            .write_multiple_registers(layout::TX_REQ, &values)
            .await
            .expect("transport")
            .expect("accepted");
        assert_eq!(pair.partner_received().await, telegram, "{name}");
        let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
        loop {
            // DONE, ERROR, STATUS, BUSY, RESULT_REQ
            let result = read(&mut client, layout::TX_DONE, 5).await;
            if result[4] == 1 {
                assert_eq!(result, [1, 0, 0, 0, 1], "{name}: DONE for request 1");
                break;
            }
            assert!(tokio::time::Instant::now() < deadline, "{name}: no result");
            tokio::time::sleep(ms(2)).await;
        }
        // The echo comes back into the receive block.
        let mailbox = pair.line.mailbox().expect("a telegram line");
        eventually("the echo", || mailbox.len() == 1).await;
        let head = read(&mut client, layout::RX_SEQ, 7).await;
        assert_eq!(head[..3], [1, 7, 1], "{name}");
        assert_eq!(bytes(&head[3..], 7), telegram, "{name}");
        assert_eq!(read(&mut client, layout::DIAG_SENT, 2).await, [0, 1]);
        pair.stop().await;
    }
}

// === a full mailbox ===

#[tokio::test]
async fn a_full_ascii_mailbox_drops_the_new_telegram_and_counts_it() {
    let protocol = TelegramProtocol::Ascii(gateway_ascii());
    let sim = partner(&protocol).every(ms(5)).limit(10);
    let pair = start_pair("t", protocol, mailbox(3, Overflow::DropNew), sim);
    let server = Server::start(&pair.line);
    let mut client = server.client().await;
    let line = &pair.line;
    eventually("seven overflows", || {
        line.telegram_status()
            .expect("a telegram line")
            .counters
            .overflows
            == 7
    })
    .await;
    assert_eq!(event_count(line, ids::NO_FREE_RECEIVE_BUFFER), 7);
    let status = line.telegram_status().expect("a telegram line");
    assert_eq!(status.line.status_word, 0x080A);
    assert_eq!(status.waiting, 3);
    assert_eq!(
        status.counters.received, 10,
        "every telegram got its number"
    );
    let waiting: Vec<u16> = line
        .mailbox()
        .expect("a telegram line")
        .waiting()
        .iter()
        .map(|t| t.seq)
        .collect();
    assert_eq!(waiting, [1, 2, 3], "the oldest are kept");
    // STATUS word and the overflow counter as registers.
    assert_eq!(read(&mut client, layout::RX_STATUS, 1).await, [0x080A]);
    assert_eq!(read(&mut client, layout::DIAG_OVERFLOWS, 2).await, [0, 7]);
    assert_eq!(
        read(&mut client, layout::DIAG_OVERFLOW_POLICY, 1).await,
        [1]
    );
    pair.stop().await;
}

#[tokio::test]
async fn an_ascii_line_that_may_overwrite_keeps_the_newest_telegram_without_an_event() {
    // 003 6.2.1 "Prevent overwriting" off, one receive buffer: each new telegram replaces the held
    // one. That is what the line was set up to do, so there is no 08 0Ah and no overflow.
    let protocol = TelegramProtocol::Ascii(gateway_ascii());
    let sim = partner(&protocol).every(ms(5)).limit(5);
    let pair = start_pair("t", protocol, mailbox(1, Overflow::Overwrite), sim);
    let line = &pair.line;
    eventually("five telegrams", || {
        line.telegram_status()
            .expect("a telegram line")
            .counters
            .received
            == 5
    })
    .await;
    let status = line.telegram_status().expect("a telegram line");
    assert_eq!(status.counters.overflows, 0);
    assert_eq!(event_count(line, ids::NO_FREE_RECEIVE_BUFFER), 0);
    let waiting: Vec<u16> = line
        .mailbox()
        .expect("a telegram line")
        .waiting()
        .iter()
        .map(|t| t.seq)
        .collect();
    assert_eq!(waiting, [5], "the newest is held");
    pair.stop().await;
}

#[tokio::test]
async fn a_full_3964r_mailbox_refuses_with_nak_and_takes_the_held_telegram_later() {
    let protocol = TelegramProtocol::P3964(gateway_3964r());
    let sim = partner(&protocol).every(ms(20)).limit(4);
    let pair = start_pair("t", protocol, mailbox(2, Overflow::Refuse), sim);
    let line = &pair.line;
    let mailbox = line.mailbox().expect("a telegram line");
    // Two in the mailbox, one held by the driver, the fourth refused (NAK, 08 0Ah).
    eventually("a refusal", || {
        line.telegram_status()
            .expect("a telegram line")
            .counters
            .overflows
            >= 1
    })
    .await;
    assert!(event_count(line, ids::NO_FREE_RECEIVE_BUFFER) >= 1);
    assert_eq!(mailbox.len(), 2);
    mailbox.ack(1).expect("oldest");
    // The telegram the driver held moves in.
    eventually("the held telegram", || mailbox.len() == 2).await;
    let third = mailbox.waiting().pop().expect("third");
    assert_eq!((third.seq, &*third.data), (3, &b"3964R 000003"[..]));
    pair.stop().await;
}

// === RS232 signals ===

#[tokio::test]
async fn a_pty_refuses_the_rs232_signals_with_a_clear_error() {
    let protocol = TelegramProtocol::Ascii(gateway_ascii());
    let sim = partner(&protocol).every(Duration::ZERO);
    let pair = start_pair("t", protocol, mailbox(4, Overflow::DropNew), sim);
    let line = &pair.line;
    eventually("port open", || {
        line.telegram_status()
            .expect("a telegram line")
            .line
            .port_open
    })
    .await;
    let signals = line.signals().expect("a telegram line");
    let err = signals.read().await.expect_err("a pty has no modem lines");
    let text = err.to_string();
    assert!(
        matches!(
            err,
            SignalError::Unsupported {
                signal: Signal::Dsr,
                ..
            }
        ),
        "{err:?}"
    );
    assert!(
        text.ends_with("(a pseudo-terminal has no modem signals)"),
        "{text}"
    );
    let err = signals.set(Output::Dtr, true).await.expect_err("no DTR");
    assert!(
        matches!(
            err,
            SignalError::Unsupported {
                signal: Signal::Dtr,
                action: "set",
                ..
            }
        ),
        "{err:?}"
    );
    pair.stop().await;
}

#[tokio::test]
async fn signals_on_a_line_that_is_not_rs232_or_driven_by_flow_control_are_refused() {
    // RS422: no modem signals at all.
    let (_partner, path, _keep) = pty();
    let shutdown = CancellationToken::new();
    let mut s = settings(
        "rs422",
        &path,
        TelegramProtocol::Ascii(gateway_ascii()),
        mailbox(4, Overflow::DropNew),
    );
    s.port.interface = Interface::Rs422;
    let line = spawn_telegram_line(s, shutdown.clone());
    eventually("port open", || {
        line.telegram_status()
            .expect("a telegram line")
            .line
            .port_open
    })
    .await;
    let err = line
        .signals()
        .expect("a telegram line")
        .read()
        .await
        .expect_err("RS422");
    assert_eq!(
        err,
        SignalError::NotRs232 {
            line: "rs422".into()
        }
    );

    // RS232 with RTS/CTS flow control: RTS belongs to the driver (000 5.4); CTS cannot be read
    // on a pty, so a send waits for CTS in vain and fails with 07 08h.
    let (_partner2, path2, _keep2) = pty();
    let params = AsciiParams::try_new(AsciiSettings {
        interface: EngineInterface::Rs232,
        flow: FlowControl::RtsCts,
        flow_wait: ms(100),
        ..AsciiSettings::default()
    })
    .expect("valid");
    let rtscts = spawn_telegram_line(
        settings(
            "rtscts",
            &path2,
            TelegramProtocol::Ascii(params),
            mailbox(4, Overflow::Refuse),
        ),
        shutdown.clone(),
    );
    eventually("the signals error", || {
        rtscts
            .telegram_status()
            .expect("a telegram line")
            .signals_error
            .is_some()
    })
    .await;
    let err = rtscts
        .signals()
        .expect("a telegram line")
        .set(Output::Rts, true)
        .await
        .expect_err("driven by RTS/CTS");
    assert!(
        matches!(
            err,
            SignalError::DrivenByDriver {
                signal: Signal::Rts,
                ..
            }
        ),
        "{err:?}"
    );
    let failed = rtscts
        .telegram_client()
        .expect("a telegram line")
        .send(b"x".to_vec())
        .await
        .expect_err("no CTS");
    assert_eq!(failed.event(), ids::SEND_FLOW_CONTROL_TIMEOUT);
    shutdown.cancel();
    line.join().await;
    rtscts.join().await;
}

// === port and shutdown ===

#[tokio::test]
async fn a_lost_port_fails_the_send_and_the_line_reopens() {
    let (partner_end, path, keep) = pty();
    let shutdown = CancellationToken::new();
    let protocol = TelegramProtocol::P3964(gateway_3964r());
    let line = spawn_telegram_line(
        settings("t", &path, protocol, mailbox(4, Overflow::Refuse)),
        shutdown.clone(),
    );
    eventually("port open", || {
        line.telegram_status()
            .expect("a telegram line")
            .line
            .port_open
    })
    .await;
    // The partner's end goes away: the pty is gone.
    drop(partner_end);
    drop(keep);
    eventually("the port lost", || event_count(&line, ids::LINE_BREAK) >= 1).await;
    eventually("reopen attempts fail with 02 0Fh", || {
        event_count(&line, ids::INVALID_PARAMETERIZATION) >= 1
    })
    .await;
    let err = line
        .telegram_client()
        .expect("a telegram line")
        .send(b"x".to_vec())
        .await
        .expect_err("closed");
    assert_eq!(err, TelegramSendError::PortClosed);
    assert_eq!(err.event(), ids::REQUEST_NOT_PERMITTED);
    assert!(
        !line
            .telegram_status()
            .expect("a telegram line")
            .line
            .port_open
    );
    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(5), line.join())
        .await
        .expect("stops at once while closed");
}

// === `gateway sim --device ascii` on a port by its path ===

#[tokio::test]
async fn the_ascii_simulator_opens_its_port_sends_its_own_and_echoes() {
    use gateway::protocols::telegram::partner::{run_telegram_sim, TelegramDevice};
    use gateway::serial::PortSettings;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    let (mut line_end, path, _keep) = pty();
    let shutdown = CancellationToken::new();
    let sim = tokio::spawn(run_telegram_sim(
        TelegramDevice::Ascii,
        PortSettings::new(path, 9600),
        ms(50),
        shutdown.clone(),
    ));
    let mut received = Vec::new();
    let mut buf = [0u8; 64];
    let first: &[u8] = b"ASCII 000001\x03";
    while !received.ends_with(first) {
        let n = tokio::time::timeout(Duration::from_secs(5), line_end.read(&mut buf))
            .await
            .expect("the simulator's own telegram in time")
            .expect("read");
        received.extend_from_slice(&buf[..n]);
    }
    assert_eq!(received, first, "nothing before its first telegram");
    line_end.write_all(b"PING\x03").await.expect("write");
    received.clear();
    while !received.windows(5).any(|w| w == b"PING\x03") {
        let n = tokio::time::timeout(Duration::from_secs(5), line_end.read(&mut buf))
            .await
            .expect("the echo in time")
            .expect("read");
        received.extend_from_slice(&buf[..n]);
    }
    shutdown.cancel();
    let result = tokio::time::timeout(Duration::from_secs(5), sim)
        .await
        .expect("the simulator stops")
        .expect("no panic");
    assert!(result.is_ok(), "{result:?}");
}

// === full duplex ===

#[tokio::test]
async fn an_ascii_line_separates_the_partners_telegrams_while_it_sends_a_long_one() {
    // 003 6.2: the ASCII driver is full duplex; the character delay time ends a received telegram
    // on the received bytes' own arrival, whatever the line sends meanwhile. At 1200 Bd the line's
    // 300-byte telegram takes about 2.75 s on a real wire; the partner sends two telegrams 300 ms
    // apart within that time, and they must stay two.
    let protocol = TelegramProtocol::Ascii(
        AsciiParams::try_new(AsciiSettings {
            end: proto_core::telegram::EndCriterion::CharacterDelay,
            zvz: ms(50),
            ..AsciiSettings::default()
        })
        .expect("valid"),
    );
    let (mut partner_end, path, _keep) = pty();
    let mut settings = settings("fd", &path, protocol, mailbox(8, Overflow::Refuse));
    settings.port.baud = 1200;
    let shutdown = CancellationToken::new();
    let line = spawn_telegram_line(settings, shutdown.clone());
    eventually("the port open", || line.status().port_open).await;
    let client = line.telegram_client().expect("a telegram line");
    let send = tokio::spawn(async move { client.send(vec![b'x'; 300]).await });
    // The line's telegram is under way (its first bytes are here).
    let mut first = [0u8; 1];
    tokio::io::AsyncReadExt::read_exact(&mut partner_end, &mut first)
        .await
        .expect("the line sends");
    tokio::io::AsyncWriteExt::write_all(&mut partner_end, b"AAAA")
        .await
        .expect("write");
    tokio::time::sleep(ms(300)).await;
    tokio::io::AsyncWriteExt::write_all(&mut partner_end, b"BBBB")
        .await
        .expect("write");
    let mailbox = line.mailbox().expect("a telegram line");
    eventually("two telegrams", || mailbox.len() >= 2).await;
    let got: Vec<Vec<u8>> = mailbox.waiting().iter().map(|t| t.data.to_vec()).collect();
    assert_eq!(got, [b"AAAA".to_vec(), b"BBBB".to_vec()]);
    drop(send);
    shutdown.cancel();
    tokio::time::timeout(Duration::from_secs(5), line.join())
        .await
        .expect("the line stops");
}
