//! Line errors of a UART, and the decoder of the marks the Linux tty layer puts into the byte
//! stream when a port is opened with `INPCK | PARMRK` (and neither `IGNPAR` nor `IGNBRK`, with
//! `BRKINT` off).
//!
//! With those flags the kernel keeps every received character in the stream and marks the faulty
//! ones in band (termios(3), `PARMRK`):
//!
//! | bytes read   | meaning                                                     |
//! |--------------|-------------------------------------------------------------|
//! | `FF FF`      | the data byte `FF`                                          |
//! | `FF 00 x`    | the character `x`, received with a parity or framing error  |
//! | `FF 00 00`   | a BREAK                                                     |
//! | anything else| data, as it is                                              |
//!
//! A framing error on a `00` character and a BREAK are one and the same mark: the kernel reports
//! both as `FF 00 00`, and so does the decoder (a BREAK is a character of zeros whose stop bit is
//! missing). An overrun is not marked in band; the runtime learns of it from the UART's counters
//! and hands it to the engine as [`LineError::Overrun`].
//!
//! [`MarkDecoder`] is a streaming decoder: a mark may be split across reads at any position, and
//! the decoder keeps the part it has seen until the next call. Decoding a read without any `FF`
//! byte (the common case on every line) yields the read itself as one borrowed slice: no copy, no
//! allocation.
//!
//! The engines take line errors through their `handle_line_error` input; the order of the pieces
//! the decoder yields is the order in which the runtime passes data and errors on, so that each
//! error lands at its position in the stream.

use crate::event::{ids, EventId};

/// A fault the UART reported for a received character, or a BREAK (003 7.2, events 08 0Ch and
/// 08 0Dh). The faulty character itself is not passed to the engine's `handle_rx`.
///
/// Every engine takes it through its `handle_line_error` input. The kernel's `PARMRK` marks do not
/// say whether a character had a parity or a framing error ([`Self::ParityOrFraming`]); the UART's
/// own counters (`TIOCGICOUNT`) do ([`Self::Parity`], [`Self::Framing`], [`Self::Overrun`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LineError {
    /// Parity error.
    Parity,
    /// Stop bit (framing) error.
    Framing,
    /// A parity or a stop bit error, as a `PARMRK` mark reports it (`FF 00 x`).
    ParityOrFraming,
    /// Receiver overrun: characters were lost.
    Overrun,
    /// BREAK: the receive line is held at space, the line to the partner is interrupted.
    Break,
}

// === impl LineError ===

impl LineError {
    /// 003 7.2: 08 0Ch "transmission error (parity error, stop bit error or overflow error)";
    /// 08 0Dh "BREAK: receive line to partner is interrupted".
    pub const fn event(self) -> EventId {
        match self {
            Self::Parity | Self::Framing | Self::ParityOrFraming | Self::Overrun => {
                ids::CHARACTER_ERROR
            }
            Self::Break => ids::LINE_BREAK,
        }
    }

    /// Whether this is a BREAK (08 0Dh) rather than a character error (08 0Ch).
    pub const fn is_break(self) -> bool {
        matches!(self, Self::Break)
    }
}

/// The byte that starts a mark and that the kernel doubles in the data (termios(3), `PARMRK`).
pub const MARK: u8 = 0xFF;

/// One piece of decoded input: a run of data bytes, or a line error between two runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Piece<'a> {
    /// Data bytes as the partner sent them (marks removed, `FF FF` undoubled).
    Data(&'a [u8]),
    /// A line error at this point of the data stream.
    Error {
        /// What went wrong.
        error: LineError,
        /// How many data bytes the decoder had yielded before the error, counted since it was
        /// created or [reset](MarkDecoder::reset).
        at: u64,
    },
}

/// Where the decoder stands inside a mark.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
enum State {
    /// Between marks.
    #[default]
    Plain,
    /// Seen `FF`.
    Mark,
    /// Seen `FF 00`.
    MarkZero,
}

/// The streaming decoder of `PARMRK` input. See the [module documentation](self).
#[derive(Clone, Debug, Default)]
pub struct MarkDecoder {
    state: State,
    data_bytes: u64,
}

// === impl MarkDecoder ===

impl MarkDecoder {
    /// A decoder between marks, with no data counted.
    pub const fn new() -> Self {
        Self {
            state: State::Plain,
            data_bytes: 0,
        }
    }

    /// Decodes one read. The iterator yields the read's pieces in order; drain it before the next
    /// call (pieces not taken are lost, and the decoder's state then describes the end of what was
    /// taken).
    pub fn decode<'d, 'a>(&'d mut self, input: &'a [u8]) -> Pieces<'d, 'a> {
        Pieces {
            decoder: self,
            input,
        }
    }

    /// Whether the last read ended inside a mark (`FF` or `FF 00` seen, the rest not yet).
    pub const fn in_mark(&self) -> bool {
        !matches!(self.state, State::Plain)
    }

