//! The routes: one request read, checked and answered per connection. `GET /` (the page,
//! with `/uplot.js`, `/uplot.css` and `/api/layout`: the panel's switch and rotary names),
//! `GET /api/state` (the snapshot), `GET /api/history` (the plots' memory), `GET
//! /api/events` (the event stream), `POST /api/sim` (a drive action on a simulated device),
//! `POST /api/force` and `DELETE /api/force/POINT` (forcing, `force`), `GET /metrics`
//! (Prometheus). Errors are JSON `{"error": ...}` with their status.

use super::request::{read_request, HttpRequest, ReadError};
use super::response::{Response, JSON};
use super::{force, metrics, sse, Shared, ANSWER_WAIT, REQUEST_WAIT};
use crate::protocol::trc1000::{Rotary, Switch};
use crate::runtime::requests::{Answer, AskError, Drive, Request};
use crate::runtime::snapshot::{DeviceState, RigSnapshot};
use std::net::TcpStream;
use std::sync::Arc;
use std::time::Instant;

/// The page, compiled in (no CDN: rigs are often offline).
const PAGE: &str = include_str!("page/index.html");

/// uPlot, the plots' library, vendored (page/vendor/README).
const UPLOT_JS: &str = include_str!("page/vendor/uPlot.iife.min.js");

/// uPlot's style sheet.
const UPLOT_CSS: &str = include_str!("page/vendor/uPlot.min.css");

/// Reads one request from `stream` and answers it.
pub(super) fn serve_client(mut stream: TcpStream, shared: &Shared) {
    let deadline = Instant::now() + REQUEST_WAIT;
    let _ = stream.set_read_timeout(Some(REQUEST_WAIT));
    let request = match read_request(&mut stream, deadline) {
        Ok(r) => r,
        Err(ReadError::Closed) => return,
        Err(e) => {
            let _ = Response::error(e.status(), &e).write_to(&mut stream);
            linger(&mut stream);
            return;
        }
    };
    if let Err(why) = shared.tokens.check(&request) {
        let _ = why.write_to(&mut stream);
        return;
    }
    // A token is what a rebinding page cannot send; without one, the Host must be ours.
    if !shared.tokens.required() {
        if let Err(why) = check_host(&request, shared) {
            let _ = why.write_to(&mut stream);
            return;
        }
    }
    if (request.method.as_str(), request.path.as_str()) == ("GET", "/api/events") {
        sse::stream_events(stream, shared);
        return;
    }
    let by = match stream.peer_addr() {
        Ok(peer) => format!("the web page ({peer})"),
        Err(_) => "the web page".to_string(),
    };
    let _ = route(&request, shared, &by).write_to(&mut stream);
}

/// After an error answer: reads (a bounded amount, a bounded time) what the client still
/// sends, so closing does not reset the connection before it has read the answer.
fn linger(stream: &mut TcpStream) {
    let _ = stream.shutdown(std::net::Shutdown::Write);
    let _ = stream.set_read_timeout(Some(std::time::Duration::from_millis(500)));
    let _ = std::io::copy(
        &mut std::io::Read::take(&mut *stream, 1 << 20),
        &mut std::io::sink(),
    );
}

fn route(request: &HttpRequest, shared: &Shared, by: &str) -> Response {
    match (request.method.as_str(), request.path.as_str()) {
        ("GET", "/") => Response::ok("text/html; charset=utf-8", PAGE),
        ("GET", "/api/state") => match snapshot(shared) {
            Ok(s) => Response::json(200, &*s),
            Err(e) => e,
        },
        ("GET", "/uplot.js") => Response::ok("text/javascript; charset=utf-8", UPLOT_JS),
        ("GET", "/uplot.css") => Response::ok("text/css; charset=utf-8", UPLOT_CSS),
        ("GET", "/api/layout") => Response::json(200, &layout()),
        ("GET", "/api/history") => Response::ok(JSON, shared.history.json()),
        ("GET", "/metrics") => match snapshot(shared) {
            Ok(s) => Response::ok(metrics::CONTENT_TYPE, metrics::render(&s)),
            Err(e) => e,
        },
        ("POST", "/api/sim") => drive(request, shared),
        ("POST", "/api/force") => force::force(request, shared, by),
        ("DELETE", path) if path.starts_with(force::UNFORCE_PREFIX) => {
            force::unforce(&path[force::UNFORCE_PREFIX.len()..], shared, by)
        }
        (
            _,
            "/" | "/uplot.js" | "/uplot.css" | "/api/layout" | "/api/state" | "/api/history"
            | "/api/events" | "/metrics" | "/api/sim" | "/api/force",
        ) => Response::error(
            405,
            format!("{} {} is not served", request.method, request.path),
        ),
        (_, path) => Response::error(
            404,
            format!(
                "{path} is not here: GET /, /api/state, /api/history, /api/layout, \
                 /api/events, /metrics; POST /api/sim, /api/force; DELETE /api/force/POINT"
            ),
        ),
    }
}

