//! Running simulated devices on a serial port or any byte stream (`gateway sim`): the devices
//! are a line engine ([`super::slaves`]) on the gateway's own line runtime, which frames the
//! requests and times the answers.

use std::time::Duration;

use proto_core::modbus::rtu::CharTiming;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio_serial::SerialPortBuilderExt;
use tokio_util::sync::CancellationToken;

use super::bus::Bus;
use super::{Faults, ModbusDevice, SimModel};
use crate::line::runtime::Unmarked;
use crate::protocols::modbus_master::partner::{spawn_line, DeviceEngine};
/// Slave addresses a device may have (Modbus over Serial Line V1.02, 2.2: 1..247; 001 3.1 and
/// 002 "Adressen" say the same).
const SLAVE_ADDRESSES: core::ops::RangeInclusive<u8> = 1..=247;

/// Which device to simulate: a Modbus model of [`super::MODBUS_MODELS`] or a telegram partner.
#[derive(Clone, Copy, Debug)]
pub enum DeviceKind {
    /// A simulated Modbus RTU slave.
    Modbus(&'static SimModel),
    /// A 3964(R) partner that echoes telegrams.
    Proc3964r,
    /// An ASCII partner that echoes telegrams.
    Ascii,
}

/// Every `--device`, as clap lists them: the Modbus models, then the telegram partners.
static DEVICE_KINDS: std::sync::LazyLock<Vec<DeviceKind>> = std::sync::LazyLock::new(|| {
    super::MODBUS_MODELS
        .iter()
        .map(DeviceKind::Modbus)
        .chain([DeviceKind::Proc3964r, DeviceKind::Ascii])
        .collect()
});

// === impl DeviceKind ===

impl DeviceKind {
    /// The device named `name` on the command line.
    pub fn named(name: &str) -> Option<Self> {
        DEVICE_KINDS.iter().copied().find(|k| k.name() == name)
    }

    /// The `--device` name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Modbus(model) => model.name,
            Self::Proc3964r => "3964r",
            Self::Ascii => "ascii",
        }
    }
}

impl clap::ValueEnum for DeviceKind {
    fn value_variants<'a>() -> &'a [Self] {
        &DEVICE_KINDS
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        let help = match self {
            Self::Modbus(model) => model.help,
            Self::Proc3964r => "a 3964(R) partner that echoes telegrams",
            Self::Ascii => "an ASCII partner that echoes telegrams",
        };
        Some(clap::builder::PossibleValue::new(self.name()).help(help))
    }
}

impl core::fmt::Display for DeviceKind {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.name())
    }
}

/// The parity of the serial line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, clap::ValueEnum)]
pub enum Parity {
    /// No parity bit.
    None,
    /// Odd parity.
    Odd,
    /// Even parity (the default of both devices: 001 3.3 offers it, 002 factory setting 8-E-1).
    Even,
}

/// A fault a simulated Modbus device injects into its answers (`gateway sim --fault`), for
/// end-to-end tests of the gateway's error handling.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, clap::ValueEnum)]
pub enum SimFault {
    /// Never answer (the master counts 003 7.2 08 30h "no reply").
    Silent,
    /// Answer `--fault-delay` late, on top of the t3.5 turnaround.
    Slow,
    /// Answer with a wrong CRC (003 7.2 0E 57h).
    BadCrc,
    /// Answer with the next slave address (003 7.2 08 31h).
    WrongAddress,
    /// Answer correctly, then send a burst of bytes nobody asked for (003 7.2 0E 53h).
    Noise,
}

