//! Connections served off the scan loop, the one way the control socket and the web page both
//! serve theirs: an accept thread that looks whether serving is over every `ACCEPT_SLICE`, a
//! thread per client up to a bound, each connection's reads ended when serving stops, and a
//! bounded wait for the clients at the end: the end of a run never waits on a client.
//!
//! A place is never held against a newcomer by a client that only waits: a client says when
//! it waits for its peer's request (`Place::waiting`); when every place is taken, the one
//! that has waited longest is let go for the newcomer, so a client trickling its request, or
//! a crowd of them, cannot keep the rig's owner out. Only when every place is busy answering
//! or streaming is the newcomer told so by the service and let go.

use crate::sync::lock;
use std::collections::HashMap;
use std::io;
use std::net::{Shutdown, TcpListener, TcpStream};
use std::os::unix::io::{AsRawFd, RawFd};
use std::os::unix::net::{UnixListener, UnixStream};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How often the accept thread looks whether serving is over.
pub const ACCEPT_SLICE: Duration = Duration::from_millis(100);

/// How long the end waits for clients to finish (subscribers to be sent the last events).
pub const FLUSH_WAIT: Duration = Duration::from_secs(1);

/// A listening socket the accept thread takes connections from.
pub trait Listening: AsRawFd + Send + 'static {
    /// What a connection is.
    type Stream: Connection;
    /// Takes the connection waiting.
    fn take(&self) -> io::Result<Self::Stream>;
}

/// A client's connection.
pub trait Connection: Send + Sized + 'static {
    /// Bounds how long a write may wait for a client that does not read.
    fn set_write_wait(&self, wait: Duration);
    /// Ends its reads (its thread then sees the end of the stream).
    fn end_reads(&self);
    /// A second handle on it.
    fn another(&self) -> io::Result<Self>;
}

impl Listening for UnixListener {
    type Stream = UnixStream;
    fn take(&self) -> io::Result<UnixStream> {
        self.accept().map(|(s, _)| s)
    }
}

impl Listening for TcpListener {
    type Stream = TcpStream;
    fn take(&self) -> io::Result<TcpStream> {
        self.accept().map(|(s, _)| s)
    }
}

/// `Connection` for std's stream types, which share the methods it needs.
macro_rules! connection {
    ($($stream:ty),*) => {$(
        impl Connection for $stream {
            fn set_write_wait(&self, wait: Duration) {
                let _ = self.set_write_timeout(Some(wait));
            }
            fn end_reads(&self) {
                let _ = self.shutdown(Shutdown::Read);
            }
            fn another(&self) -> io::Result<Self> {
                self.try_clone()
            }
        }
    )*};
}

connection!(UnixStream, TcpStream);

/// How a service's connections are bounded.
#[derive(Debug, Clone, Copy)]
pub struct Bounds {
    /// Clients served at once.
    pub clients: usize,
    /// How long a write may wait for a client that does not read.
    pub write_wait: Duration,
    /// The accept thread's name (its clients' threads are named `NAME client`).
    pub name: &'static str,
}

/// Whether serving is over, for a client's thread to look at between waits.
#[derive(Default)]
pub struct Closing(AtomicBool);

impl Closing {
    /// Whether serving is over.
    pub fn now(&self) -> bool {
        self.0.load(Ordering::SeqCst)
    }
}

/// A client's place, as its thread sees it.
pub struct Place {
    closing: Arc<Closing>,
    waiting: Arc<AtomicBool>,
}

impl Place {
    /// Whether serving is over.
    pub fn closing(&self) -> &Closing {
        &self.closing
    }

    /// Says whether the client is waiting for its peer (a request not read whole yet, an idle
    /// connection): a waiting client may be let go for a newcomer when every place is taken.
    pub fn waiting(&self, waiting: bool) {
        self.waiting.store(waiting, Ordering::SeqCst);
    }
}

/// A connection being served, as the accept thread keeps it.
struct Open<S> {
    stream: S,
    waiting: Arc<AtomicBool>,
}

struct State<S> {
    closing: Arc<Closing>,
    /// Client threads alive (a client let go is counted until its thread ends).
    clients: AtomicUsize,
    /// The clients holding a place, by number (the order they came in), to let the longest
    /// waiting go for a newcomer and to end their reads when serving stops.
    open: Mutex<HashMap<u64, Open<S>>>,
}

/// Connections being served; dropping it stops serving (see the module doc).
pub struct Serving {
    closing: Arc<Closing>,
    end: Box<dyn Fn() -> bool + Send>,
    accept: Option<JoinHandle<()>>,
}

