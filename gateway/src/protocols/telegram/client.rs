//! The way into a telegram line: send telegrams, read and set the RS232 signals. Every client
//! (the mailbox's send block, REST, zenoh) goes through one bounded command queue; a full queue
//! is refused at once, never waited on.

use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};

use proto_core::event::{ids, EventId};
use proto_core::modbus::pdu::ExceptionCode;
use proto_core::telegram::SendError;
use tokio::sync::{mpsc, oneshot};

use crate::signals::{ModemSignals, Output, SignalError};

/// What a send came to.
pub type SendResult = Result<(), TelegramSendError>;

/// A command for the line task.
#[derive(Debug)]
pub(crate) enum Command {
    /// Send a telegram.
    Send {
        data: Vec<u8>,
        reply: oneshot::Sender<SendResult>,
    },
    /// Read the RS232 signals (FC 5 V24_STAT).
    ReadSignals {
        reply: oneshot::Sender<Result<ModemSignals, SignalError>>,
    },
    /// Set DTR or RTS (FC 6 V24_SET).
    SetSignal {
        output: Output,
        on: bool,
        reply: oneshot::Sender<Result<(), SignalError>>,
    },
}

// === impl Command ===

impl Command {
    /// Answers the command with the error of a line that cannot serve it.
    pub(crate) fn refuse(self, line: &str, shutting_down: bool) {
        let send_error = if shutting_down {
            TelegramSendError::ShuttingDown
        } else {
            TelegramSendError::PortClosed
        };
        let signal_error = || {
            let line = line.to_owned();
            if shutting_down {
                SignalError::ShuttingDown { line }
            } else {
                SignalError::PortClosed { line }
            }
        };
        // A client that stopped waiting is no one to answer.
        match self {
            Self::Send { reply, .. } => {
                let _ = reply.send(Err(send_error));
            }
            Self::ReadSignals { reply } => {
                let _ = reply.send(Err(signal_error()));
            }
            Self::SetSignal { reply, .. } => {
                let _ = reply.send(Err(signal_error()));
            }
        }
    }
}

/// Why a telegram was not sent.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum TelegramSendError {
    /// The line's send queue is full; try again later.
    #[error("the line's send queue is full ({capacity} telegrams)")]
    QueueFull {
        /// The queue's capacity.
        capacity: usize,
    },
    /// The driver refused the telegram (empty, too long, an eighth bit on a 7-bit line).
    #[error("telegram refused: {0}")]
    Refused(SendError),
    /// The driver gave the telegram up (3964(R): attempts exhausted; ASCII: flow control).
    #[error("send failed with event {event} (first error {first})")]
    Failed {
        /// The event that ended the job.
        event: EventId,
        /// The first error of the job (7.2, 07 01h).
        first: EventId,
    },
    /// The port is not open (it failed and is being reopened).
    #[error("the line's port is not open")]
    PortClosed,
    /// The line is stopping.
    #[error("the line is shutting down")]
    ShuttingDown,
    /// The line only listens (a 3964(R) tap): it never sends.
    #[error("line {line} only listens (3964r-tap): it never sends a telegram")]
    ListenOnly {
        /// The line's name.
        line: String,
    },
    /// The line's write policy does not allow sends (`sends = false`).
    #[error("telegram sends are not allowed on line {line} (sends = false)")]
    NotAllowed {
        /// The line's name.
        line: String,
    },
}

// === impl TelegramSendError ===

impl TelegramSendError {
    /// The event the send block's STATUS shows (7.2): the failing event; 1E 41h or 05 17h for
    /// a refused length; 05 02h "Request not permitted in this operating mode of the CP" without
    /// an open port or for a full queue; 05 01h "Current request aborted by a CP restart" when
    /// the line stops.
    pub fn event(&self) -> EventId {
        match self {
            Self::Failed { event, .. } => *event,
            Self::Refused(e) => e.event().unwrap_or(ids::REQUEST_NOT_PERMITTED),
            Self::QueueFull { .. }
            | Self::PortClosed
            | Self::NotAllowed { .. }
            | Self::ListenOnly { .. } => ids::REQUEST_NOT_PERMITTED,
            Self::ShuttingDown => ids::REQUEST_ABORTED_BY_RESTART,
        }
    }

    /// The Modbus exception for a send refused before it started: 06 for a full queue; 01 when
    /// the line does not allow sends (the answer MODBUS/TCP Security gives a request that is not
    /// authorized) or only listens (the function is not one this line offers); 04 otherwise.
    pub fn exception(&self) -> ExceptionCode {
        match self {
            Self::QueueFull { .. } => ExceptionCode::ServerDeviceBusy,
            Self::NotAllowed { .. } | Self::ListenOnly { .. } => ExceptionCode::IllegalFunction,
            _ => ExceptionCode::ServerDeviceFailure,
        }
    }
}

/// The result of a send that was queued; resolves when the line has sent it or given it up.
#[derive(Debug)]
pub struct PendingSend {
    rx: oneshot::Receiver<SendResult>,
}

impl Future for PendingSend {
    type Output = SendResult;

