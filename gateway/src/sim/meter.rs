//! A generic Modbus RTU slave with plain register tables: the demo's energy meter, whose
//! registers hold one value of every tag type the gateway decodes (64-bit integers and floats in
//! several byte orders, a serial number string, a status word of bits, a value with scale and
//! offset). Holding and input registers `0..REGISTERS` are defined; a read or write outside
//! answers exception 02, functions other than FC 03, 04, 06 and 16 answer 01 (Modbus
//! Application Protocol V1.1b3, 6.3, 6.4, 6.6, 6.12, 7).

use proto_core::modbus::pdu::{ExceptionCode, FunctionCode, Limits, Request, Response};
use proto_core::modbus::rtu;

use super::{answer_frame, exception_frame, Answer, Faults, ModbusDevice, BROADCAST};

/// Registers of each table.
pub const REGISTERS: u16 = 128;

/// Where the demo meter keeps its values and what they are at start; the demo's config names
/// the same addresses (`[lines.meter.devices.meter]`).
pub mod map {
    /// Input registers 0..4: the energy counter in Wh, u64, DCBA (little endian); above
    /// `i64::MAX`, so that only an exact 64-bit path shows it right.
    pub const ENERGY: u16 = 0;
    pub const ENERGY_WH: u64 = 0xF0DE_BC9A_7856_3412;
    /// Input registers 4..8: the total flow in m3, f64, ABCD.
    pub const FLOW: u16 = 4;
    pub const FLOW_M3: f64 = 12_345.678_901_234;
    /// Input register 8: the temperature, raw 0.1 K steps: value = raw x 0.1 - 273.15 degC.
    pub const TEMPERATURE: u16 = 8;
    pub const TEMPERATURE_RAW: u16 = 2931;
    /// Holding registers 10..14: a correction in Wh, i64, CDAB (GHEFCDAB).
    pub const CORRECTION: u16 = 10;
    pub const CORRECTION_WH: i64 = -1_234_567_890_123;
    /// Holding registers 20..28: the serial number, 16 ASCII characters, high byte first, NUL
    /// padded.
    pub const SERIAL: u16 = 20;
    pub const SERIAL_TEXT: &str = "GW-17-0042";
    /// Holding register 30: the status and control word; bit 0 "running" (read-only tag),
    /// bit 3 "relay" (writable tag), the other bits set so that a lost neighbour shows.
    pub const STATUS: u16 = 30;
    pub const STATUS_WORD: u16 = 0xA5F1;
    /// Holding register 31: a setpoint, value = raw x 0.5 - 20.
    pub const SETPOINT: u16 = 31;
    pub const SETPOINT_RAW: u16 = 100;
    /// Holding registers 40..44: a limit, f64, DCBA.
    pub const LIMIT: u16 = 40;
    pub const LIMIT_VALUE: f64 = 99.5;
    /// Holding registers 50..54: a preset counter, u64, CDAB (GHEFCDAB).
    pub const PRESET: u16 = 50;
    pub const PRESET_VALUE: u64 = 1_000_000_000_000;
    /// Holding registers 60..62: a power factor, f32, CDAB.
    pub const POWER: u16 = 60;
    pub const POWER_VALUE: f32 = 0.95;
}

const LIMITS: Limits = Limits::SPEC;

/// The meter: two tables of plain registers.
#[derive(Clone, Debug)]
pub struct MeterSim {
    address: u8,
    holding: Vec<u16>,
    input: Vec<u16>,
    faults: Faults,
}

/// The registers of `bytes` (most significant first) with the registers reversed and/or the
/// bytes of each swapped.
fn layout(bytes: &[u8], words_reversed: bool, bytes_swapped: bool) -> Vec<u16> {
    let mut words: Vec<u16> = bytes
        .chunks(2)
        .map(|c| {
            let w = u16::from_be_bytes([
                c.first().copied().unwrap_or(0),
                c.get(1).copied().unwrap_or(0),
            ]);
            if bytes_swapped {
                w.swap_bytes()
            } else {
                w
            }
        })
        .collect();
    if words_reversed {
        words.reverse();
    }
    words
}

// === impl MeterSim ===

impl MeterSim {
    /// Sets the injected faults.
    pub fn set_faults(&mut self, faults: Faults) {
        self.faults = faults;
    }

    /// The demo meter at slave `address` with the values of [`map`].
    pub fn new(address: u8) -> Self {
        let mut sim = Self {
            address,
            holding: vec![0; usize::from(REGISTERS)],
            input: vec![0; usize::from(REGISTERS)],
            faults: Faults::default(),
        };
        // The byte layouts are written out here by hand (not through the gateway's codec), so
        // that the end-to-end tests compare two independent encodings.
        sim.put_input(
            map::ENERGY,
            &layout(&map::ENERGY_WH.to_be_bytes(), true, true),
        );
        sim.put_input(
            map::FLOW,
            &layout(&map::FLOW_M3.to_be_bytes(), false, false),
        );
        sim.put_input(map::TEMPERATURE, &[map::TEMPERATURE_RAW]);
        sim.put_holding(
            map::CORRECTION,
            &layout(&map::CORRECTION_WH.to_be_bytes(), true, false),
        );
        let mut serial = map::SERIAL_TEXT.as_bytes().to_vec();
        serial.resize(16, 0);
        sim.put_holding(map::SERIAL, &layout(&serial, false, false));
        sim.put_holding(map::STATUS, &[map::STATUS_WORD]);
        sim.put_holding(map::SETPOINT, &[map::SETPOINT_RAW]);
        sim.put_holding(
            map::LIMIT,
            &layout(&map::LIMIT_VALUE.to_be_bytes(), true, true),
        );
        sim.put_holding(
            map::PRESET,
            &layout(&map::PRESET_VALUE.to_be_bytes(), true, false),
        );
        sim.put_holding(
            map::POWER,
            &layout(&map::POWER_VALUE.to_be_bytes(), true, false),
        );
        sim
    }

