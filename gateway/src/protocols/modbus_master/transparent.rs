//! Transparent forwarding on a Modbus master line (`transparent = true`): a Modbus TCP request
//! for a unit id that no device or unit of the gateway claims goes to the slave address of the
//! same number on the line, on demand, as mbusd or a Moxa MGate forward, so that a SCADA that
//! knows the devices' own register maps reads any slave through the gateway.
//!
//! Why it is built this way:
//! - the request is an ordinary command of the line ([`LineClient::request`]): it waits in the
//!   same bounded queue, and the scheduler's fairness rule (writes, then on-demand reads, at most
//!   `commands_in_row` in a row while a poll is due) keeps the polls of the declared devices at
//!   their guaranteed share however hard a client hammers a forwarded unit;
//! - the Modbus TCP server answers the unit like any other: roles, read-only mode and
//!   `write_ranges` (the one write policy), audit of every write, request timeout. Only the unit
//!   map learns of it ([`units`]), and a unit id a device, a line or the diagnostic unit holds
//!   is never forwarded: the declared unit wins;
//! - an address that never answers costs the line what a dead device costs
//!   ([`Forwarded`]): after `offline_after` requests in a row without an answer it is offline,
//!   its requests answer 0x0B "gateway target device failed to respond" at once (Modbus
//!   Application Protocol V1.1b3, 7: exception 0B), and one request after each back-off, which
//!   doubles up to its maximum, goes to the bus as a probe (one attempt, the short wait of
//!   `probe`). The state is kept per address.

use std::collections::BTreeMap;
use std::ops::RangeInclusive;
use std::sync::Arc;
use std::time::Duration;

use proto_core::modbus::master::{Attempts, MasterConfig};
use proto_core::modbus::pdu::Request;
use proto_core::profiles::BitUpdate;
use tokio::time::Instant;

use super::command::LineClient;
use super::probe::{Probe, ProbeSettings, Prober};
use super::scheduler::Transition;
use crate::config::{
    DEFAULT_OFFLINE_AFTER, DEFAULT_OFFLINE_BACKOFF_MAX, DEFAULT_OFFLINE_BACKOFF_MIN,
};
use crate::serial::Backoff;
use crate::unit::{UnitFuture, UnitService};

/// How a Modbus master line forwards unit ids nobody claims.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TransparentSettings {
    /// The unit ids forwarded, each to the slave of the same address (`transparent_units`).
    pub units: RangeInclusive<u8>,
    /// Requests in a row without an answer that put an address offline (a device's
    /// `offline_after` default).
    pub offline_after: u32,
    /// First back-off of an offline address.
    pub backoff_min: Duration,
    /// Longest back-off of an offline address.
    pub backoff_max: Duration,
    /// How an offline address is probed.
    pub probe: ProbeSettings,
}

// === impl TransparentSettings ===

impl TransparentSettings {
    /// Forwarding of `units` with a device's default dead-device rules.
    pub fn new(units: RangeInclusive<u8>) -> Self {
        Self {
            units,
            offline_after: DEFAULT_OFFLINE_AFTER,
            backoff_min: DEFAULT_OFFLINE_BACKOFF_MIN,
            backoff_max: DEFAULT_OFFLINE_BACKOFF_MAX,
            probe: ProbeSettings::default(),
        }
    }
}

/// The forwarded units of a line, for the unit map: one [`TransparentUnit`] per unit id of
/// `settings`. The caller inserts them only where no declared unit holds the id.
pub(crate) fn units(
    settings: Option<&TransparentSettings>,
    client: &LineClient,
) -> Vec<(u8, Arc<dyn UnitService>)> {
    settings
        .map(|s| s.units.clone())
        .into_iter()
        .flatten()
        .map(|unit| {
            let service = TransparentUnit {
                slave: unit,
                client: client.clone(),
            };
            (unit, Arc::new(service) as Arc<dyn UnitService>)
        })
        .collect()
}

/// A unit id forwarded to the slave of the same address: every request goes through to the
/// device on demand and answers with the device's answer (its exception passed through).
#[derive(Clone, Debug)]
pub struct TransparentUnit {
    slave: u8,
    client: LineClient,
}

