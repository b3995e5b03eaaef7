//! Putting a new configuration in force: [`Supervisor::apply`] computes its [`Plan`] and carries
//! it out step by step, in the plan's order: the CP memory, the lines stopped, the lines started
//! (with what the lines they replace carried), the image's mirrors, the new snapshot, then the
//! servers (Modbus TCP, Modbus/TCP Security, zenoh).

use std::collections::BTreeMap;
use std::sync::{Arc, PoisonError};

use tracing::{info, warn};

use super::plan::{CpMemory, LineStop, Plan};
use super::{lock, unit_map, Snapshot, Supervisor};
use crate::api::model::ApplyReport;
use crate::api::ApiError;
use crate::app::lines::{self, LineDeps};
use crate::app::GRACE_PERIOD;
use crate::cpmem::SharedCpMemory;
use crate::feeds::gateway::RunningLine;
use crate::mailbox::Carried;
use crate::modbus_tcp;
use crate::plant::Config;
use proto_core::cpmem::AddressMap;

// === impl Supervisor ===

impl Supervisor {
    /// Puts `new` in force, restarting only what changed (its [`Plan`], carried out step by
    /// step); reports what was restarted.
    pub(crate) async fn apply(self: &Arc<Self>, new: Arc<Config>) -> Result<ApplyReport, ApiError> {
        let old = self.snapshot();
        let layout = lock(&self.cp).memory.as_ref().map(|m| m.layout().clone());
        let plan = Plan::new(&old.config, &new, layout.as_ref());
        let memory = self.cp_memory(&plan.cp_memory);
        let mut lines = old.lines.clone();
        let carried = self.stop_lines(&plan.stop, &mut lines).await;
        let mut failures = Vec::new();
        let started = self.start_lines(
            &plan.start,
            &new,
            memory.as_ref(),
            &mut lines,
            carried,
            &mut failures,
        );
        self.stop_unused_mirrors(&lines);
        let snapshot = self.put_in_force(new, lines);
        if let Some(follower) = self.follower.get() {
            follower.lines_started(&snapshot, &started).await;
        }
        let mut report = plan.report;
        if plan.modbus_tcp {
            self.apply_modbus_tcp(&snapshot, &mut report, &mut failures)
                .await;
        }
        let renamed = match self.follower.get() {
            Some(follower) if plan.rename => follower.renamed(self).await,
            _ => false,
        };
        if renamed {
            report.servers_restarted.push("zenoh".into());
        }
        if failures.is_empty() {
            Ok(report)
        } else {
            Err(ApiError::internal(format!(
                "the configuration was saved but not every part started: {}",
                failures.join("; ")
            )))
        }
    }

    /// The CP memory the slave lines serve after the change: the one in force, or a new one (the
    /// image's mirrors of the old one are forgotten with it), or none.
    fn cp_memory(&self, plan: &CpMemory) -> Option<SharedCpMemory> {
        let mut cp = lock(&self.cp);
        match plan {
            CpMemory::Unused => None,
            CpMemory::Kept => cp.memory.clone(),
            CpMemory::New(layout) => {
                // Only an unpersisted memory gets here (validate refuses the other case).
                info!("the slave lines need another CP memory layout: a new memory, every slave line restarts");
                let memory = SharedCpMemory::new(layout.clone());
                cp.memory = Some(memory.clone());
                lock(&self.mirrored).clear();
                Some(memory)
            }
        }
    }

    /// Stops the running lines of `stops`, taking them out of `lines`: their ports close before
    /// they reopen. A restarted telegram line hands its waiting telegrams (confirmed to the
    /// partner) and numbers to the line that replaces it: returned by line.
    async fn stop_lines(
        &self,
        stops: &[LineStop],
        lines: &mut BTreeMap<String, RunningLine>,
    ) -> BTreeMap<String, Carried> {
        let mut carried = BTreeMap::new();
        for stop in stops {
            let Some(line) = lines.remove(&stop.name) else {
                continue;
            };
            let mailbox = line.handle.mailbox().filter(|_| stop.restarts);
            {
                let key = (stop.name.clone(), line.port.clone());
                let mut opened = lock(&self.opened_before);
                let known = opened.contains(&key);
                opened.retain(|(line_name, _)| *line_name != stop.name);
                if stop.restarts && (known || line.handle.status().port_opens > 0) {
                    opened.insert(key);
                }
            }
            stop_line(&stop.name, line).await;
            if let Some(mailbox) = mailbox {
                carried.insert(stop.name.clone(), mailbox.carry());
            }
            let families = self.exported.metrics.line();
            for device in &stop.devices_gone {
                families.forget_device(&stop.name, device);
            }
            if let Some(protocol) = stop.series_gone {
                families.forget_line(&stop.name, protocol);
            }
        }
        carried
    }

