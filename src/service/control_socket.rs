//! The run's control socket: a Unix socket in the rig directory (`rig_dir`) through which
//! `rigscript status`, `list`, `stop` and `reload` (and later the web page) see and drive a running rig.
//! It lives off the scan loop: an accept thread and one thread per client, each request
//! answered through the control queue (`runtime::requests`) or from the event stream
//! (`runtime::observe`), never by touching the runtime.
//!
//! Hostile clients cost the loop nothing: reads are bounded (`MAX_REQUEST`), a client that
//! sends nothing is let go (`FIRST_REQUEST`, `IDLE`), a request must come whole within
//! `REQUEST_WAIT` of its first byte however it trickles, one that does not read is let go
//! (`WRITE_WAIT`), and at most `MAX_CLIENTS` are served at once: a newcomer takes the place
//! of the client that has waited longest (`serving`), so `stop` always gets through; only
//! when all are busy is it told the socket is full. Only the run's user and root are served
//! (`authority::may_act`).

use super::authority::{self, RunKey};
use super::control_protocol::{parse_request, ClientRequest, Hello, Reply, MAX_REQUEST};
use super::reload::Reloader;
use super::rig_dir::{self, Knock};
use super::serving::{self, Bounds, Closing, Place, Serving};
use crate::runtime::observe::{Events, Next, DEFAULT_QUEUE};
use crate::runtime::requests::{Answer, AskError, Request, Requester};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Clients served at once; the next one is told so and let go.
pub const MAX_CLIENTS: usize = 16;

/// How long a new client may take to send its first request.
pub const FIRST_REQUEST: Duration = Duration::from_secs(5);

/// How long a client may wait between requests (a subscriber is not waiting: it reads).
pub const IDLE: Duration = Duration::from_secs(60);

/// How long a request may take from its first byte to its newline.
pub const REQUEST_WAIT: Duration = Duration::from_secs(5);

/// How long an answer may wait for a client that does not read it.
pub const WRITE_WAIT: Duration = Duration::from_secs(2);

/// How long a request waits for the loop's answer.
pub const ANSWER_WAIT: Duration = Duration::from_secs(2);

/// Why the rig's socket could not be made.
#[derive(Debug, thiserror::Error)]
pub enum ClaimError {
    /// Another run of this rig answers on it.
    #[error(
        "a rig called {rig} is running already (pid {pid}, script {script}); see it with \
         `rigscript status {rig}`, stop it with `rigscript stop {rig}`, or give this run \
         another name (`name = \"...\"` in rig.toml)"
    )]
    Running {
        /// The rig's name.
        rig: String,
        /// The other run's pid.
        pid: u32,
        /// Its script.
        script: String,
    },
    /// Something listens on the rig's socket but did not say who it is: a run of it whose
    /// clients are all taken, most likely.
    #[error(
        "a rig called {rig} seems to be running already: its socket {} answers but did not say \
         who it is ({why}); try again, or remove the file if no run of it is left",
        path.display()
    )]
    Unanswered {
        /// The rig's name.
        rig: String,
        /// The socket.
        path: PathBuf,
        /// What the knock got.
        why: String,
    },
    /// The rig directory or the socket could not be made.
    #[error("cannot make the control socket {}: {source}", path.display())]
    Io {
        /// The socket's path.
        path: PathBuf,
        /// What failed.
        source: std::io::Error,
    },
}

/// The rig's socket, bound and not served yet: the name is this run's.
pub struct Claim {
    listener: UnixListener,
    path: PathBuf,
    inode: (u64, u64),
    hello: Hello,
    /// The run's key beside the socket, once kept.
    key: Option<PathBuf>,
    /// How a reload is made ready, when this run can be reloaded.
    reloader: Option<Reloader>,
}

/// Names a run may take when the one it was given is in use, besides that one: `NAME-2` to
/// `NAME-MAX_SUFFIX`.
pub const MAX_SUFFIX: u32 = 99;

/// How a run came by its name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Naming {
    /// rig.toml's `name`: the rig is that one, and a live run of it refuses this one.
    Configured,
    /// From a file's stem: when a live run has it, this run takes the first free `NAME-N`.
    Derived,
}

