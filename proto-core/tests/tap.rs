//! The listen-only RTU tap under arbitrary input.

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
