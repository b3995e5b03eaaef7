//! The states of the master; each holds only what it needs.

use core::time::Duration;

use super::job::Job;
use super::rx::Receiving;
use super::RequestId;
use crate::event::EventId;
use crate::time::Instant;

/// One request on its way: what was asked and the ADU that carries it.
#[derive(Clone, Debug)]
pub(super) struct Transaction {
    /// The caller's handle.
    pub(super) id: RequestId,
    /// The slave address; 0 is a broadcast.
    pub(super) slave: u8,
    /// What the user asked for.
    pub(super) job: Job,
    /// The complete frame, kept for a repetition.
    pub(super) adu: Vec<u8>,
    /// Attempts made before this one (0 for the first).
    pub(super) attempt: u8,
    /// The reply monitoring time of each attempt (the config's unless the submit chose another).
    pub(super) reply_timeout: Duration,
    /// Repetitions after a failed attempt (the config's unless the submit chose others).
    pub(super) retries: u8,
    /// A 32-bit register job made from a 16-bit request: it completes as that request.
    pub(super) image16: bool,
}

/// A wait for line silence (after a frame, after a broadcast) with possibly a request queued.
#[derive(Debug)]
pub(super) struct Quiet {
    /// When the wait ends (moves later while bytes arrive, never past `queued`'s limit).
    pub(super) until: Instant,
    /// The request to send when the wait ends, with the latest instant it may be held back by
    /// bytes on the line (a line that never falls silent must not hold it for ever).
    pub(super) queued: Option<(Transaction, Instant)>,
}

/// The ADU is out (or about to be handed out) and the end of its transmission is awaited.
#[derive(Debug)]
pub(super) struct Sending {
    /// The request being sent.
    pub(super) tx: Transaction,
    /// Whether [`Master::poll_transmit`](super::Master::poll_transmit) handed the ADU out.
    pub(super) handed_out: bool,
    /// A line error seen while sending.
    pub(super) error: Option<EventId>,
}

/// The request is out; nothing of the reply has arrived yet.
#[derive(Debug)]
pub(super) struct AwaitReply {
    /// The request sent.
    pub(super) tx: Transaction,
    /// End of the reply monitoring time (003 6.4.2.1), counted from the end of transmission.
    pub(super) deadline: Instant,
    /// The end of transmission (the reply delay is measured from here).
    pub(super) sent_end: Instant,
}

/// The states of the master; each holds only what it needs.
#[derive(Debug)]
pub(super) enum State {
    /// Nothing in flight, the line has been silent for the inter-frame gap.
    Idle,
    /// Waiting for the inter-frame gap (003 6.4.3: 3.5 character times) since the line was busy.
    Gap(Quiet),
    /// After a broadcast: waiting for the turnaround delay (003 6.4.2.2) and the gap.
    Turnaround(Quiet),
    /// The ADU is handed out, the end of its transmission is awaited.
    Sending(Sending),
    /// The reply monitoring time runs.
    AwaitReply(AwaitReply),
    /// A reply is being received.
    Receiving(Receiving),
}
