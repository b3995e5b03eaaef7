//! Simulated devices on a serial line (`gateway sim`, and the demo's in-process devices).
//!
//! Each device is a plain struct implementing [`ModbusDevice`]: one RTU ADU in, the ADU to answer
//! out, `None` for silence. The models know nothing about ports or clocks, so tests drive them
//! frame by frame; [`runner`] puts a model on a serial port or any byte stream.
//!
//! - [`altivar::AltivarSim`]: Altivar 61/71 (seed manual 002), default slave 2;
//! - [`ksvario::KsVarioSim`]: KS vario (seed manual 001), default slave 17;
//! - [`meter::MeterSim`]: a generic device with plain register tables, the demo's energy meter
//!   holding one value of every tag type;
//! - [`telegram`]: the 3964(R) and ASCII partners (echo, own telegrams every interval);
//! - [`bus::Bus`]: several of them on one port, a multi-drop RS485 bus (`gateway sim
//!   --also-address`, the demo's drive line with two drives);
//! - [`master`]: the other way round, a simulated serial master polling the gateway's Modbus slave
//!   line (the demo's HMI).
//!
//! Common rules of both manuals, applied by every model: a frame for another address is not
//! answered; a frame with a bad CRC is not answered (001 5 "Wird ein Übertragungsfehler
//! festgestellt, so wird keine Antwort erstellt"; Modbus over Serial Line V1.02, 2.4.1);
//! a broadcast (address 0) write is carried out and never answered, any other broadcast is ignored.

pub mod altivar;
pub mod bus;
pub mod ksvario;
pub mod meter;
pub mod runner;

use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use proto_core::checksum::crc16_modbus;
use proto_core::modbus::pdu::{ExceptionCode, ExceptionResponse, FunctionCode, Response};
use proto_core::modbus::rtu;

pub use runner::{run, serve_modbus, DeviceKind, Parity, SimArgs, SimError};

/// A simulated Modbus device model: what `gateway sim --device NAME` and the demo start for a
/// device of a profile. A new model is one line of [`MODBUS_MODELS`].
#[derive(Debug)]
pub struct SimModel {
    /// The `--device` name.
    pub name: &'static str,
    /// The config's profile the model plays (a registry name, or `generic`).
    pub profile: &'static str,
    /// The slave address without `--address`.
    pub default_address: u8,
    /// What it simulates, for `gateway sim --help`.
    pub help: &'static str,
    /// The model at a slave address, with faults injected.
    pub build: fn(u8, Faults) -> Box<dyn ModbusDevice>,
}

/// Every Modbus device model, by `--device` name.
pub const MODBUS_MODELS: &[SimModel] = &[
    SimModel {
        name: "altivar71",
        profile: "altivar71",
        default_address: proto_core::profiles::altivar::DEFAULT_ADDRESS,
        help: "Schneider Altivar 71 (Modbus RTU, default slave 2)",
        build: |address, faults| {
            let mut device = altivar::AltivarSim::new(address);
            device.set_faults(faults);
            Box::new(device)
        },
    },
    SimModel {
        name: "ksvario",
        profile: "ksvario",
        default_address: proto_core::profiles::ksvario::DEFAULT_ADDRESS,
        help: "PMA KS vario (Modbus RTU, default slave 17)",
        build: |address, faults| {
            let mut device = ksvario::KsVarioSim::new(address);
            device.set_faults(faults);
            Box::new(device)
        },
    },
    SimModel {
        name: "meter",
        profile: "generic",
        default_address: 30,
        help: "the demo's energy meter, one tag of every data type and byte order (Modbus RTU, \
               default slave 30; docs/tags.md)",
        build: |address, faults| {
            let mut device = meter::MeterSim::new(address);
            device.set_faults(faults);
            Box::new(device)
        },
    },
];

/// The model named `name` (`--device`).
pub fn model(name: &str) -> Option<&'static SimModel> {
    MODBUS_MODELS.iter().find(|m| m.name == name)
}

/// The model that plays a device of config profile `profile` (the meter for `generic`).
pub fn model_for_profile(profile: &str) -> Option<&'static SimModel> {
    MODBUS_MODELS
        .iter()
        .find(|m| m.profile.eq_ignore_ascii_case(profile))
}

/// The broadcast address (003 6.4.3 "ADDR"; 001 3.1; 002 "Adressen").
pub const BROADCAST: u8 = 0;

/// A simulated Modbus RTU slave.
pub trait ModbusDevice: Send {
    /// Handles one received frame (address, PDU, CRC) and returns the frame to send back, or
    /// `None` when the device stays silent.
    fn handle_frame(&mut self, adu: &[u8]) -> Option<Vec<u8>>;

