//! From the config's Modbus master sections (`modbus-master-rtu`, `modbus-master-ascii`) to the
//! master line's settings and its polled devices, and the start of the line.
//!
//! The config describes what an engineer writes (poll groups that may mix tables, tags by name,
//! the CP's parameter names); the runtime takes the engine's own settings and one poll group per
//! table. The tap line lists devices the same way and converts them with [`device_settings`].

use std::collections::BTreeMap;

use proto_core::modbus::master::{Framing, MasterConfig, OperatingMode};

use crate::config::{self, DeviceConfig};
use crate::image::Table;
use crate::line::{self, LineHandle};
use crate::protocols::start::{port_settings, StartDeps, StartError, StartLine};
use crate::protocols::{
    AddrRange, DeviceLimits, DeviceSettings, LineSettings, PollGroup, ProbeSettings,
    ScannerSettings, TransparentSettings,
};
use crate::protocols::{LineConfig, ModbusMasterAsciiConfig, ModbusMasterRtuConfig, Transparent};

// === impl StartLine for the master sections ===

impl StartLine for ModbusMasterRtuConfig {
    fn start(
        &self,
        name: &str,
        line: &LineConfig,
        deps: &StartDeps<'_>,
    ) -> Result<LineHandle, StartError> {
        let mut settings = LineSettings::rtu(name, port_settings(&line.serial));
        let timing = line::rtu_timing(&settings.port).with_multiplier(self.delay_multiplier);
        settings.master = MasterConfig {
            framing: Framing::Rtu { timing },
            reply_timeout: self.reply_timeout,
            retries: self.retries,
            turnaround_delay: self.turnaround_delay,
            mode: operating_mode(self.operating_mode),
        };
        Ok(spawn(
            settings,
            self.commands_in_row,
            &self.transparent,
            &self.devices,
            deps,
        ))
    }
}

impl StartLine for ModbusMasterAsciiConfig {
    fn start(
        &self,
        name: &str,
        line: &LineConfig,
        deps: &StartDeps<'_>,
    ) -> Result<LineHandle, StartError> {
        let mut settings = LineSettings::rtu(name, port_settings(&line.serial));
        settings.master = MasterConfig {
            framing: Framing::Ascii {
                char_delay: self.character_delay,
                registers32: self.registers32,
            },
            reply_timeout: self.reply_timeout,
            retries: 0,
            turnaround_delay: self.turnaround_delay,
            mode: operating_mode(self.operating_mode),
        };
        Ok(spawn(
            settings,
            self.commands_in_row,
            &self.transparent,
            &self.devices,
            deps,
        ))
    }
}

/// Starts a master line with the keys both sections share (`commands_in_row`, the transparent
/// forwarding, the devices) and the gateway-wide settings.
fn spawn(
    mut settings: LineSettings,
    commands_in_row: u32,
    transparent: &Transparent,
    devices: &BTreeMap<String, DeviceConfig>,
    deps: &StartDeps<'_>,
) -> LineHandle {
    settings.commands_in_row = commands_in_row;
    settings.transparent = transparent.range().map(TransparentSettings::new);
    settings.diag_depth = usize::from(deps.gateway.diag_buffer_depth);
    settings.metrics = Some(deps.metrics.clone());
    let devices = devices
        .iter()
        .map(|(name, device)| device_settings(name, device))
        .collect();
    crate::protocols::spawn_modbus_master_line(
        settings,
        devices,
        deps.image.clone(),
        deps.token.clone(),
    )
}

fn operating_mode(mode: crate::protocols::OperatingMode) -> OperatingMode {
    match mode {
        crate::protocols::OperatingMode::Normal => OperatingMode::Normal,
        crate::protocols::OperatingMode::InterferenceSuppression => {
            OperatingMode::InterferenceSuppression
        }
    }
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
