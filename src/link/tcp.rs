//! A TCP link carrying the same bytes to a serial device server (`tcp://host:port`, ser2net,
//! RS-485 gateways).

use super::fd::{self, Read};
use super::line::LineState;
use super::{ByteLink, LinkError, Watch};
use std::io;
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::os::fd::AsRawFd;
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// The scheme prefix that selects a TCP link in a port argument.
pub const SCHEME: &str = "tcp://";

/// How long a write may wait for room in the socket: a server that takes no data for this
/// long is failed rather than allowed to hold the caller (a SIGTERM's safe-state write too).
pub const WRITE_TIMEOUT: Duration = Duration::from_millis(500);

/// An open TCP connection to a serial device server.
pub struct TcpLink {
    stream: TcpStream,
    address: String,
    // The device server times its own serial line: nothing is added here.
    line: LineState,
}

/// Resolves `address`, giving up after `timeout`: the system resolver has no timeout of its own
/// (a dead DNS server holds it for tens of seconds), so it runs on a thread of its own that is
/// left to finish by itself when it is too slow.
fn resolve(address: &str, timeout: Duration) -> io::Result<Vec<SocketAddr>> {
    resolve_with(address, timeout, |name| {
        name.to_socket_addrs().map(Iterator::collect)
    })
}

fn resolve_with(
    address: &str,
    timeout: Duration,
    resolver: impl FnOnce(String) -> io::Result<Vec<SocketAddr>> + Send + 'static,
) -> io::Result<Vec<SocketAddr>> {
    let (tx, rx) = mpsc::channel();
    let name = address.to_string();
    std::thread::Builder::new()
        .name("resolve".into())
        .spawn(move || {
            let _ = tx.send(resolver(name));
        })?;
    rx.recv_timeout(timeout).unwrap_or_else(|_| {
        Err(io::Error::new(
            io::ErrorKind::TimedOut,
            format!("the name did not resolve within {timeout:?}"),
        ))
    })
}

impl TcpLink {
    /// Connects to `address` (`host:port`, or `tcp://host:port`), giving up after `timeout`
    /// (name resolution and connection together).
    pub fn connect(address: &str, timeout: Duration) -> Result<Self, LinkError> {
        // A connection blocks the loop for up to its timeout: its watcher allows for that.
        crate::guardian::pulse::allow(timeout);
        let connected = Self::connect_within(address, timeout);
        crate::guardian::pulse::allow(Duration::ZERO);
        connected
    }

    fn connect_within(address: &str, timeout: Duration) -> Result<Self, LinkError> {
        let address = address.strip_prefix(SCHEME).unwrap_or(address).to_string();
        let what = format!("serial device server {address}");
        let deadline = Instant::now() + timeout;
        let candidates = resolve(&address, timeout).map_err(|e| LinkError::NotFound {
            what: what.clone(),
            hint: format!("{e}; write it as tcp://HOST:PORT"),
        })?;
        let mut last = None;
        for candidate in candidates {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                last = Some(io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!("no connection within {timeout:?}"),
                ));
                break;
            }
            match TcpStream::connect_timeout(&candidate, left) {
                Ok(stream) => {
                    let io = |source| LinkError::Io {
                        what: what.clone(),
                        source,
                    };
                    // Frames are small and latency-bound; never wait to coalesce them.
                    stream.set_nodelay(true).map_err(io)?;
                    stream.set_nonblocking(true).map_err(io)?;
                    return Ok(Self {
                        stream,
                        address,
                        line: LineState::untimed(),
                    });
                }
                Err(e) => last = Some(e),
            }
        }
        Err(LinkError::NotFound {
            what,
            hint: match last {
                Some(e) => format!("{e}; check the host, the port and that the server is running"),
                None => "the name resolved to no address".into(),
            },
        })
    }

    fn io_error(&self, e: io::Error) -> LinkError {
        let what = format!("serial device server {}", self.address);
        match e.kind() {
            io::ErrorKind::ConnectionReset
            | io::ErrorKind::ConnectionAborted
            | io::ErrorKind::BrokenPipe
            | io::ErrorKind::UnexpectedEof => LinkError::Disconnected {
                what,
                detail: format!("{e}; check the server and the network"),
            },
            _ => LinkError::Io { what, source: e },
        }
    }
}

