//! A baud-accurate serial line between a master and a device on a pty (tests and benchmarks):
//! a pty delivers bytes at once, so the relay holds each byte for the 10 bit times it takes on
//! an 8N1 wire before handing it over, and timestamps where each frame starts and ends. From
//! those the silence a master leaves between frames can be measured.

use super::pty::PtyError;
use super::wire::{Frame, Side, Timeline};
use crate::link::fd::{self, Read};
use serialport::{SerialPort, TTYPort};
use std::collections::VecDeque;
use std::os::fd::{AsRawFd, RawFd};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Frames kept for reading back; later ones are counted, not kept.
pub const MAX_FRAMES: usize = 200_000;

/// How often the relay looks at its stop flag while the line is idle.
const IDLE_POLL: Duration = Duration::from_millis(20);

/// What the relay recorded, shared with its thread.
#[derive(Default)]
struct Record {
    frames: Mutex<Vec<Frame>>,
    dropped: AtomicU64,
}

impl Record {
    fn push(&self, frame: Frame) {
        let mut frames = self.frames.lock().unwrap_or_else(PoisonError::into_inner);
        if frames.len() < MAX_FRAMES {
            frames.push(frame);
        } else {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// A running relay; stops when dropped.
pub struct LineRelay {
    path: String,
    origin: Instant,
    stop: Arc<AtomicBool>,
    record: Arc<Record>,
    thread: Option<JoinHandle<Result<(), PtyError>>>,
}

impl LineRelay {
    /// Opens a pty for the master and relays it at `baud` to the serial device at `far` (a
    /// simulator's pty). The master opens `path()`.
    pub fn start(far: &str, baud: u32) -> Result<Self, PtyError> {
        let (near, near_slave) = TTYPort::pair().map_err(|e| PtyError::Open(e.description))?;
        let path = near_slave
            .name()
            .ok_or_else(|| PtyError::Open("the pty has no name".into()))?;
        let far = serialport::new(far, baud)
            .timeout(Duration::from_millis(100))
            .open_native()
            .map_err(|e| PtyError::Open(format!("{far}: {}", e.description)))?;
        for fd in [near.as_raw_fd(), far.as_raw_fd()] {
            fd::set_nonblocking(fd)?;
        }
        let stop = Arc::new(AtomicBool::new(false));
        let record = Arc::new(Record::default());
        let origin = Instant::now();
        let ends = Ends {
            near,
            _near_slave: near_slave,
            far,
        };
        let (stop2, record2) = (Arc::clone(&stop), Arc::clone(&record));
        let thread = std::thread::Builder::new()
            .name("line relay".into())
            .spawn(move || relay(ends, baud, origin, &stop2, &record2))
            .map_err(PtyError::Io)?;
        Ok(Self {
            path,
            origin,
            stop,
            record,
            thread: Some(thread),
        })
    }

    /// The pty the master opens.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// The relay's time now (frames are stamped in it).
    pub fn now(&self) -> Duration {
        self.origin.elapsed()
    }

    /// The frames that have ended so far, oldest first.
    pub fn frames(&self) -> Vec<Frame> {
        self.record
            .frames
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .clone()
    }

    /// Frames that ended after `MAX_FRAMES` were kept.
    pub fn frames_not_kept(&self) -> u64 {
        self.record.dropped.load(Ordering::Relaxed)
    }

    /// Stops the relay and returns every frame it saw (the open ones closed).
    pub fn stop(mut self) -> Result<Vec<Frame>, PtyError> {
        self.halt()?;
        Ok(self.frames())
    }

    fn halt(&mut self) -> Result<(), PtyError> {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(result)) => result,
            Some(Err(_)) => Err(PtyError::Open("the relay thread panicked".into())),
            None => Ok(()),
        }
    }
}

impl Drop for LineRelay {
    fn drop(&mut self) {
        let _ = self.halt();
    }
}

/// The two ends of the line, owned by the relay thread.
struct Ends {
    near: TTYPort,
    // Held open so the master's pty never hangs up between the clients that come and go.
    _near_slave: TTYPort,
    far: TTYPort,
}

/// One direction of the line: bytes waiting for their moment, and where they go.
struct Direction {
    side: Side,
    from: RawFd,
    to: RawFd,
    queue: VecDeque<(Duration, u8)>,
}

fn relay(
    ends: Ends,
    baud: u32,
    origin: Instant,
    stop: &AtomicBool,
    record: &Record,
) -> Result<(), PtyError> {
    // Prompt timers keep the byte times close to the baud.
    super::pty::prefer_realtime();
    let (near, far) = (ends.near.as_raw_fd(), ends.far.as_raw_fd());
    let mut lanes = [
        Direction {
            side: Side::Master,
            from: near,
            to: far,
            queue: VecDeque::new(),
        },
        Direction {
            side: Side::Slave,
            from: far,
            to: near,
            queue: VecDeque::new(),
        },
    ];
    let mut line = Timeline::new(baud);
    let char_time = line.wire_time(1);
    let mut buf = [0u8; 256];
    let mut out = Vec::with_capacity(256);
    while !stop.load(Ordering::Relaxed) {
        let now = origin.elapsed();
        for lane in &mut lanes {
            out.clear();
            while let Some(&(at, byte)) = lane.queue.front() {
                if at > now {
                    break;
                }
                out.push(byte);
                lane.queue.pop_front();
            }
            if !out.is_empty() {
                // Stamped before the write: the receiver can have the bytes before it returns.
                line.delivered(lane.side, origin.elapsed());
                fd::write_all_within(lane.to, &out, Duration::from_secs(1))?;
            }
            if let Some(frame) = line.close_if_idle(lane.side, now) {
                record.push(frame);
            }
        }
        let next = lanes
            .iter()
            .filter_map(|l| l.queue.front().map(|(at, _)| *at))
            .min();
        let wait = next.map_or(IDLE_POLL, |at| at.saturating_sub(origin.elapsed()));
        let ready = fd::wait_readable(&[near, far], wait.min(IDLE_POLL))?;
        for (lane, ready) in lanes.iter_mut().zip(ready) {
            if !ready {
                continue;
            }
            let Read::Bytes(n) = fd::read_now(lane.from, &mut buf)? else {
                continue;
            };
            let arrived = origin.elapsed();
            let sent = line.send(lane.side, arrived, n);
            if let Some(frame) = sent.closed {
                record.push(frame);
            }
            // The bytes leave one after the other behind what this side still has queued;
            // each is handed over when its stop bit ends.
            let first_end = sent.frame.end.saturating_sub(line.wire_time(n));
            for (k, &byte) in buf.iter().take(n).enumerate() {
                let k = u32::try_from(k).unwrap_or(u32::MAX);
                lane.queue
                    .push_back((first_end.saturating_add(char_time * (k + 1)), byte));
            }
        }
    }
    for side in [Side::Master, Side::Slave] {
        if let Some(frame) = line.close(side) {
            record.push(frame);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::line::wire_time;
    use crate::link::serial::SerialLink;
    use crate::link::ByteLink;

    #[test]
    fn bytes_take_their_wire_time_and_frames_are_stamped() {
        // The far end: a pty whose other side this test plays.
        let (far_master, far_slave) = TTYPort::pair().unwrap();
        let far_path = far_slave.name().unwrap();
        let relay = LineRelay::start(&far_path, 9600).unwrap();
        let mut master = SerialLink::open(relay.path(), 9600).unwrap();
        let started = Instant::now();
        master.write_all(&[1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
        let mut got = Vec::new();
        let mut buf = [0u8; 16];
        let far_fd = far_master.as_raw_fd();
        fd::set_nonblocking(far_fd).unwrap();
        while got.len() < 8 {
            match fd::read_within(far_fd, &mut buf, Duration::from_secs(2)).unwrap() {
                Read::Bytes(n) => got.extend_from_slice(&buf[..n]),
                other => panic!("the request did not come through: {other:?}"),
            }
        }
        let through = started.elapsed();
        assert_eq!(got, [1, 2, 3, 4, 5, 6, 7, 8]);
        assert!(
            through >= wire_time(8, 9600),
            "8 characters at 9600 baud cannot arrive in {through:?}"
        );
        // An answer after a pause: the relay sees two frames and the silence between them.
        std::thread::sleep(Duration::from_millis(10));
        fd::write_all_within(far_fd, &[9, 9, 9, 9, 9, 9], Duration::from_secs(1)).unwrap();
        let mut answer = Vec::new();
        while answer.len() < 6 {
            let n = master.read(&mut buf, Duration::from_secs(2)).unwrap();
            assert!(n > 0, "the answer did not come through");
            answer.extend_from_slice(&buf[..n]);
        }
        let frames = relay.stop().unwrap();
        assert_eq!(frames.len(), 2, "{frames:?}");
        let (request, reply) = (frames[0], frames[1]);
        assert_eq!((request.side, request.bytes), (Side::Master, 8));
        assert_eq!((reply.side, reply.bytes), (Side::Slave, 6));
        assert!(request.end - request.start >= wire_time(8, 9600));
        assert!(reply.end - reply.start >= wire_time(6, 9600));
        let silence = reply.silence.unwrap();
        assert!(silence >= Duration::from_millis(1), "{silence:?}");
        assert_eq!(silence, reply.start - request.end);
        drop(far_slave);
    }
}
