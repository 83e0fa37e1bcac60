//! The systemd notification protocol (`sd_notify`), spoken directly: one datagram per message to
//! the socket named by `$NOTIFY_SOCKET` (a path, or an abstract name written with a leading
//! `@`), and the service watchdog systemd asks for with `$WATCHDOG_USEC` (for this process
//! unless `$WATCHDOG_PID` names another).
//!
//! Every send is non-blocking: a full or missing socket costs the scan loop nothing. A failed
//! send is counted and its first error kept for the end-of-run report; it never stops the run
//! (systemd notices missing watchdog pings by itself).

use std::cell::{Cell, RefCell};
use std::ffi::OsStr;
use std::io;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::net::{SocketAddr, UnixDatagram};
use std::time::Duration;

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

/// Sends notifications to systemd and feeds its watchdog from the scan loop.
pub struct Notifier {
    socket: UnixDatagram,
    address: SocketAddr,
    /// Half of the watchdog timeout, as sd_watchdog_enabled(3) advises.
    ping_every: Option<Duration>,
    last_ping: Cell<Option<Duration>>,
    sent: Cell<u64>,
    failed: Cell<u64>,
    first_error: RefCell<Option<String>>,
}

impl std::fmt::Debug for Notifier {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Notifier")
            .field("address", &self.address)
            .field("ping_every", &self.ping_every)
            .field("sent", &self.sent.get())
            .field("failed", &self.failed.get())
            .finish_non_exhaustive()
    }
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
            sent: Cell::new(0),
            failed: Cell::new(0),
            first_error: RefCell::new(None),
        })
    }

    /// How often the watchdog is fed (half of `WATCHDOG_USEC`), if systemd asked for it.
    pub fn ping_interval(&self) -> Option<Duration> {
        self.ping_every
    }

    /// `READY=1`: every device is under control and the script is running.
    pub fn ready(&self, status: &str) {
        self.send(&format!("READY=1\nSTATUS={}", one_line(status)));
    }

    /// `STOPPING=1`: the run is ending.
    pub fn stopping(&self, status: &str) {
        self.send(&format!("STOPPING=1\nSTATUS={}", one_line(status)));
    }

    /// `STATUS=...`: a line for `systemctl status`.
    pub fn status(&self, status: &str) {
        self.send(&format!("STATUS={}", one_line(status)));
    }

    /// Called from every turn of the scan loop at monotonic time `now`: sends `WATCHDOG=1`
    /// when half the watchdog timeout has passed since the last one (at once the first time).
    /// A loop that stops turning stops the pings, and systemd kills and restarts the service.
    pub fn loop_alive(&self, now: Duration) {
        let Some(every) = self.ping_every else {
            return;
        };
        let due = self
            .last_ping
            .get()
            .map_or(true, |last| now.saturating_sub(last) >= every);
        if due {
            self.last_ping.set(Some(now));
            self.send("WATCHDOG=1");
        }
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

    /// Messages sent so far.
    pub fn sent(&self) -> u64 {
        self.sent.get()
    }

    /// Messages that could not be sent so far.
    pub fn failed(&self) -> u64 {
        self.failed.get()
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
    fn watchdog_pings_come_at_half_the_timeout() {
        let (listener, path) = bound("ping");
        let n = Notifier::new(&NotifySettings {
            socket: path.as_os_str().as_bytes().to_vec(),
            watchdog: Some(Duration::from_millis(1000)),
        })
        .unwrap();
        assert_eq!(n.ping_interval(), Some(Duration::from_millis(500)));
        let ms = Duration::from_millis;
        n.loop_alive(ms(0));
        n.loop_alive(ms(499));
        n.loop_alive(ms(500));
        n.loop_alive(ms(900));
        n.loop_alive(ms(1000));
        listener.set_nonblocking(true).unwrap();
        let mut got = Vec::new();
        let mut buf = [0u8; 64];
        while let Ok(k) = listener.recv(&mut buf) {
            got.push(String::from_utf8_lossy(&buf[..k]).into_owned());
        }
        assert_eq!(got, ["WATCHDOG=1"; 3]);
        assert_eq!(n.sent(), 3);
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
        n.loop_alive(Duration::ZERO);
        n.stopping("stopped");
        assert_eq!(receive(&listener), "READY=1\nSTATUS=running x.rhai on io");
        assert_eq!(receive(&listener), "STOPPING=1\nSTATUS=stopped");
        assert_eq!(n.sent(), 2, "no watchdog asked for, none sent");
    }

    #[test]
    fn a_missing_socket_is_counted_not_fatal() {
        let n = Notifier::new(&NotifySettings {
            socket: b"/nonexistent/rigscript/notify".to_vec(),
            watchdog: Some(Duration::from_millis(10)),
        })
        .unwrap();
        n.ready("x");
        n.loop_alive(Duration::ZERO);
        assert_eq!((n.sent(), n.failed()), (0, 2));
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
            n.status("filling the queue");
        }
        assert!(n.failed() > 0, "the queue never filled");
        assert!(n.sent() > 0);
        drop(listener);
        std::fs::remove_file(path).unwrap();
    }
}
