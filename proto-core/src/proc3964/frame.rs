//! The 3964(R) telegram on the wire: DLE doubling, the closing DLE ETX and the BCC (003 6.3.1).
//!
//! The connection setup (STX, answered by DLE) and the acknowledgement are the machine's business
//! ([`super::Proc3964`]); this module only turns user data into the bytes sent after the partner's
//! DLE, and those bytes back into user data.

use crate::checksum;
use crate::event::{ids, EventId};

use super::{Variant, DLE, ETX};

/// The bytes sent after the partner answered STX with DLE: the user data with every DLE doubled,
/// then DLE ETX, then for 3964R the BCC.
///
/// 003 6.3.1 "Data Link Escape": "The driver duplicates any DLE-character that is contained in a
/// telegram ... The telegram always terminates with the sequence DLE/ETX/BCC (only for 3964R)."
/// "Block check character": the XOR "over the entire data of the telegram, including the DLE/ETX",
/// as transmitted, so a doubled DLE contributes twice.
pub fn encode(data: &[u8], variant: Variant) -> Vec<u8> {
    let doubled = data.iter().filter(|&&b| b == DLE).count();
    let mut frame = Vec::with_capacity(data.len() + doubled + 3);
    for &byte in data {
        frame.push(byte);
        if byte == DLE {
            frame.push(DLE);
        }
    }
    frame.extend_from_slice(&[DLE, ETX]);
    if variant == Variant::P3964R {
        frame.push(checksum::bcc(&frame));
    }
    frame
}

/// What is wrong with a received telegram.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// A DLE followed by a code other than DLE or ETX.
    #[error("DLE followed by 0x{0:02X} instead of DLE or ETX")]
    DleFollowedBy(u8),
    /// More user bytes than the receive limit.
    #[error("more than {max} user bytes")]
    TooLong {
        /// The limit.
        max: usize,
    },
    /// The BCC received differs from the one computed.
    #[error("BCC 0x{actual:02X} received, 0x{expected:02X} computed")]
    BadBcc {
        /// The XOR of the bytes received.
        expected: u8,
        /// The BCC byte received.
        actual: u8,
    },
    /// The telegram has not ended yet (no DLE ETX, or no BCC after it).
    #[error("telegram incomplete")]
    Incomplete,
}

// === impl FrameError ===

impl FrameError {
    /// The receive error of 7.2 for this fault.
    pub const fn event(self) -> EventId {
        match self {
            // 7.2, 08 05h: "After DLE was received, a further random code (other than DLE or ETX)."
            Self::DleFollowedBy(_) => ids::RECEIVE_LOGICAL_ERROR,
            // 7.2, 08 16h: "The length of a received message frame was longer than agreed upon."
            Self::TooLong { .. } => ids::FRAME_TOO_LONG,
            // 7.2, 08 08h: "Internally calculated value of BCC does not match BCC received."
            Self::BadBcc { .. } => ids::BCC_ERROR,
            // 7.2, 08 06h: the end did not arrive within the character delay time.
            Self::Incomplete => ids::CHARACTER_DELAY_EXCEEDED,
        }
    }
}

/// Whether the telegram has ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Progress {
    /// More bytes are needed.
    Incomplete,
    /// DLE ETX (3964R: and the BCC) arrived; call [`Deframer::finish`].
    Complete,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    /// Inside the user data.
    Data,
    /// After a DLE: DLE (a doubled data DLE) or ETX must follow.
    Dle,
    /// After DLE ETX, 3964R: the BCC comes next.
    Bcc,
    /// The telegram ended.
    Done,
}

/// Turns the bytes received after our DLE back into user data, one byte at a time.
///
/// It keeps going after an error, so that the machine answers NAK only once the partner has
/// finished (7.2, 08 0Ch: "If this occurs during send or receive operation, repetitions are
/// initiated"), and remembers the first error.
#[derive(Clone, Debug)]
pub struct Deframer {
    /// With or without BCC.
    variant: Variant,
    /// At most this many user bytes are kept (7.2, 08 16h beyond).
    max_len: usize,
    /// The user data so far, DLE doubling removed.
    data: Vec<u8>,
    /// XOR of every byte received so far, as transmitted.
    bcc: u8,
    /// Where in the telegram the next byte falls.
    phase: Phase,
    /// The first fault seen.
    error: Option<FrameError>,
}

// === impl Deframer ===

impl Deframer {
    /// A deframer for one telegram of at most `max_len` user bytes.
    pub fn new(variant: Variant, max_len: usize) -> Self {
        Self {
            variant,
            max_len,
            data: Vec::new(),
            bcc: 0,
            phase: Phase::Data,
            error: None,
        }
    }

