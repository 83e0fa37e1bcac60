//! A baud-accurate serial line between a master on a pty and a device (tests and benchmarks):
//! a pty delivers bytes at once, so the relay hands each byte over when its stop bit would end
//! on an 8N1 wire (the frame's start plus 10 bit times a character), and timestamps where each
//! frame starts and ends. From those the silence a master leaves between frames can be measured.
//!
//! The device is a serial device on another pty (`start`) or a simulated module answering in
//! the relay's own thread (`with_device`): then no pty hop lies between the wire and the
//! module, which hears each byte when it is due and answers as soon as a request's last byte
//! is in, as a module on a real line does. The wire is modelled; the hops from the master's pty
//! to the relay and back are the host's, and show in the silence measured.

use super::pty::PtyError;
use super::wire::{Frame, Side, Timeline};
use crate::link::far_end::ByteDevice;
use crate::link::fd::{self, Read};
use serialport::{SerialPort, TTYPort};
use std::collections::VecDeque;
use std::os::fd::{AsRawFd, RawFd};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Frames kept for reading back; later ones are counted, not kept.
pub const MAX_FRAMES: usize = 200_000;

/// How often the relay looks at its stop flag while the line is idle.
const IDLE_POLL: Duration = Duration::from_millis(20);

/// How long before the last byte of a frame is due the relay stops sleeping and watches the
/// clock: a timer wakes a thread tens of microseconds late on a virtual machine, and the frame
/// ends (and the silence after it starts) when that byte is handed over. Earlier bytes are
/// handed over on the timer alone; only the last one ends the frame.
const SPIN_BEFORE_END: Duration = Duration::from_micros(60);

/// What the relay recorded, shared with its thread.
#[derive(Default)]
struct Record {
    frames: Mutex<Vec<Frame>>,
    dropped: AtomicU64,
}

impl Record {
    fn push(&self, frame: Frame) {
        let mut frames = crate::sync::lock(&self.frames);
        if frames.len() < MAX_FRAMES {
            frames.push(frame);
        } else {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }
}

/// A running relay; stops when dropped.
pub struct TimedLine {
    path: String,
    origin: Instant,
    stop: Arc<AtomicBool>,
    record: Arc<Record>,
    thread: Option<JoinHandle<Result<(), PtyError>>>,
}

impl TimedLine {
    /// Opens a pty for the master and relays it at `baud` to the serial device at `far` (a
    /// simulator's pty). The master opens `path()`.
    pub fn start(far: &str, baud: u32) -> Result<Self, PtyError> {
        let far = serialport::new(far, baud)
            .timeout(Duration::from_millis(100))
            .open_native()
            .map_err(|e| PtyError::Open(format!("{far}: {}", e.description)))?;
        fd::set_nonblocking(far.as_raw_fd())?;
        Self::spawn(baud, Far::Pty(far))
    }

    /// Opens a pty for the master and puts `device` at the far end of a line at `baud`: it
    /// hears each byte when it is due and its answers go on the wire at once. After `idle` of
    /// silence from the master it is told the line is idle (`ByteDevice::line_idle`).
    pub fn with_device(
        device: Box<dyn ByteDevice>,
        baud: u32,
        idle: Duration,
    ) -> Result<Self, PtyError> {
        Self::spawn(
            baud,
            Far::Device {
                device,
                idle,
                heard: false,
            },
        )
    }

