//! From the config's `modbus-rtu-tap` section to the tap line's settings and the devices it
//! listens to, and the start of the line.

use super::{spawn_modbus_tap_line, TapLineSettings};
use crate::line::{rtu_timing, LineHandle};
use crate::protocols::modbus_master::build::device_settings;
use crate::protocols::start::{port_settings, StartDeps, StartError, StartLine};
use crate::protocols::{LineConfig, ModbusRtuTapConfig};

// === impl StartLine for ModbusRtuTapConfig ===

impl StartLine for ModbusRtuTapConfig {
    fn start(
        &self,
        name: &str,
        line: &LineConfig,
        deps: &StartDeps<'_>,
    ) -> Result<LineHandle, StartError> {
        let mut settings = TapLineSettings::new(name, port_settings(&line.serial));
        settings.tap.timing = rtu_timing(&settings.port).with_multiplier(self.delay_multiplier);
        settings.tap.answer_timeout = self.answer_timeout;
        settings.tap.check_inter_character = self.inter_character_check;
        settings.expected_cycle = self.expected_cycle;
        settings.diag_depth = usize::from(deps.gateway.diag_buffer_depth);
        settings.metrics = Some(deps.metrics.clone());
        let devices = self
            .devices
            .iter()
            .map(|(name, device)| device_settings(name, device))
            .collect();
        Ok(spawn_modbus_tap_line(
            settings,
            devices,
            deps.image.clone(),
            deps.token.clone(),
        ))
    }
}
