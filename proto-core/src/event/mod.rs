//! The CP 341 event catalog (manual 003, chapter 7.2), the STATUS word and the diagnostic buffer.
//!
//! Every diagnostic event of a line is identified by its class and number, exactly as the CP
//! reports them in the STATUS output of its function blocks (bits 12..8 class, 7..0 number).
//!
//! - [`EventId`] and [`Status`]: the identity of an event and the STATUS word that carries it;
//! - [`catalog`]: every event of 7.2 as static data ([`lookup`], [`all`], [`class_name`]);
//! - [`ids`]: a named constant for every event;
//! - [`diag`]: the diagnostic buffer of 7.3 ([`DiagBuffer`]).

pub mod catalog;
pub mod diag;
pub mod ids;

pub use catalog::{
    all, class_name, classes, diag_event_id, lookup, master_exception_event, EventInfo,
};
pub use diag::{DiagBuffer, DiagEntry, DEFAULT_DEPTH};

/// One event of chapter 7.2: a class (00h..1Fh) and a number within it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct EventId {
    /// Event class, e.g. `0x08` "receive errors".
    pub class: u8,
    /// Event number within the class, e.g. `0x30` "no reply".
    pub number: u8,
}

// === impl EventId ===

impl EventId {
    /// An event id from its class and number.
    pub const fn new(class: u8, number: u8) -> Self {
        Self { class, number }
    }

    /// The 16-bit STATUS word of the CP: bits 12..8 the class, bits 7..0 the number (7.2).
    pub const fn status_word(self) -> u16 {
        (((self.class & 0x1F) as u16) << 8) | self.number as u16
    }

    /// The event id encoded in a STATUS word.
    pub const fn from_status_word(word: u16) -> Self {
        Self {
            class: ((word >> 8) & 0x1F) as u8,
            number: (word & 0xFF) as u8,
        }
    }
}

impl core::fmt::Display for EventId {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{:02X} {:02X}h", self.class, self.number)
    }
}

/// The STATUS output of FB 7 P_RCV_RK / FB 8 P_SND_RK as a whole word.
///
/// Layout (000 and 003 7.2, "STATUS"): bits 15..13 reserved, bits 12..8 event class, bits 7..0
/// event number. The manual defines no further bits. 003 7.1: "An error message is only output if
/// the ERROR bit (request completed with error) is set. In all other cases the STATUS word is
/// zero", so the word 0000h means "no event", not an event 00 00h (class 00 has no number 00h).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Status(pub u16);

// === impl Status ===

impl Status {
    /// The STATUS word of a request that completed without error (003 7.1).
    pub const NONE: Self = Self(0);

    /// The bits the manual reserves (15..13, 7.2).
    pub const RESERVED_MASK: u16 = 0xE000;

    /// The STATUS word that reports `id` (reserved bits zero).
    pub const fn from_event(id: EventId) -> Self {
        Self(id.status_word())
    }

    /// The event the word reports, `None` for the word 0000h (no error).
    pub const fn event(self) -> Option<EventId> {
        if self.0 & !Self::RESERVED_MASK == 0 {
            None
        } else {
            Some(EventId::from_status_word(self.0))
        }
    }

    /// The reserved bits 15..13, zero in every word the CP writes.
    pub const fn reserved_bits(self) -> u16 {
        self.0 & Self::RESERVED_MASK
    }
}

impl From<EventId> for Status {
    fn from(id: EventId) -> Self {
        Self::from_event(id)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_word_layout() {
        let id = EventId::new(0x08, 0x30);
        assert_eq!(id.status_word(), 0x0830);
        assert_eq!(EventId::from_status_word(0xE830), id);
        assert_eq!(Status(0xE830).reserved_bits(), 0xE000);
        assert_eq!(Status(0xE830).event(), Some(id));
        assert_eq!(Status::NONE.event(), None);
        assert_eq!(Status(0xE000).event(), None);
        assert_eq!(Status::from(id), Status(0x0830));
        assert_eq!(id.to_string(), "08 30h");
    }
}