/// A TRC1000's switches and rotaries by name, in the board's order (the page lays them out).
fn layout() -> serde_json::Value {
    let switches: Vec<&str> = Switch::all().map(Switch::name).collect();
    let rotaries: Vec<&str> = Rotary::ALL.iter().map(|r| r.name()).collect();
    serde_json::json!({ "switches": switches, "rotaries": rotaries })
}

/// Refuses a request whose `Host` is not this server's own address: a page of another site
/// whose name was made to point at 127.0.0.1 (DNS rebinding) names its own host.
fn check_host(request: &HttpRequest, shared: &Shared) -> Result<(), Response> {
    let Some(host) = request.header("host") else {
        return Ok(());
    };
    let port = shared.addr.port();
    let ours = [
        shared.addr.to_string(),
        format!("localhost:{port}"),
        format!("127.0.0.1:{port}"),
        format!("[::1]:{port}"),
    ];
    if ours.iter().any(|o| o.eq_ignore_ascii_case(host)) {
        Ok(())
    } else {
        Err(Response::error(
            403,
            format!("Host {host:?} is not this server ({})", shared.addr),
        ))
    }
}

/// The run's snapshot, or the error response saying why there is none.
pub(super) fn snapshot(shared: &Shared) -> Result<Arc<RigSnapshot>, Response> {
    match shared.ask.ask(Request::Snapshot, ANSWER_WAIT) {
        Ok(Answer::Snapshot(s)) => Ok(s),
        Ok(Answer::Refused(why)) => Err(Response::error(409, why)),
        Ok(Answer::Accepted) => Err(Response::error(503, "the run answered without a snapshot")),
        Err(e) => Err(unavailable(&e)),
    }
}

pub(super) fn unavailable(e: &AskError) -> Response {
    let status = match e {
        AskError::NoAnswer(_) => 504,
        AskError::Busy | AskError::Gone => 503,
    };
    Response::error(status, e)
}

/// `POST /api/sim`: a drive action as the scenario API names it, applied by the loop at a
/// tick boundary. 404 for a device the rig has not, 403 for a real one, 409 for what the
/// loop refuses (a switch the panel has not, ...).
/// Whether the body is JSON: a form of another site can post to localhost without asking;
/// JSON it cannot.
pub(super) fn is_json(request: &HttpRequest) -> bool {
    request
        .header("content-type")
        .is_some_and(|t| t.split(';').next().unwrap_or("").trim() == JSON)
}

fn drive(request: &HttpRequest, shared: &Shared) -> Response {
    if !is_json(request) {
        return Response::error(415, "a drive action is sent as application/json");
    }
    let drive: Drive = match serde_json::from_slice(&request.body) {
        Ok(d) => d,
        Err(e) => {
            return Response::error(
                400,
                format!(
                    "{e}; a drive action is {{\"device\":\"panel\",\"action\":\"press\",\
                     \"name\":\"S12\"}} (actions: press, release, turn, set_inputs, set_input, \
                     pulse, fail, restore)"
                ),
            )
        }
    };
    let state = match snapshot(shared) {
        Ok(s) => s,
        Err(e) => return e,
    };
    match state.devices.get(&drive.device) {
        None => {
            let known: Vec<&str> = state.devices.keys().map(String::as_str).collect();
            return Response::error(
                404,
                format!(
                    "the rig has no device called {} (devices: {})",
                    drive.device,
                    known.join(", ")
                ),
            );
        }
        Some(
            DeviceState::C29u {
                simulated: false, ..
            }
            | DeviceState::Trc {
                simulated: false, ..
            },
        ) => {
            return Response::error(
                403,
                format!(
                    "{} is a real device: the page drives simulators only (run --sim, \
                     --sim-device, or sim = true in rig.toml)",
                    drive.device
                ),
            )
        }
        Some(_) => {}
    }
    match shared.ask.ask(Request::Drive(drive), ANSWER_WAIT) {
        Ok(Answer::Accepted) => Response::json(200, &serde_json::json!({ "done": true })),
        Ok(Answer::Refused(why)) => Response::error(409, why),
        Ok(Answer::Snapshot(_)) => Response::error(503, "the run answered with a snapshot"),
        Err(e) => unavailable(&e),
    }
}