/// Binds the socket of rig `hello.rig` in `dir`, replacing one a dead run left. When a live
/// run answers on it, a `Configured` name is refused and a `Derived` one goes on to the next
/// free `NAME-N` (`Claim::hello` says which it took).
pub fn claim(dir: &Path, mut hello: Hello, naming: Naming) -> Result<Claim, ClaimError> {
    let base = hello.rig.clone();
    let mut first_taken = None;
    for n in 1..=MAX_SUFFIX {
        hello.rig = if n == 1 {
            base.clone()
        } else {
            format!("{base}-{n}")
        };
        match claim_name(dir, &hello) {
            Ok(listener) => return Ok(listener),
            Err(e @ (ClaimError::Running { .. } | ClaimError::Unanswered { .. })) => {
                if naming == Naming::Configured {
                    return Err(e);
                }
                first_taken.get_or_insert(e);
            }
            Err(e) => return Err(e),
        }
    }
    Err(first_taken.unwrap_or(ClaimError::Io {
        path: rig_dir::socket_path(dir, &base),
        source: std::io::Error::other("no free name"),
    }))
}

fn claim_name(dir: &Path, hello: &Hello) -> Result<Claim, ClaimError> {
    let path = rig_dir::socket_path(dir, &hello.rig);
    let io = |source| ClaimError::Io {
        path: path.clone(),
        source,
    };
    let running = |other: Hello| ClaimError::Running {
        rig: other.rig,
        pid: other.pid,
        script: other.script,
    };
    match rig_dir::knock(&path, authority::me()) {
        Knock::Answered(other) => return Err(running(other)),
        // Left by a run that died (kill -9, a power cut): nobody listens.
        Knock::Stale => match std::fs::remove_file(&path) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(io(e)),
        },
        Knock::Absent => {}
        // A live run, most likely, or a file not ours: never take its name from under it.
        Knock::Unanswered(why) | Knock::Refused(why) => {
            return Err(ClaimError::Unanswered {
                rig: hello.rig.clone(),
                path,
                why,
            })
        }
    }
    let listener = match UnixListener::bind(&path) {
        Ok(l) => l,
        // Another run bound it between the knock and here: knock again for who.
        Err(e) if e.kind() == std::io::ErrorKind::AddrInUse => {
            return Err(match rig_dir::knock(&path, authority::me()) {
                Knock::Answered(other) => running(other),
                _ => io(e),
            })
        }
        Err(e) => return Err(io(e)),
    };
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).map_err(io)?;
    let meta = std::fs::metadata(&path).map_err(io)?;
    Ok(Claim {
        listener,
        path,
        inode: (meta.dev(), meta.ino()),
        hello: hello.clone(),
        key: None,
        reloader: None,
    })
}

impl Claim {
    /// Where the socket is.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Who the run is, under the name it took.
    pub fn hello(&self) -> &Hello {
        &self.hello
    }

    /// Keeps the run's key beside the socket (`NAME.key`, mode 0600): whoever may open the
    /// socket may read it, and with it change the rig over HTTP too. Removed with the socket.
    pub fn keep_key(&mut self, key: &RunKey) -> std::io::Result<PathBuf> {
        let path = authority::key_path(&self.path);
        key.keep(&path)?;
        self.key = Some(path.clone());
        Ok(path)
    }

    /// Answers `reload` requests from now on, made ready by `reloader`.
    pub fn reloads(&mut self, reloader: Reloader) {
        self.reloader = Some(reloader);
    }

    /// Serves the socket from now on: requests through `ask`, subscriptions from `events`.
    pub fn serve(self, ask: Requester, events: Events) -> Server {
        let shared = Arc::new(Shared {
            hello: self.hello.clone(),
            ask,
            events,
            reloader: self.reloader.clone(),
        });
        let bounds = Bounds {
            clients: MAX_CLIENTS,
            write_wait: WRITE_WAIT,
            name: "control socket",
        };
        let refuse = |stream: &mut UnixStream| {
            let why = format!(
                "the rig's control socket is full ({MAX_CLIENTS} clients, all busy); try again"
            );
            let _ = stream.write_all(Reply::refused(why).line().as_bytes());
        };
        let serving = self.listener.try_clone().ok().map(|listener| {
            let closing = Arc::new(Closing::default());
            serving::serve(listener, bounds, closing, refuse, move |stream, place| {
                serve_client(stream, &shared, place);
            })
        });
        Server {
            serving,
            claim: Some(self),
        }
    }
}

