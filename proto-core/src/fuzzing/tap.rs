//! The listen-only decoders fed scripts of what another master's line carries: the Modbus RTU
//! tap ([`fuzz_rtu_tap`]) and the 3964(R) tap of a Y-cable ([`fuzz_tap_3964`]). A tap reads what
//! others send, so every byte sequence, gap and line error must end in an event or a count, and
//! the decoder must come to rest.

use core::time::Duration;

use super::as_u64;
use crate::modbus::pdu::Request;
use crate::modbus::tap::{Outcome, Tap, TapConfig, TapCounters, TapEvent, Values};
use crate::proc3964::tap::{Fault, Side, Tap3964, TapConfig3964, TapCounters3964, TapEvent3964};
use crate::proc3964::{frame, Variant, DLE, ETX, NAK, STX};
use crate::serial_marks::LineError;
use crate::time::Instant;

/// The most deadlines followed after the script before calling it a livelock.
const MAX_DRIVE_STEPS: usize = 10_000;

/// The line errors of the scripts' line error operation.
const LINE_ERRORS: [LineError; 4] = [
    LineError::Parity,
    LineError::Framing,
    LineError::Overrun,
    LineError::Break,
];

/// The Modbus RTU tap.
///
/// Input: byte 0 the setup (bits 0..2 the baud rate 1200 / 9600 / 19200 / 38400 / 57600 / 76800 /
/// 115200 / 300, bit 3 the inter-character check off, bits 4..5 the answer timeout 5 ms / 100 ms /
/// 1 s / 65.5 s), then the script, one byte an operation (`op & 3`, `a = op >> 2`):
/// - 0: receive the next `a + 1` bytes, arriving one character time apart;
/// - 1: a silence of `a * a * 100` µs without telling the tap;
/// - 2: wait until the tap's deadline (or `a` ms when it has none), then `handle_timeout`;
/// - 3: a line error (`a % 4`).
///
/// Checked: after `handle_timeout(now)` the next deadline lies after `now`; the counters match the
/// events (frames, pairs, missing answers, bad CRCs); an answered read carries exactly the
/// quantity its request asked for; at the end, following the deadlines brings the tap to rest.
pub fn fuzz_rtu_tap(data: &[u8]) {
    run_rtu_tap(data);
}

/// [`fuzz_rtu_tap`]; the tap's counters at rest (`None` for an empty input).
pub(super) fn run_rtu_tap(data: &[u8]) -> Option<TapCounters> {
    let (&setup, script) = data.split_first()?;
    let baud = [1200, 9600, 19_200, 38_400, 57_600, 76_800, 115_200, 300][usize::from(setup & 7)];
    let mut config = TapConfig::new(baud, 11);
    config.check_inter_character = setup & 8 == 0;
    config.answer_timeout = [5, 100, 1000, 65_500]
        .map(Duration::from_millis)
        .get(usize::from(setup >> 4 & 3))
        .copied()
        .unwrap_or(Duration::from_secs(1));
    let timing = config.timing;
    let mut tap = Tap::new(config);
    let mut now = Instant::ZERO;
    let mut seen = RtuSeen::default();
    let mut i = 0;
    while let Some(&op) = script.get(i) {
        i += 1;
        let a = op >> 2;
        match op & 3 {
            0 => {
                let n = usize::from(a) + 1;
                let bytes = script.get(i..(i + n).min(script.len())).unwrap_or_default();
                i += n;
                now += timing.transmit_time(bytes.len());
                tap.handle_rx(now, bytes);
            }
            1 => now += Duration::from_micros(u64::from(a) * u64::from(a) * 100),
            2 => {
                now = tap
                    .poll_timeout()
                    .unwrap_or(now + Duration::from_millis(u64::from(a)));
                tap.handle_timeout(now);
                if let Some(next) = tap.poll_timeout() {
                    assert!(next > now, "rtu tap: deadline {next:?} not after {now:?}");
                }
            }
            _ => tap.handle_line_error(now, LINE_ERRORS[usize::from(a % 4)]),
        }
        seen.drain(&mut tap);
    }
    // To rest: every frame ends, every request is answered or missing.
    let mut steps = 0;
    while let Some(deadline) = tap.poll_timeout() {
        steps += 1;
        assert!(steps <= MAX_DRIVE_STEPS, "rtu tap: no rest");
        now = now.max(deadline);
        tap.handle_timeout(now);
        seen.drain(&mut tap);
    }
    let c = tap.counters();
    assert_eq!(c.frames, seen.frames, "rtu tap: frames counted");
    assert_eq!(c.pairs, seen.pairs, "rtu tap: pairs counted");
    assert_eq!(c.missing_answers, seen.missing, "rtu tap: missing counted");
    assert_eq!(c.bad_crc, seen.bad_crc, "rtu tap: bad CRCs counted");
    Some(c)
}