/// `gateway sim` arguments.
#[derive(Clone, Debug, clap::Args)]
pub struct SimArgs {
    /// The device to simulate. Repeat it for several Modbus devices of any kinds on the same
    /// port, a multi-drop bus (a 3964r or ascii partner is alone on its port).
    #[arg(long, value_enum, required = true)]
    pub device: Vec<DeviceKind>,
    /// The serial port (a pty end or a real port).
    #[arg(long)]
    pub port: String,
    /// The slave address of each `--device`, in the same order (default: the device's, Altivar
    /// 2, KS vario 17, meter 30).
    #[arg(long)]
    pub address: Vec<u8>,
    /// Modbus devices: more devices of the first `--device`'s kind on the same port, a
    /// multi-drop bus, at these slave addresses (repeat the option or separate them by commas).
    #[arg(long, value_delimiter = ',')]
    pub also_address: Vec<u8>,
    /// Baud rate.
    #[arg(long, default_value_t = 19_200)]
    pub baud: u32,
    /// Parity.
    #[arg(long, value_enum, default_value_t = Parity::Even)]
    pub parity: Parity,
    /// Data bits (7 or 8; Modbus RTU needs 8).
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u8).range(7..=8))]
    pub data_bits: u8,
    /// Stop bits (1 or 2).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=2))]
    pub stop_bits: u8,
    /// Telegram devices: send a telegram of their own this often (0 = never).
    #[arg(long, default_value = "1s", value_parser = humantime::parse_duration)]
    pub every: Duration,
    /// Modbus devices: inject this fault into every answer (for tests).
    #[arg(long, value_enum)]
    pub fault: Option<SimFault>,
    /// How late `--fault slow` answers.
    #[arg(long, default_value = "1s", value_parser = humantime::parse_duration)]
    pub fault_delay: Duration,
    /// Modbus devices: never answer requests with this function code (e.g. 8 for FC 08), and
    /// answer every other as usual: a device that ignores one request type (for tests).
    #[arg(long)]
    pub ignore_function: Option<u8>,
}

