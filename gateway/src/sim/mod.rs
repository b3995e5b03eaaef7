//! Simulated devices on a serial line (`gateway sim`, and the demo's in-process devices).
//!
//! Each device is a plain struct implementing [`ModbusDevice`] (the contract of the Modbus
//! master's simulated partner, `protocols/modbus_master/partner.rs`): one RTU ADU in, the ADU to
//! answer out, `None` for silence. The models are profiles, not protocols: they know nothing about
//! ports or clocks, so tests drive them frame by frame; [`runner`] puts a model on a serial port or
//! any byte stream.
//!
//! - [`altivar::AltivarSim`]: Altivar 61/71 (seed manual 002), default slave 2;
//! - [`ksvario::KsVarioSim`]: KS vario (seed manual 001), default slave 17;
//! - [`meter::MeterSim`]: a generic device with plain register tables, the demo's energy meter
//!   holding one value of every tag type;
//! - [`bus::Bus`]: several of them on one port, a multi-drop RS485 bus (`gateway sim
//!   --also-address`, the demo's drive line with two drives);
//!
//! The protocols' simulated partners live in their folders: the 3964(R) and ASCII partners in
//! [`crate::protocols::telegram::partner`], the simulated serial master polling the gateway's
//! Modbus slave line (the demo's HMI) in [`crate::protocols::modbus_slave::partner`].
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

use proto_core::modbus::pdu::{ExceptionCode, ExceptionResponse, FunctionCode, Response};
use proto_core::modbus::rtu;

pub use crate::protocols::modbus_master::partner::{Faults, ModbusDevice};
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