impl UnitService for TransparentUnit {
    fn call(&self, request: Request) -> UnitFuture {
        let client = self.client.clone();
        let slave = self.slave;
        Box::pin(async move { client.request(slave, request).await })
    }

    fn mask_write(&self, update: BitUpdate) -> UnitFuture {
        let client = self.client.clone();
        let slave = self.slave;
        Box::pin(async move { client.mask_write(slave, update).await })
    }
}

/// Logs how a forwarded address changed: going offline at WARN, limited per line (a client can
/// ask for every address of the range), coming back at INFO, the rest at DEBUG.
pub(crate) fn log_transition(line: &str, slave: u8, transition: Transition) {
    match transition {
        Transition::Unchanged => {}
        Transition::WentOffline { retry_in } => {
            crate::warn_limited!(
                format!("transparent offline {line}"),
                line = %line, slave, ?retry_in,
                "forwarded address offline: its requests answer 0x0B until a probe is answered"
            );
        }
        Transition::StillOffline { retry_in } => {
            tracing::debug!(line = %line, slave, ?retry_in, "forwarded address still offline");
        }
        Transition::CameBack => {
            tracing::info!(line = %line, slave, "forwarded address answers again");
        }
    }
}

/// Whether a forwarded request goes to the bus.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Gate {
    /// Send it with these attempts (as configured; one short attempt as a probe).
    Send(Attempts),
    /// The address is offline and its back-off runs: answer 0x0B at once.
    Offline,
}

/// The dead-device rules of the forwarded addresses of one line.
#[derive(Debug)]
pub(crate) struct Forwarded {
    settings: Option<TransparentSettings>,
    /// Only addresses that were asked for: at most 247.
    addresses: BTreeMap<u8, AddressState>,
}

#[derive(Debug)]
struct AddressState {
    online: bool,
    failed: u32,
    backoff: Backoff,
    retry_at: Instant,
    prober: Prober,
    probe: Option<Probe>,
}

// === impl Forwarded ===

impl Forwarded {
    pub(crate) fn new(settings: Option<TransparentSettings>) -> Self {
        Self {
            settings,
            addresses: BTreeMap::new(),
        }
    }

    /// Whether `slave` is forwarded on this line.
    fn covers(&self, slave: u8) -> bool {
        self.settings
            .as_ref()
            .is_some_and(|s| s.units.contains(&slave))
    }

    /// Whether a request for `slave` (no declared device of the line) goes to the bus at `now`;
    /// `None` when the address is not forwarded by this line (the request goes as it is).
    pub(crate) fn gate(&mut self, slave: u8, now: Instant, line: &MasterConfig) -> Option<Gate> {
        let settings = self
            .settings
            .as_ref()
            .filter(|s| s.units.contains(&slave))?;
        let Some(state) = self.addresses.get_mut(&slave) else {
            self.addresses
                .insert(slave, AddressState::new(settings, now));
            return Some(Gate::Send(Attempts::default()));
        };
        Some(if state.online {
            Gate::Send(Attempts::default())
        } else if state.retry_at <= now {
            let probe = state.prober.next(line);
            state.probe = Some(probe);
            Gate::Send(probe.attempts())
        } else {
            Gate::Offline
        })
    }

    /// The end of a forwarded request to `slave`: answered (a response or an exception), after
    /// `reply_delay` when known, or not.
    pub(crate) fn done(
        &mut self,
        slave: u8,
        answered: bool,
        reply_delay: Option<Duration>,
        now: Instant,
    ) -> Transition {
        if !self.covers(slave) {
            return Transition::Unchanged;
        }
        let Some(state) = self.addresses.get_mut(&slave) else {
            return Transition::Unchanged;
        };
        let offline_after = self
            .settings
            .as_ref()
            .map_or(DEFAULT_OFFLINE_AFTER, |s| s.offline_after.max(1));
        let probe = state.probe.take();
        if answered {
            state.prober.answered(reply_delay);
            state.failed = 0;
            if state.online {
                return Transition::Unchanged;
            }
            state.online = true;
            state.backoff.reset();
            return Transition::CameBack;
        }
        if state.online {
            state.failed = state.failed.saturating_add(1);
            if state.failed < offline_after {
                return Transition::Unchanged;
            }
            state.prober.full_wait_failed();
            let retry_in = state.backoff.next_delay();
            state.online = false;
            state.retry_at = now + retry_in;
            return Transition::WentOffline { retry_in };
        }
        match probe {
            Some(probe) => state.prober.probe_failed(probe),
            None => state.prober.full_wait_failed(),
        }
        let retry_in = state.backoff.next_delay();
        state.retry_at = now + retry_in;
        Transition::StillOffline { retry_in }
    }
}

