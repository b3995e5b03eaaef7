//! The running gateway as the REST API and zenoh show it: a line's view from its handle.
//!
//! Every line counts its frames, bytes and commands itself since it started
//! ([`LineHandle::traffic`](crate::line::LineHandle::traffic)); the Prometheus families are fed
//! from the same counting, cumulative over the process.

use super::lines::RunningLine;
use crate::api::model::{LinePlace, LineStatusView};

/// The view of line `name` now.
pub(crate) fn line_view(name: &str, line: &RunningLine) -> LineStatusView {
    let place = LinePlace {
        name,
        protocol: line.protocol,
        port: &line.port,
        port_b: line.port_b.as_deref(),
        restarting: line.token.is_cancelled(),
    };
    LineStatusView::new(place, &line.handle.status(), line.handle.traffic())
}