/// What the RTU tap's events said.
#[derive(Debug, Default)]
struct RtuSeen {
    frames: u64,
    pairs: u64,
    missing: u64,
    bad_crc: u64,
}

// === impl RtuSeen ===

impl RtuSeen {
    fn drain(&mut self, tap: &mut Tap) {
        while let Some(event) = tap.poll_event() {
            match event {
                TapEvent::Frame { .. } => self.frames += 1,
                TapEvent::Discarded { reason, .. } => {
                    if reason == crate::modbus::tap::DiscardReason::BadCrc {
                        self.bad_crc += 1;
                    }
                }
                TapEvent::Exchange(exchange) => match exchange.outcome {
                    Outcome::Answered(blocks) => {
                        self.pairs += 1;
                        check_read(&exchange.request, &blocks);
                    }
                    Outcome::Exception(_) => self.pairs += 1,
                    Outcome::Missing => self.missing += 1,
                    Outcome::Invalid(_) | Outcome::Broadcast => {}
                },
            }
        }
    }
}

/// An answered read shows exactly the quantity its request asked for, from its start.
fn check_read(request: &Request, blocks: &[crate::modbus::tap::Block]) {
    let asked = match *request {
        Request::ReadCoils { address, quantity }
        | Request::ReadDiscreteInputs { address, quantity }
        | Request::ReadHoldingRegisters { address, quantity }
        | Request::ReadInputRegisters { address, quantity } => Some((address, quantity)),
        _ => None,
    };
    let Some((address, quantity)) = asked else {
        return;
    };
    assert_eq!(blocks.len(), 1, "rtu tap: one block for {request:?}");
    let block = &blocks[0];
    let len = match &block.values {
        Values::Bits(bits) => bits.len(),
        Values::Words(words) => words.len(),
    };
    assert_eq!(
        (block.start, len),
        (address, usize::from(quantity)),
        "rtu tap: the values of {request:?}"
    );
}

/// The 3964(R) tap of both directions of a link.
///
/// Input: byte 0 the setup (bit 0: 3964 without BCC, bits 1..2 the telegram length limit
/// 250 / 4 / 16 / 1024), then the script, one byte an operation (`op & 7`, `a = op >> 3`):
/// - 0 / 1: side A / B sends the next `a + 1` bytes;
/// - 2: a silence of `a * a` ms without telling the tap;
/// - 3: wait until the tap's deadline (or `a` ms when it has none), then `handle_timeout`;
/// - 4: a line error (`a >> 1 & 3`) on side A (`a` even) or B;
/// - 5 / 6: side A / B sends a control character: STX, DLE, ETX, NAK by `a % 4`;
/// - 7: side A (`a` even) or B sends the next `(a >> 1) + 1` bytes as a well-formed telegram
///   (DLE doubled, DLE ETX, the BCC in 3964R).
///
/// Checked: after `handle_timeout(now)` the next deadline lies after `now`; a delivered telegram
/// is within the length limit; the counters match the events (telegrams by side, repetitions,
/// line errors, stray bytes); at the end, following the deadlines brings the tap to rest.
pub fn fuzz_tap_3964(data: &[u8]) {
    run_tap_3964(data);
}