    /// The holding registers `address..address + count` (a test checks a write).
    pub fn holding(&self, address: u16, count: u16) -> Option<&[u16]> {
        let start = usize::from(address);
        self.holding.get(start..start + usize::from(count))
    }

    fn put_holding(&mut self, address: u16, words: &[u16]) {
        let start = usize::from(address);
        if let Some(slot) = self.holding.get_mut(start..start + words.len()) {
            slot.copy_from_slice(words);
        }
    }

    fn put_input(&mut self, address: u16, words: &[u16]) {
        let start = usize::from(address);
        if let Some(slot) = self.input.get_mut(start..start + words.len()) {
            slot.copy_from_slice(words);
        }
    }

    fn answer(&mut self, request: Request) -> Answer {
        let range = |address: u16, count: usize| {
            let start = usize::from(address);
            (start + count <= usize::from(REGISTERS))
                .then_some(start..start + count)
                .ok_or(ExceptionCode::IllegalDataAddress)
        };
        match request {
            Request::ReadHoldingRegisters { address, quantity } => {
                let r = range(address, usize::from(quantity))?;
                Ok(Response::ReadHoldingRegisters(
                    self.holding.get(r).unwrap_or_default().to_vec(),
                ))
            }
            Request::ReadInputRegisters { address, quantity } => {
                let r = range(address, usize::from(quantity))?;
                Ok(Response::ReadInputRegisters(
                    self.input.get(r).unwrap_or_default().to_vec(),
                ))
            }
            Request::WriteSingleRegister { address, value } => {
                range(address, 1)?;
                self.put_holding(address, &[value]);
                Ok(Response::WriteSingleRegister { address, value })
            }
            Request::WriteMultipleRegisters { address, values } => {
                range(address, values.len())?;
                self.put_holding(address, &values);
                Ok(Response::WriteMultipleRegisters {
                    address,
                    quantity: u16::try_from(values.len()).unwrap_or(u16::MAX),
                })
            }
            _ => Err(ExceptionCode::IllegalFunction),
        }
    }
}

impl ModbusDevice for MeterSim {
    fn handle_frame(&mut self, adu: &[u8]) -> Option<Vec<u8>> {
        let frame = rtu::decode_frame(adu).ok()?;
        let address = *adu.first()?;
        if address != self.address && address != BROADCAST {
            return None;
        }
        let function = FunctionCode(frame.pdu.first().copied().unwrap_or_default());
        let request = Request::decode_with(frame.pdu, &LIMITS);
        if address == BROADCAST {
            // A broadcast write is carried out and never answered.
            if let Ok(request) = request {
                let _ = self.answer(request);
            }
            return None;
        }
        let answer = match request {
            Ok(request) => self.answer(request),
            Err(error) => Err(ExceptionCode::from(&error)),
        };
        let frame = match answer {
            Err(ExceptionCode::IllegalFunction) => {
                exception_frame(self.address, function, ExceptionCode::IllegalFunction)
            }
            answer => answer_frame(self.address, function, &answer),
        };
        self.faults.apply(Some(frame))
    }

    fn faults(&self) -> Faults {
        self.faults
    }
}

#[cfg(test)]
mod tests {
    use proto_core::modbus::rtu;

    use super::*;

    fn request(sim: &mut MeterSim, pdu: &[u8]) -> Vec<u8> {
        let mut frame = Vec::new();
        rtu::encode_frame(30, pdu, &mut frame);
        let answer = sim.handle_frame(&frame).expect("answered");
        let decoded = rtu::decode_frame(&answer).expect("valid frame");
        decoded.pdu.to_vec()
    }

    #[test]
    fn the_meter_serves_its_map_and_refuses_the_rest() {
        let mut sim = MeterSim::new(30);
        // FC 04 of the energy counter: little endian, so the low byte 12h comes first.
        assert_eq!(
            request(&mut sim, &[0x04, 0, 0, 0, 4]),
            [0x04, 8, 0x12, 0x34, 0x56, 0x78, 0x9A, 0xBC, 0xDE, 0xF0]
        );
        // The serial number, high byte first.
        let serial = request(&mut sim, &[0x03, 0, 20, 0, 8]);
        assert_eq!(serial.get(2..12), Some(&b"GW-17-0042"[..]));
        // Past the table: 02; a coil read: 01.
        assert_eq!(request(&mut sim, &[0x03, 0, 127, 0, 2]), [0x83, 0x02]);
        assert_eq!(request(&mut sim, &[0x01, 0, 0, 0, 1]), [0x81, 0x01]);
        // A write lands in the holding table.
        assert_eq!(
            request(&mut sim, &[0x06, 0, 30, 0x12, 0x34]),
            [0x06, 0, 30, 0x12, 0x34]
        );
        assert_eq!(sim.holding(30, 1), Some(&[0x1234][..]));
    }
}