    fn spawn(baud: u32, far: Far) -> Result<Self, PtyError> {
        let (near, near_slave) = TTYPort::pair().map_err(|e| PtyError::Open(e.description))?;
        let path = near_slave
            .name()
            .ok_or_else(|| PtyError::Open("the pty has no name".into()))?;
        fd::set_nonblocking(near.as_raw_fd())?;
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
        crate::sync::lock(&self.record.frames).clone()
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

impl Drop for TimedLine {
    fn drop(&mut self) {
        let _ = self.halt();
    }
}

/// The far end of the line.
enum Far {
    /// A serial device on another pty.
    Pty(TTYPort),
    /// A simulated device in the relay's thread.
    Device {
        device: Box<dyn ByteDevice>,
        /// Silence from the master after which the device hears that the line is idle.
        idle: Duration,
        /// Bytes reached it since it last heard the line idle.
        heard: bool,
    },
}

/// The two ends of the line, owned by the relay thread.
struct Ends {
    near: TTYPort,
    // Held open so the master's pty never hangs up between the clients that come and go.
    _near_slave: TTYPort,
    far: Far,
}

/// One direction of the line: bytes waiting for their moment.
struct Direction {
    side: Side,
    queue: VecDeque<(Duration, u8)>,
}

impl Direction {
    /// Queues `bytes` that reached the line at `at` behind what this side still has on the
    /// wire: each is handed over when its stop bit ends. Returns the frame it closed, if any.
    fn put(&mut self, line: &mut Timeline, at: Duration, bytes: &[u8]) -> Option<Frame> {
        let sent = line.send(self.side, at, bytes.len());
        let char_time = line.wire_time(1);
        let first_end = sent.frame.end.saturating_sub(line.wire_time(bytes.len()));
        for (k, &byte) in bytes.iter().enumerate() {
            let k = u32::try_from(k).unwrap_or(u32::MAX);
            self.queue
                .push_back((first_end.saturating_add(char_time * (k + 1)), byte));
        }
        sent.closed
    }

    /// Takes the bytes due by `now` into `out`.
    fn take_due(&mut self, now: Duration, out: &mut Vec<u8>) {
        out.clear();
        while let Some(&(at, byte)) = self.queue.front() {
            if at > now {
                break;
            }
            out.push(byte);
            self.queue.pop_front();
        }
    }
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
    let Ends { near, mut far, .. } = ends;
    let near = near.as_raw_fd();
    let far_fd = match &far {
        Far::Pty(port) => Some(port.as_raw_fd()),
        Far::Device { .. } => None,
    };
    let mut lanes = [
        Direction {
            side: Side::Master,
            queue: VecDeque::new(),
        },
        Direction {
            side: Side::Slave,
            queue: VecDeque::new(),
        },
    ];
    let mut line = Timeline::new(baud);
    let mut buf = [0u8; 256];
    let mut out = Vec::with_capacity(256);
    let mut last_heard = Duration::ZERO;
    while !stop.load(Ordering::Relaxed) {
        let now = origin.elapsed();
        let [to_far, to_near] = &mut lanes;
        to_far.take_due(now, &mut out);
        if !out.is_empty() {
            // Stamped before the hand-over: the receiver can have the bytes before it returns.
            line.delivered(Side::Master, origin.elapsed());
            let answer = match &mut far {
                Far::Pty(port) => {
                    fd::write_all_within(port.as_raw_fd(), &out, Duration::from_secs(1))?;
                    Vec::new()
                }
                Far::Device { device, heard, .. } => {
                    *heard = true;
                    last_heard = origin.elapsed();
                    device.receive(&out)
                }
            };
            if !answer.is_empty() {
                if let Some(frame) = to_near.put(&mut line, origin.elapsed(), &answer) {
                    record.push(frame);
                }
            }
        }
        if let Far::Device {
            device,
            idle,
            heard,
        } = &mut far
        {
            if *heard && to_far.queue.is_empty() && now >= last_heard.saturating_add(*idle) {
                *heard = false;
                let answer = device.line_idle();
                if !answer.is_empty() {
                    if let Some(frame) = to_near.put(&mut line, origin.elapsed(), &answer) {
                        record.push(frame);
                    }
                }
            }
        }
        to_near.take_due(now, &mut out);
        if !out.is_empty() {
            line.delivered(Side::Slave, origin.elapsed());
            fd::write_all_within(near, &out, Duration::from_secs(1))?;
        }
        for lane in &lanes {
            if let Some(frame) = line.close_if_idle(lane.side, now) {
                record.push(frame);
            }
        }
        // The next byte due, and whether it ends what its side has queued.
        let next = lanes
            .iter()
            .filter_map(|l| l.queue.front().map(|(at, _)| (*at, l.queue.len() == 1)))
            .min_by_key(|(at, _)| *at);
        let mut wait = match next {
            Some((at, last)) => {
                let left = at.saturating_sub(origin.elapsed());
                if last && left <= SPIN_BEFORE_END {
                    while origin.elapsed() < at {
                        std::hint::spin_loop();
                    }
                    continue;
                }
                if last {
                    left.saturating_sub(SPIN_BEFORE_END)
                } else {
                    left
                }
            }
            None => IDLE_POLL,
        };
        if let Far::Device {
            idle, heard: true, ..
        } = &far
        {
            let idle_at = last_heard.saturating_add(*idle);
            wait = wait.min(idle_at.saturating_sub(origin.elapsed()));
        }
        let fds: &[RawFd] = match far_fd {
            Some(far_fd) => &[near, far_fd],
            None => &[near],
        };
        let ready = fd::wait_readable(fds, wait.min(IDLE_POLL))?;
        for (k, ready) in ready.into_iter().enumerate() {
            if !ready {
                continue;
            }
            let (from, lane) = match k {
                0 => (near, &mut lanes[0]),
                _ => (far_fd.unwrap_or(near), &mut lanes[1]),
            };
            let Read::Bytes(n) = fd::read_now(from, &mut buf)? else {
                continue;
            };
            let arrived = origin.elapsed();
            if let Some(frame) = lane.put(&mut line, arrived, buf.get(..n).unwrap_or_default()) {
                record.push(frame);
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
        let relay = TimedLine::start(&far_path, 9600).unwrap();
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

    /// Answers every 4 bytes with them reversed; counts the times it heard the line idle.
    struct Reverser {
        heard: Vec<u8>,
        idles: Arc<AtomicU64>,
    }
    impl ByteDevice for Reverser {
        fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
            self.heard.extend_from_slice(bytes);
            if self.heard.len() < 4 {
                return Vec::new();
            }
            let mut answer = std::mem::take(&mut self.heard);
            answer.reverse();
            answer
        }
        fn line_idle(&mut self) -> Vec<u8> {
            self.idles.fetch_add(1, Ordering::Relaxed);
            Vec::new()
        }
    }

    #[test]
    fn a_device_in_the_relay_answers_when_the_request_has_left_the_wire() {
        let idles = Arc::new(AtomicU64::new(0));
        let device = Reverser {
            heard: Vec::new(),
            idles: Arc::clone(&idles),
        };
        let relay =
            TimedLine::with_device(Box::new(device), 9600, Duration::from_millis(20)).unwrap();
        let mut master = SerialLink::open(relay.path(), 9600).unwrap();
        let started = Instant::now();
        master.write_all(&[1, 2, 3, 4]).unwrap();
        let mut answer = Vec::new();
        let mut buf = [0u8; 8];
        while answer.len() < 4 {
            let n = master.read(&mut buf, Duration::from_secs(2)).unwrap();
            assert!(n > 0, "the answer did not come through");
            answer.extend_from_slice(&buf[..n]);
        }
        let through = started.elapsed();
        assert_eq!(answer, [4, 3, 2, 1]);
        assert!(
            through >= wire_time(8, 9600),
            "4 characters there and 4 back at 9600 baud cannot take {through:?}"
        );
        std::thread::sleep(Duration::from_millis(60));
        assert_eq!(
            idles.load(Ordering::Relaxed),
            1,
            "told the line is idle once"
        );
        let frames = relay.stop().unwrap();
        assert_eq!(frames.len(), 2, "{frames:?}");
        let (request, reply) = (frames[0], frames[1]);
        assert_eq!((request.side, request.bytes), (Side::Master, 4));
        assert_eq!((reply.side, reply.bytes), (Side::Slave, 4));
        assert!(request.end - request.start >= wire_time(4, 9600));
        assert!(reply.end - reply.start >= wire_time(4, 9600), "{reply:?}");
        // The module answers as the request's last byte is in (only the relay's own work
        // between them, however late the machine woke the relay).
        assert!(
            reply.silence.unwrap() < Duration::from_millis(1),
            "{:?}",
            reply.silence
        );
    }
}
