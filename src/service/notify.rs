//! The systemd notification protocol (`sd_notify`), spoken directly: one datagram per message to
//! the socket named by `$NOTIFY_SOCKET` (a path, or an abstract name written with a leading
//! `@`), and the service watchdog systemd asks for with `$WATCHDOG_USEC` (for this process
//! unless `$WATCHDOG_PID` names another). Not the sd-notify crate: its 0.5 connects to
//! `$NOTIFY_SOCKET` as a path (no abstract names), opens a socket at every send and blocks on
//! it, and takes a malformed `$WATCHDOG_USEC` as no watchdog, without a word.
//!
//! A service like the others: a thread following the run's events (READY at the script's first
//! start, STOPPING at its end) that pings the watchdog only when the loop turned since its last
//! look (`Events::turns`, stored by the loop at every slice of its wait), so a loop stuck in a
//! handler stops the pings. Every send is non-blocking; a failed one is counted and its first
//! error kept for the end-of-run report; it never stops the run (systemd notices missing
//! watchdog pings by itself).

use crate::runtime::observe::{Bound, EventKind, Events, Kinds, Next, RunEvent};
use std::cell::{Cell, RefCell};
use std::ffi::OsStr;
use std::io;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::net::{SocketAddr, UnixDatagram};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Watches a ping interval holds: a ping follows a stall's end within one of them, and a
/// stalled loop's last ping came at most one of them after its last turn.
const CHECKS_PER_PING: u32 = 8;

/// The thread telling systemd of a run (`Notifier::attach`).
pub struct Notifying {
    /// The notifier back, and whether it owes STOPPING (it sent READY, the run's end did not
    /// come to it).
    thread: JoinHandle<(Notifier, bool)>,
    closing: Arc<AtomicBool>,
}

impl Notifying {
    /// Ends the thread once it told what the run's events hold, STOPPING with `status` if it
    /// owes it; a sentence on the notifications that could not be sent, if any.
    pub fn finish(self, status: i32) -> Option<String> {
        self.closing.store(true, Ordering::Relaxed);
        let (notifier, owed) = self.thread.join().ok()?;
        if owed {
            notifier.stopping(&format!("stopped; exit status {status}"));
        }
        notifier.failure_report()
    }
}

/// Why the notification settings in the environment cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum NotifyError {
    /// `$NOTIFY_SOCKET` is neither an absolute path nor an `@` abstract name.
    #[error(
        "NOTIFY_SOCKET={0:?} is not a socket path (/run/...) or an abstract name (@...); \
         not notifying systemd"
    )]
    Address(String),
    /// `$WATCHDOG_USEC` is not a positive number of microseconds.
    #[error(
        "WATCHDOG_USEC={0:?} is not a positive number of microseconds; not feeding the systemd \
         watchdog (set WatchdogSec= in the unit)"
    )]
    WatchdogUsec(String),
    /// The socket to send from cannot be made.
    #[error("cannot make a socket to notify systemd: {0}")]
    Socket(#[source] io::Error),
    /// The thread that tells systemd cannot follow the run.
    #[error("cannot notify systemd: {0}")]
    Attach(String),
}

/// Where systemd listens, and the watchdog it expects; read from the environment.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NotifySettings {
    /// The socket address as `$NOTIFY_SOCKET` gives it.
    pub socket: Vec<u8>,
    /// The systemd watchdog timeout, when it applies to this process.
    pub watchdog: Option<Duration>,
}

impl NotifySettings {
    /// Reads `$NOTIFY_SOCKET`, `$WATCHDOG_USEC` and `$WATCHDOG_PID`; `Ok(None)` when systemd
    /// did not ask for notifications (no `$NOTIFY_SOCKET`, as when run by hand).
    pub fn from_env() -> Result<Option<Self>, NotifyError> {
        Self::from_values(
            std::env::var_os("NOTIFY_SOCKET").as_deref(),
            std::env::var_os("WATCHDOG_USEC").as_deref(),
            std::env::var_os("WATCHDOG_PID").as_deref(),
            std::process::id(),
        )
    }

