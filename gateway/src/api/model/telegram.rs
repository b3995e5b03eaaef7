//! Received telegrams waiting to be acknowledged, and telegrams to send (ASCII and 3964(R)
//! lines; the REST view of the mailbox modeled on FB 7 P_RCV_RK / FB 8 P_SND_RK).

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use super::{EventView, Timestamp};
use crate::api::error::ApiError;

/// The CP's buffer holds at most 1024 bytes a telegram (003 6.2, 6.3); a line's configured
/// `max_telegram_len` may be lower and is checked by the line.
pub const MAX_TELEGRAM_LEN: usize = 1024;

/// A received telegram in a line's queue.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct Telegram {
    /// Its sequence number on the line (acknowledge with it).
    pub seq: u32,
    /// When it was received.
    pub received: Timestamp,
    /// Length in bytes.
    pub len: usize,
    /// The bytes as lower-case hex, two digits a byte.
    pub hex: String,
    /// The bytes as text when they are printable ASCII (with CR, LF, TAB).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub text: Option<String>,
    /// On a `3964r-tap` line, the partner that sent it: `a` (the line's `port`) or `b`
    /// (`port_b`); absent on every other line.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub side: Option<String>,
}

// === impl Telegram ===

impl Telegram {
    pub fn new(seq: u32, received: impl Into<Timestamp>, data: &[u8]) -> Self {
        let printable = data
            .iter()
            .all(|b| b.is_ascii_graphic() || matches!(b, b' ' | b'\r' | b'\n' | b'\t'));
        Self {
            seq,
            received: received.into(),
            len: data.len(),
            hex: hex(data),
            text: printable.then(|| String::from_utf8_lossy(data).into_owned()),
            side: None,
        }
    }

    /// The telegram as sent by `side` (a tap line's telegram), if it says.
    #[must_use]
    pub fn from_side(mut self, side: Option<&str>) -> Self {
        self.side = side.map(str::to_owned);
        self
    }
}

/// A line's queue of received telegrams, oldest first.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct TelegramQueue {
    pub line: String,
    /// Telegrams the queue holds at most (`receive_buffer`).
    pub capacity: usize,
    /// Telegrams dropped since the line started because the queue was full.
    pub dropped: u64,
    /// Oldest first; the first is the one to acknowledge next.
    pub telegrams: Vec<Telegram>,
}

/// A telegram to send: exactly one of `hex` or `text`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct SendRequest {
    /// Bytes as hex digits, spaces allowed between bytes (`"02 41 42 03"`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hex: Option<String>,
    /// Bytes as text (UTF-8).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub text: Option<String>,
}

// === impl SendRequest ===

impl SendRequest {
    /// The bytes to send: 1..=1024 of them.
    pub fn bytes(&self) -> Result<Vec<u8>, ApiError> {
        let data = match (&self.hex, &self.text) {
            (Some(h), None) => parse_hex(h)?,
            (None, Some(t)) => t.as_bytes().to_vec(),
            _ => return Err(ApiError::invalid_body("give exactly one of hex or text")),
        };
        if data.is_empty() || data.len() > MAX_TELEGRAM_LEN {
            return Err(ApiError::invalid_body(format!(
                "a telegram has 1..={MAX_TELEGRAM_LEN} bytes, not {}",
                data.len()
            )));
        }
        Ok(data)
    }
}

/// The outcome of a send (as DONE / ERROR / STATUS of FB 8 P_SND_RK).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct SendResult {
    /// The telegram was sent and, with 3964(R), acknowledged by the partner.
    pub done: bool,
    /// The STATUS word: 0 when done, else the event's class and number.
    pub status_word: u16,
    /// The event of a failed send, from the catalog.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub event: Option<EventView>,
    /// Bytes sent.
    pub len: usize,
}

// === impl SendResult ===

impl SendResult {
    /// A completed send of `len` bytes.
    pub fn done(len: usize) -> Self {
        Self {
            done: true,
            status_word: 0,
            event: None,
            len,
        }
    }

    /// A send that ended with the event in `status_word`.
    pub fn failed(status_word: u16, len: usize) -> Self {
        Self {
            done: false,
            status_word,
            event: EventView::from_status_word(status_word),
            len,
        }
    }
}

fn hex(data: &[u8]) -> String {
    use std::fmt::Write;
    let mut s = String::with_capacity(data.len() * 2);
    for b in data {
        let _ = write!(s, "{b:02x}");
    }
    s
}

/// Hex digits in pairs; spaces, `:` and `-` between bytes are ignored.
fn parse_hex(text: &str) -> Result<Vec<u8>, ApiError> {
    let digits: Vec<u8> = text
        .bytes()
        .filter(|b| !matches!(b, b' ' | b':' | b'-'))
        .collect();
    if digits.len() % 2 != 0 {
        return Err(ApiError::invalid_body("hex: an odd number of digits"));
    }
    digits
        .chunks_exact(2)
        .map(|pair| {
            std::str::from_utf8(pair)
                .ok()
                .and_then(|p| u8::from_str_radix(p, 16).ok())
                .ok_or_else(|| {
                    ApiError::invalid_body(format!(
                        "hex: {:?} is not a hex byte",
                        String::from_utf8_lossy(pair)
                    ))
                })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use std::time::SystemTime;

    use super::*;

    fn send(hex: Option<&str>, text: Option<&str>) -> Result<Vec<u8>, ApiError> {
        SendRequest {
            hex: hex.map(Into::into),
            text: text.map(Into::into),
        }
        .bytes()
    }

    #[test]
    fn send_requests_take_hex_or_text() {
        assert_eq!(send(Some("02 41:42-03"), None).unwrap(), [2, 0x41, 0x42, 3]);
        assert_eq!(send(None, Some("AB")).unwrap(), b"AB");
        assert_eq!(send(Some("0"), None).unwrap_err().code(), "invalid_body");
        assert_eq!(send(Some("zz"), None).unwrap_err().code(), "invalid_body");
        assert_eq!(send(Some("é1"), None).unwrap_err().code(), "invalid_body");
        assert_eq!(send(None, None).unwrap_err().code(), "invalid_body");
        assert_eq!(
            send(Some("00"), Some("a")).unwrap_err().code(),
            "invalid_body"
        );
        assert_eq!(send(None, Some("")).unwrap_err().code(), "invalid_body");
        assert!(send(None, Some(&"x".repeat(MAX_TELEGRAM_LEN))).is_ok());
        assert!(send(None, Some(&"x".repeat(MAX_TELEGRAM_LEN + 1))).is_err());
    }

    #[test]
    fn telegrams_show_hex_and_printable_text() {
        let t = Telegram::new(7, SystemTime::UNIX_EPOCH, b"AB\r\n");
        assert_eq!(t.hex, "41420d0a");
        assert_eq!(t.text.as_deref(), Some("AB\r\n"));
        assert_eq!(
            Telegram::new(8, SystemTime::UNIX_EPOCH, &[2, 0xFF]).text,
            None
        );
        let f = SendResult::failed(0x0709, 3);
        assert!(!f.done);
        assert_eq!(f.event.unwrap().code, "0709");
    }
}
