//! Starting one line of the config: its task with its own cancellation token, the Modbus TCP
//! units it answers, and the CP memory mirror of a slave line.
//!
//! The supervisor starts every line through [`start_line`] at start-up and again for each line a
//! configuration change adds or changes; it stops a line by cancelling its token and joining it.

use proto_core::cpmem::AddressMap;
use std::sync::{Mutex, PoisonError};

use tokio_util::sync::CancellationToken;

use super::AppError;
use super::Metrics;
use crate::config::check::Check;
use crate::config::Cx;
use crate::cpmem::SharedCpMemory;
use crate::feeds::gateway::RunningLine;
use crate::image::ProcessImage;
use crate::plant::check::Start;
use crate::plant::Config;
use crate::protocols::start::StartDeps;
use crate::protocols::LineConfig;

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

/// The checks of [`start_line`] that need no task: what would make a line of the configuration
/// fail to start, asked of each line's section ([`StartLine::start_issues`]) with the CP memory
/// layout the slave lines need.
pub(crate) struct LineStarts;

impl Check<Start<'_>> for LineStarts {
    fn check(&self, start: &Start<'_>, cx: &mut Cx) {
        let layout = slave_layout(start.config);
        for (name, line) in &start.config.lines {
            let issues = line
                .protocol
                .starter()
                .start_issues(name, line, layout.as_ref());
            cx.issues.extend(issues);
        }
    }
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