    /// The settings these environment values give to process `pid`.
    pub fn from_values(
        socket: Option<&OsStr>,
        watchdog_usec: Option<&OsStr>,
        watchdog_pid: Option<&OsStr>,
        pid: u32,
    ) -> Result<Option<Self>, NotifyError> {
        let Some(socket) = socket.filter(|s| !s.is_empty()) else {
            return Ok(None);
        };
        let bytes = socket.as_bytes();
        if !matches!(bytes.first(), Some(b'/' | b'@')) || bytes.len() < 2 {
            return Err(NotifyError::Address(socket.to_string_lossy().into_owned()));
        }
        // A watchdog meant for another process (a wrapper's child, say) is not ours to feed.
        let ours = watchdog_pid
            .map(|p| p.to_string_lossy().trim().parse::<u32>() == Ok(pid))
            .unwrap_or(true);
        let watchdog = match watchdog_usec.filter(|_| ours) {
            None => None,
            Some(text) => {
                let text = text.to_string_lossy();
                match text.trim().parse::<u64>() {
                    Ok(usec) if usec > 0 => Some(Duration::from_micros(usec)),
                    _ => return Err(NotifyError::WatchdogUsec(text.into_owned())),
                }
            }
        };
        Ok(Some(Self {
            socket: bytes.to_vec(),
            watchdog,
        }))
    }
}

/// Sends notifications to systemd and feeds its watchdog while the scan loop turns.
pub struct Notifier {
    socket: UnixDatagram,
    address: SocketAddr,
    /// Half of the watchdog timeout, as sd_watchdog_enabled(3) advises.
    ping_every: Option<Duration>,
    last_ping: Cell<Option<Duration>>,
    /// The loop's turns at the last `watch`.
    turns: Cell<Option<u64>>,
    sent: Cell<u64>,
    failed: Cell<u64>,
    first_error: RefCell<Option<String>>,
}

impl Notifier {
    /// A notifier for the environment's settings; `Ok(None)` when systemd asked for none.
    pub fn from_env() -> Result<Option<Self>, NotifyError> {
        NotifySettings::from_env()?
            .map(|s| Self::new(&s))
            .transpose()
    }

    /// A notifier sending to `settings.socket`.
    pub fn new(settings: &NotifySettings) -> Result<Self, NotifyError> {
        let address = socket_address(&settings.socket).map_err(NotifyError::Socket)?;
        let socket = UnixDatagram::unbound().map_err(NotifyError::Socket)?;
        socket.set_nonblocking(true).map_err(NotifyError::Socket)?;
        Ok(Self {
            socket,
            address,
            ping_every: settings.watchdog.map(|w| w / 2),
            last_ping: Cell::new(None),
            turns: Cell::new(None),
            sent: Cell::new(0),
            failed: Cell::new(0),
            first_error: RefCell::new(None),
        })
    }

    /// `READY=1`: every device is under control and the script is running.
    pub fn ready(&self, status: &str) {
        self.send(&format!("READY=1\nSTATUS={}", one_line(status)));
    }

    /// `STOPPING=1`: the run is ending.
    pub fn stopping(&self, status: &str) {
        self.send(&format!("STOPPING=1\nSTATUS={}", one_line(status)));
    }

    /// Called at every watch (`CHECKS_PER_PING` a ping interval) at monotonic time `now`, with
    /// the loop's `turns` so far (`Events::turns`): sends `WATCHDOG=1` when half the watchdog
    /// timeout has passed since the last one (at once the first time) and the loop turned
    /// since the watch before. A loop that stops turning stops the pings, and systemd kills
    /// and restarts the service.
    pub fn watch(&self, turns: u64, now: Duration) {
        let turned = self.turns.replace(Some(turns)).is_some_and(|t| t != turns);
        let Some(every) = self.ping_every else {
            return;
        };
        let due = self
            .last_ping
            .get()
            .map_or(true, |last| now.saturating_sub(last) >= every);
        if due && turned {
            self.last_ping.set(Some(now));
            self.send("WATCHDOG=1");
        }
    }

    /// How often `watch` should be called.
    fn watch_every(&self) -> Duration {
        self.ping_every
            .map_or(Duration::from_millis(200), |every| every / CHECKS_PER_PING)
            .max(Duration::from_millis(1))
    }

