//! Starting one line of the config: its task with its own cancellation token, the Modbus TCP
//! units it answers, and the CP memory mirror of a slave line.
//!
//! The supervisor starts every line through [`start_line`] at start-up and again for each line a
//! configuration change adds or changes; it stops a line by cancelling its token and joining it.

use proto_core::cpmem::AddressMap;
use std::sync::{Arc, Mutex, PoisonError};

use tokio_util::sync::CancellationToken;

use super::{build, AppError};
use crate::config::{Config, LineConfig, ProtocolConfig};
use crate::cpmem::{self, SharedCpMemory};
use crate::image::ProcessImage;
use crate::line::telegram::TelegramLineSettings;
use crate::line::{self, LineHandle, SlaveLineSettings};
use crate::metrics::Metrics;
use crate::unit::UnitService;

/// A running line and what it registered.
#[derive(Clone)]
pub(crate) struct RunningLine {
    /// The line's task: status, events, capabilities.
    pub(crate) handle: LineHandle,
    /// Cancels this line only (a child of the gateway's lines token).
    pub(crate) token: CancellationToken,
    /// The config's protocol name (`modbus-master-rtu`, `3964r`, ...).
    pub(crate) protocol: &'static str,
    /// The serial port's path.
    pub(crate) port: String,
    /// The second receive port's path, for a line that has one (`3964r-tap`).
    pub(crate) port_b: Option<String>,
    /// The Modbus TCP units the line answers.
    pub(crate) units: Vec<(u8, Arc<dyn UnitService>)>,
    /// The CP memory mirror a slave line keeps in the image: its unit id and address map.
    pub(crate) mirror: Option<(u8, AddressMap)>,
}

impl std::fmt::Debug for RunningLine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunningLine")
            .field("handle", &self.handle)
            .field("protocol", &self.protocol)
            .field("port", &self.port)
            .field(
                "units",
                &self.units.iter().map(|(u, _)| *u).collect::<Vec<_>>(),
            )
            .finish_non_exhaustive()
    }
}

/// What starting a line needs from the gateway.
pub(crate) struct LineDeps<'a> {
    /// The whole configuration (gateway-wide settings such as the buffer depth).
    pub(crate) config: &'a Config,
    pub(crate) image: &'a ProcessImage,
    pub(crate) metrics: &'a Metrics,
    /// The CP memory slave lines serve.
    pub(crate) cp_memory: Option<&'a SharedCpMemory>,
    /// The parent of the line's own token.
    pub(crate) parent: &'a CancellationToken,
    /// CP memory mirrors already set up, by unit id and address map: a restarted slave line
    /// does not mirror the memory into the image a second time.
    pub(crate) mirrored: &'a Mutex<Vec<(u8, AddressMap)>>,
}