/// Why a simulator stopped or could not start.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The device exists in the command line but not yet in the simulator.
    #[error("the {0} simulator is not yet available")]
    NotYetAvailable(DeviceKind),
    /// A slave address outside 1..=247.
    #[error("slave address {0} is outside 1..=247")]
    InvalidAddress(u8),
    /// Two devices on one port at the same slave address.
    #[error("two devices at slave address {0}")]
    DuplicateAddress(u8),
    /// Line settings the device cannot use.
    #[error("invalid line settings: {0}")]
    InvalidSettings(&'static str),
    /// The port could not be opened.
    #[error("cannot open serial port {port}: {source}")]
    Open {
        /// The port's path.
        port: String,
        /// What the serial layer said.
        #[source]
        source: tokio_serial::Error,
    },
    /// Reading or writing the port failed.
    #[error("serial I/O failed: {0}")]
    Io(#[from] std::io::Error),
    /// The 3964(R) or ASCII partner stopped.
    #[error("telegram simulator: {0}")]
    Telegram(String),
}

// === impl SimArgs ===

impl SimArgs {
    /// Bits on the wire a character: start, data, parity, stop.
    pub fn bits_per_char(&self) -> u8 {
        1 + self.data_bits + u8::from(self.parity != Parity::None) + self.stop_bits
    }

    /// The RTU timing of the line.
    pub fn timing(&self) -> CharTiming {
        CharTiming::new(self.baud, self.bits_per_char())
    }

    /// The devices the arguments describe: one, or a [`Bus`] of devices when `--device` is
    /// repeated or `--also-address` names more addresses. The i-th `--address` goes with the
    /// i-th `--device`; a device without one has its model's default address.
    pub fn device(&self) -> Result<Box<dyn ModbusDevice>, SimError> {
        if self.address.len() > self.device.len() {
            return Err(SimError::InvalidSettings("more --address than --device"));
        }
        let mut placed: Vec<(u8, &SimModel)> = Vec::new();
        for (i, kind) in self.device.iter().enumerate() {
            let DeviceKind::Modbus(model) = *kind else {
                return Err(if self.device.len() > 1 {
                    SimError::InvalidSettings("a 3964r or ascii partner is alone on its port")
                } else {
                    SimError::NotYetAvailable(*kind)
                });
            };
            let address = self.address.get(i).copied();
            placed.push((address.unwrap_or(model.default_address), model));
        }
        if let Some(&(_, first)) = placed.first() {
            placed.extend(self.also_address.iter().map(|&a| (a, first)));
        }
        let mut devices = Vec::new();
        for (i, &(address, model)) in placed.iter().enumerate() {
            if !SLAVE_ADDRESSES.contains(&address) {
                return Err(SimError::InvalidAddress(address));
            }
            if placed.iter().take(i).any(|&(a, _)| a == address) {
                return Err(SimError::DuplicateAddress(address));
            }
            devices.push((model.build)(address, self.faults()));
        }
        let device: Box<dyn ModbusDevice> = if devices.len() == 1 {
            devices.remove(0)
        } else {
            Box::new(Bus::new(devices))
        };
        let device: Box<dyn ModbusDevice> = match self.fault {
            Some(SimFault::Noise) => Box::new(Noisy::new(device)),
            _ => device,
        };
        Ok(match self.ignore_function {
            Some(function) => Box::new(Ignoring::new(device, function)),
            None => device,
        })
    }

    /// The port the arguments describe.
    fn port_settings(&self) -> crate::serial::PortSettings {
        use crate::serial::{DataBits, Parity as P, StopBits};
        let mut port = crate::serial::PortSettings::new(self.port.clone(), self.baud);
        port.parity = match self.parity {
            Parity::None => P::None,
            Parity::Odd => P::Odd,
            Parity::Even => P::Even,
        };
        port.data_bits = if self.data_bits == 7 {
            DataBits::Seven
        } else {
            DataBits::Eight
        };
        port.stop_bits = if self.stop_bits == 2 {
            StopBits::Two
        } else {
            StopBits::One
        };
        port
    }

    /// The faults `--fault` injects into the device's answers (noise is added by [`Noisy`]).
    pub fn faults(&self) -> Faults {
        let mut faults = Faults::default();
        match self.fault {
            Some(SimFault::Silent) => faults.silent = true,
            Some(SimFault::Slow) => faults.delay = self.fault_delay,
            Some(SimFault::BadCrc) => faults.bad_crc = true,
            Some(SimFault::WrongAddress) => faults.wrong_address = true,
            Some(SimFault::Noise) | None => {}
        }
        faults
    }
}

/// Runs the simulator the arguments describe until `shutdown` is cancelled.
pub async fn run(args: SimArgs, shutdown: CancellationToken) -> Result<(), SimError> {
    let telegram = match args.device.as_slice() {
        [DeviceKind::Proc3964r] => {
            Some(crate::protocols::telegram::partner::TelegramDevice::P3964r)
        }
        [DeviceKind::Ascii] => Some(crate::protocols::telegram::partner::TelegramDevice::Ascii),
        _ => None,
    };
    let port = args.port_settings();
    if let Some(device) = telegram {
        tracing::info!(device = ?args.device, port = %args.port, baud = args.baud, every = ?args.every, "simulator serving");
        return crate::protocols::telegram::partner::run_telegram_sim(
            device, port, args.every, shutdown,
        )
        .await
        .map_err(|e| SimError::Telegram(e.to_string()));
    }
    let device = args.device()?;
    if args.data_bits != 8 {
        // Modbus over Serial Line V1.02, 2.5.1: RTU characters have 8 data bits.
        return Err(SimError::InvalidSettings("Modbus RTU needs 8 data bits"));
    }
    // Opened without the error marks of `serial::open`: the simulator reads bytes as they are.
    let port = crate::serial::builder(&port)
        .open_native_async()
        .map_err(|source| SimError::Open {
            port: args.port.clone(),
            source,
        })?;
    tracing::info!(devices = ?args.device, addresses = ?args.address, port = %args.port, baud = args.baud, "simulator serving");
    serve_modbus(port, device, args.timing(), shutdown).await
}

/// Serves `device` on `stream` until `shutdown` is cancelled or the stream ends: the device as
/// a line engine on the line runtime (see [`super::slaves`]).
///
/// The demo runs a simulator in-process on one end of a `tokio_serial::SerialStream::pair()`;
/// tests do the same and talk to the other end. The stream's bytes carry no line error marks.
pub async fn serve_modbus<S>(
    stream: S,
    device: impl ModbusDevice + 'static,
    timing: CharTiming,
    shutdown: CancellationToken,
) -> Result<(), SimError>
where
    S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    // Ends with the shutdown or the stream, whichever comes first.
    let stop = shutdown.child_token();
    let engine = |_| DeviceEngine::new(device, timing, stop.clone());
    let line = spawn_line(
        "sim",
        engine,
        Unmarked(stream),
        timing.char_time,
        stop.clone(),
    );
    line.join().await;
    Ok(())
}

