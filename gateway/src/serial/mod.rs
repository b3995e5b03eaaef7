//! Opening serial ports with line settings: baud rate, character frame, and the interface
//! (RS232, RS422 four-wire, RS485 two-wire with the kernel's RS485 mode).
//!
//! Facts from the seeds: the CP 341 runs 300..76800 Bd (003 6.4.2.1 "Baud rate"), 7 or 8 data bits,
//! none/odd/even parity, 1 or 2 stop bits (003 6.4.2.1 "Character frames"); the gateway goes up
//! to 115200 Bd. A pseudo-terminal accepts every setting and ignores it, and refuses RS485 mode.

mod backoff;
mod rs485;
mod uart;

use std::io;
use std::time::Duration;

use tokio_serial::{SerialPortBuilderExt, SerialStream};

pub use backoff::Backoff;
pub use uart::{counters as uart_counters, UartCounters};

/// Data bits of a character.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DataBits {
    /// 7 data bits (ASCII driver, Modbus ASCII).
    Seven,
    /// 8 data bits (Modbus RTU: fixed, 003 6.4.2.1).
    Eight,
}

/// Parity of a character.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Parity {
    /// No parity bit.
    None,
    /// Odd parity.
    Odd,
    /// Even parity (the CP's Modbus default, 003 6.4.2.1).
    Even,
}

/// Stop bits of a character.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StopBits {
    /// One stop bit.
    One,
    /// Two stop bits.
    Two,
}

/// How RTS drives the transmitter of an RS485 two-wire line, and the delays around a send.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Rs485 {
    /// RTS high while sending (true, the usual wiring) or low while sending (false).
    pub rts_on_send: bool,
    /// Delay between RTS on and the first bit.
    pub delay_before_send: Duration,
    /// Delay between the last bit and RTS off.
    pub delay_after_send: Duration,
}

impl Default for Rs485 {
    fn default() -> Self {
        Self {
            rts_on_send: true,
            delay_before_send: Duration::ZERO,
            delay_after_send: Duration::ZERO,
        }
    }
}

/// The physical interface of a line.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Interface {
    /// RS232 (the port as the driver sets it up).
    #[default]
    Rs232,
    /// RS422 four-wire, full duplex (nothing to switch: the port as it is).
    Rs422,
    /// RS485 two-wire, half duplex: the kernel's RS485 mode is switched on after opening.
    Rs485(Rs485),
}

/// Everything needed to open one serial port.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct PortSettings {
    /// Device path, e.g. `/dev/ttyS0` or `/dev/serial/by-id/...`.
    pub path: String,
    /// Baud rate.
    pub baud: u32,
    /// Data bits.
    pub data_bits: DataBits,
    /// Parity.
    pub parity: Parity,
    /// Stop bits.
    pub stop_bits: StopBits,
    /// Physical interface.
    pub interface: Interface,
    /// Frames the line's frame monitor keeps (0: no monitor).
    pub monitor_frames: usize,
}

// === impl PortSettings ===

impl PortSettings {
    /// Settings for `path` at `baud`, 8 data bits, even parity, 1 stop bit (the CP's Modbus
    /// defaults, 003 6.4.2.1), RS232.
    pub fn new(path: impl Into<String>, baud: u32) -> Self {
        Self {
            path: path.into(),
            baud,
            data_bits: DataBits::Eight,
            parity: Parity::Even,
            stop_bits: StopBits::One,
            interface: Interface::Rs232,
            monitor_frames: crate::config::DEFAULT_MONITOR_FRAMES as usize,
        }
    }

    /// Bits on the wire for one character: start bit, data bits, parity bit, stop bits.
    pub fn bits_per_char(&self) -> u8 {
        let data = match self.data_bits {
            DataBits::Seven => 7,
            DataBits::Eight => 8,
        };
        let parity = u8::from(self.parity != Parity::None);
        let stop = match self.stop_bits {
            StopBits::One => 1,
            StopBits::Two => 2,
        };
        1 + data + parity + stop
    }