    /// Starts lines `names` of `new` on `memory`, each with what the line it replaces carried,
    /// into `lines`: the names of those started; a failure for each of the others.
    fn start_lines(
        &self,
        names: &[String],
        new: &Config,
        memory: Option<&SharedCpMemory>,
        lines: &mut BTreeMap<String, RunningLine>,
        mut carried: BTreeMap<String, Carried>,
        failures: &mut Vec<String>,
    ) -> Vec<String> {
        let deps = LineDeps {
            config: new,
            image: &self.image,
            metrics: &self.exported.metrics,
            cp_memory: memory,
            parent: &self.lines_token,
            mirrored: &self.mirrored,
        };
        let mut started = Vec::new();
        for name in names {
            let Some(line) = new.lines.get(name) else {
                continue;
            };
            match lines::start_line(name, line, &deps, carried.remove(name)) {
                Ok(running) => {
                    info!(line = %name, port = %running.port, "line started");
                    lines.insert(name.clone(), running);
                    started.push(name.clone());
                }
                Err(e) => {
                    warn!(line = %name, error = %e, "line did not start");
                    failures.push(format!("line {name}: {e}"));
                }
            }
        }
        started
    }

    /// Stops a mirror no running slave line keeps any more (its unit id or address map changed,
    /// or the line went): the memory's changes no longer reach the image there.
    fn stop_unused_mirrors(&self, lines: &BTreeMap<String, RunningLine>) {
        let gone: Vec<(u8, AddressMap)> = {
            let live: Vec<&(u8, AddressMap)> =
                lines.values().filter_map(|l| l.mirror.as_ref()).collect();
            let mut mirrored = lock(&self.mirrored);
            let (kept, gone) = mirrored.drain(..).partition(|key| live.contains(&key));
            *mirrored = kept;
            gone
        };
        // The memory in force (a replaced one was emptied of mirrors with the set). The mirror
        // set's lock is released first: `cp_memory` takes the two in the other order.
        let current = lock(&self.cp).memory.clone();
        if let Some(memory) = current {
            for (unit, map) in &gone {
                if memory.unmirror(*unit, map) {
                    info!(
                        unit = *unit,
                        "CP memory mirror stopped: no slave line serves it"
                    );
                }
            }
        }
    }

    /// Puts `config` and `lines` in force: the units of every line, then the new snapshot, in one
    /// swap each.
    fn put_in_force(
        &self,
        config: Arc<Config>,
        lines: BTreeMap<String, RunningLine>,
    ) -> Arc<Snapshot> {
        let map = unit_map(&lines, &config, &self.image);
        *self.units.write().unwrap_or_else(PoisonError::into_inner) = map;
        let snapshot = Arc::new(Snapshot::new(config, lines));
        *self.state.write().unwrap_or_else(PoisonError::into_inner) = Arc::clone(&snapshot);
        snapshot
    }

    /// `[modbus_tcp]` changed: its limits go in force in the running plain server first (it takes
    /// them for what comes next), which restarts only for a new address or when switched on or
    /// off; the Modbus/TCP Security server follows its section.
    async fn apply_modbus_tcp(
        &self,
        snapshot: &Snapshot,
        report: &mut ApplyReport,
        failures: &mut Vec<String>,
    ) {
        self.tcp_options.set(snapshot.server.clone());
        match self.restart_tcp().await {
            Ok(true) => report.servers_restarted.push("modbus_tcp".into()),
            Ok(false) => {
                info!(
                    "Modbus TCP limits applied to the running server; its clients stay connected"
                );
            }
            Err(e) => failures.push(e),
        }
        let cfg = &self.snapshot().config.modbus_tcp;
        let mut tls = self.tls.lock().await;
        if let Err(e) = crate::app::tls::apply(
            &mut tls,
            cfg,
            &self.units,
            &self.tcp_stats,
            &self.root,
            &self.reload,
        )
        .await
        {
            failures.push(e);
        }
    }

    /// Restarts the Modbus TCP server when its address changed, or switches it on or off, as the
    /// configuration in force says; `Ok(true)` when it restarted (or stopped). A port 0 address
    /// keeps the port the server had. The same address keeps the server and its connections (its
    /// limits were replaced in place).
    async fn restart_tcp(&self) -> Result<bool, String> {
        let config = self.snapshot().config.modbus_tcp.clone();
        let mut slot = self.tcp.lock().await;
        let want = self.overrides.modbus_tcp.unwrap_or(config.listen);
        let old_local = slot.as_ref().map(|s| s.local);
        let addr = match old_local {
            Some(local) if want.port() == 0 && want.ip() == local.ip() => local,
            _ => want,
        };
        let bind = |addr| {
            modbus_tcp::bind(addr).map_err(|e| format!("Modbus TCP cannot listen on {addr}: {e}"))
        };
        if !config.enabled {
            if let Some(old) = slot.take() {
                old.stop().await;
                info!("plain Modbus TCP switched off");
                return Ok(true);
            }
            return Ok(false);
        }
        if slot.is_some() && Some(addr) == old_local {
            return Ok(false);
        }
        // The new address is bound before the old server stops: a failure leaves it running.
        let listener = bind(addr)?;
        if let Some(old) = slot.take() {
            old.stop().await;
        }
        let server = self.spawn_tcp(listener).map_err(|e| e.to_string())?;
        info!(local = %server.local, "Modbus TCP server restarted");
        *slot = Some(server);
        Ok(true)
    }
}

/// Cancels a line and waits (bounded) for its task, which closes its port.
async fn stop_line(name: &str, line: RunningLine) {
    line.token.cancel();
    if tokio::time::timeout(GRACE_PERIOD, line.handle.join())
        .await
        .is_err()
    {
        warn!(line = %name, grace = ?GRACE_PERIOD, "line did not stop within the grace period");
    } else {
        info!(line = %name, "line stopped");
    }
}
