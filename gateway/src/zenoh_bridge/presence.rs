//! Liveliness tokens: one for the gateway (`<prefix>`) for as long as the bridge runs, one per
//! device (`<prefix>/<line>/<device>`) while the device is online.
//!
//! Peers watch them with a liveliness subscriber (`gw/**`) or ask with a liveliness get. A token
//! disappears when it is undeclared, when the session closes, or when the peer loses the
//! gateway (zenoh's lease expiry), so a crashed gateway also "goes offline".

use std::collections::HashMap;

use zenoh::liveliness::LivelinessToken;
use zenoh::{Session, Wait};

/// The tokens the publisher thread holds. The gateway's token is set like a device's (the
/// driver queues it as online when the session opens) and undeclared last.
pub(crate) struct Presence {
    gateway_key: String,
    tokens: HashMap<String, LivelinessToken>,
}

// === impl Presence ===

impl Presence {
    pub(crate) fn new(gateway_key: String) -> Self {
        Self {
            gateway_key,
            tokens: HashMap::new(),
        }
    }

    /// Declares or undeclares the token `key`.
    pub(crate) fn set(&mut self, session: &Session, key: String, online: bool) {
        if !online {
            if let Some(token) = self.tokens.remove(&key) {
                if let Err(e) = token.undeclare().wait() {
                    crate::warn_limited!("zenoh token not undeclared", %key, error = %e, "liveliness token not undeclared");
                }
            }
            return;
        }
        if self.tokens.contains_key(&key) {
            return;
        }
        match session.liveliness().declare_token(key.clone()).wait() {
            Ok(token) => {
                self.tokens.insert(key, token);
            }
            Err(e) => {
                crate::warn_limited!("zenoh token not declared", %key, error = %e, "liveliness token not declared");
            }
        }
    }

    /// Undeclares every token, the gateway's last.
    pub(crate) fn clear(&mut self) {
        let gateway = self.tokens.remove(&self.gateway_key);
        for (key, token) in self
            .tokens
            .drain()
            .chain(gateway.map(|t| (self.gateway_key.clone(), t)))
        {
            if let Err(e) = token.undeclare().wait() {
                tracing::debug!(%key, error = %e, "liveliness token not undeclared");
            }
        }
    }
}
