//! The listen-only Modbus RTU tap line: its keys.
//!
//! A Modbus RTU tap line lists devices as a master line does (address, unit id, profile or tags)
//! but polls nothing: it stores what another master's requests and the devices' answers show.

use std::collections::BTreeMap;
use std::time::Duration;

use serde::Serialize;

use crate::config::check::{Check, Line};
use crate::config::reader::{Cx, Fields};
use crate::config::section::ProtocolSection;
use crate::config::Baud;
use crate::config::DeviceConfig;
use crate::protocols::modbus_master::config::{
    check_rtu_data_bits, read_devices, DEFAULT_DELAY_MULTIPLIER, MAX_DELAY_MULTIPLIER,
};
use crate::protocols::ReadSection;

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

// === impl ReadSection ===

impl ReadSection for ModbusRtuTapConfig {
    fn read_section(cx: &mut Cx, f: &mut Fields<'_>, _baud: Baud) -> Self {
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

// === impl ProtocolSection ===

impl Check<Line<'_>> for ModbusRtuTapConfig {
    fn check(&self, line: &Line<'_>, cx: &mut Cx) {
        check_rtu_data_bits(cx, line.path, line.serial);
        check_tap(cx, line.path, self);
    }
}

impl ProtocolSection for ModbusRtuTapConfig {
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
