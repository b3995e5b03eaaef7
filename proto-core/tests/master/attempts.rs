//! Per-request attempts ([`Master::submit_with`]): a shorter reply monitoring time and no
//! repetition for one request, the reply delay, and a reply that comes after the shortened time.

use core::time::Duration;

use proto_core::event::ids;
use proto_core::modbus::master::{Attempts, Outcome};
use proto_core::modbus::pdu::Response;

use super::support::*;

fn short(ms: u64) -> Attempts {
    Attempts {
        reply_timeout: Some(Duration::from_millis(ms)),
        retries: Some(0),
    }
}

#[test]
fn a_short_single_attempt_fails_at_its_own_time_and_the_next_request_uses_the_config() {
    let mut config = rtu_config();
    config.retries = 2;
    let mut line = Line::new(config);
    line.master
        .submit_with(line.now, 2, atv_read(), short(50))
        .expect("accepted");
    line.transmit();
    let tx_done = line.now;
    assert_eq!(
        line.master.poll_timeout(),
        Some(tx_done + Duration::from_millis(50))
    );
    line.fire();
    // 003 7.2 08 30h, once: the configured two repetitions do not apply to this request.
    assert_eq!(line.raised(), [ids::MODBUS_NO_REPLY]);
    assert_eq!(line.outcomes(), [Outcome::Failed(ids::MODBUS_NO_REPLY)]);
    assert!(line.master.poll_transmit().is_none());
    assert_eq!(line.master.reply_delay(), None);

    // A plain submit afterwards waits the configured 2000 ms and repeats twice.
    line.events.clear();
    line.submit(2, atv_read());
    line.transmit();
    assert_eq!(
        line.master.poll_timeout(),
        Some(line.now + Duration::from_millis(2000))
    );
    for _ in 0..2 {
        line.fire();
        line.transmit();
    }
    line.fire();
    assert_eq!(line.raised(), [ids::MODBUS_NO_REPLY; 3]);
    assert_eq!(line.outcomes(), [Outcome::Failed(ids::MODBUS_NO_REPLY)]);
}

#[test]
fn the_reply_delay_runs_from_the_end_of_transmission_to_the_first_byte() {
    let mut line = Line::new(rtu_config());
    let mut slave = TestSlave::altivar();
    line.submit(2, atv_read());
    let request = line.transmit();
    assert_eq!(line.master.reply_delay(), None);
    line.advance(Duration::from_millis(7));
    let answer = slave.answer_rtu(&request).expect("answer");
    // The first bytes start the reply; the rest comes 1 ms later (within t3.5, 003 6.4.3) and
    // does not move the delay.
    line.rx(&answer[..3]);
    line.advance(Duration::from_millis(1));
    line.rx(&answer[3..]);
    line.fire();
    assert_eq!(
        line.outcomes(),
        [Outcome::Response(Response::ReadHoldingRegisters(vec![
            40, 600, 500, 0
        ]))]
    );
    assert_eq!(line.master.reply_delay(), Some(Duration::from_millis(7)));
    // A new request forgets it.
    line.settle();
    line.submit(2, atv_read());
    assert_eq!(line.master.reply_delay(), None);
}

#[test]
fn a_reply_after_the_shortened_time_is_a_late_reply_and_holds_a_request_not_yet_sent() {
    let mut line = Line::new(rtu_config());
    let mut slave = TestSlave::altivar();
    line.master
        .submit_with(line.now, 2, atv_read(), short(20))
        .expect("accepted");
    let request = line.transmit();
    line.fire();
    assert_eq!(line.outcomes(), [Outcome::Failed(ids::MODBUS_NO_REPLY)]);
    // The next request is queued; before it goes out, the slave answers the first one, late.
    line.submit(2, atv_read());
    line.advance(Duration::from_millis(30));
    let late = slave.answer_rtu(&request).expect("answer");
    line.rx(&late);
    let late_end = line.now;
    // 003 7.2 0E 53h for bytes nobody awaited; no second completion.
    assert_eq!(
        line.raised(),
        [ids::MODBUS_NO_REPLY, ids::MODBUS_BYTE_OVERFLOW]
    );
    assert_eq!(line.outcomes().len(), 1);
    // Half duplex: the queued request waits for t3.5 of silence after the late reply
    // (003 6.4.3).
    assert!(line.master.poll_transmit().is_none());
    line.fire();
    assert_eq!(line.now, late_end + timing().t35);
    assert_eq!(
        line.master.poll_transmit().as_deref(),
        Some(&ATV_READ_REQUEST[..])
    );
}