/// Serves `listener` from now on: each client on a thread of its own, given to `client` with
/// its `Place` (waiting until it says otherwise; `closing`, the flag that says serving is
/// over, set when `Serving` is dropped). One past `bounds.clients` takes the place of the
/// client that has waited longest, or, when none waits, is given to `refuse` (a short answer
/// that says so) and let go.
pub fn serve<L: Listening>(
    listener: L,
    bounds: Bounds,
    closing: Arc<Closing>,
    refuse: impl Fn(&mut L::Stream) + Send + 'static,
    client: impl Fn(L::Stream, &Place) + Send + Sync + 'static,
) -> Serving {
    let state = Arc::new(State {
        closing: Arc::clone(&closing),
        clients: AtomicUsize::new(0),
        open: Mutex::new(HashMap::new()),
    });
    let theirs = Arc::clone(&state);
    let client = Arc::new(client);
    let accept = std::thread::Builder::new()
        .name(bounds.name.into())
        .spawn(move || accept_loop(&listener, bounds, &theirs, &refuse, &client))
        .ok();
    let ending = Arc::clone(&state);
    // Ends the clients' reads; true while some are still being served.
    let end = Box::new(move || {
        for o in lock(&ending.open).values() {
            o.stream.end_reads();
        }
        ending.clients.load(Ordering::SeqCst) > 0
    });
    Serving {
        closing,
        end,
        accept,
    }
}

