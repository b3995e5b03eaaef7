//! Feeds: what flows between the lines, their mailboxes and the process image and an outward
//! service, in a layer of its own between the lines and app/. A received telegram walks from its
//! port (line/) through its mailbox (mailbox/) and a feed here to the zenoh bridge
//! (zenoh_bridge/) without climbing to app/, which only starts the feeds; the REST API's and the
//! bridge's backends ([`rest`], [`zenoh_backend`]) read and write tags ([`tag_io`]) and carry
//! telegrams, signals and diagnostics over the running [`gateway::Gateway`], which app/'s
//! supervisor is.

pub(crate) mod gateway;
pub(crate) mod rest;
pub(crate) mod tag_io;
pub mod zenoh;
pub(crate) mod zenoh_backend;
