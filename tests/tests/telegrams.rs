//! End to end on the binary: the demo's 3964R and ASCII partners' telegrams read and acknowledged
//! through the Modbus TCP mailboxes (FB 7 P_RCV_RK style), a telegram sent through the send block
//! (FB 8 P_SND_RK style), and a full queue counting its overflow.

use std::time::Duration;

use gateway_tests::Gateway;
use tokio_modbus::client::{tcp, Context, Reader, Writer};
use tokio_modbus::prelude::Slave;

/// The demo's mailbox units (gateway/src/plant/demo.toml).
const R3964_UNIT: u8 = 100;
const ASCII_UNIT: u8 = 101;

// The mailbox layout (docs/mailbox.md).
const DATA: u16 = 4;
const OVERFLOWS: u16 = 522;
const ACK: u16 = 600;
const DONE: u16 = 1000;
const REQ: u16 = 1008;

/// The oldest waiting telegram: (STATUS, SEQ, bytes), or `None` when nothing waits.
async fn head(ctx: &mut Context) -> Option<(u16, u16, Vec<u8>)> {
    let regs = ctx
        .read_holding_registers(0, 4 + 16)
        .await
        .expect("transport")
        .expect("read the receive block");
    let (status, seq, len) = (regs[0], regs[1], usize::from(regs[2]));
    if seq == 0 {
        return None;
    }
    let mut data = Vec::new();
    let words = len.div_ceil(2);
    let regs = if words <= 16 {
        regs[4..4 + words].to_vec()
    } else {
        ctx.read_holding_registers(DATA, u16::try_from(words).expect("len"))
            .await
            .expect("transport")
            .expect("data")
    };
    for w in regs {
        data.extend_from_slice(&w.to_be_bytes());
    }
    data.truncate(len);
    Some((status, seq, data))
}

/// The counter at the end of a partner's own telegram ("... 000123", framing bytes around it).
fn counter(data: &[u8]) -> Option<u64> {
    let text: String = data
        .iter()
        .map(|&b| b as char)
        .filter(char::is_ascii_digit)
        .collect();
    text.parse().ok()
}

async fn read_in_order(unit: u8, prefix: &str, count: u16) {
    let gw = Gateway::demo(&["--telegram-every", "4ms"]);
    let mut ctx = tcp::connect_slave(gw.modbus_tcp, Slave(unit))
        .await
        .expect("connect");
    let mut expected_seq = None;
    let mut last_counter: Option<u64> = None;
    let mut read = 0u16;
    let deadline = tokio::time::Instant::now() + Duration::from_secs(120);
    while read < count {
        assert!(
            tokio::time::Instant::now() < deadline,
            "only {read} of {count} telegrams within 120 s"
        );
        let Some((_, seq, data)) = head(&mut ctx).await else {
            tokio::time::sleep(Duration::from_millis(2)).await;
            continue;
        };
        if let Some(expected) = expected_seq {
            assert_eq!(
                seq, expected,
                "sequence numbers must not skip (a gap is a lost telegram)"
            );
        }
        let text = String::from_utf8_lossy(&data).into_owned();
        assert!(text.contains(prefix), "unexpected telegram {text:?}");
        let n = counter(&data).unwrap_or_else(|| panic!("no counter in {text:?}"));
        if let Some(last) = last_counter {
            assert_eq!(
                n,
                last + 1,
                "the partner's telegrams arrive in order, none lost: {text:?}"
            );
        }
        last_counter = Some(n);
        ctx.write_single_register(ACK, seq)
            .await
            .expect("transport")
            .expect("acknowledge");
        expected_seq = Some(seq.wrapping_add(1).max(1));
        read += 1;
    }
    // Nothing overflowed while the client kept up.
    let overflows = ctx
        .read_holding_registers(OVERFLOWS, 2)
        .await
        .expect("transport")
        .expect("overflows");
    assert_eq!(overflows, vec![0, 0]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn thousand_3964r_telegrams_in_order_through_the_mailbox() {
    read_in_order(R3964_UNIT, "3964R", 1000).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn thousand_ascii_telegrams_in_order_through_the_mailbox() {
    read_in_order(ASCII_UNIT, "ASCII", 1000).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_send_block_reaches_the_partner_and_sets_done() {
    // Partners that never send on their own: what arrives is the echo of what we send.
    let gw = Gateway::demo(&["--telegram-every", "0s"]);
    let mut ctx = tcp::connect_slave(gw.modbus_tcp, Slave(R3964_UNIT))
        .await
        .expect("connect");
    let payload = b"HELLO 3964R";
    let mut data = Vec::new();
    for pair in payload.chunks(2) {
        data.push(u16::from_be_bytes([pair[0], *pair.get(1).unwrap_or(&0)]));
    }
    // The line's port opens shortly after start: a send refused then is repeated with a new REQ
    // value, as a PLC program repeats FB 8 after an error.
    let deadline = tokio::time::Instant::now() + Duration::from_secs(20);
    let mut req = 7u16;
    loop {
        let mut block = vec![req, u16::try_from(payload.len()).expect("len")];
        block.extend_from_slice(&data);
        ctx.write_multiple_registers(REQ, &block)
            .await
            .expect("transport")
            .expect("write the send block");
        let (done, error) = loop {
            let r = ctx
                .read_holding_registers(DONE, 5)
                .await
                .expect("transport")
                .expect("read the result");
            if r[4] == req && (r[0] == 1 || r[1] == 1) {
                break (r[0], r[1]);
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        };
        if done == 1 {
            assert_eq!(error, 0, "DONE and ERROR both set");
            break;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "the send never succeeded"
        );
        req += 1;
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    // The partner echoes what it received: the telegram came back through the receive block.
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    loop {
        if let Some((_, seq, data)) = head(&mut ctx).await {
            assert_eq!(data, payload, "the echo of the sent telegram");
            ctx.write_single_register(ACK, seq)
                .await
                .expect("transport")
                .expect("ack");
            break;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "no echo from the simulated partner"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_queue_counts_its_overflow() {
    // Nobody acknowledges (the demo's own consumer off): the ASCII queue (250 telegrams, "prevent
    // overwriting") fills and every further telegram is dropped, counted and raised as 08 0Ah.
    let gw = Gateway::demo(&["--telegram-every", "1ms", "--no-mailbox-consumer"]);
    let mut ctx = tcp::connect_slave(gw.modbus_tcp, Slave(ASCII_UNIT))
        .await
        .expect("connect");
    let deadline = tokio::time::Instant::now() + Duration::from_secs(60);
    loop {
        let o = ctx
            .read_holding_registers(OVERFLOWS, 2)
            .await
            .expect("transport")
            .expect("overflows");
        let overflows = (u32::from(o[0]) << 16) | u32::from(o[1]);
        if overflows > 0 {
            let status = ctx
                .read_holding_registers(0, 4)
                .await
                .expect("transport")
                .expect("status");
            assert_eq!(status[0], 0x080A, "STATUS shows 08 0Ah");
            assert_eq!(status[3], 250, "the queue is full");
            break;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "the queue never overflowed"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // The oldest telegram is still the first one: nothing waiting was overwritten.
    let (_, seq, _) = head(&mut ctx).await.expect("a waiting telegram");
    assert_eq!(seq, 1);
}
