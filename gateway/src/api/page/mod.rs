//! The status page at `/`: one HTML page for the person at the cabinet, served by the REST
//! API's own listener from assets embedded in the binary (no CDN, no external font, no
//! front-end toolchain).
//!
//! The page is plain HTML, CSS and a little JavaScript. Its first look needs no JavaScript: `GET
//! /` answers the page with a snapshot of the gateway, its lines and devices rendered here from
//! the same [`GatewayStatus`] that `GET /api/v1/status` answers. The script then keeps it live
//! with the API's own calls (the frame monitor's Server-Sent Events, otherwise one request at a
//! time at most once a second) and makes changes with the same calls, token and roles as any
//! other client: the page adds no API of its own, so it can do nothing a REST client cannot.
//!
//! The answers carry a Content-Security-Policy that allows nothing but this origin: the page
//! cannot load or send anything elsewhere, even by mistake.

use std::fmt::Write as _;
use std::time::{Duration, SystemTime};

use axum::extract::State;
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::Router;

use super::model::{DeviceStatusView, GatewayStatus, LineState, LineStatusView};
use super::ApiState;

/// The page's HTML; `<!--snapshot-->` is replaced by the server-rendered snapshot.
const INDEX_HTML: &str = include_str!("index.html");
/// The style sheet.
const PAGE_CSS: &str = include_str!("page.css");
/// The script that makes the page live: ES modules, one per part of the page, each served at
/// `/page/<name>.js` with the same headers. `page.js` is the entry `index.html` names (`<script
/// type="module">`); it loads the others one after the other, in this order (lowest first).
const MODULES: &[(&str, &str)] = &[
    ("page.js", include_str!("page.js")),
    ("base.js", include_str!("base.js")),
    ("rest.js", include_str!("rest.js")),
    ("poll.js", include_str!("poll.js")),
    ("overview.js", include_str!("overview.js")),
    ("tags.js", include_str!("tags.js")),
    ("mailboxes.js", include_str!("mailboxes.js")),
    ("monitor.js", include_str!("monitor.js")),
    ("config.js", include_str!("config.js")),
    ("main.js", include_str!("main.js")),
];

/// Where the snapshot goes in [`INDEX_HTML`].
const SNAPSHOT_MARK: &str = "<!--snapshot-->";

/// The path of the style sheet.
pub const CSS_PATH: &str = "/page/page.css";
/// Where the script's modules are served: `/page/<name>.js`.
const JS_DIR: &str = "/page/";

/// Nothing but this origin: no request of the page leaves the gateway.
const CSP: &str = "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; \
     connect-src 'self'; form-action 'self'; base-uri 'none'; frame-ancestors 'none'";

/// The page's routes, merged beside the API's (outside its OpenAPI document).
pub(crate) fn routes() -> Router<ApiState> {
    let router = Router::new()
        .route("/", get(index))
        .route(CSS_PATH, get(css));
    MODULES.iter().fold(router, |router, &(name, js)| {
        router.route(
            &format!("{JS_DIR}{name}"),
            get(move || async move { asset(js, "text/javascript; charset=utf-8") }),
        )
    })
}

async fn index(State(state): State<ApiState>) -> Response {
    let status = state.backend().gateway_status();
    let html = INDEX_HTML.replacen(SNAPSHOT_MARK, &snapshot(&status, SystemTime::now()), 1);
    asset(html, "text/html; charset=utf-8")
}

async fn css() -> Response {
    asset(PAGE_CSS, "text/css; charset=utf-8")
}

fn asset(body: impl IntoResponse, content_type: &'static str) -> Response {
    let mut response = body.into_response();
    let headers = response.headers_mut();
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
    // Always asked again: after an update the page and its script stay of one version.
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    headers.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(CSP),
    );
    headers.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    headers.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    response
}

// === the snapshot ===

