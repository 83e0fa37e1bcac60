//! Byte I/O on a non-blocking file descriptor with the fewest system calls: a read that tells at
//! once whether anything is there, a read that waits (one `poll`, then `read`), and a write whose
//! wait for room is bounded. Serial ports and TCP sockets both go through here.

use super::Watch;
use rustix::event::{PollFd, PollFlags};
use rustix::fs::OFlags;
use rustix::io::Errno;
use std::io;
use std::os::fd::{BorrowedFd, RawFd};
use std::time::{Duration, Instant};

/// The caller's descriptor, for the length of one call.
fn borrow<'a>(fd: RawFd) -> BorrowedFd<'a> {
    // SAFETY: every function here is handed a descriptor its caller holds open for the call
    // (a closed one only makes the system call fail, as `ended` reports with POLLNVAL).
    unsafe { BorrowedFd::borrow_raw(fd) }
}

/// Puts `fd` in non-blocking mode, so a read with nothing to read returns at once.
pub fn set_nonblocking(fd: RawFd) -> io::Result<()> {
    set_status_flag(fd, OFlags::NONBLOCK, true)
}

/// Puts `fd` back in blocking mode (a file opened non-blocking only so that opening it could
/// not wait).
pub fn set_blocking(fd: RawFd) -> io::Result<()> {
    set_status_flag(fd, OFlags::NONBLOCK, false)
}

fn set_status_flag(fd: RawFd, flag: OFlags, on: bool) -> io::Result<()> {
    let mut flags = rustix::fs::fcntl_getfl(borrow(fd))?;
    flags.set(flag, on);
    Ok(rustix::fs::fcntl_setfl(borrow(fd), flags)?)
}

/// What a read found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Read {
    /// This many bytes (at least one).
    Bytes(usize),
    /// Nothing arrived (in time).
    Nothing,
    /// The far end has gone (a hung-up tty, a closed socket).
    Closed,
}

/// Reads what is there now, without waiting.
pub fn read_now(fd: RawFd, buf: &mut [u8]) -> io::Result<Read> {
    if buf.is_empty() {
        return Ok(Read::Nothing);
    }
    loop {
        match rustix::io::read(borrow(fd), &mut *buf) {
            Ok(0) => return Ok(Read::Closed),
            Ok(n) => return Ok(Read::Bytes(n)),
            Err(Errno::AGAIN) => return Ok(Read::Nothing),
            Err(Errno::INTR) => {}
            Err(e) => return Err(e.into()),
        }
    }
}

/// Waits up to `timeout` for bytes, then reads what is there. Costs one `poll` and one `read`
/// when bytes come; a `timeout` of zero only looks (one `read`). Only a descriptor that polls
/// readable and then has nothing (another reader was first) makes it wait again, for
/// `timeout` from then at most.
pub fn read_within(fd: RawFd, buf: &mut [u8], timeout: Duration) -> io::Result<Read> {
    if timeout.is_zero() {
        return read_now(fd, buf);
    }
    // The clock is read only if the wait has to be taken up again: most reads wait once.
    let mut deadline = None;
    let mut left = timeout;
    loop {
        match wait(fd, PollFlags::IN, left)? {
            Ready::Yes => {}
            Ready::Hangup => {
                return read_now(fd, buf).map(|r| match r {
                    Read::Nothing => Read::Closed,
                    other => other,
                })
            }
            Ready::No => return Ok(Read::Nothing),
        }
        match read_now(fd, buf)? {
            // Readable but nothing to read: another reader took it; wait out the rest.
            Read::Nothing => {
                // A timeout too long for the clock (never a real one) just waits it again.
                let end = *deadline.get_or_insert_with(|| Instant::now().checked_add(timeout));
                left = end.map_or(timeout, |end| end.saturating_duration_since(Instant::now()));
                if left.is_zero() {
                    return Ok(Read::Nothing);
                }
            }
            other => return Ok(other),
        }
    }
}