    /// The time one character takes on the wire (zero for a baud rate of zero).
    pub fn char_time(&self) -> Duration {
        if self.baud == 0 {
            return Duration::ZERO;
        }
        Duration::from_nanos(u64::from(self.bits_per_char()) * 1_000_000_000 / u64::from(self.baud))
    }
}

/// Why a port could not be opened with its settings.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// The device node does not exist (not plugged in, a wrong name).
    #[error(
        "port not found: {path} (no such device; the line opens it with back-off until it appears)"
    )]
    NotFound {
        /// The device path.
        path: String,
    },
    /// The operating system could not open or set up the port.
    #[error("cannot open port {path}: {source}")]
    Open {
        /// The device path.
        path: String,
        /// What the serial library reported.
        #[source]
        source: tokio_serial::Error,
    },
    /// The port opened but the tty layer refused the input flags that keep line errors visible.
    #[error("port {path} refused the line error flags: {source}")]
    Flags {
        /// The device path.
        path: String,
        /// The error of `tcgetattr`/`tcsetattr`.
        #[source]
        source: io::Error,
    },
    /// The port opened but its driver refused RS485 mode.
    #[error("port {path} refused RS485 mode: {source}{hint}")]
    Rs485Refused {
        /// The device path.
        path: String,
        /// The ioctl's error.
        #[source]
        source: io::Error,
        /// A hint at the cause, e.g. " (a pseudo-terminal has no RS485 driver)".
        hint: &'static str,
    },
}

// === impl OpenError ===

impl OpenError {
    /// Whether another process holds the port: the serial library opens exclusively (`TIOCEXCL`,
    /// then an exclusive `flock`), and reports a port already held so (`EBUSY` from the open,
    /// `EWOULDBLOCK` from the lock) as `NoDevice`. A running gateway holds its ports this way.
    pub fn is_busy(&self) -> bool {
        matches!(self, Self::Open { source, .. } if source.kind() == tokio_serial::ErrorKind::NoDevice)
    }

    /// The device path.
    pub fn path(&self) -> &str {
        match self {
            Self::Open { path, .. }
            | Self::NotFound { path }
            | Self::Flags { path, .. }
            | Self::Rs485Refused { path, .. } => path,
        }
    }
}

fn rs485_hint(path: &str, err: &io::Error) -> &'static str {
    #[cfg(target_os = "linux")]
    let not_a_tty = err.raw_os_error() == Some(libc::ENOTTY);
    #[cfg(not(target_os = "linux"))]
    let not_a_tty = err.kind() == io::ErrorKind::Unsupported;
    if path.starts_with("/dev/pts/") || path.starts_with("/dev/pty") {
        " (a pseudo-terminal has no RS485 driver)"
    } else if not_a_tty {
        " (the port's driver has no RS485 mode)"
    } else {
        ""
    }
}

/// Opens the port with its settings, sets the input flags that keep line errors in the stream
/// (`INPCK | PARMRK`, not `IGNPAR`/`IGNBRK`/`BRKINT`: see `uart.rs`; the reader must decode the
/// marks with [`proto_core::serial_marks::MarkDecoder`]) and, for RS485, switches the kernel's
/// RS485 mode on. Must be called within a tokio runtime (the stream registers with its reactor).
pub fn open(settings: &PortSettings) -> Result<SerialStream, OpenError> {
    let port = builder(settings)
        .open_native_async()
        .map_err(|source| open_error(settings, source))?;
    set_interface(&port, settings)?;
    Ok(port)
}

/// Opens the port as [`open`] does (RS485 mode included) and closes it again: whether a line
/// with these settings can start. Needs no runtime.
pub fn probe(settings: &PortSettings) -> Result<(), OpenError> {
    let port = builder(settings)
        .open_native()
        .map_err(|source| open_error(settings, source))?;
    set_interface(&port, settings)
}

