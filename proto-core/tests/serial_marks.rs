//! Property tests of the `PARMRK` decoder: whatever the data and line errors, encoded the way the
//! tty layer marks them and read back in arbitrary chunks, the decoder gives them back in order and
//! at their positions.

use proptest::collection::vec;
use proptest::prelude::*;
use proto_core::serial_marks::{encode, LineError, MarkDecoder, Piece, Received};

/// Data bytes (FF often, to exercise the doubling) and the errors the kernel marks in band.
fn received() -> impl Strategy<Value = Received> {
    prop_oneof![
        6 => any::<u8>().prop_map(Received::Byte),
        2 => Just(Received::Byte(0xFF)),
        1 => Just(Received::Byte(0x00)),
        1 => any::<u8>().prop_map(Received::Faulty),
        1 => Just(Received::Break),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1024, ..ProptestConfig::default() })]

    #[test]
    fn encoded_stream_decodes_back_in_any_chunks(
        items in vec(received(), 0..64),
        cuts in vec(0usize..200, 0..12),
    ) {
        let mut wire = Vec::new();
        encode(items.iter().copied(), &mut wire);

        let mut cuts: Vec<usize> = cuts.into_iter().map(|c| c % (wire.len() + 1)).collect();
        cuts.sort_unstable();
        let mut dec = MarkDecoder::new();
        let mut got = Vec::new();
        let mut positions = Vec::new();
        let mut start = 0;
        for end in cuts.into_iter().chain([wire.len()]) {
            for piece in dec.decode(&wire[start..end]) {
                match piece {
                    Piece::Data(d) => {
                        prop_assert!(!d.is_empty());
                        got.extend(d.iter().copied().map(Ok));
                    }
                    Piece::Error { error, at } => {
                        positions.push(at);
                        got.push(Err(error));
                    }
                }
            }
            start = end;
        }
        prop_assert!(!dec.in_mark());
        let expected: Vec<Result<u8, LineError>> = items.iter().map(|r| r.decoded()).collect();
        prop_assert_eq!(&got, &expected);

        // Each error's position is the number of data bytes before it.
        let expected_positions: Vec<u64> = items
            .iter()
            .enumerate()
            .filter(|(_, r)| !matches!(r, Received::Byte(_)))
            .map(|(i, _)| items[..i].iter().filter(|r| matches!(r, Received::Byte(_))).count() as u64)
            .collect();
        prop_assert_eq!(positions, expected_positions);
        let data = items.iter().filter(|r| matches!(r, Received::Byte(_))).count() as u64;
        prop_assert_eq!(dec.data_bytes(), data);
    }

    #[test]
    fn arbitrary_bytes_decode_the_same_in_any_chunks(
        wire in vec(prop_oneof![any::<u8>(), Just(0xFFu8), Just(0x00u8)], 0..64),
        cut in 0usize..64,
    ) {
        let decode = |chunks: &[&[u8]]| {
            let mut dec = MarkDecoder::new();
            let mut out: Vec<Result<u8, LineError>> = Vec::new();
            for c in chunks {
                for p in dec.decode(c) {
                    match p {
                        Piece::Data(d) => out.extend(d.iter().copied().map(Ok)),
                        Piece::Error { error, .. } => out.push(Err(error)),
                    }
                }
            }
            out
        };
        let cut = cut.min(wire.len());
        let (a, b) = wire.split_at(cut);
        prop_assert_eq!(decode(&[&wire]), decode(&[a, b]));
    }
}
