//! From the config's `modbus-slave-rtu` section to the slave line's settings over the CP memory,
//! and the start of the line.

use proto_core::cpmem::MemoryLayout;

use super::{spawn_modbus_slave_line, SlaveLineSettings};
use crate::config::ConfigIssue;
use crate::line::LineHandle;
use crate::protocols::start::{port_settings, StartDeps, StartError, StartLine};
use crate::protocols::{LineConfig, ModbusSlaveRtuConfig};

// === impl StartLine for ModbusSlaveRtuConfig ===

impl StartLine for ModbusSlaveRtuConfig {
    fn start(
        &self,
        name: &str,
        line: &LineConfig,
        deps: &StartDeps<'_>,
    ) -> Result<LineHandle, StartError> {
        let memory = deps
            .cp_memory
            .ok_or_else(|| StartError(format!("line {name}: no CP memory was set up")))?;
        let params = crate::protocols::modbus_slave::cpmem::slave_params(self, memory.layout())
            .map_err(|issues| {
                let text: Vec<String> =
                    issues.iter().map(|i| format!("lines.{name}.{i}")).collect();
                StartError(text.join("\n"))
            })?;
        let mut settings =
            SlaveLineSettings::new(name.to_owned(), port_settings(&line.serial), params);
        settings.diag_depth = usize::from(deps.gateway.diag_buffer_depth);
        settings.metrics = Some(deps.metrics.clone());
        settings.unit_id = self.unit_id;
        Ok(spawn_modbus_slave_line(
            settings,
            memory.clone(),
            deps.token.clone(),
        ))
    }

    /// The slave's areas against the CP memory the slave lines would share.
    fn start_issues(
        &self,
        name: &str,
        _line: &LineConfig,
        layout: Option<&MemoryLayout>,
    ) -> Vec<ConfigIssue> {
        let Some(layout) = layout else {
            return Vec::new();
        };
        match crate::protocols::modbus_slave::cpmem::slave_params(self, layout) {
            Ok(_) => Vec::new(),
            Err(found) => found
                .into_iter()
                .map(|i| ConfigIssue {
                    path: format!("lines.{name}"),
                    message: i.to_string(),
                })
                .collect(),
        }
    }
}
