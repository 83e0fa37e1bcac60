//! A serial port link (8N1, no flow control): USB-serial adapters and ptys. `serialport` opens
//! and configures the port; bytes move through `link::fd` with one system call per step (no
//! flush of input, no wait for output to drain: the exchange layer times the line itself).

use super::fd::{self, Read};
use super::line::LineState;
use super::{ByteLink, LinkError, Watch};
use serialport::{DataBits, FlowControl, Parity, SerialPort, StopBits, TTYPort};
use std::io;
use std::os::fd::AsRawFd;
use std::time::Duration;

/// How long a write may wait for room in the port's output buffer: frames are a few dozen
/// bytes and leave in milliseconds, so a port that takes none for this long (a stalled
/// adapter) is failed rather than allowed to hold the caller, a SIGTERM included.
pub const WRITE_TIMEOUT: Duration = Duration::from_millis(500);

/// An open serial port.
pub struct SerialLink {
    port: TTYPort,
    path: String,
    line: LineState,
}

impl SerialLink {
    /// Opens `path` at `baud`, 8 data bits, no parity, 1 stop bit, no flow control.
    pub fn open(path: &str, baud: u32) -> Result<Self, LinkError> {
        let port = serialport::new(path, baud)
            .data_bits(DataBits::Eight)
            .parity(Parity::None)
            .stop_bits(StopBits::One)
            .flow_control(FlowControl::None)
            .timeout(Duration::from_millis(100))
            .open_native()
            .map_err(|e| open_error(path, e))?;
        fd::set_nonblocking(port.as_raw_fd()).map_err(|source| LinkError::Io {
            what: format!("serial port {path}"),
            source,
        })?;
        Ok(Self {
            port,
            path: path.to_string(),
            line: LineState::serial(baud),
        })
    }

    /// serialport reports a failed ioctl (termios) without its errno (EIO becomes
    /// "Unknown"), so a device node that has vanished is what tells a hangup from other trouble.
    fn port_error(&self, e: serialport::Error) -> LinkError {
        let io = match e.kind() {
            serialport::ErrorKind::Io(kind) => io::Error::new(kind, e.description),
            _ => io::Error::other(e.description),
        };
        if std::path::Path::new(&self.path).exists() {
            self.io_error(io)
        } else {
            LinkError::Disconnected {
                what: format!("serial port {}", self.path),
                detail: format!(
                    "{io}; the device is gone: check the cable and that the adapter is still plugged in"
                ),
            }
        }
    }

    fn io_error(&self, e: io::Error) -> LinkError {
        if is_disconnect(&e) {
            LinkError::Disconnected {
                what: format!("serial port {}", self.path),
                detail: format!("{e}; check the cable and that the adapter is still plugged in"),
            }
        } else {
            LinkError::Io {
                what: format!("serial port {}", self.path),
                source: e,
            }
        }
    }
}

/// True for the errors a tty gives once its device (or a pty's other end) has gone away.
fn is_disconnect(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::BrokenPipe | io::ErrorKind::NotConnected | io::ErrorKind::UnexpectedEof
    ) || matches!(
        e.raw_os_error(),
        Some(5 /* EIO */ | 6 /* ENXIO */ | 19 /* ENODEV */)
    )
}

fn open_error(path: &str, e: serialport::Error) -> LinkError {
    let what = format!("serial port {path}");
    match e.kind() {
        // serialport's word for EBUSY at open (TIOCEXCL) and for a refused flock.
        serialport::ErrorKind::NoDevice => LinkError::Busy {
            what,
            holders: Box::new(super::holders::holders_of(std::path::Path::new(path))),
        },
        serialport::ErrorKind::Io(io::ErrorKind::NotFound) => LinkError::NotFound {
            what,
            hint: "check the path and that the module is plugged in (`rigscript scan` lists ports)"
                .into(),
        },
        serialport::ErrorKind::Io(io::ErrorKind::PermissionDenied) => LinkError::PermissionDenied {
            what,
            hint: "add your user to the `dialout` group (see README) and log in again".into(),
        },
        _ => match not_a_tty(path, &e) {
            Some(detail) => LinkError::NotSerial {
                path: path.to_string(),
                detail,
            },
            None => LinkError::Io {
                what,
                source: io::Error::other(e.description),
            },
        },
    }
}

/// What `path` is instead of a terminal, when the open failed because it is none (serialport
/// passes on ENOTTY only as nix's text for it).
fn not_a_tty(path: &str, e: &serialport::Error) -> Option<String> {
    use std::os::unix::fs::FileTypeExt;
    let kind = std::fs::metadata(path).ok()?.file_type();
    if kind.is_file() {
        Some("it is an ordinary file".into())
    } else if kind.is_dir() {
        Some("it is a directory".into())
    } else if !kind.is_char_device() {
        Some("it is not a character device".into())
    } else if e.description.contains("typewriter") || e.description.contains("ioctl") {
        Some("it is a device, but not a terminal".into())
    } else {
        None
    }
}

impl ByteLink for SerialLink {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        fd::write_all_within(self.port.as_raw_fd(), bytes, WRITE_TIMEOUT)
            .map_err(|e| self.io_error(e))
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError> {
        match fd::read_within(self.port.as_raw_fd(), buf, timeout) {
            Ok(Read::Bytes(n)) => Ok(n),
            Ok(Read::Nothing) => Ok(0),
            // A tty that polls readable and then reads nothing has hung up.
            Ok(Read::Closed) => Err(self.io_error(io::Error::from(io::ErrorKind::UnexpectedEof))),
            Err(e) => Err(self.io_error(e)),
        }
    }

