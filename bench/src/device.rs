//! The simulated devices of the benchmark: a flat register device that answers any read of 1..125
//! registers (the seed devices stop at 63 and 120, the benchmark needs 125), and a bus of several
//! devices on one serial line.
//!
//! Both implement the gateway's own [`ModbusDevice`], so they run under the same runner as the
//! Altivar and KS vario simulators ([`gateway::sim::serve_modbus`]): the same framing, the same
//! t3.5 turnaround before an answer.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

use gateway::sim::{Faults, ModbusDevice};
use proto_core::modbus::pdu::{ExceptionCode, ExceptionResponse, FunctionCode, Request, Response};
use proto_core::modbus::rtu;

/// The registers of one device (the whole 16-bit address space).
const REGISTERS: usize = 0x1_0000;

/// A device with 65536 holding (and input) registers.
pub(crate) struct FlatDevice {
    address: u8,
    registers: Vec<u16>,
    /// Every read returns new values (the register plus the number of reads so far), so that
    /// every poll changes every tag.
    changing: bool,
    faults: Faults,
    /// While set, the device answers nothing (the benchmark switches it).
    silent: Arc<AtomicBool>,
    /// Reads answered, shared with the benchmark.
    reads: Arc<AtomicU64>,
}

// === impl FlatDevice ===

impl FlatDevice {
    /// A device at `address` whose register `i` holds `i`.
    pub(crate) fn new(address: u8) -> Self {
        Self {
            address,
            registers: (0..REGISTERS).map(|i| i as u16).collect(),
            changing: false,
            faults: Faults::default(),
            silent: Arc::new(AtomicBool::new(false)),
            reads: Arc::new(AtomicU64::new(0)),
        }
    }

    /// Every read returns values it did not return before.
    pub(crate) fn changing(mut self) -> Self {
        self.changing = true;
        self
    }

    /// The switch that silences the device while it is set (shared with the benchmark).
    pub(crate) fn silence_switch(&self) -> Arc<AtomicBool> {
        Arc::clone(&self.silent)
    }

    /// The counter of reads answered.
    pub(crate) fn reads(&self) -> Arc<AtomicU64> {
        Arc::clone(&self.reads)
    }

    fn read(&mut self, address: u16, quantity: u16) -> Result<Vec<u16>, ExceptionCode> {
        let start = usize::from(address);
        let end = start + usize::from(quantity);
        let values = self
            .registers
            .get(start..end)
            .ok_or(ExceptionCode::IllegalDataAddress)?;
        let n = self.reads.fetch_add(1, Ordering::Relaxed);
        if self.changing {
            let offset = n as u16;
            Ok(values.iter().map(|v| v.wrapping_add(offset)).collect())
        } else {
            Ok(values.to_vec())
        }
    }

    fn write(&mut self, address: u16, values: &[u16]) -> Result<(), ExceptionCode> {
        let start = usize::from(address);
        let slots = self
            .registers
            .get_mut(start..start + values.len())
            .ok_or(ExceptionCode::IllegalDataAddress)?;
        slots.copy_from_slice(values);
        Ok(())
    }

    fn answer(&mut self, request: Request) -> Result<Response, ExceptionCode> {
        match request {
            Request::ReadHoldingRegisters { address, quantity } => self
                .read(address, quantity)
                .map(Response::ReadHoldingRegisters),
            Request::ReadInputRegisters { address, quantity } => self
                .read(address, quantity)
                .map(Response::ReadInputRegisters),
            Request::WriteSingleRegister { address, value } => self
                .write(address, &[value])
                .map(|()| Response::WriteSingleRegister { address, value }),
            Request::WriteMultipleRegisters { address, values } => {
                let quantity = u16::try_from(values.len()).unwrap_or(u16::MAX);
                self.write(address, &values)
                    .map(|()| Response::WriteMultipleRegisters { address, quantity })
            }
            _ => Err(ExceptionCode::IllegalFunction),
        }
    }
}

impl ModbusDevice for FlatDevice {
    fn handle_frame(&mut self, adu: &[u8]) -> Option<Vec<u8>> {
        // A bad CRC or another address: silence, as every device of the seeds.
        let frame = rtu::decode_frame(adu).ok()?;
        if frame.address != self.address || self.silent.load(Ordering::Relaxed) {
            return None;
        }
        let function = FunctionCode(*frame.pdu.first()?);
        let answer = match Request::decode(frame.pdu) {
            Ok(request) => self.answer(request),
            Err(error) => Err(ExceptionCode::from(&error)),
        };
        let mut pdu = Vec::new();
        match answer {
            Ok(response) => response.encode(&mut pdu),
            Err(code) => ExceptionResponse::new(function, code).encode(&mut pdu),
        }
        let mut out = Vec::with_capacity(pdu.len() + 3);
        rtu::encode_frame(self.address, &pdu, &mut out);
        self.faults.apply(Some(out))
    }

    fn faults(&self) -> Faults {
        self.faults
    }
}

/// Several devices on one line: each frame goes to every device, the one addressed answers.
pub(crate) struct Bus(pub(crate) Vec<FlatDevice>);

impl ModbusDevice for Bus {
    fn handle_frame(&mut self, adu: &[u8]) -> Option<Vec<u8>> {
        self.0.iter_mut().find_map(|d| d.handle_frame(adu))
    }
}
