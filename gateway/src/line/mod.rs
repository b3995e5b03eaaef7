//! Serial lines: the line runtime drives one protocol adapter per line.
//!
//! [`runtime`] owns what every line does: opening the port ([`PortOpener`]), the driver loop,
//! reopening with back-off, the port events, the status and one [`LineHandle`]. The protocols are
//! adapters over it, each in its folder under [`crate::protocols`].
//!
//! Shared by every line:
//! - `status`: diagnostic buffer, event counters, STATUS word, device states;
//! - `metrics`: the line's counters ([`LineTraffic`]) and its Prometheus metrics (events,
//!   port state, traffic, requests);
//! - [`monitor`]: the frame monitor (every frame with its times, bytes and line errors, in a
//!   bounded ring), fed by the runtime where bytes pass;
//! - [`pcapng`]: the monitor's frames as a pcapng file for Wireshark;
//! - `driver`: clock conversion and timer helpers of the driver loop.

pub(crate) mod driver;
pub(crate) use driver::Clock;
pub(crate) mod image_age;
pub mod metrics;
pub mod monitor;
pub mod pcapng;
pub mod runtime;
pub(crate) mod status;
#[cfg(test)]
pub(crate) mod testing;

use std::time::Duration;

use proto_core::modbus::rtu::CharTiming;

pub use metrics::LineTraffic;
pub use monitor::{Frame, FrameMonitor, DEFAULT_MONITOR_FRAMES, MAX_MONITOR_FRAMES};
pub use runtime::{
    LineHandle, LinePort, PortOpener, SerialOpener, EVENT_PORT_LOST, EVENT_PORT_SETUP,
};
pub use status::{DeviceStatus, LineEvent, LineStatus, DEFAULT_DIAG_DEPTH};

use crate::serial::PortSettings;

/// Depth of a line's command queue by default.
pub const DEFAULT_QUEUE_DEPTH: usize = 16;
/// First delay before reopening a failed port by default.
pub const DEFAULT_REOPEN_MIN: Duration = Duration::from_millis(500);
/// Longest delay between reopen attempts by default.
pub const DEFAULT_REOPEN_MAX: Duration = Duration::from_secs(30);
/// Slack on top of the master's own reply monitoring for a command's deadline by default.
pub const DEFAULT_COMMAND_SLACK: Duration = Duration::from_secs(1);

/// The character timing of the gateway's Modbus RTU lines, master and slave: 1.5 and 3.5
/// character times at every baud rate, as the CP 341 computes them (003 6.4.3, "Time_Out for
/// message end": 76800 -> 0.5 ms, 38400 -> 1 ms, 19200 -> 2 ms, 9600 -> 4 ms ... 300 -> 128 ms),
/// not the fixed 1.75 ms of the Modbus over Serial Line specification above 19200 Bd. The line's
/// "multiplier character delay time" (003 6.4.2.1, 1..10) multiplies t3.5 on top, for a partner
/// that needs longer (a device that follows the fixed 1.75 ms above 19200 Bd: 2 at 38400 Bd).
pub fn rtu_timing(port: &PortSettings) -> CharTiming {
    CharTiming::exact(port.baud, port.bits_per_char())
}