    /// Tells systemd of the run whose `events` these are, from a thread of its own: READY
    /// (with `status`) once the script's top level first ran, which is once every device is
    /// under control; `WATCHDOG=1` while the loop turns; STOPPING at its end. Attach before
    /// the top level runs.
    pub fn attach(self, events: &Events, status: String) -> Result<Notifying, NotifyError> {
        let kinds = Kinds::of(&[EventKind::ScriptStarted, EventKind::Ended]);
        let mut subscription = events
            .subscribe_to("systemd", Bound::events(4), kinds)
            .map_err(|e| NotifyError::Attach(e.to_string()))?;
        let closing = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&closing);
        let events = events.clone();
        let thread = std::thread::Builder::new()
            .name("systemd-notify".into())
            .spawn(move || {
                let started = Instant::now();
                let (mut ready, mut stopped) = (false, false);
                subscription.follow(
                    self.watch_every(),
                    || flag.load(Ordering::Relaxed),
                    |next| {
                        if let Next::Event(event) = next {
                            match &*event {
                                RunEvent::ScriptStarted { restarts: 0, .. } => {
                                    self.ready(&status);
                                    ready = true;
                                }
                                RunEvent::Ended { status, .. } => {
                                    self.stopping(&format!("stopped; exit status {status}"));
                                    stopped = true;
                                    return false;
                                }
                                _ => {}
                            }
                        }
                        if ready {
                            self.watch(events.turns(), started.elapsed());
                        }
                        true
                    },
                );
                (self, ready && !stopped)
            })
            .map_err(|e| NotifyError::Attach(e.to_string()))?;
        Ok(Notifying { thread, closing })
    }

    /// Sends one message without blocking; a failure is counted, never raised.
    pub fn send(&self, message: &str) -> bool {
        match self.socket.send_to_addr(message.as_bytes(), &self.address) {
            Ok(_) => {
                self.sent.set(self.sent.get().saturating_add(1));
                true
            }
            Err(e) => {
                self.failed.set(self.failed.get().saturating_add(1));
                let mut first = self.first_error.borrow_mut();
                if first.is_none() {
                    *first = Some(format!("{}: {e}", message.lines().next().unwrap_or("")));
                }
                false
            }
        }
    }

    /// A sentence on failed sends for the end-of-run log, if any failed.
    pub fn failure_report(&self) -> Option<String> {
        let failed = self.failed.get();
        (failed > 0).then(|| {
            format!(
                "{failed} of {} notifications to systemd could not be sent (first: {}); \
                 systemd may have restarted or killed the service for a missed watchdog",
                failed.saturating_add(self.sent.get()),
                self.first_error.borrow().as_deref().unwrap_or("?")
            )
        })
    }
}

/// A message value on one line: newlines would start new assignments.
fn one_line(text: &str) -> String {
    text.replace(['\n', '\r'], " ")
}

/// The socket address `$NOTIFY_SOCKET` names: `@name` is in the abstract namespace.
fn socket_address(name: &[u8]) -> io::Result<SocketAddr> {
    match name.split_first() {
        Some((b'@', abstract_name)) => abstract_address(abstract_name),
        _ => SocketAddr::from_pathname(OsStr::from_bytes(name)),
    }
}

#[cfg(any(target_os = "linux", target_os = "android"))]
fn abstract_address(name: &[u8]) -> io::Result<SocketAddr> {
    #[cfg(target_os = "android")]
    use std::os::android::net::SocketAddrExt;
    #[cfg(target_os = "linux")]
    use std::os::linux::net::SocketAddrExt;
    SocketAddr::from_abstract_name(name)
}