/// Writes all of `bytes`, waiting at most `timeout` in all for room (a stalled adapter or a
/// peer that stopped reading ends in `TimedOut` instead of holding the caller).
pub fn write_all_within(fd: RawFd, mut bytes: &[u8], timeout: Duration) -> io::Result<()> {
    let deadline = Instant::now().checked_add(timeout);
    while !bytes.is_empty() {
        match rustix::io::write(borrow(fd), bytes) {
            Ok(n) => bytes = bytes.get(n..).unwrap_or_default(),
            Err(Errno::INTR) => continue,
            Err(Errno::AGAIN) => {
                let left =
                    deadline.map_or(timeout, |d| d.saturating_duration_since(Instant::now()));
                if left.is_zero() || wait(fd, PollFlags::OUT, left)? == Ready::No {
                    return Err(io::Error::new(
                        io::ErrorKind::TimedOut,
                        format!("could not send for {timeout:?}: the other end takes no data"),
                    ));
                }
            }
            Err(e) => return Err(e.into()),
        }
    }
    Ok(())
}

/// Waits up to `timeout` until one of `fds` has bytes to read (or has hung up); tells which.
pub fn wait_readable(fds: &[RawFd], timeout: Duration) -> io::Result<Vec<bool>> {
    let mut pfds: Vec<PollFd> = fds
        .iter()
        .map(|&fd| PollFd::from_borrowed_fd(borrow(fd), PollFlags::IN))
        .collect();
    poll_all(&mut pfds, timeout)?;
    Ok(pfds.iter().map(|p| !p.revents().is_empty()).collect())
}

/// One `ppoll` of `pfds` for up to `timeout`, again after a signal interrupts it; how many
/// have news. A timeout too long for a timespec (never a real one) waits for ever.
fn poll_all(pfds: &mut [PollFd], timeout: Duration) -> io::Result<usize> {
    let ts = rustix::time::Timespec::try_from(timeout).ok();
    loop {
        match rustix::event::poll(pfds, ts.as_ref()) {
            Err(Errno::INTR) => continue,
            done => return Ok(done?),
        }
    }
}

/// Asks the OS, without waiting or reading, which of `watches` have ended: a terminal hung
/// up or in error (a pty's other side closed, a USB-serial adapter unplugged), a socket closed
/// or reset by its peer. One `ppoll` for them all; each entry is `None` (still up) or the OS's
/// reason in words.
pub fn ended(watches: &[Watch]) -> io::Result<Vec<Option<String>>> {
    let mut pfds: Vec<PollFd> = watches
        .iter()
        .map(|w| {
            // Bytes waiting are no news: only the end is asked for (hang-up and error are
            // always reported; a socket's orderly close needs POLLRDHUP).
            let events = if w.socket {
                PollFlags::RDHUP
            } else {
                PollFlags::empty()
            };
            PollFd::from_borrowed_fd(borrow(w.fd), events)
        })
        .collect();
    poll_all(&mut pfds, Duration::ZERO)?;
    Ok(pfds
        .iter()
        .zip(watches)
        .map(|(p, w)| end_reason(p.revents(), *w))
        .collect())
}

/// What `revents` says of a watched link's end, in words; `None` while it is up.
fn end_reason(revents: PollFlags, w: Watch) -> Option<String> {
    let hup = revents.contains(PollFlags::HUP);
    let err = revents.contains(PollFlags::ERR);
    if revents.contains(PollFlags::NVAL) {
        return Some("its descriptor is no longer open".into());
    }
    if w.socket {
        if err {
            return Some(match socket_error(w.fd) {
                Some(e) => format!("the connection failed: {e}"),
                None => "the connection failed".into(),
            });
        }
        if hup || revents.contains(PollFlags::RDHUP) {
            return Some("the server closed the connection (end of stream)".into());
        }
        return None;
    }
    match (hup, err) {
        (true, _) => Some(
            "hang-up: the other end of the line closed it, or the adapter was unplugged".into(),
        ),
        (false, true) => Some("an error on the line (the adapter failed or went away)".into()),
        (false, false) => None,
    }
}

