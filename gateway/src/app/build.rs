//! From the validated config to the runtime's settings types.
//!
//! The config describes what an engineer writes (tables by name, poll groups that may mix tables,
//! the CP's parameter names); the runtime takes the engines' own settings. Every conversion lives
//! here, so neither side knows the other.

use std::collections::BTreeMap;

use proto_core::modbus::master::{Framing, MasterConfig, OperatingMode};

use crate::config::{self, Config, DeviceConfig, LineConfig, ModbusTable, ProtocolConfig};
use crate::image::Table;
use crate::line::telegram::Tap3964LineSettings;
use crate::line::{
    AddrRange, DeviceLimits, DeviceSettings, LineSettings, PollGroup, ProbeSettings,
    ScannerSettings, TapLineSettings, TransparentSettings,
};
use crate::modbus_tcp::{WriteRange, WriteTable};
use crate::serial::{self, PortSettings};

/// The runtime's port settings of a line.
pub(crate) fn port_settings(serial: &config::SerialConfig) -> PortSettings {
    let mut port = PortSettings::new(serial.port.clone(), serial.baud.get());
    port.data_bits = match serial.data_bits {
        config::DataBits::Seven => serial::DataBits::Seven,
        config::DataBits::Eight => serial::DataBits::Eight,
    };
    port.parity = match serial.parity {
        config::Parity::None => serial::Parity::None,
        config::Parity::Odd => serial::Parity::Odd,
        config::Parity::Even => serial::Parity::Even,
    };
    port.stop_bits = match serial.stop_bits {
        config::StopBits::One => serial::StopBits::One,
        config::StopBits::Two => serial::StopBits::Two,
    };
    port.monitor_frames = usize::try_from(serial.monitor_frames).unwrap_or(usize::MAX);
    port.interface = match serial.interface {
        config::Interface::Rs232 => serial::Interface::Rs232,
        config::Interface::Rs422 => serial::Interface::Rs422,
        config::Interface::Rs485 => {
            let rs485 = serial.rs485.clone().unwrap_or_default();
            serial::Interface::Rs485(serial::Rs485 {
                rts_on_send: rs485.rts_on_send,
                delay_before_send: rs485.delay_before_send,
                delay_after_send: rs485.delay_after_send,
            })
        }
    };
    port
}

fn operating_mode(mode: config::OperatingMode) -> OperatingMode {
    match mode {
        config::OperatingMode::Normal => OperatingMode::Normal,
        config::OperatingMode::InterferenceSuppression => OperatingMode::InterferenceSuppression,
    }
}

/// The settings and devices of a Modbus master line (RTU or ASCII); `None` for lines of other
/// protocols.
pub(crate) fn master_line(
    name: &str,
    line: &LineConfig,
    config: &Config,
) -> Option<(LineSettings, Vec<DeviceSettings>)> {
    let port = port_settings(&line.serial);
    let mut settings = LineSettings::rtu(name, port);
    let (master, devices) = match &line.protocol {
        ProtocolConfig::ModbusMasterRtu(m) => {
            let timing =
                crate::line::rtu_timing(&settings.port).with_multiplier(m.delay_multiplier);
            let master = MasterConfig {
                framing: Framing::Rtu { timing },
                reply_timeout: m.reply_timeout,
                retries: m.retries,
                turnaround_delay: m.turnaround_delay,
                mode: operating_mode(m.operating_mode),
            };
            settings.commands_in_row = m.commands_in_row;
            (master, &m.devices)
        }
        ProtocolConfig::ModbusMasterAscii(m) => {
            let master = MasterConfig {
                framing: Framing::Ascii {
                    char_delay: m.character_delay,
                    registers32: m.registers32,
                },
                reply_timeout: m.reply_timeout,
                retries: 0,
                turnaround_delay: m.turnaround_delay,
                mode: operating_mode(m.operating_mode),
            };
            settings.commands_in_row = m.commands_in_row;
            (master, &m.devices)
        }
        // Every other protocol: not a master line.
        _ => return None,
    };
    settings.master = master;
    settings.transparent = config::transparent_units(line).map(TransparentSettings::new);
    settings.diag_depth = usize::from(config.gateway.diag_buffer_depth);
    let devices = devices
        .iter()
        .map(|(name, device)| device_settings(name, device))
        .collect();
    Some((settings, devices))
}

/// The settings and devices of a listen-only tap line; `None` for lines of other protocols.
pub(crate) fn tap_line(
    name: &str,
    line: &LineConfig,
    config: &Config,
) -> Option<(TapLineSettings, Vec<DeviceSettings>)> {
    let ProtocolConfig::ModbusRtuTap(t) = &line.protocol else {
        return None;
    };
    let port = port_settings(&line.serial);
    let mut settings = TapLineSettings::new(name, port);
    settings.tap.timing =
        crate::line::rtu_timing(&settings.port).with_multiplier(t.delay_multiplier);
    settings.tap.answer_timeout = t.answer_timeout;
    settings.tap.check_inter_character = t.inter_character_check;
    settings.expected_cycle = t.expected_cycle;
    settings.diag_depth = usize::from(config.gateway.diag_buffer_depth);
    let devices = t
        .devices
        .iter()
        .map(|(name, device)| device_settings(name, device))
        .collect();
    Some((settings, devices))
}

