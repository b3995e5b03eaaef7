//! Serial lines: the line runtime drives one protocol adapter per line.
//!
//! [`runtime`] owns what every line does: opening the port ([`PortOpener`]), the driver loop,
//! reopening with back-off, the port events, the status and one [`LineHandle`]. The protocols are
//! adapters over it:
//! - [`master`] ([`spawn_modbus_master_line`]): the Modbus master line, in a folder of its own
//!   (settings, scheduler and probing, scanner, probe, plan, writeback, device unit, command
//!   queue, 32-bit registers and the driver): polls its devices on a schedule, keeps their
//!   registers in the [`ProcessImage`](crate::image::ProcessImage), and carries writes and
//!   on-demand reads from the Modbus TCP server ([`DeviceUnit`]) through a bounded command queue;
//! - `modbus_slave` ([`spawn_modbus_slave_line`]): the Modbus slave RTU line serving the CP memory;
//! - `modbus_tap` ([`spawn_modbus_tap_line`]): a listen-only line that stores what another
//!   master's requests and the devices' answers show, never transmitting;
//! - [`telegram`]: ASCII and 3964(R) lines with their mailboxes.
//!
//! Shared by every line:
//! - `status`: diagnostic buffer, event counters, STATUS word, device states;
//! - `metrics`: the line's counters ([`LineTraffic`]) and its Prometheus metrics (events,
//!   port state, traffic, requests);
//! - [`monitor`]: the frame monitor (every frame with its times, bytes and line errors, in a
//!   bounded ring), fed by the runtime where bytes pass;
//! - [`pcapng`]: the monitor's frames as a pcapng file for Wireshark;
//! - `driver`: clock conversion and timer helpers of the driver loop.

mod driver;
pub(crate) use driver::Clock;
mod image_age;
pub mod master;
pub mod metrics;
mod modbus_slave;
mod modbus_tap;
pub mod monitor;
pub mod pcapng;
pub mod runtime;
pub(crate) mod start;
mod status;
pub mod telegram;
#[cfg(test)]
mod testing;

use std::time::Duration;

use proto_core::modbus::rtu::CharTiming;

pub use master::{
    exception_for, exception_for_queue, merge_ranges, plan, spawn_modbus_master_line, AddrRange,
    CommandError, CommandResult, DeviceLimits, DeviceSettings, DeviceUnit, LineClient,
    LineSettings, PollGroup, ProbeSettings, QueueError, ReadBlock, ScannerSettings,
    PROBE_TIMEOUT_FACTOR, SCANNER_WORDS,
};
pub use master::{TransparentSettings, TransparentUnit};
pub use metrics::LineTraffic;
pub use modbus_slave::{spawn_modbus_slave_line, CpMemoryView, SlaveCounters, SlaveLineSettings};
pub use modbus_tap::{spawn_modbus_tap_line, TapLineSettings, TAP_PROTOCOL};
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

#[cfg(test)]
mod tests {
    use proto_core::modbus::master::Framing;

    use super::*;

    /// 003 6.4.3 "Time_Out for message end": 76800 -> 0.5 ms, 38400 -> 1 ms, 19200 -> 2 ms,
    /// 9600 -> 4 ms, 300 -> 128 ms (3.5 characters of 11 bits, rounded in the manual).
    #[test]
    fn rtu_lines_end_a_frame_after_the_cps_time_out_at_every_baud_rate() {
        for (baud, manual_us) in [
            (76_800, 500),
            (38_400, 1_000),
            (19_200, 2_000),
            (9_600, 4_000),
            (300, 128_000),
        ] {
            let port = PortSettings::new("/dev/null", baud);
            let t35 = rtu_timing(&port).t3_5().as_micros();
            let off = t35.abs_diff(manual_us);
            assert!(off * 100 <= manual_us * 3, "{baud} Bd: {t35} us");
            // The master line and the slave line take the same timing.
            let Framing::Rtu { timing } = LineSettings::rtu("l", port.clone()).master.framing
            else {
                panic!("an RTU line");
            };
            assert_eq!(timing.t3_5().as_micros(), t35);
            let params = proto_core::cpmem::SlaveParams::new(
                1,
                proto_core::cpmem::OperatingMode::Normal,
                1,
                proto_core::cpmem::AddressMap::manual_example(),
            )
            .expect("params");
            let slave = SlaveLineSettings::new("s", port, params);
            assert_eq!(slave.timing().t3_5().as_micros(), t35);
        }
        // The multiplier (003 6.4.2.1, 1..10) on top: 2 at 38400 Bd gives 2 ms.
        let doubled = rtu_timing(&PortSettings::new("/dev/null", 38_400)).with_multiplier(2);
        assert_eq!(doubled.t3_5().as_micros(), 2_005);
    }
}
