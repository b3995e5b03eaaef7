//! Several simulated slaves on one port: a multi-drop RS485 bus.
//!
//! Every frame reaches every device, as on the wire. A device answers only frames for its own
//! address (or stays silent), so at most one answers a request; a broadcast (address 0) write is
//! carried out by every device and answered by none (Modbus over Serial Line V1.02, 2.2; 003 6.4.3
//! "ADDR"). The faults the runner applies (the answer's delay) are those of the device that
//! answered.

use std::time::Duration;

use super::{Faults, ModbusDevice};

/// The devices on one bus.
pub struct Bus {
    devices: Vec<Box<dyn ModbusDevice>>,
    /// The device that answered the last frame.
    answered: Option<usize>,
}

// === impl Bus ===

impl Bus {
    /// A bus with `devices` (each at its own slave address).
    pub fn new(devices: Vec<Box<dyn ModbusDevice>>) -> Self {
        Self {
            devices,
            answered: None,
        }
    }

    /// How many devices are on the bus.
    pub fn len(&self) -> usize {
        self.devices.len()
    }

    /// Whether the bus has no device.
    pub fn is_empty(&self) -> bool {
        self.devices.is_empty()
    }
}

impl ModbusDevice for Bus {
    fn handle_frame(&mut self, adu: &[u8]) -> Option<Vec<u8>> {
        self.answered = None;
        let mut reply = None;
        for (i, device) in self.devices.iter_mut().enumerate() {
            // Every device sees the frame (a broadcast write is carried out by all of them);
            // only the first answer goes on the wire.
            if let Some(answer) = device.handle_frame(adu) {
                if reply.is_none() {
                    reply = Some(answer);
                    self.answered = Some(i);
                }
            }
        }
        reply
    }

    fn tick(&mut self, elapsed: Duration) {
        for device in &mut self.devices {
            device.tick(elapsed);
        }
    }

    fn faults(&self) -> Faults {
        self.answered
            .and_then(|i| self.devices.get(i))
            .map(|d| d.faults())
            .unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use proto_core::modbus::rtu;

    use super::*;
    use crate::sim::altivar::AltivarSim;
    use crate::sim::ksvario::KsVarioSim;

    fn frame(address: u8, pdu: &[u8]) -> Vec<u8> {
        let mut adu = Vec::new();
        rtu::encode_frame(address, pdu, &mut adu);
        adu
    }

    fn address_of(answer: &[u8]) -> u8 {
        rtu::decode_frame(answer).expect("a valid frame").address
    }

    #[test]
    fn each_device_answers_its_own_address_and_only_it() {
        let mut bus = Bus::new(vec![
            Box::new(AltivarSim::new(2)),
            Box::new(AltivarSim::new(3)),
            Box::new(KsVarioSim::new(17)),
        ]);
        assert_eq!(bus.len(), 3);
        // FC 03 W3102, 4 registers: SFr, tFr, HSP, LSP.
        let read = [0x03, 0x0C, 0x1E, 0x00, 0x04];
        for address in [2, 3] {
            let answer = bus.handle_frame(&frame(address, &read)).expect("answered");
            assert_eq!(address_of(&answer), address);
        }
        // FC 04 at 1004, three registers (001's example).
        let answer = bus
            .handle_frame(&frame(17, &[0x04, 0x03, 0xEC, 0x00, 0x03]))
            .expect("answered");
        assert_eq!(address_of(&answer), 17);
        assert_eq!(bus.handle_frame(&frame(4, &read)), None, "nobody at 4");
    }

    #[test]
    fn a_broadcast_write_reaches_every_drive_and_is_not_answered() {
        let mut bus = Bus::new(vec![
            Box::new(AltivarSim::new(2)),
            Box::new(AltivarSim::new(3)),
        ]);
        // FC 06 ACC (W9001) = 45 to everybody.
        assert_eq!(
            bus.handle_frame(&frame(0, &[0x06, 0x23, 0x29, 0x00, 0x2D])),
            None
        );
        for address in [2, 3] {
            let answer = bus
                .handle_frame(&frame(address, &[0x03, 0x23, 0x29, 0x00, 0x01]))
                .expect("answered");
            let decoded = rtu::decode_frame(&answer).expect("valid");
            assert_eq!(decoded.pdu, [0x03, 0x02, 0x00, 0x2D], "drive {address}");
        }
    }
}