/// The pending error of socket `fd` (`SO_ERROR`: a reset, an unreachable host), if any.
fn socket_error(fd: RawFd) -> Option<io::Error> {
    match rustix::net::sockopt::socket_error(borrow(fd)) {
        Ok(Err(e)) => Some(e.into()),
        _ => None,
    }
}

#[derive(Debug, PartialEq, Eq)]
enum Ready {
    Yes,
    No,
    Hangup,
}

fn wait(fd: RawFd, events: PollFlags, timeout: Duration) -> io::Result<Ready> {
    let mut pfd = [PollFd::from_borrowed_fd(borrow(fd), events)];
    if poll_all(&mut pfd, timeout)? == 0 {
        return Ok(Ready::No);
    }
    let revents = pfd[0].revents();
    Ok(if revents.intersects(events) {
        Ready::Yes
    } else if revents.intersects(PollFlags::HUP | PollFlags::ERR | PollFlags::NVAL) {
        Ready::Hangup
    } else {
        Ready::No
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::fd::AsRawFd;
    use std::os::unix::net::UnixStream;

    #[test]
    fn reads_tell_nothing_bytes_and_closed_apart() {
        let (a, b) = UnixStream::pair().unwrap();
        set_nonblocking(a.as_raw_fd()).unwrap();
        let mut buf = [0u8; 8];
        assert_eq!(read_now(a.as_raw_fd(), &mut buf).unwrap(), Read::Nothing);
        assert_eq!(
            read_within(a.as_raw_fd(), &mut buf, Duration::from_millis(10)).unwrap(),
            Read::Nothing
        );
        write_all_within(b.as_raw_fd(), b"hi", Duration::from_secs(1)).unwrap();
        assert_eq!(
            read_within(a.as_raw_fd(), &mut buf, Duration::from_secs(1)).unwrap(),
            Read::Bytes(2)
        );
        assert_eq!(&buf[..2], b"hi");
        drop(b);
        assert_eq!(
            read_within(a.as_raw_fd(), &mut buf, Duration::from_secs(1)).unwrap(),
            Read::Closed
        );
    }

    #[test]
    fn the_end_of_a_socket_or_a_terminal_is_told_and_bytes_waiting_are_not() {
        let (a, b) = UnixStream::pair().unwrap();
        let sock = Watch {
            fd: a.as_raw_fd(),
            socket: true,
        };
        assert_eq!(ended(&[sock]).unwrap(), vec![None]);
        write_all_within(b.as_raw_fd(), b"hi", Duration::from_secs(1)).unwrap();
        assert_eq!(ended(&[sock]).unwrap(), vec![None], "bytes waiting");
        drop(b);
        let why = ended(&[sock]).unwrap().remove(0).expect("told");
        assert!(why.contains("closed the connection"), "{why}");

        let (master, slave) = serialport::TTYPort::pair().unwrap();
        let tty = Watch {
            fd: slave.as_raw_fd(),
            socket: false,
        };
        assert_eq!(ended(&[tty]).unwrap(), vec![None]);
        drop(master);
        let why = ended(&[tty]).unwrap().remove(0).expect("told");
        assert!(why.starts_with("hang-up"), "{why}");
    }

    #[test]
    fn a_write_nobody_reads_gives_up_in_time() {
        let (a, _b) = UnixStream::pair().unwrap();
        set_nonblocking(a.as_raw_fd()).unwrap();
        let big = vec![0u8; 16 << 20];
        let started = Instant::now();
        let err = write_all_within(a.as_raw_fd(), &big, Duration::from_millis(100)).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::TimedOut);
        assert!(started.elapsed() < Duration::from_secs(5));
    }
}
