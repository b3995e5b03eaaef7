//! The CP 341 event catalog (manual 003, chapter 7.2), the STATUS word and the diagnostic buffer.
//!
//! Every diagnostic event of a line is identified by its class and number, exactly as the CP
//! reports them in the STATUS output of its function blocks (bits 12..8 class, 7..0 number).

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
        Self { class: ((word >> 8) & 0x1F) as u8, number: (word & 0xFF) as u8 }
    }
}

impl core::fmt::Display for EventId {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{:02X} {:02X}h", self.class, self.number)
    }
}
