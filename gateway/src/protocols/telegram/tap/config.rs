//! The listen-only 3964(R) tap line: its keys.
//!
//! A 3964(R) tap line reads the two directions of a point-to-point link on two ports (a Y-cable)
//! and keeps the telegrams both partners exchanged in a read-only mailbox.

use std::time::Duration;

use serde::Serialize;

use crate::config::check::{Check, Line};
use crate::config::reader::{Cx, Fields};
use crate::config::section::ProtocolSection;
use crate::config::Baud;
use crate::protocols::telegram::config::{check_3964_link, mailbox_unit_id, Link3964};
use crate::protocols::ReadSection;

/// `protocol = "3964r-tap"`: listens to both directions of a 3964(R) point-to-point link through
/// a Y-cable, `port` receiving what partner A transmits and `port_b` what partner B transmits.
/// It never transmits; the telegrams go to a read-only mailbox.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Proc3964TapConfig {
    /// The second receive port: partner B's transmit line (same serial settings as `port`).
    pub port_b: String,
    /// The partners use 3964R (with BCC) or 3964.
    pub block_check: bool,
    /// The partners' character delay time (ZVZ).
    #[serde(with = "humantime_serde")]
    pub character_delay: Duration,
    /// The partners' acknowledgement delay time (QVZ).
    #[serde(with = "humantime_serde")]
    pub ack_delay: Duration,
    /// Longest telegram, 1..=1024 bytes.
    pub max_telegram_len: u16,
    /// Telegrams the mailbox keeps, 1..=250; when it is full the oldest goes (a tap cannot
    /// refuse a telegram: it is not a partner).
    pub receive_buffer: u16,
    /// Modbus TCP unit id of the mailbox, if served (read-only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unit_id: Option<u8>,
}

// === impl ReadSection ===

impl ReadSection for Proc3964TapConfig {
    fn read_section(cx: &mut Cx, f: &mut Fields<'_>, _baud: Baud) -> Self {
        let port_b = f.required_string(cx, "port_b").unwrap_or_default();
        if f.has("port_b") && port_b.is_empty() {
            cx.issue(f.at("port_b"), "must not be empty");
        }
        let link = Link3964::read(cx, f);
        Self {
            port_b,
            block_check: link.block_check,
            character_delay: link.character_delay,
            ack_delay: link.ack_delay,
            max_telegram_len: link.max_telegram_len,
            receive_buffer: link.receive_buffer,
            unit_id: mailbox_unit_id(cx, f),
        }
    }
}

// === impl ProtocolSection ===

impl Check<Line<'_>> for Proc3964TapConfig {
    fn check(&self, line: &Line<'_>, cx: &mut Cx) {
        check_3964_link(
            cx,
            line.path,
            line.serial,
            (self.character_delay, self.ack_delay),
        );
    }
}

impl ProtocolSection for Proc3964TapConfig {
    fn second_port(&self) -> Option<&str> {
        Some(&self.port_b)
    }

    fn unit_id(&self) -> Option<u8> {
        self.unit_id
    }
}
