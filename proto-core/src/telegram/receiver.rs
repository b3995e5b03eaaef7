//! The ASCII driver's receive side: cutting the byte stream into telegrams (003 6.2.1 "End code of
//! a message").

use core::time::Duration;

use crate::event::{ids, EventId};
use crate::time::Instant;

use super::config::{EndCriterion, MAX_TELEGRAM};

/// What ended a telegram.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum Outcome {
    /// A complete telegram without error.
    Telegram(Vec<u8>),
    /// The telegram was discarded for this reason (003 6.2: "A telegram is only passed on to the
    /// CPU if this was received completely").
    Discarded(EventId),
}

/// A telegram being collected.
#[derive(Clone, Debug)]
struct Collecting {
    /// The bytes so far (at most [`MAX_TELEGRAM`]).
    data: Vec<u8>,
    /// Characters received, including faulty ones and the ones beyond the limit.
    count: usize,
    /// The previous character, for two end characters.
    last: Option<u8>,
    /// When the character delay time expires.
    deadline: Instant,
    /// The first error; the telegram is discarded at its end.
    fault: Option<EventId>,
}

/// Cuts received characters into telegrams by the configured end criterion. The character delay
/// time is watched in every mode: 003 6.2.1 "The character delay time (ZVZ) defines the maximum
/// amount of time permitted between two incoming characters within a message frame."
#[derive(Clone, Debug)]
pub(crate) struct Receiver {
    /// How a telegram ends.
    end: EndCriterion,
    /// The character delay time.
    zvz: Duration,
    /// The telegram in progress, if any.
    current: Option<Collecting>,
}

// === impl Receiver ===

impl Receiver {
    pub(crate) fn new(end: EndCriterion, zvz: Duration) -> Self {
        Self {
            end,
            zvz,
            current: None,
        }
    }

    /// When the telegram in progress times out.
    pub(crate) fn deadline(&self) -> Option<Instant> {
        self.current.as_ref().map(|c| c.deadline)
    }

    /// Takes one received character (already masked to the data bits).
    pub(crate) fn push(&mut self, now: Instant, byte: u8) -> Option<Outcome> {
        let end = self.end;
        let current = self.collecting(now);
        if current.data.len() < MAX_TELEGRAM {
            current.data.push(byte);
        } else {
            // 7.2, 08 16h: "The length of a received message frame was longer than the length
            // agreed upon" (003 6.2.1: at most 1024 bytes).
            current.fault.get_or_insert(ids::FRAME_TOO_LONG);
        }
        let ended = match end {
            EndCriterion::CharacterDelay => false,
            EndCriterion::FixedLength(len) => current.count >= usize::from(len),
            EndCriterion::EndChars {
                first,
                second: None,
            } => byte == first,
            EndCriterion::EndChars {
                first,
                second: Some(second),
            } => current.last == Some(first) && byte == second,
        };
        current.last = Some(byte);
        ended.then(|| self.finish())
    }

    /// Takes a character the UART received with an error: it counts, and spoils the telegram.
    pub(crate) fn push_faulty(&mut self, now: Instant, cause: EventId) -> Option<Outcome> {
        let end = self.end;
        let current = self.collecting(now);
        current.fault.get_or_insert(cause);
        current.last = None;
        let ended =
            matches!(end, EndCriterion::FixedLength(len) if current.count >= usize::from(len));
        ended.then(|| self.finish())
    }

    /// Ends the telegram in progress when the character delay time has expired.
    pub(crate) fn handle_timeout(&mut self, now: Instant) -> Option<Outcome> {
        if self.deadline()? > now {
            return None;
        }
        match self.end {
            // 003 6.2: "Individual messages are separated by means of character delay time".
            EndCriterion::CharacterDelay => Some(self.finish()),
            // With the other criteria the gap came before the end: 7.2, 08 06h "Two successive
            // characters were not received within character delay time".
            EndCriterion::FixedLength(_) | EndCriterion::EndChars { .. } => {
                let current = self.current.take()?;
                Some(Outcome::Discarded(
                    current.fault.unwrap_or(ids::CHARACTER_DELAY_EXCEEDED),
                ))
            }
        }
    }

    /// Drops the telegram in progress; returns whether there was one.
    pub(crate) fn abort(&mut self) -> bool {
        self.current.take().is_some()
    }

    fn collecting(&mut self, now: Instant) -> &mut Collecting {
        let deadline = now + self.zvz;
        let current = self.current.get_or_insert_with(|| Collecting {
            data: Vec::new(),
            count: 0,
            last: None,
            deadline,
            fault: None,
        });
        current.count += 1;
        current.deadline = deadline;
        current
    }

    fn finish(&mut self) -> Outcome {
        match self.current.take() {
            Some(Collecting {
                fault: Some(cause), ..
            }) => Outcome::Discarded(cause),
            Some(Collecting { data, .. }) => Outcome::Telegram(data),
            None => Outcome::Telegram(Vec::new()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ZVZ: Duration = Duration::from_millis(4);

    fn feed(r: &mut Receiver, now: Instant, bytes: &[u8]) -> Vec<Outcome> {
        bytes.iter().filter_map(|&b| r.push(now, b)).collect()
    }

    #[test]
    fn fixed_length_cuts_and_a_gap_discards() {
        let mut r = Receiver::new(EndCriterion::FixedLength(3), ZVZ);
        let t = Instant::from_millis(1);
        assert_eq!(
            feed(&mut r, t, b"abcdefg"),
            [
                Outcome::Telegram(b"abc".to_vec()),
                Outcome::Telegram(b"def".to_vec())
            ]
        );
        assert_eq!(r.deadline(), Some(t + ZVZ));
        assert_eq!(r.handle_timeout(t), None, "not yet");
        assert_eq!(
            r.handle_timeout(t + ZVZ),
            Some(Outcome::Discarded(ids::CHARACTER_DELAY_EXCEEDED))
        );
        assert_eq!(r.deadline(), None);
    }

    #[test]
    fn two_end_characters_and_faults() {
        let mut r = Receiver::new(
            EndCriterion::EndChars {
                first: b'\r',
                second: Some(b'\n'),
            },
            ZVZ,
        );
        let t = Instant::ZERO;
        assert_eq!(
            feed(&mut r, t, b"a\rb\r\nc"),
            [Outcome::Telegram(b"a\rb\r\n".to_vec())]
        );
        assert_eq!(r.push_faulty(t, ids::CHARACTER_ERROR), None);
        assert_eq!(
            feed(&mut r, t, b"\r\n"),
            [Outcome::Discarded(ids::CHARACTER_ERROR)]
        );
        let mut long = Receiver::new(EndCriterion::CharacterDelay, ZVZ);
        assert!(feed(&mut long, t, &[0x55; MAX_TELEGRAM + 1]).is_empty());
        assert_eq!(
            long.handle_timeout(t + ZVZ),
            Some(Outcome::Discarded(ids::FRAME_TOO_LONG))
        );
    }
}
