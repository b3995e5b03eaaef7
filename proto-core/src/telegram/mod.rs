//! The ASCII telegram driver (manual 003 6.2; RS232 signals and flow control 000 5.4 and 6.2),
//! sans-IO, and the types it shares with the 3964(R) procedure ([`crate::proc3964`]).
//!
//! ASCII telegrams carry no protocol of their own: the receiver cuts the byte stream into
//! telegrams by the character delay time, a fixed length or end characters, and keeps them in a
//! ring buffer; the sender sends the bytes as given, held back by the partner under XON/XOFF,
//! RTS/CTS or the automatic V24 signal handling.
//!
//! - [`AsciiParams`]: the validated parameters of 6.2.1, with the manual's defaults;
//! - [`AsciiDriver`]: the state machine, driven like every engine of this crate (see its docs);
//! - [`TelegramEvent`], [`TelegramId`], [`SendError`], [`LineError`], [`ConfigError`],
//!   [`Interface`]: shared with [`crate::proc3964::Proc3964`].

pub(crate) mod common;
mod config;
mod machine;
mod receiver;

pub use common::{ConfigError, Interface, LineError, SendError, TelegramEvent, TelegramId};
pub use config::{
    AsciiParams, AsciiSettings, EndCriterion, FlowControl, SendLength, DEFAULT_END_CHAR,
    DEFAULT_FIXED_LENGTH, DEFAULT_FLOW_WAIT, DEFAULT_OUTPUT_WAIT, DEFAULT_RECEIVE_BUFFERS,
    DEFAULT_RTS_HOLD, DEFAULT_SEND_QUEUE, DEFAULT_TX_CHUNK, DEFAULT_XOFF, DEFAULT_XON, DEFAULT_ZVZ,
    MAX_TELEGRAM,
};
pub use machine::{Action, AsciiDriver, AsciiEvent, Signals};
