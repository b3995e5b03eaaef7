//! The `PARMRK` mark decoder (`serial_marks::MarkDecoder`).

use crate::serial_marks::{encode, LineError, MarkDecoder, Piece, Received};

/// Decodes `data` (the bytes a tty delivers with `PARMRK`) once whole and once in chunks whose
/// sizes come from the input itself, and checks: the same pieces either way, no empty data piece,
/// each error's position equals the data bytes before it, and re-encoding the result gives back
/// as many bytes as `data` whenever `data` holds only marks the kernel writes.
pub fn fuzz_marks(data: &[u8]) {
    let whole = decode_chunks(data, usize::MAX);
    // The first byte chooses the chunk size (1..=8) for the second decoding.
    let step = data.first().map_or(1, |b| usize::from(b % 8) + 1);
    let chunked = decode_chunks(data, step);
    assert_eq!(whole, chunked, "chunks of {step} decode differently");

    let mut again = Vec::new();
    let items = whole.iter().map(|d| match d {
        Ok(b) => Received::Byte(*b),
        Err(LineError::Break) => Received::Break,
        // The faulty byte is not kept; any non-zero byte stands for it.
        Err(_) => Received::Faulty(1),
    });
    encode(items, &mut again);
    if well_formed(data) {
        assert_eq!(again.len(), data.len(), "re-encoding changes the length");
    }
}

/// The decoded stream of `data` read `step` bytes at a time.
fn decode_chunks(data: &[u8], step: usize) -> Vec<Result<u8, LineError>> {
    let mut dec = MarkDecoder::new();
    let mut out = Vec::new();
    let mut data_bytes = 0u64;
    for chunk in data.chunks(step.max(1)) {
        for piece in dec.decode(chunk) {
            match piece {
                Piece::Data(d) => {
                    assert!(!d.is_empty(), "empty data piece");
                    data_bytes += super::as_u64(d.len());
                    out.extend(d.iter().copied().map(Ok));
                }
                Piece::Error { error, at } => {
                    assert_eq!(at, data_bytes, "error position");
                    out.push(Err(error));
                }
            }
        }
    }
    assert_eq!(dec.data_bytes(), data_bytes);
    out
}

/// Whether every FF in `data` starts `FF FF` or `FF 00 x`, and the input does not end inside one.
fn well_formed(data: &[u8]) -> bool {
    let mut i = 0;
    while let Some(&b) = data.get(i) {
        if b != 0xFF {
            i += 1;
            continue;
        }
        match data.get(i + 1) {
            Some(0xFF) => i += 2,
            Some(0x00) if data.len() > i + 2 => i += 3,
            _ => return false,
        }
    }
    true
}