    /// Data bytes yielded since the decoder was created or reset.
    pub const fn data_bytes(&self) -> u64 {
        self.data_bytes
    }

    /// Forgets a partial mark and the data count (after the port was reopened or flushed).
    pub fn reset(&mut self) {
        *self = Self::new();
    }
}

/// The pieces of one read; see [`MarkDecoder::decode`].
#[derive(Debug)]
pub struct Pieces<'d, 'a> {
    decoder: &'d mut MarkDecoder,
    input: &'a [u8],
}

impl<'a> Iterator for Pieces<'_, 'a> {
    type Item = Piece<'a>;

    fn next(&mut self) -> Option<Piece<'a>> {
        let dec = &mut *self.decoder;
        loop {
            let (&first, rest) = self.input.split_first()?;
            match dec.state {
                State::Plain => {
                    let run = self
                        .input
                        .iter()
                        .position(|&b| b == MARK)
                        .unwrap_or(self.input.len());
                    if run > 0 {
                        let (data, tail) = self.input.split_at(run);
                        self.input = tail;
                        dec.data_bytes = dec.data_bytes.saturating_add(data.len() as u64);
                        return Some(Piece::Data(data));
                    }
                    // `first` is the mark byte.
                    self.input = rest;
                    dec.state = State::Mark;
                }
                State::Mark => match first {
                    MARK => {
                        // FF FF: the data byte FF (the second FF is the byte itself).
                        let (data, tail) = self.input.split_at(1);
                        self.input = tail;
                        dec.state = State::Plain;
                        dec.data_bytes = dec.data_bytes.saturating_add(1);
                        return Some(Piece::Data(data));
                    }
                    0x00 => {
                        self.input = rest;
                        dec.state = State::MarkZero;
                    }
                    _ => {
                        // Not a mark the kernel writes (it doubles every FF): the FF was data.
                        // Keep `first` for the next round, so that nothing is dropped.
                        dec.state = State::Plain;
                        dec.data_bytes = dec.data_bytes.saturating_add(1);
                        return Some(Piece::Data(&[MARK]));
                    }
                },
                State::MarkZero => {
                    self.input = rest;
                    dec.state = State::Plain;
                    let error = if first == 0x00 {
                        LineError::Break
                    } else {
                        LineError::ParityOrFraming
                    };
                    return Some(Piece::Error {
                        error,
                        at: dec.data_bytes,
                    });
                }
            }
        }
    }
}

/// One element of a received stream, for [`encode`]: a good data byte, a faulty character, or a
/// BREAK.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Received {
    /// A byte received without error.
    Byte(u8),
    /// The byte as the UART read it with a parity or framing error: the mark `FF 00 x`, which
    /// decodes to [`LineError::ParityOrFraming`]. A faulty `00` is the mark of a BREAK (the
    /// kernel's marks cannot tell them apart) and decodes to [`LineError::Break`].
    Faulty(u8),
    /// A BREAK (`FF 00 00`).
    Break,
}

// === impl Received ===

impl Received {
    /// What [`MarkDecoder`] yields for this element: the byte, or the line error.
    pub const fn decoded(self) -> Result<u8, LineError> {
        match self {
            Self::Byte(b) => Ok(b),
            Self::Faulty(0) | Self::Break => Err(LineError::Break),
            Self::Faulty(_) => Err(LineError::ParityOrFraming),
        }
    }
}