impl Drop for Claim {
    fn drop(&mut self) {
        // Only the file this run made: a later run's is not ours to remove.
        let ours = std::fs::metadata(&self.path)
            .map(|m| (m.dev(), m.ino()) == self.inode)
            .unwrap_or(false);
        if ours {
            let _ = std::fs::remove_file(&self.path);
            if let Some(key) = &self.key {
                let _ = std::fs::remove_file(key);
            }
        }
    }
}

/// A served socket; dropping it stops serving, gives subscribers a bounded time to be sent
/// the last events (`serving::FLUSH_WAIT`), and removes the socket.
pub struct Server {
    serving: Option<Serving>,
    claim: Option<Claim>,
}

impl Drop for Server {
    fn drop(&mut self) {
        // Serving first: the file goes once nobody is being served from it.
        self.serving.take();
        self.claim.take();
    }
}

struct Shared {
    hello: Hello,
    ask: Requester,
    events: Events,
    reloader: Option<Reloader>,
}

/// What a client's read gave.
enum Line {
    Request(String),
    TooLong,
    NotText,
    TooSlow,
    Closed,
}

/// Reads one request line: its first byte within `wait`, the rest within `REQUEST_WAIT` of
/// it, however the client trickles it.
fn read_request(reader: &mut BufReader<UnixStream>, wait: Duration) -> Line {
    let mut buf = Vec::new();
    let mut deadline = Instant::now() + wait;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() || reader.get_ref().set_read_timeout(Some(left)).is_err() {
            return if buf.is_empty() {
                Line::Closed
            } else {
                Line::TooSlow
            };
        }
        let available = match reader.fill_buf() {
            Ok([]) => return Line::Closed,
            Ok(bytes) => bytes,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(_) if !buf.is_empty() => return Line::TooSlow,
            Err(_) => return Line::Closed,
        };
        if buf.is_empty() {
            deadline = deadline.min(Instant::now() + REQUEST_WAIT);
        }
        let (take, whole) = match available.iter().position(|b| *b == b'\n') {
            Some(i) => (i + 1, true),
            None => (available.len(), false),
        };
        buf.extend_from_slice(&available[..take]);
        reader.consume(take);
        if buf.len() > MAX_REQUEST {
            return Line::TooLong;
        }
        if whole {
            return match String::from_utf8(buf) {
                Ok(s) => Line::Request(s),
                Err(_) => Line::NotText,
            };
        }
    }
}

fn serve_client(stream: UnixStream, shared: &Shared, place: &Place) {
    let Ok(reading) = stream.try_clone() else {
        return;
    };
    let mut out = stream;
    if !authority::may_act(authority::peer(&out)) {
        let why = "only the rig's user (and root) may use its control socket";
        let _ = out.write_all(Reply::refused(why).line().as_bytes());
        return;
    }
    let mut reader = BufReader::new(reading);
    let mut wait = FIRST_REQUEST;
    loop {
        place.waiting(true);
        let line = read_request(&mut reader, wait);
        place.waiting(false);
        let reply = match line {
            Line::Closed => return,
            Line::TooLong => {
                let why = format!("a request is one line of at most {MAX_REQUEST} bytes");
                let _ = out.write_all(Reply::refused(why).line().as_bytes());
                return;
            }
            Line::NotText => {
                let why = "a request is a line of UTF-8 text (JSON)";
                let _ = out.write_all(Reply::refused(why).line().as_bytes());
                return;
            }
            Line::TooSlow => {
                let why = format!(
                    "a request comes whole within {}s of its first byte",
                    REQUEST_WAIT.as_secs()
                );
                let _ = out.write_all(Reply::refused(why).line().as_bytes());
                return;
            }
            Line::Request(text) if text.trim().is_empty() => continue,
            Line::Request(text) => match parse_request(&text) {
                Err(why) => Reply::refused(why),
                Ok(ClientRequest::Subscribe) => {
                    stream_events(&mut out, shared, place.closing());
                    return;
                }
                Ok(request) => answer(request, shared, &out),
            },
        };
        if out.write_all(reply.line().as_bytes()).is_err() {
            return;
        }
        wait = IDLE;
    }
}