    /// Advances the device's own clock by `elapsed`: the process behind the registers moves on
    /// and time-outs run. The default does nothing.
    fn tick(&mut self, elapsed: Duration) {
        let _ = elapsed;
    }

    /// The faults injected into the device's answers (the runner applies `delay`).
    fn faults(&self) -> Faults {
        Faults::default()
    }

    /// Bytes the line picks up after the answer just sent, once the answer has ended (the runner
    /// sends them after a silence of more than t3.5, so they are a burst of their own). The
    /// default is none.
    fn after_answer(&mut self) -> Option<Vec<u8>> {
        None
    }
}

impl<D: ModbusDevice + ?Sized> ModbusDevice for Box<D> {
    fn handle_frame(&mut self, adu: &[u8]) -> Option<Vec<u8>> {
        (**self).handle_frame(adu)
    }

    fn tick(&mut self, elapsed: Duration) {
        (**self).tick(elapsed);
    }

    fn faults(&self) -> Faults {
        (**self).faults()
    }

    fn after_answer(&mut self) -> Option<Vec<u8>> {
        (**self).after_answer()
    }
}

/// A device shared with the code that started it (a test reads its registers or changes its
/// faults while it serves). The lock is held for one frame or one tick, never across an await.
impl<D: ModbusDevice> ModbusDevice for Arc<Mutex<D>> {
    fn handle_frame(&mut self, adu: &[u8]) -> Option<Vec<u8>> {
        self.lock()
            .unwrap_or_else(PoisonError::into_inner)
            .handle_frame(adu)
    }

    fn tick(&mut self, elapsed: Duration) {
        self.lock()
            .unwrap_or_else(PoisonError::into_inner)
            .tick(elapsed);
    }

    fn faults(&self) -> Faults {
        self.lock().unwrap_or_else(PoisonError::into_inner).faults()
    }

    fn after_answer(&mut self) -> Option<Vec<u8>> {
        self.lock()
            .unwrap_or_else(PoisonError::into_inner)
            .after_answer()
    }
}

/// Faults to inject for tests of the gateway's error handling. The default injects none.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Faults {
    /// Never answer (the master sees "no reply", 003 7.2 08 30h).
    pub silent: bool,
    /// Wait this long before answering, on top of the normal turnaround.
    pub delay: Duration,
    /// Send answers with a wrong CRC (003 7.2 0E 57h).
    pub bad_crc: bool,
    /// Send answers with another slave address (003 7.2 08 31h).
    pub wrong_address: bool,
}

// === impl Faults ===

impl Faults {
    /// The answer as the faults change it.
    pub fn apply(&self, answer: Option<Vec<u8>>) -> Option<Vec<u8>> {
        if self.silent {
            return None;
        }
        let mut frame = answer?;
        if self.wrong_address {
            if let Some(address) = frame.first_mut() {
                *address = address.wrapping_add(1).max(1);
            }
            reseal(&mut frame);
        }
        if self.bad_crc {
            if let Some(last) = frame.last_mut() {
                *last ^= 0xFF;
            }
        }
        Some(frame)
    }
}

/// Recomputes the CRC of a frame after its bytes changed.
fn reseal(frame: &mut Vec<u8>) {
    if frame.len() >= rtu::MIN_FRAME_LEN {
        frame.truncate(frame.len() - 2);
        let crc = crc16_modbus(frame);
        frame.extend_from_slice(&crc.to_le_bytes());
    }
}

/// An RTU frame around a response PDU.
pub(crate) fn response_frame(address: u8, response: &Response) -> Vec<u8> {
    let mut pdu = Vec::new();
    response.encode(&mut pdu);
    pdu_frame(address, &pdu)
}

/// An RTU frame around an exception response.
pub(crate) fn exception_frame(address: u8, function: FunctionCode, code: ExceptionCode) -> Vec<u8> {
    let mut pdu = Vec::new();
    ExceptionResponse::new(function, code).encode(&mut pdu);
    pdu_frame(address, &pdu)
}

/// An RTU frame around any PDU.
pub(crate) fn pdu_frame(address: u8, pdu: &[u8]) -> Vec<u8> {
    let mut frame = Vec::with_capacity(pdu.len() + 3);
    rtu::encode_frame(address, pdu, &mut frame);
    frame
}

/// What a device answers: a response or an exception code.
pub(crate) type Answer = Result<Response, ExceptionCode>;

/// The frame carrying an answer.
pub(crate) fn answer_frame(address: u8, function: FunctionCode, answer: &Answer) -> Vec<u8> {
    match answer {
        Ok(response) => response_frame(address, response),
        Err(code) => exception_frame(address, function, *code),
    }
}
