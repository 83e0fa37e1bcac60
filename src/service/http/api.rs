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
use crate::service::serving::Place;
use std::io::Read;
use std::net::TcpStream;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The page, compiled in (no CDN: rigs are often offline).
const PAGE: &str = include_str!("page/index.html");

/// uPlot, the plots' library, vendored (page/vendor/README).
const UPLOT_JS: &str = include_str!("page/vendor/uPlot.iife.min.js");

/// uPlot's style sheet.
const UPLOT_CSS: &str = include_str!("page/vendor/uPlot.min.css");

/// Reads one request from `stream` and answers it: its first byte within `REQUEST_WAIT`, the
/// whole of it within `REQUEST_WAIT` of that, however it trickles.
pub(super) fn serve_client(mut stream: TcpStream, shared: &Shared, place: &Place) {
    let _ = stream.set_read_timeout(Some(REQUEST_WAIT));
    match stream.peek(&mut [0u8; 1]) {
        Ok(1..) => {}
        _ => return,
    }
    let deadline = Instant::now() + REQUEST_WAIT;
    let read = read_request(&mut Timed(&stream, deadline), deadline);
    place.waiting(false);
    let request = match read {
        Ok(r) => r,
        Err(ReadError::Closed) => return,
        Err(e) => {
            let _ = Response::error(e.status(), &e).write_to(&mut stream);
            linger(&mut stream);
            return;
        }
    };
    let right = match shared.tokens.check(&request) {
        Ok(right) => right,
        Err(why) => {
            let _ = why.write_to(&mut stream);
            return;
        }
    };
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
    let by = right.by(stream.peer_addr().ok());
    let _ = route(&request, shared, &by).write_to(&mut stream);
}

/// A connection whose every read ends by the request's deadline.
struct Timed<'a>(&'a TcpStream, Instant);

impl Read for Timed<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let left = self.1.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(std::io::ErrorKind::TimedOut.into());
        }
        self.0.set_read_timeout(Some(left))?;
        (&mut &*self.0).read(buf)
    }
}

/// How long, at most, what a client still sends after an error answer is read.
const LINGER: Duration = Duration::from_millis(200);

/// The most read of it.
const LINGER_BYTES: u64 = 64 * 1024;

/// After an error answer: reads what the client still sends, for a short bounded time and
/// amount (`LINGER`, `LINGER_BYTES`, however it trickles), so closing does not reset the
/// connection before it has read the answer.
fn linger(stream: &mut TcpStream) {
    let _ = stream.shutdown(std::net::Shutdown::Write);
    let until = Instant::now() + LINGER;
    let _ = std::io::copy(
        &mut Read::take(Timed(stream, until), LINGER_BYTES),
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
