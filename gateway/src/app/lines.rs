//! Starting one line of the config: its task with its own cancellation token, the Modbus TCP
//! units it answers, and the CP memory mirror of a slave line.
//!
//! The supervisor starts every line through [`start_line`] at start-up and again for each line a
//! configuration change adds or changes; it stops a line by cancelling its token and joining it.

use proto_core::cpmem::AddressMap;
use std::sync::{Arc, Mutex, PoisonError};

use tokio_util::sync::CancellationToken;

use super::AppError;
use super::Metrics;
use crate::cpmem::SharedCpMemory;
use crate::image::ProcessImage;
use crate::line::LineHandle;
use crate::plant::Config;
use crate::protocols::start::StartDeps;
use crate::protocols::LineConfig;
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

/// Starts line `name` of `deps.config` under its own token; `carried` is what the line it
/// replaces left (its waiting telegrams, when both are telegram lines).
pub(crate) fn start_line(
    name: &str,
    line: &LineConfig,
    deps: &LineDeps<'_>,
    carried: Option<crate::mailbox::Carried>,
) -> Result<RunningLine, AppError> {
    let token = deps.parent.child_token();
    let start = StartDeps {
        gateway: &deps.config.gateway,
        zenoh_on: deps.config.zenoh.as_ref().is_some_and(|z| z.enabled),
        image: deps.image,
        metrics: deps.metrics.line(),
        cp_memory: deps.cp_memory,
        token: token.clone(),
        carried,
    };
    let handle = line
        .protocol
        .starter()
        .start(name, line, &start)
        .map_err(|e| AppError::Setup(e.to_string()))?;
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
        protocol: line.protocol.kind().as_str(),
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
    config
        .lines
        .iter()
        .flat_map(|(name, line)| line.protocol.starter().start_issues(name, line, layout))
        .collect()
}

/// The CP memory layout the slave lines of `config` need; `None` without slave lines.
pub(super) fn slave_layout(config: &Config) -> Option<proto_core::cpmem::MemoryLayout> {
    let slaves: Vec<_> = config
        .lines
        .values()
        .filter_map(|l| l.protocol.cp_memory_slave())
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
    Some(crate::protocols::modbus_slave::cpmem::memory_layout(
        slaves,
        (!blocks.is_empty()).then_some(blocks.as_slice()),
    ))
}
