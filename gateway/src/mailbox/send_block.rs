//! The send block of a mailbox, modeled on FB 8 P_SND_RK: a client writes the telegram (DATA,
//! LEN) and a new REQ value; the mailbox hands the telegram to the line and shows BUSY, then DONE
//! or ERROR with the STATUS word of the event that failed it (003 7.1: "An error message is only
//! output if the ERROR bit ... is set. In all other cases the STATUS word is zero").
//!
//! One request at a time, as FB 8 (000 5.3 "Greifen Sie auf den Sende-DB erst wieder zu, wenn
//! die Daten komplett übertragen wurden (DONE = 1)"): a new REQ while BUSY answers exception 06.
//! The telegram is copied when the request starts, so DATA may be rewritten while BUSY. Writing
//! REQ with its current value starts nothing, so a client may repeat a write whose answer it
//! lost.

use proto_core::event::{ids, EventId};
use proto_core::modbus::pdu::ExceptionCode;

use super::layout::{self, Reg, DATA_REGISTERS};
use super::Mailbox;

/// The registers of the send block.
#[derive(Clone, Debug)]
pub(super) struct SendBlock {
    /// REQ as last written.
    req: u16,
    /// LEN as last written.
    len: u16,
    /// DATA as last written.
    data: Vec<u16>,
    /// The request RESULT_REQ was sent.
    done: bool,
    /// The request RESULT_REQ failed.
    error: bool,
    /// The event that failed it.
    status: u16,
    /// A request is being sent.
    busy: bool,
    /// The request the result belongs to.
    result_req: u16,
}

impl Default for SendBlock {
    fn default() -> Self {
        Self {
            req: 0,
            len: 0,
            data: vec![0; usize::from(DATA_REGISTERS)],
            done: false,
            error: false,
            status: 0,
            busy: false,
            result_req: 0,
        }
    }
}

// === impl SendBlock ===

impl SendBlock {
    pub(super) fn register(&self, reg: Reg) -> u16 {
        match reg {
            Reg::TxDone => u16::from(self.done),
            Reg::TxError => u16::from(self.error),
            Reg::TxStatus => self.status,
            Reg::TxBusy => u16::from(self.busy),
            Reg::TxResultReq => self.result_req,
            Reg::TxReq => self.req,
            Reg::TxLen => self.len,
            Reg::TxData(n) => self.data.get(n).copied().unwrap_or(0),
            _ => 0,
        }
    }

    /// Writes `values` from `offset` (0 = REQ, 1 = LEN, 2.. = DATA); the layout checked the span.
    fn apply(&mut self, offset: usize, values: &[u16]) {
        for (i, &value) in (offset..).zip(values) {
            match i {
                0 => self.req = value,
                1 => self.len = value,
                n => {
                    if let Some(word) = self.data.get_mut(n - 2) {
                        *word = value;
                    }
                }
            }
        }
    }

    fn finish(&mut self, req: u16, failure: Option<EventId>) {
        self.busy = false;
        self.result_req = req;
        self.done = failure.is_none();
        self.error = failure.is_some();
        self.status = failure.map_or(0, EventId::status_word);
    }
}

/// A send the block started: its request number and whatever the starter returned.
#[derive(Debug)]
pub(crate) struct Started<T> {
    pub(crate) req: u16,
    pub(crate) pending: T,
}

// === impl Mailbox (send block) ===

impl Mailbox {
    /// Applies a write of the send block at `offset`. When REQ changes, the telegram DATA[..LEN]
    /// goes to `start`, which queues it on the line; its error is the exception of the write,
    /// and nothing is written then.
    ///
    /// A LEN of 0 or above the line's limit does not reach the line: the request ends at once
    /// with ERROR and STATUS 1E 41h (7.2: "Number of bytes in the LEN parameter of the FBs
    /// illegal") or 05 17h ("Transmission length ... too great").
    pub(crate) fn write_send_block<T>(
        &self,
        offset: usize,
        values: &[u16],
        start: impl FnOnce(Vec<u8>) -> Result<T, ExceptionCode>,
    ) -> Result<Option<Started<T>>, ExceptionCode> {
        let mut state = self.lock();
        let mut block = state.send.clone();
        block.apply(offset, values);
        if block.req == state.send.req {
            state.send = block;
            return Ok(None);
        }
        if state.send.busy {
            return Err(ExceptionCode::ServerDeviceBusy);
        }
        let len = usize::from(block.len);
        let refusal = if len == 0 {
            Some(ids::BACKPLANE_LEN_ILLEGAL)
        } else if len > self.max_send_len {
            Some(ids::TRANSFER_LENGTH_INVALID)
        } else {
            None
        };
        if let Some(event) = refusal {
            let req = block.req;
            block.finish(req, Some(event));
            state.send = block;
            state.counters.send_failed += 1;
            return Ok(None);
        }
        let telegram = layout::data_bytes(&block.data, len);
        let pending = start(telegram)?;
        block.busy = true;
        block.done = false;
        block.error = false;
        block.status = 0;
        let req = block.req;
        state.send = block;
        Ok(Some(Started { req, pending }))
    }

    /// Ends request `req` of the send block: DONE, or ERROR with the STATUS word of `failure`.
    pub(crate) fn finish_send(&self, req: u16, failure: Option<EventId>) {
        self.lock().send.finish(req, failure);
    }
}
