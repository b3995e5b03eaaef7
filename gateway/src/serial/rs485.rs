//! Switching a port to RS485 two-wire mode with the kernel's `TIOCSRS485` ioctl
//! (Linux `Documentation/driver-api/serial/serial-rs485.rst`).
//!
//! `unsafe` code of the gateway lives here (one `ioctl` call on a file descriptor the caller
//! owns, with a pointer to a properly initialised `#[repr(C)]` struct) and in `heap.rs` (one
//! `malloc_trim` call).
#![allow(unsafe_code)]

use std::io;
use std::os::fd::AsRawFd;
use std::time::Duration;

/// `SER_RS485_ENABLED` (include/uapi/linux/serial.h).
const SER_RS485_ENABLED: u32 = 1 << 0;
/// `SER_RS485_RTS_ON_SEND`: logical level of RTS while sending.
const SER_RS485_RTS_ON_SEND: u32 = 1 << 1;
/// `SER_RS485_RTS_AFTER_SEND`: logical level of RTS after sending.
const SER_RS485_RTS_AFTER_SEND: u32 = 1 << 2;

/// `struct serial_rs485` (include/uapi/linux/serial.h): 8 words of 32 bits.
#[repr(C)]
#[derive(Debug, Default)]
struct SerialRs485 {
    flags: u32,
    /// Milliseconds.
    delay_rts_before_send: u32,
    /// Milliseconds.
    delay_rts_after_send: u32,
    /// The union of the address fields and padding; zero means "no addressing".
    padding: [u32; 5],
}

fn millis(d: Duration) -> u32 {
    u32::try_from(d.as_millis()).unwrap_or(u32::MAX)
}

/// Enables RS485 mode on `port`: RTS driven high while sending when `rts_on_send` (low otherwise),
/// with the given delays around the transmission.
#[cfg(target_os = "linux")]
pub(crate) fn enable(
    port: &impl AsRawFd,
    rts_on_send: bool,
    before: Duration,
    after: Duration,
) -> io::Result<()> {
    let flags = SER_RS485_ENABLED
        | if rts_on_send {
            SER_RS485_RTS_ON_SEND
        } else {
            SER_RS485_RTS_AFTER_SEND
        };
    let mut conf = SerialRs485 {
        flags,
        delay_rts_before_send: millis(before),
        delay_rts_after_send: millis(after),
        padding: [0; 5],
    };
    // SAFETY: the descriptor is open for as long as `port` is borrowed; TIOCSRS485 reads (and may
    // write back) exactly one `struct serial_rs485`, which `SerialRs485` matches in size and layout
    // (#[repr(C)], eight u32), and `conf` lives until the call returns.
    let rc = unsafe { libc::ioctl(port.as_raw_fd(), libc::TIOCSRS485, &raw mut conf) };
    if rc == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// RS485 mode needs the Linux ioctl.
#[cfg(not(target_os = "linux"))]
pub(crate) fn enable(
    _port: &impl AsRawFd,
    _rts_on_send: bool,
    _before: Duration,
    _after: Duration,
) -> io::Result<()> {
    Err(io::Error::new(
        io::ErrorKind::Unsupported,
        "RS485 mode needs the Linux TIOCSRS485 ioctl",
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_struct_has_the_kernel_layout() {
        assert_eq!(size_of::<SerialRs485>(), 32);
        assert_eq!(SerialRs485::default().flags, 0);
        assert_eq!(millis(Duration::from_micros(2500)), 2);
    }
}
