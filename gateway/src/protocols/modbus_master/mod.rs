//! The Modbus master line: one folder for the adapter over proto-core's master and what it builds
//! on.
//!
//! - `driver` ([`spawn_modbus_master_line`]): the line's adapter: it starts the next job (a
//!   command, a due poll, the scanner's exchange), hands it to the master engine and completes
//!   it, one function per kind of job;
//! - [`plan`]: merging polled ranges into the fewest reads within a device's limits (pure);
//! - `scheduler` (with `probing`): which request goes next (writes, on-demand reads, due polls
//!   within the fairness rule, reads riding on a due poll, offline after failed polls, back-off);
//! - `scanner`: the Altivar communication scanner, one FC 23 exchange per cycle;
//! - `probe`: how a device that stopped answering is probed (one attempt, a short wait derived
//!   from its own reply delay, every n-th probe the full reply monitoring time);
//! - `command`: the bounded command queue and the error-to-exception mapping;
//! - `writeback`: the image refresh after a confirmed write, the broadcast echo;
//! - `device_unit`: a polled device as a Modbus TCP unit;
//! - `registers32`: the gateway's side of 32-bit registers (limits, read-modify-write of a bit);
//! - `settings`: the line's and its devices' settings;
//! - `transparent`: unit ids nobody claims forwarded to the slave of the same address, with the
//!   dead-device rules per address;
//! - `build`: from the config's master sections (RTU and ASCII) to the line's settings and its
//!   polled devices, and the start of the line.

pub(crate) mod build;
mod command;
pub(crate) mod config;
mod device_unit;
mod driver;
pub(crate) mod partner;
pub mod plan;
mod probe;
mod registers32;
mod scanner;
mod scheduler;
mod settings;
mod transparent;
mod writeback;

pub use command::{
    exception_for, exception_for_queue, CommandError, CommandResult, LineClient, QueueError,
};
pub use device_unit::DeviceUnit;
pub use driver::spawn_modbus_master_line;
pub use plan::{merge_ranges, AddrRange, DeviceLimits, ReadBlock};
pub use probe::{ProbeSettings, PROBE_TIMEOUT_FACTOR};
pub use scanner::{ScannerSettings, SCANNER_WORDS};
pub use settings::{DeviceSettings, LineSettings, PollGroup};
pub use transparent::{TransparentSettings, TransparentUnit};
