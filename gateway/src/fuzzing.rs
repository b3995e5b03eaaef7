//! The entry point of the MBAP fuzz target (`fuzz/fuzz_targets/mbap.rs`); the targets of the
//! serial protocols are in `proto_core::fuzzing`.
//!
//! Compiled with `cfg(fuzzing)` (set by cargo-fuzz) or for tests; the tests run it on the
//! committed seeds (`fuzz/seeds/mbap/`) and simple mutations of them.

use proto_core::modbus::pdu::{ExceptionResponse, Request};

use crate::modbus_tcp::mbap::{self, FrameReader, MbapError, MbapHeader, MAX_ADU_LEN};

/// The MBAP frame reader and header codec, and the PDU decoder behind them.
///
/// - the frames and the error cut from the input are the same whether it arrives at once or in
///   chunks (of 1 to 13 bytes, by the first byte), and the reader never holds more than one
///   incomplete frame plus one chunk;
/// - [`mbap::check_frame`] agrees with the reader about the first frame;
/// - every frame re-encodes (header and PDU) to the bytes it was cut from, and the answer framed
///   for it ([`mbap::encode_frame`]) is a valid frame with the same transaction and unit id;
/// - every PDU either decodes as a request or maps to a two-byte exception response.
pub fn fuzz_mbap(data: &[u8]) {
    let whole = cut(data, data.len().max(1));
    let chunk = data.first().map_or(1, |&b| usize::from(b % 13) + 1);
    assert_eq!(cut(data, chunk), whole, "chunking changed the frames");

    match mbap::check_frame(data) {
        Ok(Some(len)) => {
            let first = whole.frames.first().map(|(h, _)| h.frame_len());
            assert_eq!(first, Some(len), "check_frame and the reader disagree");
        }
        Ok(None) => assert!(whole.frames.is_empty() && whole.error.is_none()),
        Err(error) => {
            assert!(whole.frames.is_empty(), "a frame before a bad header");
            assert_eq!(whole.error, Some(error));
        }
    }

    let mut at = 0;
    for (header, pdu) in &whole.frames {
        let mut again = Vec::new();
        header.encode(&mut again);
        again.extend_from_slice(pdu);
        let original = data.get(at..at + header.frame_len()).unwrap_or_default();
        assert_eq!(again, original, "MBAP re-encoding");
        at += header.frame_len();

        let answer = match Request::decode(pdu) {
            Ok(request) => request.to_bytes(),
            Err(error) => {
                let mut out = Vec::new();
                let function = pdu.first().copied().unwrap_or(0);
                ExceptionResponse::for_error(function, &error).encode(&mut out);
                assert_eq!(out.len(), 2, "an exception response is two bytes");
                out
            }
        };
        let mut framed = Vec::new();
        assert!(
            mbap::encode_frame(*header, &answer, &mut framed),
            "answer too long"
        );
        assert_eq!(mbap::check_frame(&framed), Ok(Some(framed.len())));
        assert_eq!(
            MbapHeader::check(&framed),
            Ok(header.reply(answer.len())),
            "answer header"
        );
    }
}

/// The frames and the error a reader cuts from `data` fed in chunks of `chunk` bytes.
#[derive(Debug, PartialEq, Eq)]
struct Cut {
    frames: Vec<(MbapHeader, Vec<u8>)>,
    error: Option<MbapError>,
}

fn cut(data: &[u8], chunk: usize) -> Cut {
    let mut reader = FrameReader::new();
    let mut frames = Vec::new();
    for part in data.chunks(chunk) {
        reader.extend(part);
        loop {
            match reader.next_frame() {
                Ok(Some(frame)) => frames.push((frame.header, frame.pdu.to_vec())),
                Ok(None) => break,
                Err(error) => {
                    return Cut {
                        frames,
                        error: Some(error),
                    }
                }
            }
        }
        assert!(
            reader.buffered() < MAX_ADU_LEN + chunk,
            "reader holds too much"
        );
    }
    Cut {
        frames,
        error: None,
    }
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;

    fn seeds() -> Vec<(String, Vec<u8>)> {
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../fuzz/seeds/mbap");
        let mut seeds: Vec<(String, Vec<u8>)> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
            .map(|entry| {
                let path = entry.expect("directory entry").path();
                let bytes = std::fs::read(&path).expect("seed");
                (path.display().to_string(), bytes)
            })
            .collect();
        seeds.sort();
        assert!(!seeds.is_empty(), "no seeds in {}", dir.display());
        seeds
    }

    #[test]
    fn seeds_and_their_truncations_and_byte_changes() {
        for (path, seed) in seeds() {
            fuzz_mbap(&seed);
            for len in 0..seed.len() {
                fuzz_mbap(&seed[..len]);
            }
            for at in 0..seed.len() {
                for value in [0x00, 0x01, 0x7F, 0xFF] {
                    let mut changed = seed.clone();
                    changed[at] = value;
                    let outcome = std::panic::catch_unwind(|| fuzz_mbap(&changed));
                    assert!(outcome.is_ok(), "{path}: {changed:02x?} panicked");
                }
            }
        }
    }

    #[test]
    fn the_seeds_hold_good_frames() {
        for (path, seed) in seeds() {
            let whole = cut(&seed, seed.len());
            if path.ends_with("-bad-protocol") {
                assert_eq!(whole.error, Some(MbapError::ProtocolId(1)), "{path}");
            } else {
                assert!(!whole.frames.is_empty(), "{path}: {whole:?}");
                assert_eq!(whole.error, None, "{path}");
            }
        }
    }
}
