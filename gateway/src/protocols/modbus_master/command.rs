//! Commands into a line: writes and on-demand reads from the Modbus TCP server, REST or zenoh.
//!
//! The queue is bounded, so that a slow line pushes back instead of growing: at most `queue_depth` commands wait or are in flight
//! on a line (each holds a permit of a semaphore until it is answered); one more is refused at
//! once, and the Modbus TCP server turns that into exception 06 "server device busy". Every command is answered exactly
//! once, with the device's answer or a [`CommandError`]; the mapping of both to a Modbus exception
//! is in one place, [`exception_for`].

use std::sync::Arc;
use std::time::Duration;

use proto_core::event::EventId;
use proto_core::modbus::pdu::{ExceptionCode, Request, Response};
use proto_core::profiles::BitUpdate;
use tokio::sync::{mpsc, oneshot, OwnedSemaphorePermit, Semaphore};

/// The device's answer ([`Response`] or its exception), or why there is none.
pub type CommandResult = Result<Result<Response, ExceptionCode>, CommandError>;

/// Why a command got no answer from the device.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum CommandError {
    /// The device did not answer (after the master's retries); the event says why.
    #[error("no valid reply from slave {slave} (event {event})")]
    NoReply {
        /// The slave address.
        slave: u8,
        /// The master's event, e.g. 08 30h "reply monitoring time elapsed".
        event: EventId,
    },
    /// The device is offline (backed off after it stopped answering).
    #[error("slave {0} is offline")]
    Offline(u8),
    /// The line's port is closed (being reopened).
    #[error("the port of the line is closed")]
    PortClosed,
    /// The master engine refused the request (e.g. a quantity beyond the CP's limits).
    #[error("request refused by the master: {0}")]
    Refused(String),
    /// The line stopped.
    #[error("the line is shutting down")]
    ShuttingDown,
}

/// Why a command could not be queued.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum QueueError {
    /// The bounded command queue is full.
    #[error("the line's command queue is full")]
    Full,
    /// The line task has ended.
    #[error("the line has stopped")]
    Closed,
}

/// The Modbus exception a client receives for a failed command: a device that does not answer,
/// is offline or out of reach is 0x0B "gateway target device failed to respond".
pub fn exception_for(error: &CommandError) -> ExceptionCode {
    match error {
        CommandError::NoReply { .. }
        | CommandError::Offline(_)
        | CommandError::PortClosed
        | CommandError::ShuttingDown => ExceptionCode::GatewayTargetFailedToRespond,
        // The request itself is not acceptable on this line.
        CommandError::Refused(_) => ExceptionCode::IllegalDataValue,
    }
}

/// The Modbus exception for a command that could not be queued: a full queue is 0x06 "server
/// device busy", a stopped line 0x0A "gateway path unavailable".
pub fn exception_for_queue(error: QueueError) -> ExceptionCode {
    match error {
        QueueError::Full => ExceptionCode::ServerDeviceBusy,
        QueueError::Closed => ExceptionCode::GatewayPathUnavailable,
    }
}

/// One queued command.
#[derive(Debug)]
pub(crate) struct Command {
    /// The slave address on the line.
    pub(crate) slave: u8,
    /// The request.
    pub(crate) request: Request,
    /// A read-modify-write of one register: `request` reads it (FC 03), and the line writes
    /// the changed word (FC 06) as the next exchange of the same job, so that no other request
    /// of this gateway comes between the two.
    pub(crate) mask: Option<BitUpdate>,
    /// Where the answer goes.
    pub(crate) reply: oneshot::Sender<CommandResult>,
    /// The command's place in the bounded queue, freed when it is answered.
    pub(crate) _permit: OwnedSemaphorePermit,
}

// === impl Command ===

impl Command {
    /// Whether the command writes (queued ahead of reads): FC 05, 06, 15, 16 and 23.
    pub(crate) fn is_write(&self) -> bool {
        self.mask.is_some()
            || matches!(
                self.request,
                Request::WriteSingleCoil { .. }
                    | Request::WriteSingleRegister { .. }
                    | Request::WriteMultipleCoils { .. }
                    | Request::WriteMultipleRegisters { .. }
                    | Request::ReadWriteMultipleRegisters { .. }
            )
    }

