//! `GET /api/events`: the run's event stream as Server-Sent Events, one JSON event a
//! message (its `event` field names the kind). Lost events are told as `event: dropped`
//! with `{"events": N}`; ticks are sent at most every `TICK_EVERY` (a browser has no use
//! for fifty a second, and each costs this thread a serialization); a comment every
//! `KEEP_ALIVE` finds a viewer that went away.

use super::response::Response;
use super::{Shared, MAX_STREAMS};
use crate::runtime::observe::{Next, RunEvent, DEFAULT_QUEUE};
use std::io::Write;
use std::net::TcpStream;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

/// The least time between two tick events sent to one viewer.
pub const TICK_EVERY: Duration = Duration::from_millis(100);

/// How long a stream may stay silent before a keep-alive comment is sent.
pub const KEEP_ALIVE: Duration = Duration::from_secs(15);

/// Streams events to `out` until the viewer goes, the run ends or the server closes.
pub(super) fn stream_events(mut out: TcpStream, shared: &Shared) {
    if shared.streams.fetch_add(1, Ordering::SeqCst) >= MAX_STREAMS {
        shared.streams.fetch_sub(1, Ordering::SeqCst);
        let why = format!("{MAX_STREAMS} viewers follow the event stream already");
        let _ = Response::error(503, why).write_to(&mut out);
        return;
    }
    let who = format!(
        "web viewer {}",
        out.peer_addr().map_or("?".into(), |a| a.to_string())
    );
    follow(&mut out, shared, &who);
    shared.streams.fetch_sub(1, Ordering::SeqCst);
}

fn follow(out: &mut TcpStream, shared: &Shared, who: &str) {
    let mut events = match shared.events.subscribe(who, DEFAULT_QUEUE) {
        Ok(s) => s,
        Err(e) => {
            let _ = Response::error(503, e).write_to(out);
            return;
        }
    };
    // A viewer following the stream watches the rig: the inputs the script does not read are
    // read for it too (`runtime::watched_image`).
    let _watching = shared.events.watching();
    let head = "HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-store\r\n\
                Connection: close\r\n\r\nretry: 1000\n\n";
    if out.write_all(head.as_bytes()).is_err() {
        return;
    }
    let mut last_tick: Option<Instant> = None;
    let mut last_sent = Instant::now();
    let closing = || shared.closing.now();
    events.follow(Duration::from_millis(200), closing, |next| {
        let message = match next {
            Next::Event(event) => {
                let is_tick = matches!(*event, RunEvent::Tick { .. });
                if is_tick && last_tick.is_some_and(|t| t.elapsed() < TICK_EVERY) {
                    String::new()
                } else {
                    if is_tick {
                        last_tick = Some(Instant::now());
                    }
                    let data = serde_json::to_string(&*event).unwrap_or_default();
                    format!("data: {data}\n\n")
                }
            }
            Next::Dropped(lost) => format!("event: dropped\ndata: {{\"events\":{lost}}}\n\n"),
            Next::Quiet => String::new(),
        };
        // Throttled ticks are silence too: a viewer that went away is found by the keep-alive.
        let message = match message.is_empty() && last_sent.elapsed() >= KEEP_ALIVE {
            true => ": keep-alive\n\n".to_string(),
            false => message,
        };
        if message.is_empty() {
            return true;
        }
        last_sent = Instant::now();
        out.write_all(message.as_bytes()).is_ok()
    });
}
