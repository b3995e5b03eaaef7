//! The listen-only taps (Modbus RTU, 3964(R)) under arbitrary input.

use proptest::prelude::*;
use proto_core::modbus::tap::{Tap, TapConfig};
use proto_core::serial_marks::LineError;
use proto_core::time::Instant;

proptest! {
    /// Arbitrary chunks at arbitrary gaps, with line errors between them, never panic; the counts
    /// stay consistent and the tap ends idle after a long silence.
    #[test]
    fn noise_never_panics(
        chunks in proptest::collection::vec(
            (proptest::collection::vec(any::<u8>(), 0..300), 0u64..20_000, any::<bool>()),
            0..30,
        ),
        check in any::<bool>(),
    ) {
        let mut tap = Tap::new(TapConfig {
            check_inter_character: check,
            ..TapConfig::new(19_200, 11)
        });
        let mut now = 0u64;
        let mut events = 0u64;
        for (chunk, gap, error) in chunks {
            now += gap;
            tap.handle_rx(Instant::from_micros(now), &chunk);
            if error {
                tap.handle_line_error(Instant::from_micros(now), LineError::Break);
            }
            if let Some(t) = tap.poll_timeout().filter(|t| t.as_micros() <= now) {
                tap.handle_timeout(t);
            }
            while tap.poll_event().is_some() {
                events += 1;
            }
        }
        tap.handle_timeout(Instant::from_micros(now + 10_000_000));
        while tap.poll_event().is_some() {
            events += 1;
        }
        prop_assert_eq!(tap.poll_timeout(), None);
        let c = tap.counters();
        prop_assert!(c.pairs + c.missing_answers + c.bad_crc + c.discarded <= events);
        prop_assert!(c.bad_crc <= c.frames);
    }
}

proptest! {
    /// The 3964(R) tap under arbitrary bytes on both sides at arbitrary gaps: no panic, every
    /// count backed by an event, idle after a long silence.
    #[test]
    fn noise_never_panics_3964(
        chunks in proptest::collection::vec(
            (any::<bool>(), proptest::collection::vec(
                prop_oneof![Just(0x02u8), Just(0x03), Just(0x10), Just(0x15), any::<u8>()],
                0..40,
            ), 0u64..300_000),
            0..40,
        ),
        with_bcc in any::<bool>(),
    ) {
        use proto_core::proc3964::tap::{Side, Tap3964, TapConfig3964, TapEvent3964};
        use proto_core::proc3964::Variant;
        let variant = if with_bcc { Variant::P3964R } else { Variant::P3964 };
        let mut tap = Tap3964::new(TapConfig3964 { max_len: 16, ..TapConfig3964::new(variant) });
        let mut now = 0u64;
        let mut telegrams = 0u64;
        let mut events = 0u64;
        for (b_side, chunk, gap) in chunks {
            now += gap;
            let side = if b_side { Side::B } else { Side::A };
            tap.handle_rx(side, Instant::from_micros(now), &chunk);
            while let Some(event) = tap.poll_event() {
                events += 1;
                if let TapEvent3964::Telegram { data, .. } = event {
                    prop_assert!(data.len() <= 16);
                    telegrams += 1;
                }
            }
        }
        for _ in 0..3 {
            now += 10_000_000;
            tap.handle_timeout(Instant::from_micros(now));
        }
        while tap.poll_event().is_some() {
            events += 1;
        }
        prop_assert_eq!(tap.poll_timeout(), None);
        let c = tap.counters();
        prop_assert_eq!(c.telegrams[0] + c.telegrams[1], telegrams);
        prop_assert!(
            telegrams + c.naks + c.missing_dle + c.bad_bcc + c.bad_telegrams + c.repetitions
                + c.conflicts <= events
        );
    }
}