    fn poll(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<SendResult> {
        // A dropped reply means the line task ended without answering: it is stopping.
        Pin::new(&mut self.rx)
            .poll(cx)
            .map(|r| r.unwrap_or(Err(TelegramSendError::ShuttingDown)))
    }
}

/// Sends telegrams on one line; cheap to clone.
#[derive(Clone, Debug)]
pub struct TelegramClient {
    line: Arc<str>,
    tx: mpsc::Sender<Command>,
    capacity: usize,
    /// The line's write policy: sends allowed. The one check every send path passes (REST,
    /// zenoh `tx`, the mailbox's send block).
    sends: bool,
    /// The line only listens (a 3964(R) tap): every send is refused.
    listen_only: bool,
}

// === impl TelegramClient ===

impl TelegramClient {
    pub(crate) fn new(line: Arc<str>, tx: mpsc::Sender<Command>, capacity: usize) -> Self {
        Self {
            line,
            tx,
            capacity,
            sends: true,
            listen_only: false,
        }
    }

    /// The client of a line that only listens: every send is refused
    /// ([`TelegramSendError::ListenOnly`]).
    #[must_use]
    pub fn listen_only(mut self) -> Self {
        self.listen_only = true;
        self.sends = false;
        self
    }

    /// The client of a line whose write policy allows sends (`true`) or refuses them.
    #[must_use]
    pub fn with_sends(mut self, sends: bool) -> Self {
        self.sends = sends;
        self
    }

    /// Whether the line allows sends.
    pub fn sends_allowed(&self) -> bool {
        self.sends
    }

    /// Whether the line only listens (a 3964(R) tap): it has no send side at all.
    pub fn is_listen_only(&self) -> bool {
        self.listen_only
    }

    /// The line's name.
    pub fn line(&self) -> &str {
        &self.line
    }

    /// Queues `data` for sending and returns the pending result.
    ///
    /// # Errors
    ///
    /// [`TelegramSendError::NotAllowed`] when the line's write policy refuses sends,
    /// [`TelegramSendError::QueueFull`] at once when the queue is full,
    /// [`TelegramSendError::ShuttingDown`] when the line has stopped.
    pub fn try_send(&self, data: Vec<u8>) -> Result<PendingSend, TelegramSendError> {
        if self.listen_only {
            return Err(TelegramSendError::ListenOnly {
                line: self.line.to_string(),
            });
        }
        if !self.sends {
            return Err(TelegramSendError::NotAllowed {
                line: self.line.to_string(),
            });
        }
        let (reply, rx) = oneshot::channel();
        match self.tx.try_send(Command::Send { data, reply }) {
            Ok(()) => Ok(PendingSend { rx }),
            Err(mpsc::error::TrySendError::Full(_)) => Err(TelegramSendError::QueueFull {
                capacity: self.capacity,
            }),
            Err(mpsc::error::TrySendError::Closed(_)) => Err(TelegramSendError::ShuttingDown),
        }
    }

    /// Sends `data` and waits for the result.
    ///
    /// # Errors
    ///
    /// As [`TelegramClient::try_send`], and the line's result.
    pub async fn send(&self, data: Vec<u8>) -> SendResult {
        self.try_send(data)?.await
    }

    /// The line's RS232 signals.
    pub fn signals(&self) -> SignalsClient {
        SignalsClient {
            line: Arc::clone(&self.line),
            tx: self.tx.clone(),
        }
    }
}

/// Reads and sets the RS232 signals of one line (FC 5 V24_STAT, FC 6 V24_SET); cheap to clone.
#[derive(Clone, Debug)]
pub struct SignalsClient {
    line: Arc<str>,
    tx: mpsc::Sender<Command>,
}

// === impl SignalsClient ===

impl SignalsClient {
    fn stopped(&self) -> SignalError {
        SignalError::ShuttingDown {
            line: self.line.to_string(),
        }
    }

    async fn ask<T>(
        &self,
        command: Command,
        rx: oneshot::Receiver<Result<T, SignalError>>,
    ) -> Result<T, SignalError> {
        self.tx.send(command).await.map_err(|_| self.stopped())?;
        rx.await.unwrap_or_else(|_| Err(self.stopped()))
    }

    /// Reads DSR, CTS, DCD and RI, with DTR and RTS as last set.
    ///
    /// # Errors
    ///
    /// The port cannot read its signals (a pseudo-terminal, a line that is not RS232), is not
    /// open, or the line stopped.
    pub async fn read(&self) -> Result<ModemSignals, SignalError> {
        let (reply, rx) = oneshot::channel();
        self.ask(Command::ReadSignals { reply }, rx).await
    }

    /// Sets DTR or RTS.
    ///
    /// # Errors
    ///
    /// The port refuses, the data flow control drives the output (000 5.4), the line is not
    /// RS232, the port is not open, or the line stopped.
    pub async fn set(&self, output: Output, on: bool) -> Result<(), SignalError> {
        let (reply, rx) = oneshot::channel();
        self.ask(Command::SetSignal { output, on, reply }, rx).await
    }
}