    fn set_baud(&mut self, baud: u32) -> Result<(), LinkError> {
        self.port
            .set_baud_rate(baud)
            .map_err(|e| self.port_error(e))?;
        self.line.baud = Some(baud);
        Ok(())
    }

    fn describe(&self) -> String {
        format!(
            "serial port {} at {} baud",
            self.path,
            self.line.baud.unwrap_or_default()
        )
    }

    fn line(&mut self) -> Option<&mut LineState> {
        Some(&mut self.line)
    }

    fn watch(&self) -> Option<Watch> {
        Some(Watch {
            fd: self.port.as_raw_fd(),
            socket: false,
        })
    }
}

impl Drop for SerialLink {
    fn drop(&mut self) {
        // TIOCEXCL outlives our descriptor while another process (a simulator) keeps the tty
        // open, which would lock out the next non-root opener; release it explicitly.
        let _ = self.port.set_exclusive(false);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn missing_port_is_not_found_with_a_hint() {
        match SerialLink::open("/dev/does-not-exist-rigscript", 9600) {
            Err(LinkError::NotFound { what, hint }) => {
                assert!(what.contains("/dev/does-not-exist-rigscript"));
                assert!(hint.contains("scan"));
            }
            Err(other) => panic!("expected NotFound, got {other}"),
            Ok(_) => panic!("opened a port that does not exist"),
        }
    }

    #[test]
    fn a_port_another_opener_holds_is_busy_and_names_the_holder() {
        let (_master, slave) = TTYPort::pair().unwrap();
        let path = slave.name().unwrap();
        let first = SerialLink::open(&path, 9600).unwrap();
        match SerialLink::open(&path, 9600) {
            Err(e @ LinkError::Busy { .. }) => {
                let text = e.to_string();
                assert!(
                    text.starts_with(&format!("serial port {path} is busy: another program holds it exclusively (held by this process, pid {}", std::process::id())),
                    "{text}"
                );
                assert!(!text.contains("not found"), "{text}");
            }
            Err(other) => panic!("expected Busy, got {other}"),
            Ok(_) => panic!("opened a port held exclusively"),
        }
        drop(first);
        assert!(
            SerialLink::open(&path, 9600).is_ok(),
            "free again once released"
        );
    }

    #[test]
    fn a_file_or_directory_is_not_a_serial_port() {
        for (path, what) in [
            ("/etc/passwd", "an ordinary file"),
            ("/tmp", "a directory"),
            ("/dev/null", "a device, but not a terminal"),
        ] {
            match SerialLink::open(path, 9600) {
                Err(e @ LinkError::NotSerial { .. }) => {
                    let text = e.to_string();
                    assert!(
                        text.contains(&format!("{path} is not a serial port (it is {what})")),
                        "{text}"
                    );
                    assert!(!text.contains("typewriter"), "{text}");
                }
                Err(other) => panic!("{path}: expected NotSerial, got {other}"),
                Ok(_) => panic!("{path} opened as a serial port"),
            }
        }
    }

    #[test]
    fn pty_round_trip_timeout_and_hangup() {
        use std::io::{Read as _, Write as _};
        let (mut master, slave) = TTYPort::pair().unwrap();
        let path = slave.name().unwrap();
        let mut link = SerialLink::open(&path, 9600).unwrap();
        link.write_all(b"ping").unwrap();
        let mut buf = [0u8; 8];
        master.set_timeout(Duration::from_secs(2)).unwrap();
        let n = master.read(&mut buf).unwrap();
        assert_eq!(&buf[..n], b"ping");
        assert_eq!(
            link.read(&mut buf, Duration::from_millis(20)).unwrap(),
            0,
            "timeout reads nothing"
        );
        master.write_all(b"pong").unwrap();
        let n = link.read(&mut buf, Duration::from_secs(2)).unwrap();
        assert_eq!(&buf[..n], b"pong");
        assert!(link.describe().contains(&path));
        drop(master);
        drop(slave);
        match link.read(&mut buf, Duration::from_millis(200)) {
            Err(LinkError::Disconnected { .. }) => {}
            other => panic!("expected Disconnected after the far end closed, got {other:?}"),
        }
        match link.read(&mut buf, Duration::ZERO) {
            Err(LinkError::Disconnected { .. }) => {}
            other => panic!("expected Disconnected from a look after hangup, got {other:?}"),
        }
        match link.write_all(b"x") {
            Err(LinkError::Disconnected { .. }) => {}
            other => panic!("expected Disconnected from a write after hangup, got {other:?}"),
        }
    }

    #[test]
    fn writes_never_wait_for_the_line_to_drain_and_give_up_when_it_takes_nothing() {
        // Nobody reads the far end: a tcdrain would wait for ever.
        let (_master, slave) = TTYPort::pair().unwrap();
        let path = slave.name().unwrap();
        let (done, outcome) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut link = SerialLink::open(&path, 9600).unwrap();
            let small = link.write_all(b"01 01 00 20");
            let big = (0..64).find_map(|_| link.write_all(&[0u8; 65536]).err());
            let _ = done.send((small.is_ok(), big.map(|e| e.to_string())));
        });
        let (small, big) = outcome
            .recv_timeout(Duration::from_secs(20))
            .expect("the writes returned");
        assert!(
            small,
            "a frame is handed over without waiting for it to leave"
        );
        let big = big.expect("a port that takes nothing fails the write");
        assert!(big.contains("takes no data"), "{big}");
    }
}
