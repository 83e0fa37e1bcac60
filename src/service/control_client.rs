//! The client end of a rig's control socket (`control_protocol`), for `rigscript status`,
//! `list` and `stop`.

use super::authority::{self, Peer};
use super::control_protocol::{ClientRequest, Hello, Reply};
use crate::runtime::snapshot::RigSnapshot;
use std::io::{self, BufRead, BufReader, Read, Write};
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::time::Duration;

/// The longest answer line read (a snapshot of a large rig is a few kilobytes).
pub const MAX_ANSWER: u64 = 1 << 20;

/// One connection to a run.
pub struct Connection {
    out: UnixStream,
    reader: BufReader<UnixStream>,
}

impl Connection {
    /// Connects to the socket at `path`; every read and write waits at most `wait`.
    pub fn open(path: &Path, wait: Duration) -> io::Result<Self> {
        let out = UnixStream::connect(path)?;
        out.set_read_timeout(Some(wait))?;
        out.set_write_timeout(Some(wait))?;
        let reader = BufReader::new(out.try_clone()?);
        Ok(Self { out, reader })
    }

    /// Sends `request` and reads its answer; a refusal is an error with the run's words.
    pub fn ask(&mut self, request: &ClientRequest) -> io::Result<Reply> {
        let mut line = serde_json::to_string(request).map_err(io::Error::other)?;
        line.push('\n');
        let sent = self.out.write_all(line.as_bytes());
        // A run that turned this client away (all its places taken) said why before it
        // closed: its words, not the broken pipe.
        let text = match (sent, self.read_line()) {
            (_, Ok(text)) => text,
            (Err(e), Err(_)) | (Ok(()), Err(e)) => return Err(e),
        };
        let reply: Reply = serde_json::from_str(&text).map_err(|e| {
            io::Error::new(
                io::ErrorKind::InvalidData,
                format!("not an answer of rigscript's ({e})"),
            )
        })?;
        if reply.ok {
            Ok(reply)
        } else {
            Err(io::Error::other(
                reply.error.unwrap_or_else(|| "refused".into()),
            ))
        }
    }

    /// Who is at the other end, as the kernel tells it.
    pub fn peer(&self) -> Option<Peer> {
        authority::peer(&self.out)
    }

    /// Who the run is.
    pub fn hello(&mut self) -> io::Result<Hello> {
        self.ask(&ClientRequest::Hello)?
            .hello
            .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidData, "no hello in the answer"))
    }

    /// The run as it stands.
    pub fn status(&mut self) -> io::Result<RigSnapshot> {
        self.ask(&ClientRequest::Status)?
            .status
            .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidData, "no status in the answer"))
    }

    /// Turns the connection into the run's event stream: each `next_event` is one event's
    /// JSON object.
    pub fn subscribe(&mut self) -> io::Result<()> {
        self.ask(&ClientRequest::Subscribe).map(|_| ())
    }

    /// The next event of a subscribed connection; `Ok(None)` once the run closed it.
    pub fn next_event(&mut self) -> io::Result<Option<serde_json::Value>> {
        match self.read_line() {
            Ok(text) => serde_json::from_str(&text)
                .map(Some)
                .map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e)),
            Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => Ok(None),
            Err(e) => Err(e),
        }
    }

    /// Sets how long reads wait (a subscriber waits for events longer than for answers).
    pub fn set_read_wait(&self, wait: Option<Duration>) -> io::Result<()> {
        self.out.set_read_timeout(wait)
    }

    fn read_line(&mut self) -> io::Result<String> {
        let mut buf = Vec::new();
        let n = (&mut self.reader)
            .take(MAX_ANSWER)
            .read_until(b'\n', &mut buf)?;
        if n == 0 {
            return Err(io::Error::new(
                io::ErrorKind::UnexpectedEof,
                "the run closed the connection",
            ));
        }
        String::from_utf8(buf).map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e))
    }
}