/// Bytes of noise after each answer of a [`Noisy`] device.
const NOISE_LEN: usize = 12;

/// A device whose every answer is followed by a burst of pseudo-random bytes (`--fault noise`):
/// a line picking up interference after the frame. The burst comes after a silence longer than
/// t3.5 (the runner sends it as [`ModbusDevice::after_answer`]): the master has its complete
/// answer by then, so the burst reaches it while it awaits nothing. Noise inside the silence would
/// be part of the answer, which then fails (003 6.4.3, 7.2 0E 53h).
pub struct Noisy {
    inner: Box<dyn ModbusDevice>,
    /// State of a xorshift generator (never 0).
    state: u32,
}

// === impl Noisy ===

impl Noisy {
    /// `inner` with noise after each answer.
    pub fn new(inner: Box<dyn ModbusDevice>) -> Self {
        Self {
            inner,
            state: 0x9E37_79B9,
        }
    }

    fn next_byte(&mut self) -> u8 {
        // xorshift32 (Marsaglia 2003).
        let mut x = self.state;
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        self.state = x;
        x.to_le_bytes()[0]
    }
}

impl ModbusDevice for Noisy {
    fn handle_frame(&mut self, adu: &[u8]) -> Option<Vec<u8>> {
        self.inner.handle_frame(adu)
    }

    fn after_answer(&mut self) -> Option<Vec<u8>> {
        Some((0..NOISE_LEN).map(|_| self.next_byte()).collect())
    }

    fn tick(&mut self, elapsed: Duration) {
        self.inner.tick(elapsed);
    }

    fn faults(&self) -> Faults {
        self.inner.faults()
    }
}

/// A device that never answers requests of one function code (`--ignore-function`), and answers
/// every other as `inner` does.
pub struct Ignoring {
    inner: Box<dyn ModbusDevice>,
    function: u8,
}

// === impl Ignoring ===

impl Ignoring {
    /// `inner`, silent to requests of `function`.
    pub fn new(inner: Box<dyn ModbusDevice>, function: u8) -> Self {
        Self { inner, function }
    }
}

impl ModbusDevice for Ignoring {
    fn handle_frame(&mut self, adu: &[u8]) -> Option<Vec<u8>> {
        // An RTU ADU: address, function code, data, CRC.
        if adu.get(1) == Some(&self.function) {
            return None;
        }
        self.inner.handle_frame(adu)
    }

    fn after_answer(&mut self) -> Option<Vec<u8>> {
        self.inner.after_answer()
    }

    fn tick(&mut self, elapsed: Duration) {
        self.inner.tick(elapsed);
    }

    fn faults(&self) -> Faults {
        self.inner.faults()
    }
}

#[cfg(test)]
mod tests {
    use proto_core::modbus::rtu::{self, decode_frame};

    use super::*;

    fn args(fault: Option<SimFault>) -> SimArgs {
        SimArgs {
            device: vec![DeviceKind::named("ksvario").expect("a model")],
            port: String::new(),
            address: Vec::new(),
            also_address: Vec::new(),
            baud: 19_200,
            parity: Parity::Even,
            data_bits: 8,
            stop_bits: 1,
            every: Duration::from_secs(1),
            fault,
            fault_delay: Duration::from_millis(700),
            ignore_function: None,
        }
    }