/// The settings of a listen-only 3964(R) tap line; `None` for lines of other protocols.
pub(crate) fn tap_3964_line(
    name: &str,
    line: &LineConfig,
    config: &Config,
) -> Option<Tap3964LineSettings> {
    let ProtocolConfig::Proc3964Tap(t) = &line.protocol else {
        return None;
    };
    let variant = if t.block_check {
        proto_core::proc3964::Variant::P3964R
    } else {
        proto_core::proc3964::Variant::P3964
    };
    let mut settings =
        Tap3964LineSettings::new(name, port_settings(&line.serial), &t.port_b, variant);
    settings.tap.zvz = t.character_delay;
    settings.tap.qvz = t.ack_delay;
    settings.tap.max_len = t.max_telegram_len;
    settings.mailbox_depth = usize::from(t.receive_buffer);
    settings.unit_id = t.unit_id;
    settings.diag_depth = usize::from(config.gateway.diag_buffer_depth);
    Some(settings)
}

/// A polled device: its limits, and its poll groups split by table (a config group may mix
/// tables; a runtime group reads one table), tag names resolved to their addresses.
pub(crate) fn device_settings(name: &str, device: &DeviceConfig) -> DeviceSettings {
    let mut settings = DeviceSettings::new(name, device.address, device.unit_id);
    settings.limits = DeviceLimits::from_request(device.limits, device.bridge_gap);
    settings.backoff_min = device.offline_backoff_min;
    settings.backoff_max = device.offline_backoff_max;
    settings.probe = ProbeSettings {
        timeout_min: device.probe_timeout_min,
        full_every: device.full_probe_every,
    };
    settings.offline_after = device.offline_after;
    settings.scanner = device
        .scanner
        .filter(|s| s.enabled)
        .map(|s| ScannerSettings {
            inputs: s.inputs,
            outputs: s.outputs,
            period: s.period,
        });
    for group in &device.poll {
        let mut by_table: BTreeMap<Table, Vec<AddrRange>> = BTreeMap::new();
        for range in &group.ranges {
            push_range(&mut by_table, range.table.into(), range.start, range.count);
        }
        for tag in &group.tags {
            // Names compare without letter case, as in the config's rules and REST and zenoh.
            if let Some(t) = device
                .tags
                .iter()
                .find(|t| t.name.eq_ignore_ascii_case(tag))
            {
                push_range(&mut by_table, t.table.into(), t.address, t.width());
            } else if let Some((t, address, width)) = profile_tag(device.profile, tag) {
                push_range(&mut by_table, t, address, width);
            }
        }
        for (table, ranges) in by_table {
            settings.groups.push(PollGroup {
                period: group.period,
                table,
                ranges,
            });
        }
    }
    settings
}

/// Splits a config range (count up to 65536) into runtime ranges (count up to 65535).
fn push_range(
    by_table: &mut BTreeMap<Table, Vec<AddrRange>>,
    table: Table,
    start: u16,
    count: u32,
) {
    let mut start = u32::from(start);
    let end = start + count;
    while start < end {
        let n = (end - start).min(u32::from(u16::MAX));
        by_table
            .entry(table)
            .or_default()
            .push(AddrRange::new(start as u16, n as u16));
        start += n;
    }
}

/// Table, address and width of a profile's named tag.
fn profile_tag(profile: config::Profile, name: &str) -> Option<(Table, u16, u32)> {
    let profile = profile.device_profile()?;
    let tag = profile.tag(name)?;
    Some((tag.table, tag.address, u32::from(tag.words())))
}

/// The Modbus TCP write policy of the config (`None`: every address of every unit is writable).
pub(crate) fn write_ranges(cfg: &config::ModbusTcpConfig) -> Option<Vec<WriteRange>> {
    unit_write_ranges(&cfg.write_ranges)
}

/// Configured write ranges as the server checks them; `None` (no limit) when there are none.
pub(crate) fn unit_write_ranges(ranges: &[config::UnitRange]) -> Option<Vec<WriteRange>> {
    if ranges.is_empty() {
        return None;
    }
    let ranges = ranges
        .iter()
        .filter_map(|r| {
            let table = match r.table {
                ModbusTable::Holding => WriteTable::HoldingRegisters,
                ModbusTable::Coil => WriteTable::Coils,
                // Input registers and discrete inputs are never written; the validation refuses
                // such ranges.
                ModbusTable::Input | ModbusTable::Discrete => return None,
            };
            let last = (u32::from(r.start) + r.count.max(1) - 1).min(u32::from(u16::MAX)) as u16;
            Some(WriteRange {
                unit: r.unit_id,
                table,
                first: r.start,
                last,
            })
        })
        .collect();
    Some(ranges)
}