// === impl AddressState ===

impl AddressState {
    fn new(settings: &TransparentSettings, now: Instant) -> Self {
        Self {
            online: true,
            failed: 0,
            backoff: Backoff::clamped(settings.backoff_min, settings.backoff_max),
            retry_at: now,
            prober: Prober::new(settings.probe),
            probe: None,
        }
    }
}

#[cfg(test)]
mod tests {
    use proto_core::modbus::master::MasterConfig;

    use super::*;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn settings() -> TransparentSettings {
        let mut s = TransparentSettings::new(5..=9);
        s.offline_after = 3;
        s.backoff_min = ms(1000);
        s.backoff_max = ms(4000);
        s
    }

    #[test]
    fn only_the_forwarded_range_is_gated() {
        let line = MasterConfig::rtu(19200, 11);
        let now = Instant::now();
        let mut f = Forwarded::new(Some(settings()));
        assert_eq!(f.gate(4, now, &line), None);
        assert_eq!(f.gate(10, now, &line), None);
        assert_eq!(f.gate(5, now, &line), Some(Gate::Send(Attempts::default())));
        let mut off = Forwarded::new(None);
        assert_eq!(off.gate(5, now, &line), None);
        assert_eq!(off.done(5, false, None, now), Transition::Unchanged);
    }

    #[test]
    fn a_silent_address_goes_offline_is_answered_at_once_and_probed_after_its_back_off() {
        let line = MasterConfig::rtu(19200, 11);
        let t0 = Instant::now();
        let mut f = Forwarded::new(Some(settings()));
        // Two failures: still online, the next request goes as configured.
        for _ in 0..2 {
            assert_eq!(f.gate(7, t0, &line), Some(Gate::Send(Attempts::default())));
            assert_eq!(f.done(7, false, None, t0), Transition::Unchanged);
        }
        // The third puts it offline for the first back-off.
        assert_eq!(f.gate(7, t0, &line), Some(Gate::Send(Attempts::default())));
        assert_eq!(
            f.done(7, false, None, t0),
            Transition::WentOffline { retry_in: ms(1000) }
        );
        // Meanwhile its requests are answered at once, another address is untouched.
        assert_eq!(f.gate(7, t0 + ms(999), &line), Some(Gate::Offline));
        assert_eq!(
            f.gate(8, t0 + ms(999), &line),
            Some(Gate::Send(Attempts::default()))
        );
        // After the back-off one request is a probe: one attempt with the probe's short wait.
        let Some(Gate::Send(probe)) = f.gate(7, t0 + ms(1000), &line) else {
            panic!("no probe");
        };
        assert_eq!(probe.retries, Some(0));
        assert!(probe.reply_timeout.is_some_and(|t| t < line.reply_timeout));
        // It fails: the back-off doubles.
        assert_eq!(
            f.done(7, false, None, t0 + ms(1100)),
            Transition::StillOffline { retry_in: ms(2000) }
        );
        assert_eq!(f.gate(7, t0 + ms(3099), &line), Some(Gate::Offline));
        // The next probe is answered: back, and the back-off starts over.
        assert!(matches!(
            f.gate(7, t0 + ms(3100), &line),
            Some(Gate::Send(_))
        ));
        assert_eq!(
            f.done(7, true, Some(ms(5)), t0 + ms(3110)),
            Transition::CameBack
        );
        assert_eq!(
            f.gate(7, t0 + ms(3110), &line),
            Some(Gate::Send(Attempts::default()))
        );
    }

    #[test]
    fn an_answer_resets_the_count_of_failures() {
        let line = MasterConfig::rtu(19200, 11);
        let t0 = Instant::now();
        let mut f = Forwarded::new(Some(settings()));
        for answered in [false, false, true, false, false] {
            let _ = f.gate(6, t0, &line);
            assert_eq!(f.done(6, answered, None, t0), Transition::Unchanged);
        }
    }
}