fn answer(request: ClientRequest, shared: &Shared, client: &UnixStream) -> Reply {
    match request {
        ClientRequest::Hello => Reply {
            hello: Some(shared.hello.clone()),
            ..Reply::done()
        },
        ClientRequest::Status => match shared.ask.ask(Request::Snapshot, ANSWER_WAIT) {
            Ok(Answer::Snapshot(s)) => Reply {
                status: Some((*s).clone()),
                ..Reply::done()
            },
            Ok(Answer::Refused(why)) => Reply::refused(why),
            Ok(Answer::Accepted) => Reply::done(),
            Err(e) => Reply::refused(e.to_string()),
        },
        ClientRequest::Stop => {
            shared.ask.stop(&asker(client, "stop"));
            Reply::done()
        }
        ClientRequest::Subscribe => Reply::refused("subscribe is answered by the stream"),
        ClientRequest::Drive(drive) => done(shared.ask.ask(Request::Drive(drive), ANSWER_WAIT)),
        ClientRequest::Force(order) => {
            let by = asker(client, "force");
            done(shared.ask.ask(Request::Force { order, by }, ANSWER_WAIT))
        }
        ClientRequest::Unforce { point } => {
            let by = asker(client, "unforce");
            done(shared.ask.ask(Request::Unforce { point, by }, ANSWER_WAIT))
        }
        ClientRequest::Reload { script } => {
            let by = asker(client, "reload");
            reload(shared, script.as_deref(), by)
        }
    }
}

/// A reload: made ready on this thread (read, `check`, the scenario tests), then swapped in
/// by the loop at a tick boundary.
fn reload(shared: &Shared, script: Option<&str>, by: String) -> Reply {
    let Some(reloader) = &shared.reloader else {
        return Reply::refused("this run cannot be reloaded");
    };
    match super::reload::reload(reloader, &shared.ask, script.map(Path::new), by) {
        Ok(()) => Reply::done(),
        Err(why) => Reply::refused(why),
    }
}

/// The reply to a request the loop does or refuses.
fn done(answer: Result<Answer, AskError>) -> Reply {
    match answer {
        Ok(Answer::Accepted) => Reply::done(),
        Ok(Answer::Refused(why)) => Reply::refused(why),
        Ok(Answer::Snapshot(_)) => Reply::refused("the run answered with a snapshot"),
        Err(e) => Reply::refused(e.to_string()),
    }
}

/// Who sent a request over the socket, for the log: `rigscript force (pid 7, uid 1000)`.
fn asker(client: &UnixStream, command: &str) -> String {
    match authority::peer(client) {
        Some(p) => format!("rigscript {command} (pid {}, uid {})", p.pid, p.uid),
        None => "a client of the control socket".to_string(),
    }
}

/// Sends the run's events, one JSON line each, until the client goes, the run ends, or the
/// socket closes; lost events are told as `{"event":"dropped","events":N}`.
fn stream_events(out: &mut UnixStream, shared: &Shared, closing: &Closing) {
    let who = authority::peer(out).map_or("socket client".to_string(), |p| {
        format!("socket client pid {}", p.pid)
    });
    let mut events = match shared.events.subscribe(&who, DEFAULT_QUEUE) {
        Ok(s) => s,
        Err(e) => {
            let _ = out.write_all(Reply::refused(e.to_string()).line().as_bytes());
            return;
        }
    };
    if out.write_all(Reply::done().line().as_bytes()).is_err() {
        return;
    }
    events.follow(
        Duration::from_millis(200),
        || closing.now(),
        |next| {
            let line = match next {
                Next::Event(event) => serde_json::to_string(&*event).unwrap_or_default() + "\n",
                Next::Dropped(lost) => format!("{{\"event\":\"dropped\",\"events\":{lost}}}\n"),
                Next::Quiet => return true,
            };
            out.write_all(line.as_bytes()).is_ok()
        },
    );
}