    #[test]
    fn an_ignored_function_gets_no_answer_and_the_others_do() {
        let mut a = args(None);
        a.ignore_function = Some(0x08);
        let mut device = a.device().unwrap();
        let mut echo = Vec::new();
        rtu::encode_frame(17, &[0x08, 0x00, 0x00, 0x12, 0x34], &mut echo);
        assert_eq!(device.handle_frame(&echo), None);
        let answer = device.handle_frame(&request()).expect("FC 04 answered");
        assert!(decode_frame(&answer).is_ok());
        // Without the option the echo is answered.
        let mut plain = args(None).device().unwrap();
        assert!(plain.handle_frame(&echo).is_some());
    }

    /// `--device meter`: the demo's meter at slave 30 by default, with its faults.
    #[test]
    fn the_meter_answers_at_30_by_default_and_takes_its_faults() {
        let mut a = args(None);
        a.device = vec![DeviceKind::named("meter").expect("a model")];
        let mut meter = a.device().expect("a meter");
        let mut read = Vec::new();
        let address = crate::sim::meter::map::TEMPERATURE;
        let [hi, lo] = address.to_be_bytes();
        rtu::encode_frame(30, &[0x04, hi, lo, 0x00, 0x01], &mut read);
        let answer = meter.handle_frame(&read).expect("answered");
        let [t_hi, t_lo] = crate::sim::meter::map::TEMPERATURE_RAW.to_be_bytes();
        assert_eq!(
            decode_frame(&answer).expect("a frame").pdu,
            [0x04, 0x02, t_hi, t_lo]
        );
        a.fault = Some(SimFault::Silent);
        let mut silent = a.device().expect("a meter");
        assert_eq!(silent.handle_frame(&read), None);
        assert_eq!(
            DeviceKind::named("meter").expect("a model").to_string(),
            "meter"
        );
    }

    /// FC 04 at 1004, three registers, of slave 17 (001's example).
    fn request() -> Vec<u8> {
        let mut frame = Vec::new();
        rtu::encode_frame(17, &[0x04, 0x03, 0xEC, 0x00, 0x03], &mut frame);
        frame
    }

    #[test]
    fn also_address_puts_more_devices_of_the_kind_on_the_port() {
        let mut bus_args = args(None);
        bus_args.also_address = vec![18, 19];
        let mut bus = bus_args.device().expect("a bus of three");
        for address in [17, 18, 19] {
            let mut frame = Vec::new();
            rtu::encode_frame(address, &[0x04, 0x03, 0xEC, 0x00, 0x03], &mut frame);
            let answer = bus.handle_frame(&frame).expect("answered");
            assert_eq!(decode_frame(&answer).map(|f| f.address), Ok(address));
        }
        bus_args.also_address = vec![248];
        assert!(matches!(
            bus_args.device().err(),
            Some(SimError::InvalidAddress(248))
        ));
    }

    #[test]
    fn each_fault_changes_the_answer_as_named() {
        let answer = |fault| args(fault).device().unwrap().handle_frame(&request());
        let good = answer(None).expect("an answer");
        assert!(decode_frame(&good).is_ok());

        assert_eq!(answer(Some(SimFault::Silent)), None);
        let bad_crc = answer(Some(SimFault::BadCrc)).expect("an answer");
        assert!(decode_frame(&bad_crc).is_err());
        let wrong = answer(Some(SimFault::WrongAddress)).expect("an answer");
        assert_eq!(decode_frame(&wrong).map(|f| f.address), Ok(18));
        let mut noisy = args(Some(SimFault::Noise)).device().unwrap();
        assert_eq!(noisy.handle_frame(&request()), Some(good.clone()));
        let burst = noisy.after_answer().expect("noise after the answer");
        assert_eq!(burst.len(), NOISE_LEN);

        let slow = args(Some(SimFault::Slow));
        assert_eq!(slow.device().unwrap().faults().delay, slow.fault_delay);
        assert_eq!(answer(Some(SimFault::Slow)), Some(good));
    }
}