#[cfg(not(any(target_os = "linux", target_os = "android")))]
fn abstract_address(_name: &[u8]) -> io::Result<SocketAddr> {
    Err(io::Error::new(
        io::ErrorKind::Unsupported,
        "abstract socket names exist on Linux only",
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(socket: &str, usec: Option<&str>, pid: Option<&str>) -> Option<NotifySettings> {
        NotifySettings::from_values(
            Some(OsStr::new(socket)),
            usec.map(OsStr::new),
            pid.map(OsStr::new),
            4242,
        )
        .unwrap()
    }

    #[test]
    fn the_environment_is_read_as_systemd_writes_it() {
        let s = settings("/run/systemd/notify", Some("10000000"), None).unwrap();
        assert_eq!(s.socket, b"/run/systemd/notify");
        assert_eq!(s.watchdog, Some(Duration::from_secs(10)));
        let s = settings("@abstract", Some("500000"), Some("4242")).unwrap();
        assert_eq!(s.watchdog, Some(Duration::from_millis(500)));
        // Another process's watchdog: notify, but do not feed it.
        let s = settings("@abstract", Some("500000"), Some("17")).unwrap();
        assert_eq!(s.watchdog, None);
        assert!(
            NotifySettings::from_values(None, Some(OsStr::new("1")), None, 1)
                .unwrap()
                .is_none(),
            "no socket, no notifications"
        );
        assert!(
            NotifySettings::from_values(Some(OsStr::new("")), None, None, 1)
                .unwrap()
                .is_none()
        );
    }

    #[test]
    fn bad_values_are_refused_with_what_to_do() {
        let e = NotifySettings::from_values(Some(OsStr::new("vsock:2:1")), None, None, 1)
            .unwrap_err()
            .to_string();
        assert!(e.contains("\"vsock:2:1\" is not a socket path"), "{e}");
        for bad in ["0", "-5", "ten", ""] {
            let e = NotifySettings::from_values(
                Some(OsStr::new("/run/n")),
                Some(OsStr::new(bad)),
                None,
                1,
            )
            .unwrap_err()
            .to_string();
            assert!(e.contains("WatchdogSec="), "{bad}: {e}");
        }
    }

    fn bound(tag: &str) -> (UnixDatagram, std::path::PathBuf) {
        let path = std::env::temp_dir().join(format!(
            "rigscript-notify-{tag}-{}.sock",
            std::process::id()
        ));
        let _ = std::fs::remove_file(&path);
        let socket = UnixDatagram::bind(&path).unwrap();
        socket
            .set_read_timeout(Some(Duration::from_secs(2)))
            .unwrap();
        (socket, path)
    }

    fn receive(socket: &UnixDatagram) -> String {
        let mut buf = [0u8; 512];
        let n = socket.recv(&mut buf).unwrap();
        String::from_utf8_lossy(&buf[..n]).into_owned()
    }

    #[test]
    fn watchdog_pings_come_at_half_the_timeout_while_the_loop_turns() {
        let (listener, path) = bound("ping");
        let n = Notifier::new(&NotifySettings {
            socket: path.as_os_str().as_bytes().to_vec(),
            watchdog: Some(Duration::from_millis(1000)),
        })
        .unwrap();
        assert_eq!(n.ping_every, Some(Duration::from_millis(500)));
        let ms = Duration::from_millis;
        n.watch(0, ms(0));
        n.watch(1, ms(1));
        n.watch(2, ms(499));
        n.watch(3, ms(500));
        n.watch(4, ms(900));
        // The loop stands still: no ping, however long since the last.
        n.watch(4, ms(1000));
        n.watch(4, ms(1400));
        n.watch(5, ms(1401));
        listener.set_nonblocking(true).unwrap();
        let mut got = Vec::new();
        let mut buf = [0u8; 64];
        while let Ok(k) = listener.recv(&mut buf) {
            got.push(String::from_utf8_lossy(&buf[..k]).into_owned());
        }
        assert_eq!(got, ["WATCHDOG=1"; 3]);
        assert_eq!(n.sent.get(), 3);
        std::fs::remove_file(path).unwrap();
    }

    #[test]
    fn messages_reach_an_abstract_socket_on_one_line_each() {
        let name = format!("rigscript-notify-test-{}", std::process::id());
        let address = abstract_address(name.as_bytes()).unwrap();
        let listener = UnixDatagram::bind_addr(&address).unwrap();
        listener
            .set_read_timeout(Some(Duration::from_secs(2)))
            .unwrap();
        let n = Notifier::new(&NotifySettings {
            socket: format!("@{name}").into_bytes(),
            watchdog: None,
        })
        .unwrap();
        n.ready("running x.rhai\non io");
        n.watch(0, Duration::ZERO);
        n.watch(1, Duration::from_secs(1));
        n.stopping("stopped");
        assert_eq!(receive(&listener), "READY=1\nSTATUS=running x.rhai on io");
        assert_eq!(receive(&listener), "STOPPING=1\nSTATUS=stopped");
        assert_eq!(n.sent.get(), 2, "no watchdog asked for, none sent");
    }

    #[test]
    fn a_missing_socket_is_counted_not_fatal() {
        let n = Notifier::new(&NotifySettings {
            socket: b"/nonexistent/rigscript/notify".to_vec(),
            watchdog: Some(Duration::from_millis(10)),
        })
        .unwrap();
        n.ready("x");
        n.watch(0, Duration::ZERO);
        n.watch(1, Duration::ZERO);
        assert_eq!((n.sent.get(), n.failed.get()), (0, 2));
        let report = n.failure_report().unwrap();
        assert!(report.starts_with("2 of 2 notifications"), "{report}");
        assert!(report.contains("READY=1: "), "{report}");
    }

    #[test]
    fn a_full_socket_does_not_block_the_sender() {
        let (listener, path) = bound("full");
        let n = Notifier::new(&NotifySettings {
            socket: path.as_os_str().as_bytes().to_vec(),
            watchdog: None,
        })
        .unwrap();
        // Nobody reads: the queue fills, and later sends fail at once (a blocking send would
        // hang here).
        for _ in 0..10_000 {
            n.send("STATUS=filling the queue");
        }
        assert!(n.failed.get() > 0, "the queue never filled");
        assert!(n.sent.get() > 0);
        drop(listener);
        std::fs::remove_file(path).unwrap();
    }
}
