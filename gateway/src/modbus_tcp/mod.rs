//! The Modbus TCP server: our own MBAP framing, request validation, write policy and limits.
//!
//! ```text
//! TcpListener -- serve(): network filter, connection cap, accept errors, shutdown
//!      |
//!      +-- one task per connection: FrameReader (MBAP check, then parse), requests in order,
//!              idle timeout
//!              |
//!              +-- per request: Request::decode -> unit lookup -> write policy
//!                     -> UnitService::call under request_timeout -> response or exception
//! ```
//!
//! Bad input closes or answers, never panics or waits: a bad MBAP header closes the connection
//! (it cannot be resynchronised), a bad PDU gets its exception on the same connection. Every case
//! is counted in [`ServerStats`].

pub mod access;
pub mod diagnostic;
pub mod mbap;
pub mod metrics;
pub mod server;
pub mod tls;

mod connection;
mod options;
mod request;
mod shared;

pub use access::{Authority, FunctionClass, Refusal, RoleRights, Roles};
pub use diagnostic::DiagnosticUnit;
pub use metrics::{
    AcceptError, CloseReason, FrameReject, RejectReason, RequestCount, RequestResult, ServerStats,
};
pub use options::LiveOptions;
pub use server::{
    bind, serve, serve_live, serve_tls, serve_tls_live, ServerOptions, DEFAULT_BACKLOG,
    DEFAULT_IDLE_TIMEOUT, DEFAULT_MAX_CONNECTIONS, DEFAULT_REQUEST_TIMEOUT,
};
pub use tls::{TlsError, TlsFiles, TlsServer, ROLE_OID};