impl Drop for Serving {
    fn drop(&mut self) {
        self.closing.0.store(true, Ordering::SeqCst);
        let until = Instant::now() + FLUSH_WAIT;
        loop {
            let clients = (self.end)();
            let accepting = self.accept.as_ref().is_some_and(|t| !t.is_finished());
            if !(clients || accepting) || Instant::now() >= until {
                break;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        if let Some(t) = self.accept.take().filter(JoinHandle::is_finished) {
            let _ = t.join();
        }
    }
}

/// Waits up to `ACCEPT_SLICE` for a connection; true if one waits.
fn connection_waiting(fd: RawFd) -> bool {
    crate::link::fd::wait_readable(&[fd], ACCEPT_SLICE).is_ok_and(|ready| ready[0])
}

/// Lets the client that has waited longest go (its reads end, and its place is free at once):
/// true if one was waiting.
fn let_go_longest<S: Connection>(open: &mut HashMap<u64, Open<S>>) -> bool {
    let longest = open
        .iter()
        .filter(|(_, o)| o.waiting.load(Ordering::SeqCst))
        .map(|(n, _)| *n)
        .min();
    match longest.and_then(|n| open.remove(&n)) {
        Some(o) => {
            o.stream.end_reads();
            true
        }
        None => false,
    }
}

/// Client threads alive at most, as a multiple of the places: a client let go ends its
/// thread at once (its read ends), but until it has, its thread is still counted.
const THREADS_PER_PLACE: usize = 3;

/// How long a newcomer may wait, at most, for clients already let go to end their threads
/// before it is refused: on a loaded machine a crowd let go can take a moment to end, and the
/// rig's owner must not be refused for clients that are already leaving.
const ENDING_WAIT: Duration = Duration::from_millis(500);

/// Gives a newcomer a place (`number`, its `copy` and its `waiting` flag kept in `open`):
/// a free one, or the longest waiting client's; false when every place is busy, or when the
/// clients let go have not ended their threads within `ENDING_WAIT`.
fn admit<S: Connection>(
    state: &State<S>,
    places: usize,
    number: u64,
    copy: S,
    waiting: &Arc<AtomicBool>,
) -> bool {
    let until = Instant::now() + ENDING_WAIT;
    loop {
        let mut open = lock(&state.open);
        if state.clients.load(Ordering::SeqCst) < THREADS_PER_PLACE * places {
            let place = open.len() < places || let_go_longest(&mut open);
            if place {
                let o = Open {
                    stream: copy,
                    waiting: Arc::clone(waiting),
                };
                open.insert(number, o);
                state.clients.fetch_add(1, Ordering::SeqCst);
            }
            return place;
        }
        // The threads over the bound are clients let go, still ending: they need the lock.
        drop(open);
        if Instant::now() >= until {
            return false;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

fn accept_loop<L: Listening>(
    listener: &L,
    bounds: Bounds,
    state: &Arc<State<L::Stream>>,
    refuse: &impl Fn(&mut L::Stream),
    client: &Arc<impl Fn(L::Stream, &Place) + Send + Sync + 'static>,
) {
    let mut number = 0u64;
    while !state.closing.now() {
        if !connection_waiting(listener.as_raw_fd()) {
            continue;
        }
        number = number.wrapping_add(1);
        let Ok(mut stream) = listener.take() else {
            // Out of descriptors, most likely: a moment, then on.
            std::thread::sleep(Duration::from_millis(10));
            continue;
        };
        stream.set_write_wait(bounds.write_wait);
        let waiting = Arc::new(AtomicBool::new(true));
        let admitted = match stream.another() {
            Ok(copy) => admit(state, bounds.clients, number, copy, &waiting),
            Err(_) => false,
        };
        if !admitted {
            stream.set_write_wait(Duration::from_millis(100));
            refuse(&mut stream);
            continue;
        }
        let place = Place {
            closing: Arc::clone(&state.closing),
            waiting,
        };
        let (theirs, serve) = (Arc::clone(state), Arc::clone(client));
        let spawned = std::thread::Builder::new()
            .name(format!("{} client", bounds.name))
            .spawn(move || {
                serve(stream, &place);
                lock(&theirs.open).remove(&number);
                theirs.clients.fetch_sub(1, Ordering::SeqCst);
            });
        if spawned.is_err() {
            lock(&state.open).remove(&number);
            state.clients.fetch_sub(1, Ordering::SeqCst);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Read, Write};

    /// Reads what `s` says until it closes or a newline.
    fn said(s: &mut UnixStream) -> String {
        let mut text = Vec::new();
        let mut b = [0u8; 1];
        while let Ok(1) = s.read(&mut b) {
            text.push(b[0]);
            if b[0] == b'\n' {
                break;
            }
        }
        String::from_utf8_lossy(&text).into_owned()
    }

    /// Two places; a newcomer refused is told "full".
    const TWO_PLACES: Bounds = Bounds {
        clients: 2,
        write_wait: Duration::from_secs(1),
        name: "places test",
    };

    fn refuse(s: &mut UnixStream) {
        let _ = s.write_all(b"full\n");
    }

    #[test]
    fn a_newcomer_takes_the_place_of_the_longest_waiting_and_a_busy_house_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.sock");
        let listener = UnixListener::bind(&path).unwrap();
        // A client waits until it sends a byte; then it is busy until it goes.
        let serving = serve(listener, TWO_PLACES, Arc::default(), refuse, |mut s, place| {
            let mut b = [0u8; 1];
            if matches!(s.read(&mut b), Ok(1)) {
                place.waiting(false);
                let _ = s.write_all(b"busy\n");
                let _ = s.read(&mut b);
            }
        });
        let connect = || {
            let s = UnixStream::connect(&path).unwrap();
            s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
            std::thread::sleep(Duration::from_millis(50));
            s
        };
        let (mut first, mut second) = (connect(), connect());
        let mut busy = connect();
        busy.write_all(b"x").unwrap();
        assert_eq!(said(&mut busy), "busy\n");
        assert_eq!(said(&mut first), "", "the longest waiting was let go");
        let mut busy_too = connect();
        busy_too.write_all(b"x").unwrap();
        assert_eq!(said(&mut busy_too), "busy\n");
        assert_eq!(said(&mut second), "", "then the next");
        assert_eq!(said(&mut connect()), "full\n", "every place busy: refused");
        drop(serving);
    }

    #[test]
    fn a_newcomer_waits_for_a_crowd_let_go_to_end_instead_of_being_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.sock");
        let listener = UnixListener::bind(&path).unwrap();
        // A client let go takes 100 ms to end its thread, as on a loaded machine.
        let serving = serve(listener, TWO_PLACES, Arc::default(), refuse, |mut s, place| {
            let mut b = [0u8; 1];
            if matches!(s.read(&mut b), Ok(1)) {
                place.waiting(false);
                let _ = s.write_all(b"served\n");
            } else {
                std::thread::sleep(Duration::from_millis(100));
            }
        });
        let connect = || {
            let s = UnixStream::connect(&path).unwrap();
            s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
            s
        };
        // Twelve idle clients at once: each takes the place of the one before, and the ones
        // let go are still ending (more threads than the bound of six) when the owner comes.
        let crowd: Vec<UnixStream> = (0..12).map(|_| connect()).collect();
        let mut owner = connect();
        owner.write_all(b"x").unwrap();
        assert_eq!(said(&mut owner), "served\n");
        drop(crowd);
        drop(serving);
    }
}