    /// Answers the command; a requester that gave up meanwhile is no error.
    pub(crate) fn answer(self, result: CommandResult) {
        if self.reply.send(result).is_err() {
            tracing::debug!(
                slave = self.slave,
                "command answered after its requester gave up"
            );
        }
    }
}

/// A handle to send commands to one line; clones share the queue.
#[derive(Clone, Debug)]
pub struct LineClient {
    tx: mpsc::Sender<Command>,
    /// One permit per command that may wait or be in flight.
    permits: Arc<Semaphore>,
    /// How long [`LineClient::request`] waits for an answer.
    deadline: Duration,
}

// === impl LineClient ===

impl LineClient {
    /// A client of a queue of `depth` commands; `tx` must have room for `depth` commands.
    pub(crate) fn new(tx: mpsc::Sender<Command>, depth: usize, deadline: Duration) -> Self {
        Self {
            tx,
            permits: Arc::new(Semaphore::new(depth.max(1))),
            deadline,
        }
    }

    /// How long [`Self::request`] waits for the answer.
    pub fn deadline(&self) -> Duration {
        self.deadline
    }

    /// Queues `request` for `slave` without waiting; the receiver gets the answer.
    pub fn try_submit(
        &self,
        slave: u8,
        request: Request,
    ) -> Result<oneshot::Receiver<CommandResult>, QueueError> {
        self.try_submit_job(slave, request, None)
    }

    /// Queues `request`, with the write of a read-modify-write when `mask` is given.
    fn try_submit_job(
        &self,
        slave: u8,
        request: Request,
        mask: Option<BitUpdate>,
    ) -> Result<oneshot::Receiver<CommandResult>, QueueError> {
        if self.tx.is_closed() {
            return Err(QueueError::Closed);
        }
        let permit = Arc::clone(&self.permits)
            .try_acquire_owned()
            .map_err(|_| QueueError::Full)?;
        let (reply, rx) = oneshot::channel();
        self.tx
            .try_send(Command {
                slave,
                request,
                mask,
                reply,
                _permit: permit,
            })
            .map_err(|e| match e {
                mpsc::error::TrySendError::Full(_) => QueueError::Full,
                mpsc::error::TrySendError::Closed(_) => QueueError::Closed,
            })?;
        Ok(rx)
    }

    /// Sends `request` to `slave` and waits for the device's answer, at most the line's deadline:
    /// the answer or the exception the Modbus TCP client receives.
    pub async fn request(&self, slave: u8, request: Request) -> Result<Response, ExceptionCode> {
        self.job(slave, request, None).await
    }

    /// Changes bits of one holding register of `slave` by read-modify-write: one job on the
    /// line, an FC 03 read of the register and an FC 06 write of
    /// `(read AND update.and) OR (update.or AND NOT update.and)`, with no other request of this
    /// gateway between them. Another master on the same bus can still write the register
    /// between the two exchanges; Modbus has no lock. The answer is the device's answer to the
    /// write (or to the read, if that failed).
    pub async fn mask_write(
        &self,
        slave: u8,
        update: BitUpdate,
    ) -> Result<Response, ExceptionCode> {
        let read = Request::ReadHoldingRegisters {
            address: update.address,
            quantity: 1,
        };
        self.job(slave, read, Some(update)).await
    }

    async fn job(
        &self,
        slave: u8,
        request: Request,
        mask: Option<BitUpdate>,
    ) -> Result<Response, ExceptionCode> {
        let rx = self
            .try_submit_job(slave, request, mask)
            .map_err(exception_for_queue)?;
        match tokio::time::timeout(self.deadline, rx).await {
            Ok(Ok(Ok(answer))) => answer,
            Ok(Ok(Err(error))) => {
                tracing::debug!(slave, %error, "command failed");
                Err(exception_for(&error))
            }
            // The line dropped the command without answering: it stopped.
            Ok(Err(_)) => Err(ExceptionCode::GatewayTargetFailedToRespond),
            Err(_) => {
                tracing::debug!(slave, deadline = ?self.deadline, "no answer within the deadline");
                Err(ExceptionCode::GatewayTargetFailedToRespond)
            }
        }
    }
}
