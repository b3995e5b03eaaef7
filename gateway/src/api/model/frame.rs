//! The frame monitor of a line (`GET /api/v1/lines/{line}/frames`, zenoh `<line>/frames`).

use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};
use utoipa::{IntoParams, ToSchema};

use super::Timestamp;
use crate::line::{Frame, FrameMonitor};

/// One frame sent or received on a line.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct FrameView {
    /// Sequence number on the line, from 1 (a page continues with `?since=<seq>`).
    pub seq: u64,
    /// `rx` (received) or `tx` (sent by the gateway).
    pub direction: String,
    /// Wall-clock time of the first byte (milliseconds; `first_us` has the microseconds).
    pub time: Timestamp,
    /// First byte, microseconds since 1970 (UTC).
    pub first_us: u64,
    /// Last byte, microseconds since 1970 (UTC); for a sent frame its estimated end on the wire.
    pub last_us: u64,
    /// First byte on the line's monotonic clock (microseconds since the line started): orders
    /// frames whatever the wall clock does.
    pub mono_first_us: u64,
    /// Last byte on the line's monotonic clock.
    pub mono_last_us: u64,
    /// The bytes as hex, two digits each, without separators.
    pub bytes: String,
    /// How many bytes.
    pub length: usize,
    /// Line errors inside the frame (parity or framing error, overrun, BREAK), each before the
    /// byte at `offset`.
    pub errors: Vec<FrameErrorView>,
    /// `ok`, `exception`, `control`, `bad-checksum`, `malformed`, `line-error` or `raw`.
    pub verdict: String,
    /// What the frame is, e.g. `slave 1 read holding registers start 0 quantity 10, CRC ok`.
    pub summary: String,
}

/// A line error inside a frame.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct FrameErrorView {
    /// Data bytes of the frame before it.
    pub offset: usize,
    /// `parity`, `framing`, `parity-or-framing`, `overrun` or `break`.
    pub error: String,
}

/// A line's frame monitor: the frames kept (oldest first) and how many it let go.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
pub struct FramesView {
    /// The line.
    pub line: String,
    /// Frames the ring keeps (`monitor_frames`).
    pub capacity: usize,
    /// The sequence number the next frame will have: `?since=<next_seq - 1>` gets only newer
    /// frames.
    pub next_seq: u64,
    /// Frames pushed out of the full ring since the line started.
    pub overwritten: u64,
    /// Frames live followers missed because they fell behind.
    pub lagged: u64,
    /// The frames above `since`, oldest first.
    pub frames: Vec<FrameView>,
}

/// Query of `GET /api/v1/lines/{line}/frames`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct FramesQuery {
    /// Only frames with a sequence number above this one.
    pub since: Option<u64>,
    /// `true`: a live stream of Server-Sent Events (`event: frame`, `id: <seq>`, data: one
    /// frame as JSON), beginning with the frames above `since` that the ring still has.
    pub follow: Option<bool>,
}

/// Query of `GET /api/v1/lines/{line}/capture`.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize, IntoParams)]
#[serde(deny_unknown_fields)]
#[into_params(parameter_in = Query)]
pub struct CaptureQuery {
    /// Record the next N seconds (1..=300) instead of answering with the ring.
    pub seconds: Option<u64>,
}

fn unix_micros(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_micros()).unwrap_or(u64::MAX))
}

fn micros(d: std::time::Duration) -> u64 {
    u64::try_from(d.as_micros()).unwrap_or(u64::MAX)
}

// === impl FrameView ===

impl FrameView {
    /// `frame` of `monitor`'s line, described now.
    pub fn new(monitor: &FrameMonitor, frame: &Frame) -> Self {
        use std::fmt::Write as _;
        let description = monitor.describe(frame);
        let mut bytes = String::with_capacity(frame.bytes.len() * 2);
        for b in &frame.bytes {
            let _ = write!(bytes, "{b:02X}");
        }
        Self {
            seq: frame.seq,
            direction: frame.direction.as_str().to_owned(),
            time: Timestamp(frame.first),
            first_us: unix_micros(frame.first),
            last_us: unix_micros(frame.last),
            mono_first_us: micros(frame.first_mono),
            mono_last_us: micros(frame.last_mono),
            bytes,
            length: frame.bytes.len(),
            errors: frame
                .errors
                .iter()
                .map(|e| FrameErrorView {
                    offset: e.offset,
                    error: line_error_name(e.error).to_owned(),
                })
                .collect(),
            verdict: description.verdict.as_str().to_owned(),
            summary: description.summary,
        }
    }
}

fn line_error_name(error: proto_core::serial_marks::LineError) -> &'static str {
    use proto_core::serial_marks::LineError;
    match error {
        LineError::Parity => "parity",
        LineError::Framing => "framing",
        LineError::ParityOrFraming => "parity-or-framing",
        LineError::Overrun => "overrun",
        LineError::Break => "break",
    }
}
