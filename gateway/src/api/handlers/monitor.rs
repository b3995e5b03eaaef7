//! `/api/v1/lines/{line}/frames` and `/capture`: the line's frame monitor as JSON, as a live
//! stream of Server-Sent Events, and as a pcapng file for Wireshark.

use std::convert::Infallible;
use std::sync::Arc;
use std::time::Duration;

use axum::body::{Body, Bytes};
use axum::extract::State;
use axum::http::{header, HeaderValue};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::Extension;
use axum::Json;
use futures::stream::{self, Stream, StreamExt};
use tokio::sync::broadcast::error::{RecvError, TryRecvError};

use super::{ApiPath, ApiQuery};
use crate::api::auth::PeerAddr;
use crate::api::error::{ApiError, ErrorBody};
use crate::api::model::{CaptureQuery, FrameView, FramesQuery, FramesView};
use crate::api::{ApiState, StreamPlace};
use crate::line::{pcapng, Frame, FrameMonitor};

/// The longest `?seconds=` of a capture.
pub(crate) const MAX_CAPTURE_SECONDS: u64 = 300;
/// The most bytes of a timed capture the gateway holds at once: the capture is written to the
/// client as it is recorded, in pieces of at most this size (plus one packet, at most 4.2 KiB: the
/// monitor cuts frames at 4096 bytes). Beyond it hyper buffers at most about 400 KiB of a body
/// it cannot write, and a client that does not read is closed after `[http] write_timeout`; so a
/// capture costs well under 0.5 MiB whatever the line's rate and `?seconds=`, and `max_streams`
/// of them at most that many times.
pub(crate) const CAPTURE_CHUNK: usize = 64 * 1024;

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
        (status = 503, description = "With `follow=true`: every stream place is taken \
            (`[http] max_streams`); try again after Retry-After seconds", body = ErrorBody,
            headers(("Retry-After" = u32, description = "Seconds to wait"))),
    )
)]
pub(crate) async fn get_frames(
    State(state): State<ApiState>,
    peer: Option<Extension<PeerAddr>>,
    ApiPath(line): ApiPath<String>,
    ApiQuery(q): ApiQuery<FramesQuery>,
) -> Result<Response, Response> {
    let monitor = state
        .backend()
        .monitor(&line)
        .map_err(IntoResponse::into_response)?;
    let since = q.since.unwrap_or(0);
    if q.follow.unwrap_or(false) {
        let place = state
            .stream_place(peer.map(|Extension(p)| p.0))
            .map_err(closing)?;
        return Ok(follow(monitor, since, place).into_response());
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

/// A stream refused for want of a place: the answer closes the connection too, so that a client
/// that asks again (as a follower does) takes no connection place while it waits.
fn closing(e: ApiError) -> Response {
    let mut response = e.into_response();
    response
        .headers_mut()
        .insert(header::CONNECTION, HeaderValue::from_static("close"));
    response
}

/// The frames above `since` and every new one, as Server-Sent Events, until the client goes or
/// the line stops.
fn follow(
    monitor: Arc<FrameMonitor>,
    since: u64,
    place: StreamPlace,
) -> Sse<impl Stream<Item = Result<Event, Infallible>>> {
    let (backlog, live) = monitor.follow(since);
    let ended = Box::pin(monitor.ended());
    let first = {
        let monitor = Arc::clone(&monitor);
        stream::iter(backlog).map(move |f| Ok(frame_event(&monitor, &f)))
    };
    let rest = stream::unfold(
        (monitor, live, ended, place),
        |(monitor, mut live, mut ended, place)| async move {
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
            Some((Ok(event), (monitor, live, ended, place)))
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
/// next N seconds (1..=300; the answer starts at once and the file is written as the frames come,
/// ending when the N seconds are over).
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
        (status = 503, description = "With `seconds`: every stream place is taken \
            (`[http] max_streams`); try again after Retry-After seconds", body = ErrorBody,
            headers(("Retry-After" = u32, description = "Seconds to wait"))),
    )
)]
pub(crate) async fn get_capture(
    State(state): State<ApiState>,
    peer: Option<Extension<PeerAddr>>,
    ApiPath(line): ApiPath<String>,
    ApiQuery(q): ApiQuery<CaptureQuery>,
) -> Result<Response, Response> {
    let monitor = state
        .backend()
        .monitor(&line)
        .map_err(IntoResponse::into_response)?;
    let body = match q.seconds {
        None => Body::from(pcapng::capture(&monitor, &monitor.frames_since(0).0)),
        Some(seconds) if (1..=MAX_CAPTURE_SECONDS).contains(&seconds) => {
            let place = state
                .stream_place(peer.map(|Extension(p)| p.0))
                .map_err(closing)?;
            let live = monitor.subscribe();
            Body::from_stream(record(monitor, live, Duration::from_secs(seconds), place))
        }
        Some(seconds) => {
            return Err(ApiError::bad_request(format!(
                "seconds must be 1..={MAX_CAPTURE_SECONDS}, not {seconds}"
            ))
            .into_response())
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

/// The frames of the next `time` as a pcapng file, written as they come: the file's header at
/// once, then pieces of at most [`CAPTURE_CHUNK`] bytes (every frame already received, taken
/// without waiting), until the time is over or the line stops.
fn record(
    monitor: Arc<FrameMonitor>,
    live: tokio::sync::broadcast::Receiver<Arc<Frame>>,
    time: Duration,
    place: StreamPlace,
) -> impl Stream<Item = Result<Bytes, Infallible>> + Send {
    let until = tokio::time::Instant::now() + time;
    let header = Bytes::from(pcapng::header(&monitor));
    let ended = Box::pin(monitor.ended());
    let rest = stream::unfold(
        Some((monitor, live, ended, place)),
        move |state| async move {
            let (monitor, mut live, mut ended, place) = state?;
            let mut chunk = Vec::new();
            let over = loop {
                let received = tokio::select! {
                    () = tokio::time::sleep_until(until) => break true,
                    () = &mut ended => break true,
                    r = live.recv() => r,
                };
                match received {
                    Ok(frame) => {
                        pcapng::packet(&mut chunk, &monitor, &frame);
                        while chunk.len() < CAPTURE_CHUNK {
                            match live.try_recv() {
                                Ok(frame) => pcapng::packet(&mut chunk, &monitor, &frame),
                                Err(TryRecvError::Lagged(n)) => monitor.count_lagged(n),
                                Err(_) => break,
                            }
                        }
                        break false;
                    }
                    Err(RecvError::Lagged(n)) => monitor.count_lagged(n),
                    Err(RecvError::Closed) => break true,
                }
            };
            if over && chunk.is_empty() {
                return None;
            }
            let next = (!over).then_some((monitor, live, ended, place));
            Some((Ok(Bytes::from(chunk)), next))
        },
    );
    stream::once(async move { Ok(header) }).chain(rest)
}
