//! The listen-only tap lines: their keys.
//!
//! A Modbus RTU tap line lists devices as a master line does (address, unit id, profile or tags)
//! but polls nothing: it stores what another master's requests and the devices' answers show.
//! A 3964(R) tap line reads the two directions of a point-to-point link on two ports (a Y-cable)
//! and keeps the telegrams both partners exchanged in a read-only mailbox.

use std::collections::BTreeMap;
use std::time::Duration;

use serde::Serialize;

use crate::config::reader::{Cx, Fields};
use crate::config::section::ProtocolSection;
use crate::config::DeviceConfig;
use crate::config::SerialConfig;
use crate::protocols::modbus_master::config::{
    check_rtu_data_bits, read_devices, DEFAULT_DELAY_MULTIPLIER, MAX_DELAY_MULTIPLIER,
};
use crate::protocols::telegram::config::{check_3964_link, mailbox_unit_id, Link3964};

/// How long a request waits for its answer by default (see `proto_core::modbus::tap`).
pub const DEFAULT_ANSWER_TIMEOUT: Duration = proto_core::modbus::tap::DEFAULT_ANSWER_TIMEOUT;
/// Range of `answer_timeout`: the CP's range of the reply monitoring time (003 6.4.2.1 "Reply
/// monitoring time ... Range: 5 ... 65500ms").
pub const ANSWER_TIMEOUT_RANGE: (Duration, Duration) =
    (Duration::from_millis(5), Duration::from_millis(65_500));
/// How often the other master is expected to read a value by default: a value not seen again
/// within the image's stale factor (3) times this turns stale.
pub const DEFAULT_EXPECTED_CYCLE: Duration = Duration::from_secs(1);
/// Range of `expected_cycle`.
pub const EXPECTED_CYCLE_RANGE: (Duration, Duration) =
    (Duration::from_millis(1), Duration::from_secs(3600));
/// A silence above t1.5 inside a frame voids it by default (Modbus over Serial Line V1.02,
/// 2.5.1.1).
pub const DEFAULT_INTER_CHARACTER_CHECK: bool = true;

/// `protocol = "modbus-rtu-tap"`: listens to a Modbus RTU bus another master drives.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModbusRtuTapConfig {
    /// How long a request waits for its answer before it counts as missing.
    #[serde(with = "humantime_serde")]
    pub answer_timeout: Duration,
    /// Multiplies the 3.5-character end-of-frame time, 1..=10 (003 6.4.2.1).
    pub delay_multiplier: u8,
    /// Whether a silence above 1.5 characters inside a frame voids it.
    pub inter_character_check: bool,
    /// How often the other master reads a value (the values' freshness).
    #[serde(with = "humantime_serde")]
    pub expected_cycle: Duration,
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub devices: BTreeMap<String, DeviceConfig>,
}

// === impl ModbusRtuTapConfig ===

impl ModbusRtuTapConfig {
    pub(crate) fn read(cx: &mut Cx, f: &mut Fields<'_>) -> Self {
        let (lo, hi) = ANSWER_TIMEOUT_RANGE;
        let answer_timeout =
            f.duration_or(cx, "answer_timeout", lo..=hi, DEFAULT_ANSWER_TIMEOUT, "");
        let delay_multiplier = f.int_or(
            cx,
            "delay_multiplier",
            1..=MAX_DELAY_MULTIPLIER,
            DEFAULT_DELAY_MULTIPLIER,
            "003 6.4.2.1",
        );
        let inter_character_check =
            f.bool_or(cx, "inter_character_check", DEFAULT_INTER_CHARACTER_CHECK);
        let (lo, hi) = EXPECTED_CYCLE_RANGE;
        let expected_cycle =
            f.duration_or(cx, "expected_cycle", lo..=hi, DEFAULT_EXPECTED_CYCLE, "");
        Self {
            answer_timeout,
            delay_multiplier,
            inter_character_check,
            expected_cycle,
            devices: read_devices(cx, f),
        }
    }
}

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

// === impl Proc3964TapConfig ===

impl Proc3964TapConfig {
    pub(crate) fn read(cx: &mut Cx, f: &mut Fields<'_>) -> Self {
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

// === impl ProtocolSection for the tap lines ===

impl ProtocolSection for ModbusRtuTapConfig {
    fn check(&self, cx: &mut Cx, path: &str, serial: &SerialConfig) {
        check_rtu_data_bits(cx, path, serial);
        check_tap(cx, path, self);
    }

    fn devices(&self) -> Option<&BTreeMap<String, DeviceConfig>> {
        Some(&self.devices)
    }

    fn devices_mut(&mut self) -> Option<&mut BTreeMap<String, DeviceConfig>> {
        Some(&mut self.devices)
    }
}

/// A tap line never transmits: its devices have no poll groups and no communication scanner.
fn check_tap(cx: &mut Cx, path: &str, tap: &ModbusRtuTapConfig) {
    for (name, device) in &tap.devices {
        let dev_path = format!("{path}.devices.{name}");
        if !device.poll.is_empty() {
            cx.issue(
                format!("{dev_path}.poll"),
                "a modbus-rtu-tap line only listens: its devices have no poll groups (it stores \
                 what another master reads and writes)",
            );
        }
        if device.scanner.is_some_and(|s| s.enabled) {
            cx.issue(
                format!("{dev_path}.scanner"),
                "a modbus-rtu-tap line only listens: it cannot run a communication scanner",
            );
        }
    }
}

impl ProtocolSection for Proc3964TapConfig {
    fn check(&self, cx: &mut Cx, path: &str, serial: &SerialConfig) {
        check_3964_link(cx, path, serial, (self.character_delay, self.ack_delay));
    }

    fn second_port(&self) -> Option<&str> {
        Some(&self.port_b)
    }

    fn unit_id(&self) -> Option<u8> {
        self.unit_id
    }
}