/// [`fuzz_tap_3964`]; the tap's counters at rest (`None` for an empty input).
pub(super) fn run_tap_3964(data: &[u8]) -> Option<TapCounters3964> {
    let (&setup, script) = data.split_first()?;
    let variant = if setup & 1 == 0 {
        Variant::P3964R
    } else {
        Variant::P3964
    };
    let mut config = TapConfig3964::new(variant);
    config.max_len = [250, 4, 16, 1024][usize::from(setup >> 1 & 3)];
    let max_len = usize::from(config.max_len);
    let mut tap = Tap3964::new(config);
    let mut now = Instant::ZERO;
    let mut seen = Seen3964::default();
    let step = Duration::from_millis(1);
    let mut i = 0;
    while let Some(&op) = script.get(i) {
        i += 1;
        let a = op >> 3;
        let side = |even: bool| if even { Side::A } else { Side::B };
        match op & 7 {
            code @ (0 | 1) => {
                let n = usize::from(a) + 1;
                let bytes = script.get(i..(i + n).min(script.len())).unwrap_or_default();
                i += n;
                now += step;
                tap.handle_rx(side(code == 0), now, bytes);
            }
            2 => now += Duration::from_millis(u64::from(a) * u64::from(a)),
            3 => {
                now = tap
                    .poll_timeout()
                    .unwrap_or(now + Duration::from_millis(u64::from(a)));
                tap.handle_timeout(now);
                if let Some(next) = tap.poll_timeout() {
                    assert!(next > now, "3964 tap: deadline {next:?} not after {now:?}");
                }
            }
            4 => {
                now += step;
                let error = LINE_ERRORS[usize::from(a >> 1 & 3)];
                tap.handle_line_error(side(a % 2 == 0), now, error);
            }
            code @ (5 | 6) => {
                now += step;
                let control = [STX, DLE, ETX, NAK][usize::from(a % 4)];
                tap.handle_rx(side(code == 5), now, &[control]);
            }
            _ => {
                let n = usize::from(a >> 1) + 1;
                let user = script.get(i..(i + n).min(script.len())).unwrap_or_default();
                i += n;
                now += step;
                tap.handle_rx(side(a % 2 == 0), now, &frame::encode(user, variant));
            }
        }
        seen.drain(&mut tap, max_len);
    }
    let mut steps = 0;
    while let Some(deadline) = tap.poll_timeout() {
        steps += 1;
        assert!(steps <= MAX_DRIVE_STEPS, "3964 tap: no rest");
        now = now.max(deadline);
        tap.handle_timeout(now);
        seen.drain(&mut tap, max_len);
    }
    let c = tap.counters();
    assert_eq!(c.telegrams, seen.telegrams, "3964 tap: telegrams counted");
    assert_eq!(
        c.repetitions, seen.repetitions,
        "3964 tap: repetitions counted"
    );
    assert_eq!(
        c.line_errors, seen.line_errors,
        "3964 tap: line errors counted"
    );
    assert_eq!(
        c.stray_bytes, seen.stray_bytes,
        "3964 tap: stray bytes counted"
    );
    Some(c)
}

/// What the 3964(R) tap's events said.
#[derive(Debug, Default)]
struct Seen3964 {
    telegrams: [u64; 2],
    repetitions: u64,
    line_errors: u64,
    stray_bytes: u64,
}

// === impl Seen3964 ===

impl Seen3964 {
    fn drain(&mut self, tap: &mut Tap3964, max_len: usize) {
        while let Some(event) = tap.poll_event() {
            match event {
                TapEvent3964::Telegram { side, data, .. } => {
                    assert!(data.len() <= max_len, "3964 tap: {} bytes", data.len());
                    self.telegrams[usize::from(side == Side::B)] += 1;
                }
                TapEvent3964::Repetition { .. } => self.repetitions += 1,
                TapEvent3964::Fault { fault, .. } => match fault {
                    Fault::LineError { .. } => self.line_errors += 1,
                    Fault::Stray { len } => self.stray_bytes += as_u64(len),
                    _ => {}
                },
            }
        }
    }
}