impl ByteLink for TcpLink {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        fd::write_all_within(self.stream.as_raw_fd(), bytes, WRITE_TIMEOUT)
            .map_err(|e| self.io_error(e))
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError> {
        match fd::read_within(self.stream.as_raw_fd(), buf, timeout) {
            Ok(Read::Bytes(n)) => Ok(n),
            Ok(Read::Nothing) => Ok(0),
            Ok(Read::Closed) => Err(self.io_error(io::ErrorKind::UnexpectedEof.into())),
            Err(e) => Err(self.io_error(e)),
        }
    }

    fn set_baud(&mut self, _baud: u32) -> Result<(), LinkError> {
        // The device server owns the line speed (configured on the server, or by RFC 2217).
        Ok(())
    }

    fn describe(&self) -> String {
        format!("tcp://{}", self.address)
    }

    fn line(&mut self) -> Option<&mut LineState> {
        Some(&mut self.line)
    }

    fn watch(&self) -> Option<Watch> {
        Some(Watch {
            fd: self.stream.as_raw_fd(),
            socket: true,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Read as _, Write as _};
    use std::net::TcpListener;

    #[test]
    fn round_trip_stale_input_and_server_close() {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let port = listener.local_addr().unwrap().port();
        let server = std::thread::spawn(move || {
            let (mut s, _) = listener.accept().unwrap();
            s.write_all(b"stale").unwrap();
            let mut buf = [0u8; 4];
            s.read_exact(&mut buf).unwrap();
            assert_eq!(&buf, b"ping");
            s.write_all(b"pong").unwrap();
            s.read_exact(&mut buf[..1]).unwrap();
        });
        let mut link =
            TcpLink::connect(&format!("tcp://127.0.0.1:{port}"), Duration::from_secs(2)).unwrap();
        let mut buf = [0u8; 8];
        assert_eq!(link.read(&mut buf, Duration::from_secs(2)).unwrap(), 5);
        assert_eq!(&buf[..5], b"stale");
        assert_eq!(
            link.read(&mut buf, Duration::ZERO).unwrap(),
            0,
            "a look finds nothing more"
        );
        link.write_all(b"ping").unwrap();
        let mut got = Vec::new();
        while got.len() < 4 {
            let n = link.read(&mut buf, Duration::from_secs(2)).unwrap();
            assert!(n > 0, "answer did not arrive");
            got.extend_from_slice(&buf[..n]);
        }
        assert_eq!(got, b"pong");
        link.write_all(b"x").unwrap();
        server.join().unwrap();
        match link.read(&mut buf, Duration::from_secs(2)) {
            Err(LinkError::Disconnected { .. }) => {}
            other => panic!("expected Disconnected, got {other:?}"),
        }
    }

    #[test]
    fn refused_connection_is_not_found_with_a_hint() {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let port = listener.local_addr().unwrap().port();
        drop(listener);
        match TcpLink::connect(&format!("127.0.0.1:{port}"), Duration::from_secs(1)) {
            Err(LinkError::NotFound { hint, .. }) => assert!(hint.contains("server")),
            Err(e) => panic!("unexpected error {e}"),
            Ok(_) => panic!("connected to a closed port"),
        }
    }

    #[test]
    fn a_server_that_takes_no_data_fails_the_write_in_bounded_time() {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let port = listener.local_addr().unwrap().port();
        let (hold_tx, hold_rx) = mpsc::channel::<()>();
        let server = std::thread::spawn(move || {
            let (_s, _) = listener.accept().unwrap();
            let _ = hold_rx.recv();
        });
        let mut link =
            TcpLink::connect(&format!("127.0.0.1:{port}"), Duration::from_secs(2)).unwrap();
        let started = Instant::now();
        let chunk = vec![0u8; 1 << 20];
        let err = (0..256)
            .find_map(|_| link.write_all(&chunk).err())
            .expect("a socket nobody reads fills up");
        assert!(
            matches!(err, LinkError::Io { ref source, .. } if source.kind() == io::ErrorKind::TimedOut),
            "{err}"
        );
        assert!(started.elapsed() < Duration::from_secs(30));
        drop(hold_tx);
        server.join().unwrap();
    }

    #[test]
    fn a_resolver_that_hangs_is_given_up_on() {
        let started = Instant::now();
        let err = resolve_with("slow.example:1", Duration::from_millis(50), |_| {
            std::thread::sleep(Duration::from_secs(5));
            Ok(Vec::new())
        })
        .unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::TimedOut);
        assert!(started.elapsed() < Duration::from_secs(4));
    }
}
