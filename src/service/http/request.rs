//! One HTTP/1.1 request read off a connection, with bounds on everything a client controls:
//! the head (`MAX_HEAD`), the body (`MAX_BODY`, by `Content-Length` only) and the time the
//! whole request may take (a slow-loris client sending a byte a second is cut off too).

use std::io::Read;
use std::time::Instant;

/// The longest request head (request line and headers) read.
pub const MAX_HEAD: usize = 8 * 1024;

/// The longest body read (a drive action is a few dozen bytes).
pub const MAX_BODY: usize = 4 * 1024;

/// A request as read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HttpRequest {
    /// `GET`, `POST`, ...
    pub method: String,
    /// The target's path, without its query.
    pub path: String,
    /// Headers as sent, names in lower case.
    pub headers: Vec<(String, String)>,
    /// The body (empty without `Content-Length`).
    pub body: Vec<u8>,
}

impl HttpRequest {
    /// The first header called `name` (lower case).
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_str())
    }
}

/// Why no request could be read; each but `Closed` is answered with its status.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ReadError {
    /// The client went before sending a whole head.
    #[error("the client closed the connection")]
    Closed,
    /// The request took longer than it may.
    #[error("the request took too long")]
    TimedOut,
    /// The head is larger than `MAX_HEAD`.
    #[error("the request head is larger than {MAX_HEAD} bytes")]
    HeadTooLarge,
    /// The body is larger than `MAX_BODY`.
    #[error("the body is larger than {MAX_BODY} bytes")]
    BodyTooLarge,
    /// Not HTTP/1.x as this server reads it.
    #[error("{0}")]
    Malformed(String),
}

impl ReadError {
    /// The status this error is answered with.
    pub fn status(&self) -> u16 {
        match self {
            ReadError::Closed | ReadError::Malformed(_) => 400,
            ReadError::TimedOut => 408,
            ReadError::HeadTooLarge => 431,
            ReadError::BodyTooLarge => 413,
        }
    }
}

/// Reads one request from `from`, giving up at `deadline` (each read must also end: the
/// caller sets the connection's read timeout).
pub fn read_request(from: &mut impl Read, deadline: Instant) -> Result<HttpRequest, ReadError> {
    let mut buf = Vec::with_capacity(1024);
    let mut chunk = [0u8; 1024];
    let head_end = loop {
        if let Some(end) = find_head_end(&buf) {
            break end;
        }
        if buf.len() > MAX_HEAD {
            return Err(ReadError::HeadTooLarge);
        }
        let n = read_some(from, &mut chunk, deadline)?;
        buf.extend_from_slice(&chunk[..n]);
    };
    if head_end > MAX_HEAD {
        return Err(ReadError::HeadTooLarge);
    }
    let mut request = parse_head(&buf[..head_end])?;
    let length = body_length(&request)?;
    let mut body = buf.split_off(head_end + 4);
    while body.len() < length {
        let n = read_some(from, &mut chunk, deadline)?;
        body.extend_from_slice(&chunk[..n]);
    }
    body.truncate(length);
    request.body = body;
    Ok(request)
}

fn read_some(
    from: &mut impl Read,
    chunk: &mut [u8],
    deadline: Instant,
) -> Result<usize, ReadError> {
    if Instant::now() > deadline {
        return Err(ReadError::TimedOut);
    }
    match from.read(chunk) {
        Ok(0) => Err(ReadError::Closed),
        Ok(n) => Ok(n),
        Err(e) if e.kind() == std::io::ErrorKind::Interrupted => Ok(0),
        Err(e)
            if matches!(
                e.kind(),
                std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
            ) =>
        {
            Err(ReadError::TimedOut)
        }
        Err(_) => Err(ReadError::Closed),
    }
}

/// Where the head's blank line starts.
fn find_head_end(buf: &[u8]) -> Option<usize> {
    buf.windows(4).position(|w| w == b"\r\n\r\n")
}

fn body_length(request: &HttpRequest) -> Result<usize, ReadError> {
    if request.header("transfer-encoding").is_some() {
        return Err(ReadError::Malformed(
            "a body is sent with Content-Length (no Transfer-Encoding)".into(),
        ));
    }
    let Some(text) = request.header("content-length") else {
        return Ok(0);
    };
    let length: u64 = text
        .trim()
        .parse()
        .map_err(|_| ReadError::Malformed(format!("Content-Length {text:?} is not a number")))?;
    match usize::try_from(length) {
        Ok(n) if n <= MAX_BODY => Ok(n),
        _ => Err(ReadError::BodyTooLarge),
    }
}

