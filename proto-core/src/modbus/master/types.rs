//! The public vocabulary of the master: request ids, line errors, submit errors, outcomes and
//! events.

use core::time::Duration;

use super::job::JobError;
use super::registers32::{Request32, Response32};
use crate::event::EventId;
use crate::modbus::pdu::{ExceptionCode, Request, Response};

/// Identifies one submitted request in its [`MasterEvent::Completed`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct RequestId(pub u64);

/// How one request is tried where it differs from the line's
/// [`MasterConfig`](super::MasterConfig), for [`Master::submit_with`](super::Master::submit_with).
/// The default changes nothing.
///
/// The CP has one reply monitoring time per interface (003 6.4.2.1); a per-request value is the
/// gateway's own addition, for a runtime that probes a device known to be silent with a shorter
/// wait than its normal polls.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Attempts {
    /// The reply monitoring time of each attempt (`None`: the configured one). Used as given,
    /// like the config's; the caller keeps it within 5..65500 ms (003 6.4.2.1).
    pub reply_timeout: Option<Duration>,
    /// Repetitions after a failed attempt (`None`: the configured ones).
    pub retries: Option<u8>,
}

/// Why [`Master::submit`](super::Master::submit) refused a request.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SubmitError {
    /// A transaction is in flight or already queued (the bus carries one at a time).
    #[error("a transaction is in flight")]
    Busy,
    /// The request fails the CP's job checks; its event has been raised too.
    #[error("request refused: {0}")]
    Invalid(JobError),
    /// On a line with 32-bit registers (003 6.4.4) the 16-bit range starts or ends inside a
    /// 32-bit register of the slave (odd address or count): half of one cannot be sent.
    #[error(
        "holding registers {address}+{quantity} split a 32-bit register of the slave \
         (registers32: each is two image registers from an even address)"
    )]
    HalfRegister { address: u16, quantity: u16 },
}

/// How a transaction ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome<R = Response> {
    /// The slave answered and the answer fits the request.
    Response(R),
    /// The slave answered with an exception (01..07 also raised as 0E 61h..0E 67h).
    Exception(ExceptionCode),
    /// The request was a broadcast: sent, never answered (003 6.4.3 "ADDR").
    Broadcast,
    /// No usable answer after every attempt: the event of the last attempt's first error
    /// (08 30h no reply, 0E 57h checksum, ...).
    Failed(EventId),
}

/// What the master reports.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum MasterEvent {
    /// Every diagnostic event raised (one per occurrence, including a failed attempt that is
    /// retried). `slave` is the slave of the transaction it belongs to, 0 when the line was idle.
    Raised { id: EventId, slave: u8 },
    /// The transaction finished.
    Completed {
        id: RequestId,
        slave: u8,
        request: Request,
        outcome: Outcome,
    },
    /// A 32-bit register job (ASCII, [`Master::submit_registers32`](super::Master::submit_registers32)) finished.
    Completed32 {
        id: RequestId,
        slave: u8,
        request: Request32,
        outcome: Outcome<Response32>,
    },
}