/// Appends `items` to `out` the way the tty layer delivers them with `INPCK | PARMRK`: the inverse
/// of [`MarkDecoder`], for tests and simulated lines.
pub fn encode(items: impl IntoIterator<Item = Received>, out: &mut Vec<u8>) {
    for item in items {
        match item {
            Received::Byte(MARK) => out.extend_from_slice(&[MARK, MARK]),
            Received::Byte(b) => out.push(b),
            Received::Faulty(byte) => out.extend_from_slice(&[MARK, 0x00, byte]),
            Received::Break => out.extend_from_slice(&[MARK, 0x00, 0x00]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Decodes `chunks` with one decoder and returns data bytes and errors in order.
    fn decode_chunks(chunks: &[&[u8]]) -> (Vec<Result<u8, LineError>>, MarkDecoder) {
        let mut dec = MarkDecoder::new();
        let mut out = Vec::new();
        for chunk in chunks {
            for piece in dec.decode(chunk) {
                match piece {
                    Piece::Data(d) => out.extend(d.iter().copied().map(Ok)),
                    Piece::Error { error, .. } => out.push(Err(error)),
                }
            }
        }
        (out, dec)
    }

    /// Every way to split `input` into two and three reads gives `expected`.
    fn check_all_splits(input: &[u8], expected: &[Result<u8, LineError>]) {
        let (whole, dec) = decode_chunks(&[input]);
        assert_eq!(whole, expected, "whole {input:02X?}");
        assert!(!dec.in_mark());
        for i in 0..=input.len() {
            let (a, b) = input.split_at(i);
            let (got, dec) = decode_chunks(&[a, b]);
            assert_eq!(got, expected, "split at {i} of {input:02X?}");
            assert!(!dec.in_mark());
            for j in i..=input.len() {
                let (b1, b2) = input[i..].split_at(j - i);
                let (got, _) = decode_chunks(&[a, b1, b2]);
                assert_eq!(got, expected, "split at {i} and {j} of {input:02X?}");
            }
        }
    }

    use Received::{Byte, Faulty};

    #[test]
    fn plain_read_is_one_borrowed_slice() {
        let input = [0x01, 0x03, 0x02, 0x00, 0x2A];
        let mut dec = MarkDecoder::new();
        let pieces: Vec<_> = dec.decode(&input).collect();
        assert_eq!(pieces, vec![Piece::Data(&input)]);
        assert!(matches!(pieces[0], Piece::Data(d) if core::ptr::eq(d, &input[..])));
        assert_eq!(dec.data_bytes(), 5);
        assert_eq!(dec.decode(&[]).count(), 0);
    }

    #[test]
    fn doubled_ff_is_one_data_byte_at_every_split() {
        check_all_splits(&[0x10, 0xFF, 0xFF, 0x20], &[Ok(0x10), Ok(0xFF), Ok(0x20)]);
        check_all_splits(&[0xFF, 0xFF, 0xFF, 0xFF], &[Ok(0xFF), Ok(0xFF)]);
    }

    #[test]
    fn character_error_mark_at_every_split() {
        check_all_splits(
            &[0x41, 0xFF, 0x00, 0x7E, 0x42],
            &[Ok(0x41), Err(LineError::ParityOrFraming), Ok(0x42)],
        );
        // A faulty FF is not doubled inside the mark.
        check_all_splits(
            &[0xFF, 0x00, 0xFF, 0xFF, 0xFF],
            &[Err(LineError::ParityOrFraming), Ok(0xFF)],
        );
    }

    #[test]
    fn break_mark_at_every_split() {
        check_all_splits(
            &[0x01, 0xFF, 0x00, 0x00, 0x00, 0x02],
            &[Ok(0x01), Err(LineError::Break), Ok(0x00), Ok(0x02)],
        );
        check_all_splits(
            &[0xFF, 0x00, 0x00, 0xFF, 0x00, 0x00],
            &[Err(LineError::Break), Err(LineError::Break)],
        );
    }

    #[test]
    fn errors_carry_their_position_in_the_data() {
        let mut dec = MarkDecoder::new();
        let first: Vec<_> = dec.decode(&[1, 2, 0xFF, 0xFF, 0xFF]).collect();
        assert_eq!(first, vec![Piece::Data(&[1, 2]), Piece::Data(&[0xFF])]);
        assert!(dec.in_mark());
        let second: Vec<_> = dec.decode(&[0x00, 0x00, 9]).collect();
        assert_eq!(
            second,
            vec![
                Piece::Error {
                    error: LineError::Break,
                    at: 3
                },
                Piece::Data(&[9])
            ]
        );
        dec.reset();
        assert_eq!(dec.data_bytes(), 0);
        assert!(!dec.in_mark());
    }

    #[test]
    fn a_lone_ff_is_kept_as_data() {
        // The kernel never writes FF followed by anything but FF or 00; if it did, nothing is lost.
        check_all_splits(&[0xFF, 0x41, 0x42], &[Ok(0xFF), Ok(0x41), Ok(0x42)]);
    }

    #[test]
    fn line_errors_raise_the_catalog_events() {
        assert_eq!(LineError::ParityOrFraming.event(), ids::CHARACTER_ERROR);
        assert_eq!(LineError::Parity.event(), ids::CHARACTER_ERROR);
        assert_eq!(LineError::Framing.event(), ids::CHARACTER_ERROR);
        assert_eq!(LineError::Overrun.event(), ids::CHARACTER_ERROR);
        assert_eq!(LineError::Break.event(), ids::LINE_BREAK);
        assert!(LineError::Break.is_break());
        assert!(!LineError::Overrun.is_break());
    }

    #[test]
    fn encode_marks_like_the_kernel() {
        let mut out = Vec::new();
        let items = [
            Byte(0xFF),
            Byte(1),
            Faulty(0x55),
            Received::Break,
            Faulty(0),
        ];
        encode(items, &mut out);
        assert_eq!(
            out,
            [0xFF, 0xFF, 1, 0xFF, 0x00, 0x55, 0xFF, 0x00, 0x00, 0xFF, 0x00, 0x00]
        );
        let (decoded, _) = decode_chunks(&[&out]);
        let expected: Vec<_> = items.iter().map(|r| r.decoded()).collect();
        assert_eq!(decoded, expected);
        assert_eq!(expected[2], Err(LineError::ParityOrFraming));
        assert_eq!(expected[4], Err(LineError::Break));
    }
}