/// Why the port did not open: a device node that does not exist is [`OpenError::NotFound`]
/// (said as such, not as the generic "invalid parameterization" of event 02 0Fh).
fn open_error(settings: &PortSettings, source: tokio_serial::Error) -> OpenError {
    // NoDevice for a node that exists: another process holds the port (`OpenError::is_busy`).
    let missing = matches!(
        source.kind(),
        tokio_serial::ErrorKind::Io(io::ErrorKind::NotFound)
    ) || !std::path::Path::new(&settings.path).exists();
    if missing {
        OpenError::NotFound {
            path: settings.path.clone(),
        }
    } else {
        OpenError::Open {
            path: settings.path.clone(),
            source,
        }
    }
}

/// The port's builder with the settings' frame and no flow control.
pub(crate) fn builder(settings: &PortSettings) -> tokio_serial::SerialPortBuilder {
    let data_bits = match settings.data_bits {
        DataBits::Seven => tokio_serial::DataBits::Seven,
        DataBits::Eight => tokio_serial::DataBits::Eight,
    };
    let parity = match settings.parity {
        Parity::None => tokio_serial::Parity::None,
        Parity::Odd => tokio_serial::Parity::Odd,
        Parity::Even => tokio_serial::Parity::Even,
    };
    let stop_bits = match settings.stop_bits {
        StopBits::One => tokio_serial::StopBits::One,
        StopBits::Two => tokio_serial::StopBits::Two,
    };
    tokio_serial::new(&settings.path, settings.baud)
        .data_bits(data_bits)
        .parity(parity)
        .stop_bits(stop_bits)
        .flow_control(tokio_serial::FlowControl::None)
}

/// Sets the input flags that keep line errors in the stream and switches the kernel's RS485 mode
/// on when the settings ask for it.
fn set_interface(
    port: &impl std::os::fd::AsRawFd,
    settings: &PortSettings,
) -> Result<(), OpenError> {
    uart::mark_line_errors(port).map_err(|source| OpenError::Flags {
        path: settings.path.clone(),
        source,
    })?;
    if let Interface::Rs485(rs485) = settings.interface {
        rs485::enable(
            port,
            rs485.rts_on_send,
            rs485.delay_before_send,
            rs485.delay_after_send,
        )
        .map_err(|source| {
            let hint = rs485_hint(&settings.path, &source);
            OpenError::Rs485Refused {
                path: settings.path.clone(),
                source,
                hint,
            }
        })?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn character_times_follow_the_frame() {
        let mut s = PortSettings::new("/dev/null", 19200);
        assert_eq!(s.bits_per_char(), 11);
        assert_eq!(s.char_time(), Duration::from_nanos(572_916));
        s.parity = Parity::None;
        s.data_bits = DataBits::Seven;
        s.stop_bits = StopBits::Two;
        assert_eq!(s.bits_per_char(), 10);
        s.baud = 0;
        assert_eq!(s.char_time(), Duration::ZERO);
    }

    #[tokio::test]
    async fn a_missing_port_is_a_typed_error_naming_the_path() {
        let err = open(&PortSettings::new("/dev/does-not-exist-gw", 9600)).unwrap_err();
        assert!(matches!(err, OpenError::NotFound { .. }), "{err:?}");
        assert_eq!(err.path(), "/dev/does-not-exist-gw");
        assert!(
            err.to_string()
                .starts_with("port not found: /dev/does-not-exist-gw (no such device"),
            "{err}"
        );
    }

    #[tokio::test]
    async fn a_pty_refuses_rs485_mode_with_a_clear_error() {
        let (_master, slave) = SerialStream::pair().unwrap();
        let path = tokio_serial::SerialPort::name(&slave).unwrap();
        let mut settings = PortSettings::new(path.clone(), 19200);
        settings.interface = Interface::Rs485(Rs485::default());
        let err = open(&settings).unwrap_err();
        assert!(matches!(err, OpenError::Rs485Refused { .. }), "{err:?}");
        let text = err.to_string();
        assert!(
            text.starts_with(&format!("port {path} refused RS485 mode: ")),
            "{text}"
        );
        assert!(
            text.ends_with("(a pseudo-terminal has no RS485 driver)"),
            "{text}"
        );

        // Without RS485 the same pty opens.
        settings.interface = Interface::Rs422;
        assert!(open(&settings).is_ok());
    }
}