    /// Takes the next received byte. Bytes after the end are ignored.
    pub fn push(&mut self, byte: u8) -> Progress {
        match self.phase {
            Phase::Data => {
                self.bcc ^= byte;
                if byte == DLE {
                    self.phase = Phase::Dle;
                } else {
                    self.keep(byte);
                }
            }
            Phase::Dle => {
                self.bcc ^= byte;
                self.phase = Phase::Data;
                match byte {
                    DLE => self.keep(DLE),
                    ETX if self.variant == Variant::P3964R => self.phase = Phase::Bcc,
                    ETX => self.phase = Phase::Done,
                    other => self.fail(FrameError::DleFollowedBy(other)),
                }
            }
            Phase::Bcc => {
                if byte != self.bcc {
                    self.fail(FrameError::BadBcc {
                        expected: self.bcc,
                        actual: byte,
                    });
                }
                self.phase = Phase::Done;
            }
            Phase::Done => {}
        }
        self.progress()
    }

    /// Whether the telegram has ended.
    pub fn progress(&self) -> Progress {
        if self.phase == Phase::Done {
            Progress::Complete
        } else {
            Progress::Incomplete
        }
    }

    /// The first fault seen so far.
    pub fn error(&self) -> Option<FrameError> {
        self.error
    }

    /// The user data.
    ///
    /// # Errors
    ///
    /// The first fault seen, or [`FrameError::Incomplete`] before the end.
    pub fn finish(self) -> Result<Vec<u8>, FrameError> {
        match (self.error, self.phase) {
            (Some(error), _) => Err(error),
            (None, Phase::Done) => Ok(self.data),
            (None, _) => Err(FrameError::Incomplete),
        }
    }

    fn keep(&mut self, byte: u8) {
        if self.data.len() < self.max_len {
            self.data.push(byte);
        } else {
            self.fail(FrameError::TooLong { max: self.max_len });
        }
    }

    fn fail(&mut self, error: FrameError) {
        self.error.get_or_insert(error);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn deframe(bytes: &[u8], variant: Variant) -> Result<Vec<u8>, FrameError> {
        let mut d = Deframer::new(variant, 1024);
        for &b in bytes {
            d.push(b);
        }
        d.finish()
    }

    #[test]
    fn manual_vectors() {
        // vectors/README.md, 3964(R) table (both CP 341 manuals, 6.3).
        assert_eq!(
            encode(b"ABC", Variant::P3964R),
            [0x41, 0x42, 0x43, 0x10, 0x03, 0x53]
        );
        assert_eq!(
            encode(&[0x10, 0x20], Variant::P3964R),
            [0x10, 0x10, 0x20, 0x10, 0x03, 0x33]
        );
        assert_eq!(
            encode(b"ABC", Variant::P3964),
            [0x41, 0x42, 0x43, 0x10, 0x03]
        );
        assert_eq!(
            deframe(&[0x10, 0x10, 0x20, 0x10, 0x03, 0x33], Variant::P3964R),
            Ok(vec![0x10, 0x20])
        );
        assert_eq!(
            deframe(&[0x41, 0x42, 0x43, 0x10, 0x03, 0x54], Variant::P3964R),
            Err(FrameError::BadBcc {
                expected: 0x53,
                actual: 0x54
            })
        );
    }

    #[test]
    fn faults_are_kept_until_the_end() {
        let mut d = Deframer::new(Variant::P3964R, 2);
        for &b in &[0x41, 0x10, 0x07, 0x42, 0x43, 0x44] {
            assert_eq!(d.push(b), Progress::Incomplete);
        }
        assert_eq!(d.error(), Some(FrameError::DleFollowedBy(0x07)));
        assert_eq!(d.push(0x10), Progress::Incomplete);
        assert_eq!(d.push(0x03), Progress::Incomplete);
        assert_eq!(d.push(0x00), Progress::Complete);
        assert_eq!(
            d.push(0x00),
            Progress::Complete,
            "bytes after the end are ignored"
        );
        assert_eq!(d.finish(), Err(FrameError::DleFollowedBy(0x07)));
        assert_eq!(
            deframe(&[1, 2, 3, 0x10, 0x03], Variant::P3964).map(|d| d.len()),
            Ok(3)
        );
        let mut short = Deframer::new(Variant::P3964, 2);
        [1, 2, 3, 0x10, 0x03].iter().for_each(|&b| {
            short.push(b);
        });
        assert_eq!(short.finish(), Err(FrameError::TooLong { max: 2 }));
        assert_eq!(
            deframe(&[1, 0x10], Variant::P3964),
            Err(FrameError::Incomplete)
        );
    }
}
