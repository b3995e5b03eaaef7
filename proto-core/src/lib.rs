//! Sans-IO protocol engines of the CP 341 gateway.
//!
//! Everything in this crate is deterministic: bytes and time are arguments, never read from the
//! operating system. The runtime (the `gateway` crate) owns the serial port, the sockets and the
//! clock, and drives the engines:
//!
//! ```text
//!            bytes from the wire           bytes to send
//!   runtime ── handle_rx(now, &[u8]) ──▶ ┌──────────────┐ ── poll_transmit() ──▶ runtime ─▶ port
//!   clock   ── handle_timeout(now) ────▶ │   engine      │ ── poll_event()    ──▶ image / metrics
//!   app     ── submit(now, request) ───▶ └──────────────┘ ── poll_timeout()  ──▶ next deadline
//! ```
//!
//! Modules:
//! - [`checksum`]: CRC-16/Modbus, LRC, BCC;
//! - [`codec`]: a cursor reader/writer that owns every length check;
//! - [`modbus`]: the PDU codec, RTU and ASCII framing, the master and slave engines;
//! - `fuzzing` (with `cfg(fuzzing)`, the `fuzzing` feature or in tests): the fuzz targets' entry
//!   points;
//! - [`event`]: the CP 341 event catalog (chapter 7.2), the STATUS word and the diagnostic buffer;
//! - [`monitor`]: where a line's frames end and what they are (the frame monitor);
//! - [`profiles`]: the register-map models of the supported devices;
//! - [`proc3964`]: the 3964(R) procedure (6.3);
//! - [`serial_marks`]: UART line errors and the decoder of the tty layer's `PARMRK` marks;
//! - [`telegram`]: the ASCII telegram driver (6.2);
//! - [`cpmem`]: the CP memory areas and the Modbus slave address conversion (6.4.8);
//! - [`time`]: the instant type the engines take as input.

pub mod checksum;
pub mod codec;
pub mod cpmem;
pub mod event;
#[cfg(any(fuzzing, test, feature = "fuzzing"))]
pub mod fuzzing;
pub mod modbus;
pub mod monitor;
pub mod proc3964;
pub mod profiles;
pub mod serial_marks;
pub mod telegram;
pub mod time;
