//! The CP 341 gateway service: configuration, serial lines driving the proto-core engines, the
//! process image, the Modbus TCP server and the device simulators.
//!
//! Module ownership (one concern each):
//! - [`config`]: the TOML configuration's shared sections as plain data (one reader, one error
//!   type, the defaults and ranges of their keys); it names no protocol and imports no other
//!   module of the gateway, they import it;
//! - [`serial`]: opening ports with line settings, RS485 mode, reopen with back-off;
//! - [`line`]: the line runtime (one port task per line, whatever the protocol): the engine
//!   contract, status, monitor, the line's metric families;
//! - [`protocols`]: one folder per line protocol (config section, adapter, start, simulated
//!   partner) and the one table of protocols;
//! - [`plant`]: the configuration root (`Config`: the sections and the lines), reading a document
//!   and the checks across the whole of it;
//! - [`cpmem`]: the CP memory (M, Q, I, T, C, DBs) shared by slave lines, Modbus TCP and the image;
//! - [`image`]: the process image (value, quality, timestamp per register);
//! - [`mailbox`]: telegram lines' received telegrams and sends as Modbus TCP registers;
//! - [`signals`]: RS232 modem signals of a port (read DTR/DSR/RTS/CTS/DCD/RI, set DTR/RTS);
//! - [`unit`]: the contract between the Modbus TCP server and whatever answers a unit id;
//! - [`modbus_tcp`]: our own MBAP framing, validation and the TCP server;
//! - [`paced`]: a paced link, a virtual serial cable with the timing of a real one;
//! - [`sim`]: simulated devices on a serial port (`gateway sim`);
//! - [`timer`]: a timer finer than tokio's milliseconds for the lines' t3.5 and the paced link;
//! - [`task`]: every task spawned in one place with a name (polls over 1 ms reported in a
//!   `stall-watch` build);
//! - [`zenoh_bridge`]: telegrams, tag values, queries, writes, events and presence on zenoh;
//! - [`api`]: the REST API under `/api/v1`, health, readiness and the OpenAPI document;
//! - [`persist`]: the configuration file, replaced atomically with the previous version kept;
//! - [`app`]: wiring a config into running tasks (`gateway run`, `gateway demo`), and the checks
//!   of a config that need other parts of the gateway (`gateway check`).

pub mod api;
pub mod app;
pub mod audit;
pub mod config;
pub mod cpmem;
pub mod feeds;
#[cfg(any(fuzzing, test))]
pub mod fuzzing;
mod heap;
pub mod image;
pub mod line;
pub mod log_limit;
pub mod mailbox;
pub mod metrics;
pub mod modbus_tcp;
pub mod paced;
pub mod persist;
pub mod plant;
pub mod protocols;
pub mod scan;
pub mod serial;
pub mod signals;
pub mod sigpipe;
pub mod sim;
pub mod tags;
pub mod task;
pub mod timer;
pub mod unit;
pub mod zenoh_bridge;
