//! What the gateway asks of the tty layer beyond baud rate and character frame: the input flags
//! that keep a UART's line errors visible, and the UART's own error counters.
//!
//! Line errors (003 7.2: 08 0Ch "transmission error (parity error, stop bit error or overflow
//! error)", 08 0Dh "BREAK: receive line to partner is interrupted"). With `INPCK | PARMRK`, and
//! neither `IGNPAR` nor `IGNBRK`, with `BRKINT` off, the kernel keeps every received character
//! and marks the faulty ones in the byte stream (`FF 00 x`, a BREAK as `FF 00 00`, a data byte
//! `FF` doubled), which [`proto_core::serial_marks::MarkDecoder`] undoes. Without `PARMRK` a
//! faulty character would reach the engine as a plain `00`, and with `IGNPAR`/`IGNBRK` not at all.
//! `INPCK` is set whatever the parity: the tty layer marks framing errors only with it.
//!
//! An overrun is not marked in the stream: the UART counts it (`TIOCGICOUNT`,
//! `struct serial_icounter_struct` of include/uapi/linux/serial.h). A pseudo-terminal and most
//! USB adapters have no such counters; the ioctl then fails.
//!
//! `unsafe` code: borrowing the port's descriptor for the duration of a call (the caller owns the
//! port), and one `TIOCGICOUNT` ioctl into a properly initialised `#[repr(C)]` struct.
#![allow(unsafe_code)]

use std::io;
use std::os::fd::AsRawFd;

/// The UART's error counters since the driver was loaded (they only grow, and wrap at `i32`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UartCounters {
    /// Characters with a stop bit (framing) error.
    pub frame: u32,
    /// Characters with a parity error.
    pub parity: u32,
    /// Characters lost because the UART's receive register was overwritten.
    pub overrun: u32,
    /// BREAKs received.
    pub brk: u32,
    /// Characters lost because the tty layer's buffer was full.
    pub buf_overrun: u32,
}

// === impl UartCounters ===

impl UartCounters {
    /// Characters lost since `earlier` (UART overruns and tty buffer overruns): the errors that
    /// the stream's marks do not show. Parity, framing and BREAK are marked in the stream
    /// already and are not counted again here.
    pub fn lost_since(&self, earlier: &Self) -> u32 {
        self.overrun
            .wrapping_sub(earlier.overrun)
            .saturating_add(self.buf_overrun.wrapping_sub(earlier.buf_overrun))
    }
}

/// `struct serial_icounter_struct` (include/uapi/linux/serial.h): 20 `int`s.
#[repr(C)]
#[derive(Debug, Default)]
struct SerialIcounter {
    cts: i32,
    dsr: i32,
    rng: i32,
    dcd: i32,
    rx: i32,
    tx: i32,
    frame: i32,
    overrun: i32,
    parity: i32,
    brk: i32,
    buf_overrun: i32,
    reserved: [i32; 9],
}

/// Sets the input flags that keep line errors in the stream (module documentation) on the open
/// port, leaving the rest of its settings as they are.
#[cfg(target_os = "linux")]
pub(crate) fn mark_line_errors(port: &impl AsRawFd) -> io::Result<()> {
    use rustix::termios::{tcgetattr, tcsetattr, InputModes, OptionalActions};
    // SAFETY: the descriptor is open for as long as `port` is borrowed, which outlives `fd`.
    let fd = unsafe { std::os::fd::BorrowedFd::borrow_raw(port.as_raw_fd()) };
    let mut termios = tcgetattr(fd)?;
    termios.input_modes |= InputModes::INPCK | InputModes::PARMRK;
    termios.input_modes &= !(InputModes::IGNPAR | InputModes::IGNBRK | InputModes::BRKINT);
    tcsetattr(fd, OptionalActions::Now, &termios)?;
    Ok(())
}

/// The input flags need the Linux tty layer.
#[cfg(not(target_os = "linux"))]
pub(crate) fn mark_line_errors(_port: &impl AsRawFd) -> io::Result<()> {
    Err(io::Error::new(
        io::ErrorKind::Unsupported,
        "line error marks need the Linux tty layer",
    ))
}

/// Reads the UART's error counters; fails where the driver has none (a pty: `ENOTTY`/`EINVAL`).
#[cfg(target_os = "linux")]
pub fn counters(port: &impl AsRawFd) -> io::Result<UartCounters> {
    let mut icount = SerialIcounter::default();
    // SAFETY: the descriptor is open for as long as `port` is borrowed; TIOCGICOUNT writes exactly
    // one `struct serial_icounter_struct`, which `SerialIcounter` matches in size and layout
    // (#[repr(C)], twenty i32), and `icount` lives until the call returns.
    let rc = unsafe { libc::ioctl(port.as_raw_fd(), libc::TIOCGICOUNT, &raw mut icount) };
    if rc != 0 {
        return Err(io::Error::last_os_error());
    }
    let count = |n: i32| u32::from_ne_bytes(n.to_ne_bytes());
    Ok(UartCounters {
        frame: count(icount.frame),
        parity: count(icount.parity),
        overrun: count(icount.overrun),
        brk: count(icount.brk),
        buf_overrun: count(icount.buf_overrun),
    })
}

/// The counters need the Linux ioctl.
#[cfg(not(target_os = "linux"))]
pub fn counters(_port: &impl AsRawFd) -> io::Result<UartCounters> {
    Err(io::Error::new(
        io::ErrorKind::Unsupported,
        "UART counters need the Linux TIOCGICOUNT ioctl",
    ))
}

#[cfg(test)]
mod tests {
    use rustix::termios::{tcgetattr, InputModes};
    use tokio_serial::{SerialPort, SerialStream};

    use super::*;
    use crate::serial::{open, Parity, PortSettings};

    #[test]
    fn the_counter_struct_has_the_kernel_layout() {
        assert_eq!(size_of::<SerialIcounter>(), 80);
        let earlier = UartCounters {
            overrun: u32::MAX,
            buf_overrun: 3,
            frame: 7,
            ..UartCounters::default()
        };
        let now = UartCounters {
            overrun: 1,
            buf_overrun: 4,
            frame: 9,
            ..UartCounters::default()
        };
        // Two overruns across the wrap, one buffer overrun; framing errors are marked in band.
        assert_eq!(now.lost_since(&earlier), 3);
    }

    #[tokio::test]
    async fn every_port_opens_with_line_errors_marked() {
        for parity in [Parity::None, Parity::Even, Parity::Odd] {
            let (outside, line_end) = SerialStream::pair().expect("pty pair");
            let path = line_end.name().expect("pty path");
            let mut settings = PortSettings::new(path.clone(), 19200);
            settings.parity = parity;
            let _port = open(&settings).expect("open");
            // The other end reads the flags back: the slave path opened afresh by an independent
            // reader (one tty, one termios).
            let reader = std::fs::File::open(&path).expect("slave path");
            let modes = tcgetattr(&reader).expect("tcgetattr").input_modes;
            assert!(
                modes.contains(InputModes::INPCK | InputModes::PARMRK),
                "{parity:?}: {modes:?}"
            );
            assert!(
                !modes.intersects(InputModes::IGNPAR | InputModes::IGNBRK | InputModes::BRKINT),
                "{parity:?}: {modes:?}"
            );
            // A pty has no UART counters: the runtime stops asking after the first failure.
            assert!(counters(&outside).is_err());
        }
    }
}
