//! The contract between the Modbus TCP server and whatever answers a unit id.
//!
//! The server frames and validates requests (MBAP, PDU) and applies its own policy (read-only mode,
//! write-enabled ranges); it then hands each request to the [`UnitService`] registered for the unit
//! id. A polled device answers reads of polled ranges from the process image, other reads on demand
//! from the device, and writes through to the device. Telegram mailboxes and the gateway's CP memory
//! are further implementations.

use std::collections::HashMap;
use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, RwLock};

pub mod write_policy;

use proto_core::modbus::pdu::{ExceptionCode, Request, Response};
use proto_core::profiles::BitUpdate;

/// What a unit answers: a response, or the exception the client receives.
pub type UnitResult = Result<Response, ExceptionCode>;

/// The future a [`UnitService`] returns.
pub type UnitFuture = Pin<Box<dyn Future<Output = UnitResult> + Send + 'static>>;

/// Something that answers Modbus requests for one unit id.
pub trait UnitService: Send + Sync + 'static {
    /// Answers one request. Must not block; may wait (for the device) asynchronously. A device
    /// that does not answer gives `GatewayTargetFailedToRespond` (0x0B), a full write queue
    /// `ServerDeviceBusy` (0x06).
    fn call(&self, request: Request) -> UnitFuture;

    /// Answers `request` at once when that needs no waiting (a read served from the process
    /// image): appends the response PDU, function code first, to `out` and gives `Some(Ok(()))`,
    /// or gives `Some(Err(code))` for an exception, with nothing appended. `None` (the default,
    /// and nothing appended either) means the answer takes [`Self::call`]. An answer given here
    /// must be the one `call` would give; the Modbus TCP server tries this first on every request
    /// and saves the boxed future, the response's allocations and the request timer.
    fn answer_now(
        &self,
        request: &Request,
        out: &mut Vec<u8>,
    ) -> Option<Result<(), ExceptionCode>> {
        let _ = (request, out);
        None
    }

    /// Changes bits of one holding register by read-modify-write as one exchange of the line
    /// (see `LineClient::mask_write`). Units that are not a polled device answer exception
    /// 01 "illegal function" (the default).
    fn mask_write(&self, update: BitUpdate) -> UnitFuture {
        let _ = update;
        Box::pin(std::future::ready(Err(ExceptionCode::IllegalFunction)))
    }

    /// Whether the unit only listens to another master's traffic (a device on a tap line): it
    /// refuses every write with exception 01, and REST and zenoh refuse tag writes before they
    /// reach it.
    fn listen_only(&self) -> bool {
        false
    }

    /// The unit's own write policy: `Some(code)` refuses `request` before it is served (the
    /// server answers the exception and audits the request as refused). `None` (the default):
    /// the unit serves it.
    fn refuses(&self, request: &Request) -> Option<ExceptionCode> {
        let _ = request;
        None
    }
}

/// The unit map the Modbus TCP server answers from and REST and zenoh write through, replaceable
/// at run time: take the write lock and swap the map. Each request clones its unit's service out
/// and drops the lock before it waits.
pub type SharedUnits = Arc<RwLock<UnitMap>>;

/// The unit ids the server knows, each with its service.
#[derive(Clone, Default)]
pub struct UnitMap {
    units: HashMap<u8, Arc<dyn UnitService>>,
}

// === impl UnitMap ===

impl UnitMap {
    /// An empty map: every unit id answers 0x0A.
    pub fn new() -> Self {
        Self::default()
    }

    /// Registers `service` under `unit`, replacing any earlier one.
    pub fn insert(&mut self, unit: u8, service: Arc<dyn UnitService>) {
        self.units.insert(unit, service);
    }

    /// The service of `unit`, if any.
    pub fn get(&self, unit: u8) -> Option<&Arc<dyn UnitService>> {
        self.units.get(&unit)
    }

    /// The registered unit ids, sorted.
    pub fn unit_ids(&self) -> Vec<u8> {
        let mut ids: Vec<u8> = self.units.keys().copied().collect();
        ids.sort_unstable();
        ids
    }
}

impl std::fmt::Debug for UnitMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("UnitMap")
            .field("units", &self.unit_ids())
            .finish()
    }
}