/// The gateway, its lines and devices as HTML, for the first look without JavaScript: the
/// script replaces it with the live view.
fn snapshot(status: &GatewayStatus, now: SystemTime) -> String {
    let mut out = String::new();
    let _ = write!(
        out,
        "<p class=\"snap-head\"><b>{}</b> · version {} · up {} · Modbus TCP {} · {}</p>",
        esc(&status.name),
        esc(&status.version),
        duration_words(Duration::from_secs(status.uptime_seconds)),
        match status.modbus_tcp.connections {
            1 => "1 client".to_owned(),
            n => format!("{n} clients"),
        },
        match &status.zenoh {
            Some(z) if z.up => format!("zenoh {} up", esc(&z.mode)),
            Some(z) => format!("zenoh {} down", esc(&z.mode)),
            None => "zenoh off".to_owned(),
        },
    );
    let problems = problems(status);
    if problems.is_empty() {
        out.push_str("<p class=\"snap-ok\">No problem: every line runs, every device answers.</p>");
    } else {
        out.push_str("<ul class=\"snap-problems\">");
        for p in &problems {
            let _ = write!(out, "<li>{}</li>", esc(p));
        }
        out.push_str("</ul>");
    }
    out.push_str(
        "<table class=\"snap-lines\"><caption>Lines</caption><thead><tr><th scope=\"col\">line</th>\
         <th scope=\"col\">protocol</th><th scope=\"col\">port</th><th scope=\"col\">state</th>\
         <th scope=\"col\">last event</th><th scope=\"col\">frames</th></tr></thead><tbody>",
    );
    for line in &status.lines {
        let _ = write!(
            out,
            "<tr data-line=\"{name}\"><th scope=\"row\">{name}</th><td>{}</td><td>{}</td>\
             <td>{}</td><td>{}</td><td>{} sent, {} received</td></tr>",
            esc(&line.protocol),
            esc(&line.port),
            state_word(line.state),
            event_words(line),
            line.counters.frames_sent,
            line.counters.frames_received,
            name = esc(&line.name),
        );
    }
    out.push_str("</tbody></table>");
    for line in status.lines.iter().filter(|l| !l.devices.is_empty()) {
        let _ = write!(
            out,
            "<table class=\"snap-devices\"><caption>Devices on {}</caption><thead><tr>\
             <th scope=\"col\">device</th><th scope=\"col\">unit</th><th scope=\"col\">state</th>\
             <th scope=\"col\">last answer</th><th scope=\"col\">polls</th></tr></thead><tbody>",
            esc(&line.name)
        );
        for device in &line.devices {
            let _ = write!(
                out,
                "<tr><th scope=\"row\">{}</th><td>{} (address {})</td><td>{}</td><td>{}</td>\
                 <td>{} ok, {} exception, {} failed</td></tr>",
                esc(&device.name),
                device.unit_id,
                device.address,
                if device.online { "online" } else { "offline" },
                last_answer(device, now),
                device.polls_ok,
                device.polls_exception,
                device.polls_failed,
            );
        }
        out.push_str("</tbody></table>");
    }
    out
}

/// What is wrong, most urgent first: lines not running, devices not answering, lines whose
/// newest event is an error.
fn problems(status: &GatewayStatus) -> Vec<String> {
    let mut out = Vec::new();
    if let Some(conflict) = status.zenoh.as_ref().and_then(|z| z.name_conflict.as_ref()) {
        out.push(format!(
            "zenoh: this gateway's name is held by another session, so it publishes nothing on \
             zenoh until the name is free: {conflict}"
        ));
    }
    for line in &status.lines {
        if line.state != LineState::Running {
            let why = line
                .port_error
                .as_deref()
                .map(|e| format!(": {e}"))
                .unwrap_or_default();
            out.push(format!("{}: {}{why}", line.name, state_word(line.state)));
        }
    }
    for line in &status.lines {
        for device in line.devices.iter().filter(|d| !d.online) {
            out.push(format!(
                "{} / {}: offline (unit {})",
                line.name, device.name, device.unit_id
            ));
        }
    }
    // Class 00h reports the start-up (003 7.2 "CP start-up"), not a fault.
    for line in &status.lines {
        if let Some(e) = line.last_event.as_ref().filter(|e| e.class != 0) {
            out.push(format!(
                "{}: {} {} — {} Remedy: {}",
                line.name,
                status_word_text(e.status_word),
                e.class_name,
                e.description,
                if e.remedy.is_empty() {
                    "none given"
                } else {
                    &e.remedy
                }
            ));
        }
    }
    out
}

fn state_word(state: LineState) -> &'static str {
    match state {
        LineState::Starting => "starting",
        LineState::Running => "running",
        LineState::PortClosed => "port closed",
        LineState::Restarting => "restarting",
        LineState::Stopped => "stopped",
    }
}

/// The STATUS word as the manual writes it: class and number in hex, `08 30h`.
fn status_word_text(word: u16) -> String {
    let [class, number] = word.to_be_bytes();
    format!("{class:02X} {number:02X}h")
}

fn event_words(line: &LineStatusView) -> String {
    match &line.last_event {
        Some(e) => format!(
            "{} {}: {}",
            status_word_text(e.status_word),
            esc(&e.class_name),
            esc(&e.description)
        ),
        None => "none".to_owned(),
    }
}

fn last_answer(device: &DeviceStatusView, now: SystemTime) -> String {
    match device.last_answer {
        Some(t) => match now.duration_since(t.0) {
            Ok(age) => format!("{} ago", duration_words(age)),
            Err(_) => "just now".to_owned(),
        },
        None => "never".to_owned(),
    }
}