/// Reads the request line and headers (without the blank line).
pub fn parse_head(head: &[u8]) -> Result<HttpRequest, ReadError> {
    let bad = |why: &str| ReadError::Malformed(why.to_string());
    let text = std::str::from_utf8(head).map_err(|_| bad("the request head is not text"))?;
    let mut lines = text.split("\r\n");
    let line = lines.next().unwrap_or_default();
    let mut parts = line.split(' ');
    let (Some(method), Some(target), Some(version), None) =
        (parts.next(), parts.next(), parts.next(), parts.next())
    else {
        return Err(bad("the request line is not METHOD TARGET HTTP/1.1"));
    };
    if !version.starts_with("HTTP/1.") {
        return Err(bad("only HTTP/1.0 and HTTP/1.1 are served"));
    }
    if method.is_empty() || !method.bytes().all(|b| b.is_ascii_uppercase()) {
        return Err(bad("the method is not a word in capitals"));
    }
    if !target.starts_with('/') {
        return Err(bad("the target is not a path"));
    }
    let path = target.split(['?', '#']).next().unwrap_or("/").to_string();
    let mut headers = Vec::new();
    for line in lines {
        let Some((name, value)) = line.split_once(':') else {
            return Err(bad("a header line has no ':'"));
        };
        if name.is_empty() || name.contains(' ') {
            return Err(bad("a header's name is not a token"));
        }
        headers.push((name.to_ascii_lowercase(), value.trim().to_string()));
    }
    Ok(HttpRequest {
        method: method.to_string(),
        path,
        headers,
        body: Vec::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn read(bytes: &[u8]) -> Result<HttpRequest, ReadError> {
        read_request(&mut &bytes[..], Instant::now() + Duration::from_secs(5))
    }

    #[test]
    fn a_post_is_read_with_its_body_and_headers_in_lower_case() {
        let r =
            read(b"POST /api/sim?x=1 HTTP/1.1\r\nHost: a\r\nContent-Length: 4\r\n\r\nabcdEXTRA")
                .unwrap();
        assert_eq!(r.method, "POST");
        assert_eq!(r.path, "/api/sim");
        assert_eq!(r.header("host"), Some("a"));
        assert_eq!(r.body, b"abcd");
    }

    #[test]
    fn hostile_heads_and_bodies_are_refused_with_their_status() {
        let huge = format!("GET / HTTP/1.1\r\nX: {}\r\n\r\n", "a".repeat(MAX_HEAD));
        assert_eq!(read(huge.as_bytes()), Err(ReadError::HeadTooLarge));
        let endless = format!("GET / HTTP/1.1\r\nX: {}", "a".repeat(3 * MAX_HEAD));
        assert_eq!(read(endless.as_bytes()), Err(ReadError::HeadTooLarge));
        let big = b"POST / HTTP/1.1\r\nContent-Length: 1000000000\r\n\r\n";
        assert_eq!(read(big), Err(ReadError::BodyTooLarge));
        assert_eq!(read(b"GET / HTTP/1.1\r\n"), Err(ReadError::Closed));
        for garbage in [
            &b"\x00\x01\x02\r\n\r\n"[..],
            b"GET /\r\n\r\n",
            b"GET / SPDY/3\r\n\r\n",
            b"GET x HTTP/1.1\r\n\r\n",
            b"GET / HTTP/1.1\r\nno colon\r\n\r\n",
            b"POST / HTTP/1.1\r\nContent-Length: -1\r\n\r\n",
            b"POST / HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\n",
        ] {
            assert_eq!(
                read(garbage).map_err(|e| e.status()),
                Err(400),
                "{garbage:?}"
            );
        }
    }

    #[test]
    fn a_request_past_its_deadline_is_timed_out() {
        let past = Instant::now() - Duration::from_millis(1);
        assert_eq!(
            read_request(&mut &b"GET / HTTP/1.1\r\n"[..], past),
            Err(ReadError::TimedOut)
        );
    }
}
