//! Feeds: what flows from the lines, their mailboxes and the process image to an outward
//! service, in a layer of its own between the lines and app/. A received telegram walks from its
//! port (line/) through its mailbox (mailbox/) and a feed here to the zenoh bridge
//! (zenoh_bridge/) without climbing to app/, which only starts the feeds.

pub mod zenoh;
