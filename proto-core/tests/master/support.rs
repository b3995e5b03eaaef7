//! The simulated line and the test slave the master tests share.

use core::time::Duration;

use proto_core::event::EventId;
use proto_core::modbus::master::{Master, MasterConfig, MasterEvent, Outcome, RequestId};
use proto_core::modbus::pdu::{ExceptionCode, ExceptionResponse, Request, Response};
use proto_core::modbus::{ascii, rtu};
use proto_core::time::Instant;

// --- Frames from the Altivar 61/71 manual (002, "Modbus-Protokoll"), CRC checked ---

/// FC 03: read W3102..W3105 (SFr, tFr, HSP, LSP) of slave 2.
pub(crate) const ATV_READ_REQUEST: [u8; 8] = [0x02, 0x03, 0x0C, 0x1E, 0x00, 0x04, 0x27, 0x6C];
/// The answer: SFr = 40, tFr = 600, HSP = 500, LSP = 0.
pub(crate) const ATV_READ_RESPONSE: [u8; 13] = [
    0x02, 0x03, 0x08, 0x00, 0x28, 0x02, 0x58, 0x01, 0xF4, 0x00, 0x00, 0x52, 0xB0,
];
/// FC 06: write 13 to W9001 (ACC) of slave 2; the answer is the same frame.
pub(crate) const ATV_WRITE_ACC: [u8; 8] = [0x02, 0x06, 0x23, 0x29, 0x00, 0x0D, 0x92, 0x70];
/// FC 16 to the read-only ETA (W3201) of slave 4, answered with exception 04.
pub(crate) const ATV_WRITE_ETA_REQUEST: [u8; 11] = [
    0x04, 0x10, 0x0C, 0x81, 0x00, 0x01, 0x02, 0x00, 0x01, 0x8A, 0xD1,
];
pub(crate) const ATV_WRITE_ETA_EXCEPTION: [u8; 5] = [0x04, 0x90, 0x04, 0x5D, 0xC2];

pub(crate) const BAUD: u32 = 19_200;
/// 8E1: start, 8 data, parity, stop.
pub(crate) const BITS_PER_CHAR: u8 = 11;
pub(crate) const START: Instant = Instant::from_millis(10_000);

pub(crate) fn atv_read() -> Request {
    Request::ReadHoldingRegisters {
        address: 0x0C1E,
        quantity: 4,
    }
}

pub(crate) fn rtu_config() -> MasterConfig {
    MasterConfig::rtu(BAUD, BITS_PER_CHAR)
}

pub(crate) fn timing() -> rtu::CharTiming {
    rtu::CharTiming::exact(BAUD, BITS_PER_CHAR)
}

pub(crate) fn rtu_frame(address: u8, pdu: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    rtu::encode_frame(address, pdu, &mut out);
    out
}

/// A master on a simulated line: the test moves the clock and plays the slave.
pub(crate) struct Line {
    pub(crate) master: Master,
    pub(crate) now: Instant,
    pub(crate) events: Vec<MasterEvent>,
}

impl Line {
    pub(crate) fn new(config: MasterConfig) -> Self {
        Self {
            master: Master::new(config),
            now: START,
            events: Vec::new(),
        }
    }

    pub(crate) fn drain(&mut self) {
        while let Some(event) = self.master.poll_event() {
            self.events.push(event);
        }
    }

    /// Moves the clock on, running the timers that expire on the way, as a runtime does.
    pub(crate) fn advance(&mut self, by: Duration) {
        let target = self.now + by;
        while let Some(at) = self.master.poll_timeout().filter(|at| *at <= target) {
            self.now = self.now.max(at);
            self.master.handle_timeout(self.now);
            self.drain();
        }
        self.now = target;
    }

    pub(crate) fn submit(&mut self, slave: u8, request: Request) -> RequestId {
        let id = self
            .master
            .submit(self.now, slave, request)
            .expect("request accepted");
        self.drain();
        id
    }

    /// Takes the ADU the master wants to send and reports its end after the time it takes.
    pub(crate) fn transmit(&mut self) -> Vec<u8> {
        let adu = self.master.poll_transmit().expect("an ADU to send");
        self.now += timing().transmit_time(adu.len());
        self.master.handle_tx_done(self.now);
        self.drain();
        adu
    }

    pub(crate) fn rx(&mut self, bytes: &[u8]) {
        self.master.handle_rx(self.now, bytes);
        self.drain();
    }