/// Starts line `name` of `deps.config` under its own token.
pub(crate) fn start_line(
    name: &str,
    line: &LineConfig,
    deps: &LineDeps<'_>,
) -> Result<RunningLine, AppError> {
    let token = deps.parent.child_token();
    let config = deps.config;
    let protocol = line.protocol.kind().as_str();
    let handle = match &line.protocol {
        ProtocolConfig::ModbusMasterRtu(_) | ProtocolConfig::ModbusMasterAscii(_) => {
            let (mut settings, devices) = build::master_line(name, line, config)
                .ok_or_else(|| AppError::Setup(format!("line {name}: not a Modbus master")))?;
            settings.metrics = Some(deps.metrics.clone());
            line::spawn_modbus_master_line(settings, devices, deps.image.clone(), token.clone())
        }
        ProtocolConfig::ModbusRtuTap(_) => {
            let (mut settings, devices) = build::tap_line(name, line, config)
                .ok_or_else(|| AppError::Setup(format!("line {name}: not a tap line")))?;
            settings.metrics = Some(deps.metrics.clone());
            line::spawn_modbus_tap_line(settings, devices, deps.image.clone(), token.clone())
        }
        ProtocolConfig::Proc3964Tap(_) => {
            let mut settings = build::tap_3964_line(name, line, config)
                .ok_or_else(|| AppError::Setup(format!("line {name}: not a 3964(R) tap line")))?;
            settings.metrics = Some(deps.metrics.clone());
            line::telegram::spawn_3964_tap_line(settings, token.clone())
        }
        ProtocolConfig::ModbusSlaveRtu(cfg) => {
            let memory = deps
                .cp_memory
                .ok_or_else(|| AppError::Setup(format!("line {name}: no CP memory was set up")))?;
            let params = cpmem::config::slave_params(cfg, memory.layout()).map_err(|issues| {
                let text: Vec<String> =
                    issues.iter().map(|i| format!("lines.{name}.{i}")).collect();
                AppError::Setup(text.join("\n"))
            })?;
            let mut settings =
                SlaveLineSettings::new(name.to_owned(), build::port_settings(&line.serial), params);
            settings.diag_depth = usize::from(config.gateway.diag_buffer_depth);
            settings.metrics = Some(deps.metrics.clone());
            settings.unit_id = cfg.unit_id;
            line::spawn_modbus_slave_line(settings, memory.clone(), token.clone())
        }
        ProtocolConfig::Proc3964(_) | ProtocolConfig::Ascii(_) => {
            let port = build::port_settings(&line.serial);
            let mut settings = TelegramLineSettings::from_config(name, line, port)
                .map_err(|e| AppError::Setup(format!("line {name}: {e}")))?;
            settings.diag_depth = usize::from(config.gateway.diag_buffer_depth);
            settings.metrics = Some(deps.metrics.clone());
            settings.mailbox.ack =
                line::telegram::mailbox_ack(crate::config::ack_mode(config, line));
            line::telegram::try_spawn_telegram_line(settings, token.clone())
                .map_err(|e| AppError::Setup(format!("line {name}: {e}")))?
        }
    };
    // The CP memory a slave line serves is mirrored into the image under its unit id, once.
    let mirror = handle.cp_memory().and_then(|view| {
        let key = (view.unit_id?, view.map.clone());
        let mut mirrored = deps.mirrored.lock().unwrap_or_else(PoisonError::into_inner);
        if !mirrored.contains(&key) {
            view.memory
                .mirror_to(deps.image.clone(), key.0, view.map.clone());
            mirrored.push(key.clone());
        }
        Some(key)
    });
    Ok(RunningLine {
        units: handle.units(),
        handle,
        token,
        protocol,
        port: line.serial.port.clone(),
        port_b: line.second_port().map(str::to_owned),
        mirror,
    })
}

/// The checks of [`start_line`] that need no task: what would make a line of `config` fail to
/// start, each with its path.
pub(crate) fn start_issues(
    config: &Config,
    layout: Option<&proto_core::cpmem::MemoryLayout>,
) -> Vec<crate::config::ConfigIssue> {
    let mut issues = Vec::new();
    for (name, line) in &config.lines {
        match &line.protocol {
            ProtocolConfig::ModbusMasterRtu(_)
            | ProtocolConfig::ModbusMasterAscii(_)
            | ProtocolConfig::ModbusRtuTap(_)
            | ProtocolConfig::Proc3964Tap(_) => {}
            ProtocolConfig::ModbusSlaveRtu(cfg) => {
                if let Some(layout) = layout {
                    if let Err(found) = cpmem::config::slave_params(cfg, layout) {
                        for i in found {
                            issues.push(crate::config::ConfigIssue {
                                path: format!("lines.{name}"),
                                message: i.to_string(),
                            });
                        }
                    }
                }
            }
            ProtocolConfig::Proc3964(_) | ProtocolConfig::Ascii(_) => {
                let port = build::port_settings(&line.serial);
                if let Err(e) = TelegramLineSettings::from_config(name, line, port) {
                    issues.push(crate::config::ConfigIssue {
                        path: format!("lines.{name}"),
                        message: e.to_string(),
                    });
                }
                if let Some(journal) = line.journal() {
                    let dir = match journal.parent() {
                        Some(p) if !p.as_os_str().is_empty() => p,
                        _ => std::path::Path::new("."),
                    };
                    if !dir.is_dir() {
                        issues.push(crate::config::ConfigIssue {
                            path: format!("lines.{name}.journal"),
                            message: format!(
                                "the directory {} of the journal does not exist",
                                dir.display()
                            ),
                        });
                    }
                }
            }
        }
    }
    issues
}

/// The CP memory layout the slave lines of `config` need; `None` without slave lines.
pub(super) fn slave_layout(config: &Config) -> Option<proto_core::cpmem::MemoryLayout> {
    let slaves: Vec<_> = config
        .lines
        .values()
        .filter_map(|l| l.protocol.section().cp_memory_slave())
        .collect();
    if slaves.is_empty() {
        return None;
    }
    let blocks: Vec<(u16, u16)> = config
        .cp_memory
        .data_blocks
        .iter()
        .map(|b| (b.db, b.words))
        .collect();
    Some(cpmem::config::memory_layout(
        slaves,
        (!blocks.is_empty()).then_some(blocks.as_slice()),
    ))
}
