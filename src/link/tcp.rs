//! A TCP link carrying the same bytes to a serial device server (`tcp://host:port`, ser2net,
//! RS-485 gateways).

use super::{ByteLink, LinkError};
use std::io::{self, Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::time::Duration;

/// The scheme prefix that selects a TCP link in a port argument.
pub const SCHEME: &str = "tcp://";

/// An open TCP connection to a serial device server.
pub struct TcpLink {
    stream: TcpStream,
    address: String,
}

impl TcpLink {
    /// Connects to `address` (`host:port`, or `tcp://host:port`), giving up after `timeout`.
    pub fn connect(address: &str, timeout: Duration) -> Result<Self, LinkError> {
        let address = address.strip_prefix(SCHEME).unwrap_or(address).to_string();
        let what = format!("serial device server {address}");
        let candidates: Vec<SocketAddr> = address
            .to_socket_addrs()
            .map_err(|e| LinkError::NotFound {
                what: what.clone(),
                hint: format!("{e}; write it as tcp://HOST:PORT"),
            })?
            .collect();
        let mut last = None;
        for candidate in candidates {
            match TcpStream::connect_timeout(&candidate, timeout) {
                Ok(stream) => {
                    // Frames are small and latency-bound; never wait to coalesce them.
                    stream.set_nodelay(true).map_err(|source| LinkError::Io {
                        what: what.clone(),
                        source,
                    })?;
                    return Ok(Self { stream, address });
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
        self.stream.write_all(bytes).map_err(|e| self.io_error(e))
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError> {
        // A zero read timeout means "block forever" to the OS; the smallest real wait instead.
        let timeout = timeout.max(Duration::from_micros(1));
        self.stream
            .set_read_timeout(Some(timeout))
            .map_err(|e| self.io_error(e))?;
        match self.stream.read(buf) {
            Ok(0) if !buf.is_empty() => Err(self.io_error(io::ErrorKind::UnexpectedEof.into())),
            Ok(n) => Ok(n),
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                Ok(0)
            }
            Err(e) => Err(self.io_error(e)),
        }
    }

    fn discard_input(&mut self) -> Result<(), LinkError> {
        self.stream
            .set_nonblocking(true)
            .map_err(|e| self.io_error(e))?;
        let mut scratch = [0u8; 256];
        let outcome = loop {
            match self.stream.read(&mut scratch) {
                Ok(0) => break Err(self.io_error(io::ErrorKind::UnexpectedEof.into())),
                Ok(_) => continue,
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => break Ok(()),
                Err(e) => break Err(self.io_error(e)),
            }
        };
        self.stream
            .set_nonblocking(false)
            .map_err(|e| self.io_error(e))?;
        outcome
    }

    fn set_baud(&mut self, _baud: u32) -> Result<(), LinkError> {
        // The device server owns the line speed (configured on the server, or by RFC 2217).
        Ok(())
    }

    fn describe(&self) -> String {
        format!("tcp://{}", self.address)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::net::TcpListener;

    #[test]
    fn round_trip_discard_and_server_close() {
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
        std::thread::sleep(Duration::from_millis(50));
        link.discard_input().unwrap();
        link.write_all(b"ping").unwrap();
        let mut buf = [0u8; 8];
        let mut got = Vec::new();
        while got.len() < 4 {
            let n = link.read(&mut buf, Duration::from_secs(2)).unwrap();
            assert!(n > 0, "answer did not arrive");
            got.extend_from_slice(&buf[..n]);
        }
        assert_eq!(
            got, b"pong",
            "stale bytes were discarded before the request"
        );
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
}
