//! A simulated KS vario controller system with its Modbus RTU coupler (seed manual 001).
//!
//! Defaults reproduce the manual's examples (which the README and the tests use): slave 17; FC 04 at 1004..1006
//! reads 1066 / 140 / 4158; ti1 / ti2 of channel 1 (04 98 hex) read 180 / 333; one value store
//! behind the integer, fix point and float addresses, so that the float FC 16 example (9A AE hex:
//! 222.0 and 333.0) changes integer addresses 3415 and 3416. Every channel 1..30 has the data the
//! examples name (SetpInterface at word 118, ti1 / ti2 at 152 / 153, words 343 / 344); the full
//! address table (9499-040-72918) is not among the seeds.
//!
//! FC 08 (001 4.3): sub-functions 00, 01, 02, 04, 0A, 0B..12, 40..42 with listen-only mode. A
//! message longer than the 250-byte buffer is not answered (001 3.1).

mod store;

use proto_core::modbus::pdu::{ExceptionCode, FunctionCode, Limits, Request, Response};
use proto_core::modbus::rtu;
use proto_core::modbus::FrameError;
use proto_core::profiles::ksvario::{self as profile, diag};

pub use self::store::Datum;
use self::store::{Entry, Store};
use super::{answer_frame, exception_frame, Answer, Faults, ModbusDevice, BROADCAST};

/// The request limits as the PDU decoder takes them (001 3.1: 120 integer data a message).
const LIMITS: Limits = Limits {
    read_bits: 0,
    read_registers: profile::MAX_READ,
    write_bits: 0,
    write_registers: profile::MAX_WRITE,
    read_write_read_registers: 0,
    read_write_write_registers: 0,
};

/// FC 08 / 01 data that also clears the communication event log (Modbus Application Protocol
/// V1.1b3, 6.8.1 sub-function 01: 00 00 or FF 00).
const RESTART_CLEAR_LOG: [u8; 2] = [0xFF, 0x00];

/// Word offsets inside a channel's 512-word area that 001's examples name.
const SETP_INTERFACE: u16 = 118;
const TI1: u16 = 152;
const TI2: u16 = 153;
const DATA_15: u16 = 343;
const DATA_16: u16 = 344;

/// The FC 08 counters of 001 4.3.6..4.3.15 (16-bit word counters).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    /// 0B: messages seen on the bus (all stations, own answers excluded).
    pub bus_messages: u16,
    /// 0C: messages to this slave with a transmission error (CRC or parity).
    pub comm_errors: u16,
    /// 0D: messages answered with an exception.
    pub exceptions: u16,
    /// 0E: messages for this slave (broadcasts included).
    pub slave_messages: u16,
    /// 0F: messages for this slave not answered.
    pub no_response: u16,
    /// 10: messages answered with NAK (never, here).
    pub naks: u16,
    /// 11: messages answered with busy (never, here).
    pub busy: u16,
    /// 12: messages too long for the receive buffer.
    pub overruns: u16,
    /// 40: parity errors (a pty cannot produce them).
    pub parity_errors: u16,
    /// 41: framing errors (a pty cannot produce them).
    pub framing_errors: u16,
    /// 42: messages longer than the receive buffer.
    pub buffer_full: u16,
}

// === impl Counters ===

impl Counters {
    fn get(&self, sub_function: u16) -> Option<u16> {
        Some(match sub_function {
            diag::BUS_MESSAGE_COUNT => self.bus_messages,
            diag::BUS_COMMUNICATION_ERROR_COUNT => self.comm_errors,
            diag::EXCEPTION_COUNT => self.exceptions,
            diag::SLAVE_MESSAGE_COUNT => self.slave_messages,
            diag::NO_RESPONSE_COUNT => self.no_response,
            diag::NAK_COUNT => self.naks,
            diag::BUSY_COUNT => self.busy,
            diag::OVERRUN_COUNT => self.overruns,
            diag::PARITY_ERROR_COUNT => self.parity_errors,
            diag::FRAMING_ERROR_COUNT => self.framing_errors,
            diag::BUFFER_FULL_COUNT => self.buffer_full,
            _ => return None,
        })
    }
}

fn bump(counter: &mut u16) {
    *counter = counter.saturating_add(1);
}

/// A simulated KS vario.
#[derive(Debug)]
pub struct KsVarioSim {
    /// The coupler's Modbus address.
    address: u8,
    store: Store,
    /// 001 4.3.4: in listen-only mode nothing is carried out or answered until FC 08 / 01.
    listen_only: bool,
    counters: Counters,
    /// 001 4.3.3: the 16-bit diagnostic register (free content; the simulator reports 0).
    diagnostic_register: u16,
    faults: Faults,
}

impl Default for KsVarioSim {
    fn default() -> Self {
        Self::new(profile::DEFAULT_ADDRESS)
    }
}

// === impl KsVarioSim ===