    /// Moves the clock to the next deadline and runs it.
    pub(crate) fn fire(&mut self) {
        let at = self.master.poll_timeout().expect("a timer runs");
        assert!(
            at >= self.now,
            "deadline {at:?} lies before now {:?}",
            self.now
        );
        self.now = at;
        self.master.handle_timeout(at);
        self.drain();
    }

    /// Runs timers until the master is idle (bounded).
    pub(crate) fn settle(&mut self) {
        for _ in 0..16 {
            if self.master.is_idle() {
                return;
            }
            self.fire();
        }
        panic!("master does not become idle");
    }

    pub(crate) fn raised(&self) -> Vec<EventId> {
        self.events
            .iter()
            .filter_map(|e| {
                if let MasterEvent::Raised { id, .. } = e {
                    Some(*id)
                } else {
                    None
                }
            })
            .collect()
    }

    pub(crate) fn outcomes(&self) -> Vec<Outcome> {
        self.events
            .iter()
            .filter_map(|e| {
                if let MasterEvent::Completed { outcome, .. } = e {
                    Some(outcome.clone())
                } else {
                    None
                }
            })
            .collect()
    }
}

/// A slave built from proto-core's codec: holding registers, FC 03/06/16, exceptions otherwise.
pub(crate) struct TestSlave {
    pub(crate) address: u8,
    /// Register `start + i` holds `registers[i]`.
    pub(crate) start: u16,
    pub(crate) registers: Vec<u16>,
}

impl TestSlave {
    /// The Altivar of the manual's example: W3102..W3105 = 40, 600, 500, 0 and W9001 (ACC).
    pub(crate) fn altivar() -> Self {
        let mut registers = vec![0; 9001 - 3102 + 1];
        registers[..4].copy_from_slice(&[40, 600, 500, 0]);
        Self {
            address: 2,
            start: 3102,
            registers,
        }
    }

    pub(crate) fn slot(&mut self, address: u16) -> Option<&mut u16> {
        self.registers
            .get_mut(usize::from(address.checked_sub(self.start)?))
    }

    pub(crate) fn serve(&mut self, request: &Request) -> Result<Response, ExceptionCode> {
        match request {
            Request::ReadHoldingRegisters { address, quantity } => (0..*quantity)
                .map(|i| {
                    address
                        .checked_add(i)
                        .and_then(|a| self.slot(a).map(|v| *v))
                })
                .collect::<Option<Vec<u16>>>()
                .map(Response::ReadHoldingRegisters)
                .ok_or(ExceptionCode::IllegalDataAddress),
            Request::WriteSingleRegister { address, value } => {
                *self
                    .slot(*address)
                    .ok_or(ExceptionCode::IllegalDataAddress)? = *value;
                Ok(Response::WriteSingleRegister {
                    address: *address,
                    value: *value,
                })
            }
            _ => Err(ExceptionCode::IllegalFunction),
        }
    }

    /// The answer PDU to a request PDU, `None` when the request is not for this slave.
    pub(crate) fn answer_pdu(&mut self, address: u8, pdu: &[u8]) -> Option<Vec<u8>> {
        if address != self.address && address != 0 {
            return None;
        }
        let function = pdu.first().copied().unwrap_or(0);
        let mut out = Vec::new();
        match Request::decode(pdu) {
            Ok(request) => match self.serve(&request) {
                Ok(response) => response.encode(&mut out),
                Err(code) => ExceptionResponse::new(request.function(), code).encode(&mut out),
            },
            Err(error) => ExceptionResponse::for_error(function, &error).encode(&mut out),
        }
        // A broadcast is carried out and never answered (003 6.4.3 "ADDR").
        (address != 0).then_some(out)
    }

    pub(crate) fn answer_rtu(&mut self, frame: &[u8]) -> Option<Vec<u8>> {
        let frame = rtu::decode_frame(frame).ok()?;
        let pdu = self.answer_pdu(frame.address, frame.pdu)?;
        Some(rtu_frame(self.address, &pdu))
    }

    pub(crate) fn answer_ascii(&mut self, frame: &[u8]) -> Option<Vec<u8>> {
        let (address, pdu) = ascii::decode_frame(frame).ok()?;
        let answer = self.answer_pdu(address, &pdu)?;
        let mut out = Vec::new();
        ascii::encode_frame(self.address, &answer, &mut out);
        Some(out)
    }
}
