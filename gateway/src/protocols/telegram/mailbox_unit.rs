//! A telegram mailbox as a Modbus TCP unit: FC 03 reads, FC 06 and FC 16 writes, FC 23 (write
//! first, then read: acknowledge and fetch the next telegram in one exchange). Every other
//! function answers 01.

use std::sync::Arc;

use proto_core::modbus::pdu::{ExceptionCode, Request, Response};

use super::{PendingSend, TelegramClient};
use crate::mailbox::layout::{self, WritePlan};
use crate::mailbox::Mailbox;
use crate::unit::{UnitFuture, UnitService};

/// One telegram line's mailbox served under its unit id; cheap to clone.
#[derive(Clone, Debug)]
pub struct MailboxUnit {
    mailbox: Arc<Mailbox>,
    client: TelegramClient,
}

// === impl MailboxUnit ===

impl MailboxUnit {
    /// The mailbox of a line, sending through `client`.
    pub fn new(mailbox: Arc<Mailbox>, client: TelegramClient) -> Self {
        Self { mailbox, client }
    }

    /// The mailbox served.
    pub fn mailbox(&self) -> &Arc<Mailbox> {
        &self.mailbox
    }

    /// The line client its send block uses.
    pub fn client(&self) -> &TelegramClient {
        &self.client
    }

    /// Carries out a write of `values` at `address`.
    fn write(&self, address: u16, values: &[u16]) -> Result<(), ExceptionCode> {
        match layout::plan_write(address, values)? {
            // A number other than the oldest telegram's is an illegal value (documented).
            WritePlan::Ack(seq) => self
                .mailbox
                .ack(seq)
                .map_err(|_| ExceptionCode::IllegalDataValue),
            // A listening line has no send block: nothing is staged that could never go.
            WritePlan::SendBlock { .. } if self.client.is_listen_only() => {
                Err(ExceptionCode::IllegalFunction)
            }
            WritePlan::SendBlock { offset, values } => {
                let client = &self.client;
                let started = self.mailbox.write_send_block(offset, &values, |telegram| {
                    client.try_send(telegram).map_err(|e| e.exception())
                })?;
                if let Some(started) = started {
                    let mailbox = Arc::clone(&self.mailbox);
                    crate::task::spawn(
                        "mailbox send result",
                        wait_for_result(mailbox, started.req, started.pending),
                    );
                }
                Ok(())
            }
        }
    }

    /// Answers one request (what [`UnitService::call`] runs).
    pub fn answer(&self, request: Request) -> Result<Response, ExceptionCode> {
        match request {
            Request::ReadHoldingRegisters { address, quantity } => self
                .mailbox
                .read_registers(address, quantity)
                .map(Response::ReadHoldingRegisters),
            Request::WriteSingleRegister { address, value } => {
                self.write(address, &[value])?;
                Ok(Response::WriteSingleRegister { address, value })
            }
            Request::WriteMultipleRegisters { address, values } => {
                self.write(address, &values)?;
                let quantity =
                    u16::try_from(values.len()).map_err(|_| ExceptionCode::IllegalDataValue)?;
                Ok(Response::WriteMultipleRegisters { address, quantity })
            }
            Request::ReadWriteMultipleRegisters {
                read_address,
                read_quantity,
                write_address,
                values,
            } => {
                // Modbus Application Protocol V1.1b3, 6.17: "The write operation is performed
                // before the read." Check the read first so that a bad read changes nothing.
                layout::read_span(read_address, read_quantity)?;
                self.write(write_address, &values)?;
                self.mailbox
                    .read_registers(read_address, read_quantity)
                    .map(Response::ReadWriteMultipleRegisters)
            }
            _ => Err(ExceptionCode::IllegalFunction),
        }
    }
}

/// Waits for the line's result of a send-block request and shows it.
async fn wait_for_result(mailbox: Arc<Mailbox>, req: u16, pending: PendingSend) {
    let failure = pending.await.err().map(|e| e.event());
    mailbox.finish_send(req, failure);
}

/// The registers a write of `request` touches, if it writes.
fn written_span(request: &Request) -> Option<(u16, usize)> {
    match request {
        Request::WriteSingleRegister { address, .. } => Some((*address, 1)),
        Request::WriteMultipleRegisters { address, values } => Some((*address, values.len())),
        Request::ReadWriteMultipleRegisters {
            write_address,
            values,
            ..
        } => Some((*write_address, values.len())),
        _ => None,
    }
}

impl UnitService for MailboxUnit {
    fn call(&self, request: Request) -> UnitFuture {
        let answer = self.answer(request);
        Box::pin(async move { answer })
    }

    /// A line that does not allow sends (`sends = false`) refuses every write to the send block
    /// (REQ, TX_LEN, TX_DATA) with exception 01, the answer MODBUS/TCP Security gives a request
    /// that is not authorized; the line client refuses such a send too.
    fn refuses(&self, request: &Request) -> Option<ExceptionCode> {
        if self.client.sends_allowed() {
            return None;
        }
        let (address, count) = written_span(request)?;
        let end = usize::from(address) + count;
        let touches =
            usize::from(address) < usize::from(layout::TX_END) && end > usize::from(layout::TX_REQ);
        touches.then_some(ExceptionCode::IllegalFunction)
    }
}
