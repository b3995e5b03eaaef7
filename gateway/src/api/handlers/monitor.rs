//! `/api/v1/lines/{line}/frames` and `/capture`: the line's frame monitor as JSON, as a live
//! stream of Server-Sent Events, and as a pcapng file for Wireshark.

use std::convert::Infallible;
use std::sync::Arc;
use std::time::Duration;

use axum::body::Body;
use axum::extract::State;
use axum::http::{header, HeaderValue};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::Json;
use futures::stream::{self, Stream, StreamExt};
use tokio::sync::broadcast::error::RecvError;

use super::{ApiPath, ApiQuery};
use crate::api::error::{ApiError, ErrorBody};
use crate::api::model::{CaptureQuery, FrameView, FramesQuery, FramesView};
use crate::api::ApiState;
use crate::line::{pcapng, Frame, FrameMonitor};

/// The longest `?seconds=` of a capture.
pub(crate) const MAX_CAPTURE_SECONDS: u64 = 300;
/// The most frames one timed capture keeps, the rest are left out (at 115200 Bd a line carries
/// under 2000 frames a second, 600 000 in 300 s).
const MAX_CAPTURE_FRAMES: usize = 1_000_000;

/// A line's frames, oldest first (`?since=<seq>` for the newer ones), or with `?follow=true`
/// the same as Server-Sent Events that go on with every new frame.
#[utoipa::path(
    get,
    path = "/lines/{line}/frames",
    tag = "lines",
    params(("line" = String, Path, description = "The line's name"), FramesQuery),
    responses(
        (status = 200, description = "The monitor's frames, oldest first; with `follow=true` a \
            `text/event-stream` of `frame` events (id: the frame's seq, data: a FrameView) and \
            `lagged` events (data: how many frames the stream missed)",
            content(
                (FramesView = "application/json"),
                (String = "text/event-stream"),
            )),
        (status = 404, description = "No such line", body = ErrorBody),
        (status = 409, description = "The line's monitor is off (monitor_frames = 0)", body = ErrorBody),
    )
)]
pub(crate) async fn get_frames(
    State(state): State<ApiState>,
    ApiPath(line): ApiPath<String>,
    ApiQuery(q): ApiQuery<FramesQuery>,
) -> Result<Response, ApiError> {
    let monitor = state.backend().monitor(&line)?;
    let since = q.since.unwrap_or(0);
    if q.follow.unwrap_or(false) {
        return Ok(follow(monitor, since).into_response());
    }
    let (frames, next_seq) = monitor.frames_since(since);
    let (overwritten, lagged) = monitor.dropped();
    Ok(Json(FramesView {
        line: monitor.line().to_owned(),
        capacity: monitor.capacity(),
        next_seq,
        overwritten,
        lagged,
        frames: frames.iter().map(|f| FrameView::new(&monitor, f)).collect(),
    })
    .into_response())
}

/// The frames above `since` and every new one, as Server-Sent Events, until the client goes or
/// the line stops.
fn follow(
    monitor: Arc<FrameMonitor>,
    since: u64,
) -> Sse<impl Stream<Item = Result<Event, Infallible>>> {
    let (backlog, live) = monitor.follow(since);
    let ended = Box::pin(monitor.ended());
    let first = {
        let monitor = Arc::clone(&monitor);
        stream::iter(backlog).map(move |f| Ok(frame_event(&monitor, &f)))
    };
    let rest = stream::unfold(
        (monitor, live, ended),
        |(monitor, mut live, mut ended)| async move {
            let received = tokio::select! {
                () = &mut ended => return None,
                r = live.recv() => r,
            };
            let event = match received {
                Ok(frame) => frame_event(&monitor, &frame),
                Err(RecvError::Lagged(n)) => {
                    monitor.count_lagged(n);
                    Event::default().event("lagged").data(n.to_string())
                }
                Err(RecvError::Closed) => return None,
            };
            Some((Ok(event), (monitor, live, ended)))
        },
    );
    Sse::new(first.chain(rest)).keep_alive(KeepAlive::new().interval(Duration::from_secs(15)))
}

fn frame_event(monitor: &FrameMonitor, frame: &Frame) -> Event {
    let view = FrameView::new(monitor, frame);
    let data = serde_json::to_string(&view).unwrap_or_default();
    Event::default()
        .event("frame")
        .id(frame.seq.to_string())
        .data(data)
}

/// The line's frames as a pcapng file: the ring as it is, or with `?seconds=N` the frames of the
/// next N seconds (1..=300; the answer starts at once and its body follows when they are over).
/// Interface 0 holds the received frames, 1 the sent ones; Modbus RTU frames have link type 147
/// (Wireshark's `mbrtu` through the `user_dlts` preference), 3964(R) 148 (the Lua dissector
/// deploy/wireshark/cp341_3964r.lua), others 149; each packet's comment has the verdict.
#[utoipa::path(
    get,
    path = "/lines/{line}/capture",
    tag = "lines",
    params(("line" = String, Path, description = "The line's name"), CaptureQuery),
    responses(
        (status = 200, description = "A pcapng file", content_type = "application/x-pcapng", body = Vec<u8>),
        (status = 404, description = "No such line", body = ErrorBody),
        (status = 409, description = "The line's monitor is off (monitor_frames = 0)", body = ErrorBody),
    )
)]
pub(crate) async fn get_capture(
    State(state): State<ApiState>,
    ApiPath(line): ApiPath<String>,
    ApiQuery(q): ApiQuery<CaptureQuery>,
) -> Result<Response, ApiError> {
    let monitor = state.backend().monitor(&line)?;
    let body = match q.seconds {
        None => Body::from(pcapng::capture(&monitor, &monitor.frames_since(0).0)),
        Some(seconds) if (1..=MAX_CAPTURE_SECONDS).contains(&seconds) => {
            let live = monitor.subscribe();
            let file = record(monitor, live, Duration::from_secs(seconds));
            Body::from_stream(stream::once(async move { Ok::<_, Infallible>(file.await) }))
        }
        Some(seconds) => {
            return Err(ApiError::bad_request(format!(
                "seconds must be 1..={MAX_CAPTURE_SECONDS}, not {seconds}"
            )))
        }
    };
    let mut response = body.into_response();
    let headers = response.headers_mut();
    headers.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(pcapng::MEDIA_TYPE),
    );
    if let Ok(v) = HeaderValue::from_str(&format!("attachment; filename=\"{line}.pcapng\"")) {
        headers.insert(header::CONTENT_DISPOSITION, v);
    }
    Ok(response)
}

/// The frames of the next `time` as a pcapng file.
async fn record(
    monitor: Arc<FrameMonitor>,
    mut live: tokio::sync::broadcast::Receiver<Arc<Frame>>,
    time: Duration,
) -> Vec<u8> {
    let until = tokio::time::Instant::now() + time;
    let mut frames = Vec::new();
    let ended = monitor.ended();
    tokio::pin!(ended);
    loop {
        let received = tokio::select! {
            () = tokio::time::sleep_until(until) => break,
            () = &mut ended => break,
            r = live.recv() => r,
        };
        match received {
            Ok(frame) if frames.len() < MAX_CAPTURE_FRAMES => frames.push(Frame::clone(&frame)),
            Ok(_) => {}
            Err(RecvError::Lagged(n)) => monitor.count_lagged(n),
            Err(RecvError::Closed) => break,
        }
    }
    pcapng::capture(&monitor, &frames)
}