impl KsVarioSim {
    /// A controller at `address` with the manual's example data.
    pub fn new(address: u8) -> Self {
        let mut store = Store::default();
        // 001 4 "Beispiel für eine Übertragung": FC 04 at 1004 reads 1066, 140, 4158.
        for (index, value) in (profile::FC04_EXAMPLE..).zip([1066.0, 140.0, 4158.0]) {
            store.define(index, Entry::read_only(value));
        }
        let setpoint = (profile::INT_MIN as f32, profile::INT_MAX as f32);
        for channel in 1..=30u8 {
            let word = |offset| profile::channel_index(channel, offset).unwrap_or_default();
            store.define(
                word(SETP_INTERFACE),
                Entry::adjustable(0.0, setpoint.0, setpoint.1),
            );
            // 001 4.2.1: ti1 / ti2 of channel 1 read 180 / 333; the limits are the simulator's.
            store.define(word(TI1), Entry::adjustable(180.0, 0.0, 9999.0));
            store.define(word(TI2), Entry::adjustable(333.0, 0.0, 9999.0));
            store.define(
                word(DATA_15),
                Entry::adjustable(0.0, setpoint.0, setpoint.1),
            );
            store.define(
                word(DATA_16),
                Entry::adjustable(0.0, setpoint.0, setpoint.1),
            );
        }
        Self {
            address,
            store,
            listen_only: false,
            counters: Counters::default(),
            diagnostic_register: 0,
            faults: Faults::default(),
        }
    }

    /// The coupler's Modbus address.
    pub fn address(&self) -> u8 {
        self.address
    }

    /// The datum at integer address `index`, if defined.
    pub fn datum(&self, index: u16) -> Option<Datum> {
        self.store.get(index).map(|e| e.datum)
    }

    /// Sets a defined datum without checks (switching its function off included); false when the
    /// datum is not defined.
    pub fn set_datum(&mut self, index: u16, datum: Datum) -> bool {
        self.store.set(index, datum)
    }

    /// Defines a datum: its value, whether it is writable, and its limits.
    pub fn define(&mut self, index: u16, value: f32, writable: bool, min: f32, max: f32) {
        let entry = Entry {
            datum: Datum::Value(value),
            writable,
            min,
            max,
        };
        self.store.define(index, entry);
    }

    /// The word a read returns at register address `register` (any format).
    pub fn read_register(&self, register: u16) -> u16 {
        self.store.read_register(register)
    }

    /// Whether the device is in listen-only mode.
    pub fn is_listen_only(&self) -> bool {
        self.listen_only
    }

    /// The FC 08 counters.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Sets the injected faults.
    pub fn set_faults(&mut self, faults: Faults) {
        self.faults = faults;
    }

    fn process(&mut self, adu: &[u8]) -> Option<Vec<u8>> {
        let address = *adu.first()?;
        let for_us = address == self.address || address == BROADCAST;
        // 001 3.1: "Die Nachricht wird in einen Datenbuffer mit einer maximalen Länge von 250 Byte
        // eingelesen. Ist die Nachricht länger, so wird sie nicht akzeptiert."
        if adu.len() > profile::MESSAGE_BUFFER {
            if for_us {
                bump(&mut self.counters.overruns);
                bump(&mut self.counters.buffer_full);
                bump(&mut self.counters.no_response);
            }
            return None;
        }
        let frame = match rtu::decode_frame(adu) {
            Ok(frame) => frame,
            Err(FrameError::BadCrc { .. }) => {
                if for_us {
                    bump(&mut self.counters.comm_errors);
                }
                return None;
            }
            Err(_) => return None,
        };
        bump(&mut self.counters.bus_messages);
        if !for_us {
            return None;
        }
        bump(&mut self.counters.slave_messages);
        let function = FunctionCode(frame.pdu.first().copied().unwrap_or_default());
        if self.listen_only {
            // 001 4.3.2: only a restart ends listen-only mode, and it is not answered then.
            let restart = matches!(
                Request::decode_with(frame.pdu, &LIMITS),
                Ok(Request::Diagnostics {
                    sub_function: diag::RESTART,
                    ..
                })
            );
            bump(&mut self.counters.no_response);
            if restart && address != BROADCAST {
                self.restart();
            }
            return None;
        }
        if address == BROADCAST {
            self.broadcast(frame.pdu);
            bump(&mut self.counters.no_response);
            return None;
        }
        if !profile::FUNCTIONS.contains(&function) {
            bump(&mut self.counters.exceptions);
            return Some(exception_frame(
                self.address,
                function,
                ExceptionCode::IllegalFunction,
            ));
        }
        let answer = match Request::decode_with(frame.pdu, &LIMITS) {
            Ok(request) => self.answer(request)?,
            Err(error) => Err(ExceptionCode::from(&error)),
        };
        if answer.is_err() {
            bump(&mut self.counters.exceptions);
        }
        Some(answer_frame(self.address, function, &answer))
    }

