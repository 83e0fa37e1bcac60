//! The run's web page and HTTP API (`run --ui ADDR`): a small HTTP/1.1 server over
//! `std::net`, off the scan loop like the control socket (`service::control_socket`): an
//! accept thread polling in slices and a thread per client, each request answered through
//! the control queue (`runtime::requests`) or from the event stream (`runtime::observe`).
//!
//! Hand-written rather than a crate: the page needs a few routes, one request a connection
//! and Server-Sent Events, which std's sockets give in a few hundred lines; every HTTP crate
//! of note brings an async runtime or a thread pool this process has no other use for.
//!
//! Hostile clients cost the loop nothing: the head and body are bounded (`request`), a
//! request must come whole within `REQUEST_WAIT` of its first byte (slow clients are cut
//! off, then closed after a short bounded linger), a client that does not read is let go
//! (`WRITE_WAIT`), at most `MAX_CLIENTS` are served at once, a newcomer taking the place of
//! the client that has waited longest for its request (`serving`: tricklers never keep the
//! owner out; the next is answered 503 only when all are busy answering or streaming), and at
//! most `MAX_STREAMS` of them follow the event stream. Without a token only a loopback
//! address is served, and only requests naming it as their `Host` (a page of another site
//! that rebinds its name to 127.0.0.1 is refused); any other address needs a token (`auth`),
//! which every request then carries. Whatever the address, changing the rig needs the run's
//! key or the control token (`auth`).

mod api;
pub mod auth;
mod force;
pub mod history;
pub mod metrics;
pub mod request;
pub mod response;
mod sse;

use super::serving::{self, Bounds, Closing, Serving};
use crate::runtime::observe::Events;
use crate::runtime::requests::Requester;
use auth::Tokens;
use history::History;
use response::Response;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::AtomicUsize;
use std::sync::Arc;
use std::time::Duration;

/// Clients served at once; the next one is answered 503 and let go.
pub const MAX_CLIENTS: usize = 32;

/// Clients following the event stream at once (each holds a client's place too).
pub const MAX_STREAMS: usize = 16;

/// How long a client may take to send its whole request.
pub const REQUEST_WAIT: Duration = Duration::from_secs(5);

/// How long a write may wait for a client that does not read.
pub const WRITE_WAIT: Duration = Duration::from_secs(2);

/// How long a request waits for the loop's answer.
pub const ANSWER_WAIT: Duration = Duration::from_secs(2);

/// Why the page could not be served.
#[derive(Debug, thiserror::Error)]
pub enum BindError {
    /// Not a loopback address, and no token: the page drives the rig.
    #[error(
        "{0}: the web page is served on an address other than loopback (127.0.0.1, ::1) only \
         with a token: set ui_token in rig.toml or RIGSCRIPT_UI_TOKEN in the environment \
         (ui_read_token / RIGSCRIPT_UI_READ_TOKEN for one that may only look), or reach it \
         through an SSH tunnel (ssh -L 7878:127.0.0.1:7878 HOST)"
    )]
    NotLoopback(SocketAddr),
    /// The address could not be bound (in use, not this machine's).
    #[error("cannot serve the web page on {addr}: {source}")]
    Io {
        /// The address asked for.
        addr: SocketAddr,
        /// What failed.
        source: std::io::Error,
    },
}

/// The page's address, bound and not served yet.
pub struct Binding {
    listener: TcpListener,
    addr: SocketAddr,
    tokens: Tokens,
}

/// Binds `addr` (port 0: a free one, `Binding::addr` says which), served with `tokens`; an
/// address other than loopback needs a control token.
pub fn bind(addr: SocketAddr, tokens: Tokens) -> Result<Binding, BindError> {
    if !addr.ip().is_loopback() && !tokens.controlled() {
        return Err(BindError::NotLoopback(addr));
    }
    let io = |source| BindError::Io { addr, source };
    let listener = TcpListener::bind(addr).map_err(io)?;
    let addr = listener.local_addr().map_err(io)?;
    Ok(Binding {
        listener,
        addr,
        tokens,
    })
}

impl Binding {
    /// The address bound.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Serves the page from now on: requests through `ask`, the stream from `events`, the
    /// plots' history and the log from `early` (following `events` from the run's first
    /// line: `History::follow` given to `RigBuilder::watch_from_start`), else from now.
    pub fn serve(self, ask: Requester, events: &Events, early: Option<History>) -> Server {
        let history = early.unwrap_or_else(|| History::follow(events));
        let closing = Arc::new(Closing::default());
        let shared = Arc::new(Shared {
            addr: self.addr,
            tokens: self.tokens,
            ask,
            events: events.clone(),
            history,
            closing: Arc::clone(&closing),
            streams: AtomicUsize::new(0),
        });
        let bounds = Bounds {
            clients: MAX_CLIENTS,
            write_wait: WRITE_WAIT,
            name: "web",
        };
        let refuse = |stream: &mut TcpStream| {
            let why = format!("{MAX_CLIENTS} clients are being served already; try again");
            let _ = Response::error(503, why).write_to(stream);
        };
        let theirs = Arc::clone(&shared);
        let serving = serving::serve(
            self.listener,
            bounds,
            closing,
            refuse,
            move |stream, place| {
                api::serve_client(stream, &theirs, place);
            },
        );
        Server {
            shared,
            serving: Some(serving),
        }
    }
}

/// A served page; dropping it stops serving and gives streams a bounded time to be sent the
/// last events (`serving::FLUSH_WAIT`).
pub struct Server {
    shared: Arc<Shared>,
    serving: Option<Serving>,
}

/// What the clients share.
struct Shared {
    addr: SocketAddr,
    tokens: Tokens,
    ask: Requester,
    events: Events,
    history: History,
    /// Set when serving is over: streams end.
    closing: Arc<Closing>,
    streams: AtomicUsize,
}

impl Drop for Server {
    fn drop(&mut self) {
        self.serving.take();
        self.shared.history.stop();
    }
}