/// A duration in words a person reads at a glance: `0.4 s`, `12 s`, `3 min 5 s`, `2 h 5 min`,
/// `3 d 4 h`.
pub fn duration_words(d: Duration) -> String {
    let s = d.as_secs();
    match s {
        0..=9 => format!("{:.1} s", d.as_secs_f64()),
        10..=59 => format!("{s} s"),
        60..=3599 => format!("{} min {} s", s / 60, s % 60),
        3600..=86_399 => format!("{} h {} min", s / 3600, s % 3600 / 60),
        _ => format!("{} d {} h", s / 86_400, s % 86_400 / 3600),
    }
}

/// Text for HTML: `& < > " '` escaped.
fn esc(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The path of the script's entry module.
    const JS_PATH: &str = "/page/page.js";

    /// The bytes of every embedded asset, for the size budget (300 KB).
    fn asset_bytes() -> usize {
        INDEX_HTML.len() + PAGE_CSS.len() + MODULES.iter().map(|(_, js)| js.len()).sum::<usize>()
    }

    /// The budget for the page's assets.
    const ASSET_BUDGET: usize = 300 * 1024;

    #[test]
    fn the_assets_stay_within_the_budget() {
        assert!(
            asset_bytes() <= ASSET_BUDGET,
            "{} bytes of assets, more than {ASSET_BUDGET}",
            asset_bytes()
        );
        assert_eq!(INDEX_HTML.matches(SNAPSHOT_MARK).count(), 1);
    }

    #[test]
    fn the_page_names_no_other_origin() {
        let assets = [("index.html", INDEX_HTML), ("page.css", PAGE_CSS)];
        for &(name, text) in assets.iter().chain(MODULES) {
            // The SVG namespace names no resource: the script creates the sparklines with it.
            let text = text.replace("http://www.w3.org/2000/svg", "");
            for scheme in ["http://", "https://", "//fonts", "@import"] {
                assert!(!text.contains(scheme), "{name} contains {scheme}");
            }
        }
    }

    /// The names a module imports: `from './x.js'` and `import(`./${name}.js`)` of the entry's
    /// list.
    fn imports(js: &str) -> Vec<String> {
        let mut out: Vec<String> = js
            .split("from './")
            .skip(1)
            .filter_map(|rest| rest.split_once('\'').map(|(name, _)| name.to_owned()))
            .collect();
        if let Some(list) = js.split("const MODULES = [").nth(1) {
            let list = list.split_once(']').map_or("", |(l, _)| l);
            out.extend(
                list.split(',')
                    .map(|n| format!("{}.js", n.trim().trim_matches('\'')))
                    .filter(|n| n != ".js"),
            );
        }
        out
    }

    #[test]
    fn the_script_modules_are_served_loaded_in_order_and_small() {
        assert!(INDEX_HTML.contains(&format!("<script type=\"module\" src=\"{JS_PATH}\">")));
        assert_eq!(JS_PATH, format!("{JS_DIR}{}", MODULES[0].0));
        let served: Vec<String> = MODULES.iter().map(|(n, _)| (*n).to_owned()).collect();
        // The entry loads every other module, in the order of MODULES (lowest first).
        assert_eq!(imports(MODULES[0].1), served[1..], "page.js's list");
        for (i, &(name, js)) in MODULES.iter().enumerate().skip(1) {
            for import in imports(js) {
                let at = served.iter().position(|n| *n == import);
                // A module imports only modules loaded before it: they are in the browser's
                // module map already, so no import asks for a script of its own.
                assert!(
                    at.is_some_and(|at| at > 0 && at < i),
                    "{name} imports {import}, which is not loaded before it"
                );
            }
            let lines = js.lines().count();
            assert!(lines <= 300, "{name} has {lines} lines, more than 300");
        }
    }

    #[test]
    fn text_is_escaped_and_times_are_in_words() {
        assert_eq!(
            esc("<b a=\"x\">'&'</b>"),
            "&lt;b a=&quot;x&quot;&gt;&#39;&amp;&#39;&lt;/b&gt;"
        );
        assert_eq!(duration_words(Duration::from_millis(400)), "0.4 s");
        assert_eq!(duration_words(Duration::from_secs(12)), "12 s");
        assert_eq!(duration_words(Duration::from_secs(185)), "3 min 5 s");
        assert_eq!(duration_words(Duration::from_secs(7500)), "2 h 5 min");
        assert_eq!(
            duration_words(Duration::from_secs(3 * 86_400 + 4 * 3600)),
            "3 d 4 h"
        );
        assert_eq!(status_word_text(0x0830), "08 30h");
    }
}