    /// The answer to a request, `None` when the request is not answered (FC 08 / 04).
    fn answer(&mut self, request: Request) -> Option<Answer> {
        Some(match request {
            Request::ReadHoldingRegisters { address, quantity } => self
                .store
                .read_block(address, quantity)
                .map(Response::ReadHoldingRegisters),
            Request::ReadInputRegisters { address, quantity } => self
                .store
                .read_block(address, quantity)
                .map(Response::ReadInputRegisters),
            Request::WriteSingleRegister { address, value } => self
                .store
                .write_single(address, value)
                .map(|()| Response::WriteSingleRegister { address, value }),
            Request::WriteMultipleRegisters { address, values } => {
                let quantity = values.len() as u16;
                self.store
                    .write_multiple(address, &values)
                    .map(|()| Response::WriteMultipleRegisters { address, quantity })
            }
            Request::Diagnostics { sub_function, data } => {
                return self.diagnostics(sub_function, data)
            }
            _ => Err(ExceptionCode::IllegalFunction),
        })
    }

    /// FC 08 (001 4.3). Every sub-function but 00 carries 00 00 (01 also FF 00); other data answer
    /// 03, an unknown sub-function 01 (Modbus Application Protocol V1.1b3, 6.8).
    ///
    /// 001 4.3 "Anfrage im Integerformat / Floatformat": the top three bits of the request's
    /// "address" select the format of the counters: 010 fix point (the counter x 10), 100 float
    /// (four bytes IEEE-754). FC 08 carries no address but the sub-function word, so the simulator
    /// reads those bits there (0x400B, 0x800B); plain sub-functions answer two bytes.
    fn diagnostics(&mut self, sub_function: u16, data: Vec<u8>) -> Option<Answer> {
        let format = sub_function >> 13;
        let base = sub_function & 0x1FFF;
        let echo = |data: Vec<u8>| Some(Ok(Response::Diagnostics { sub_function, data }));
        if base == diag::RETURN_QUERY_DATA && format == 0 {
            return echo(data);
        }
        let zero = data == [0, 0];
        if !(zero || (base == diag::RESTART && data == RESTART_CLEAR_LOG)) {
            return Some(Err(ExceptionCode::IllegalDataValue));
        }
        if let (true, Some(count)) = (diag::is_counter(base), self.counters.get(base)) {
            let bytes = match format {
                0 => count.to_be_bytes().to_vec(),
                0b010 => {
                    let scaled = u32::from(count) * 10;
                    let word = u16::try_from(scaled)
                        .ok()
                        .filter(|w| i32::from(*w) <= profile::INT_MAX);
                    word.unwrap_or(profile::OUT_OF_RANGE).to_be_bytes().to_vec()
                }
                0b100 => f32::from(count).to_be_bytes().to_vec(),
                _ => return Some(Err(ExceptionCode::IllegalFunction)),
            };
            return Some(Ok(Response::Diagnostics {
                sub_function,
                data: bytes,
            }));
        }
        if format != 0 {
            return Some(Err(ExceptionCode::IllegalFunction));
        }
        match base {
            diag::RESTART => {
                self.restart();
                echo(data)
            }
            diag::DIAGNOSTIC_REGISTER => echo(self.diagnostic_register.to_be_bytes().to_vec()),
            diag::LISTEN_ONLY => {
                self.listen_only = true;
                bump(&mut self.counters.no_response);
                None
            }
            diag::CLEAR_COUNTERS => {
                self.counters = Counters::default();
                self.diagnostic_register = 0;
                echo(data)
            }
            _ => Some(Err(ExceptionCode::IllegalFunction)),
        }
    }

    /// 001 4.3.2: initialise the interface, clear the event counters, leave listen-only mode.
    fn restart(&mut self) {
        self.listen_only = false;
        self.counters = Counters::default();
    }

    /// A broadcast: FC 06 and FC 16 are carried out (001 4.2.2, 4.4 "Broadcast ist möglich"),
    /// reads and diagnostics are not (4.2.1, 4.3 "Broadcast ist ... nicht möglich").
    fn broadcast(&mut self, pdu: &[u8]) {
        match Request::decode_with(pdu, &LIMITS) {
            Ok(Request::WriteSingleRegister { address, value }) => {
                let _ = self.store.write_single(address, value);
            }
            Ok(Request::WriteMultipleRegisters { address, values }) => {
                let _ = self.store.write_multiple(address, &values);
            }
            _ => {}
        }
    }
}

impl ModbusDevice for KsVarioSim {
    fn handle_frame(&mut self, adu: &[u8]) -> Option<Vec<u8>> {
        let answer = self.process(adu);
        self.faults.apply(answer)
    }

    fn faults(&self) -> Faults {
        self.faults
    }
}
