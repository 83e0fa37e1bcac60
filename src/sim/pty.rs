//! Serves a simulated byte device on a pseudo-terminal, so any serial program can talk to it,
//! with optional faults drawn for each answer (`sim::faults::drawn`: dropped, flipped or late
//! answers) and, with strict
//! timing, the line's timing as a module on a shared line sees it.

use super::faults::drawn::Drawn;
use super::wire::{Side, Timeline};
use crate::link::far_end::ByteDevice;
use crate::link::holders::{holders_of, Holders};
use serialport::{SerialPort, TTYPort};
use std::io::{self, Read, Write};
use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Why the pty server failed.
#[derive(Debug, thiserror::Error)]
pub enum PtyError {
    /// No pseudo-terminal could be created.
    #[error("cannot create a pseudo-terminal: {0}")]
    Open(String),
    /// The requested symlink could not be made.
    #[error("cannot create the link {path}: {source}; pick another path or remove the file there")]
    Link {
        /// The path asked for.
        path: PathBuf,
        /// Why it could not be made.
        #[source]
        source: io::Error,
    },
    /// The link asked for points to a pty that a live process (another simulator) holds.
    #[error(
        "cannot create the link {path}: it points to {target}, which is still in use ({holders}): \
         another simulator serving there? stop it, or pick another path"
    )]
    LinkInUse {
        /// The path asked for.
        path: PathBuf,
        /// The pty it points to.
        target: PathBuf,
        /// Who holds that pty.
        holders: Box<Holders>,
    },
    /// Reading or writing the pty failed.
    #[error("pseudo-terminal I/O failed: {0}")]
    Io(#[from] io::Error),
}

/// Real-time line timing for the served device (`sim c29u --strict-timing`): a pty delivers
/// bytes at once, so the server times the line itself at `baud`. Answers leave when their
/// frame would end on the wire (after the request's frame); a request that starts less than
/// `required` after the previous frame on the line ended (its own answer included) is dropped,
/// as a module on a shared line drops the merged frame it hears, and counted in `early`.
#[derive(Debug, Clone)]
pub struct StrictTiming {
    /// The module's configured line speed.
    pub baud: u32,
    /// The silence a request must follow (t3.5 for Modbus).
    pub required: Duration,
    /// Requests dropped for starting too early.
    pub early: Arc<AtomicU64>,
}

/// A pseudo-terminal whose far end is a simulated device.
pub struct PtyServer {
    master: TTYPort,
    // Held open so the pty never hangs up between the clients that come and go.
    _slave: TTYPort,
    path: String,
    link: Option<PathBuf>,
    replaced_stale: bool,
    strict: Option<StrictTiming>,
}

/// The line as the server times it under strict timing.
struct Line {
    origin: Instant,
    timeline: Timeline,
    rules: StrictTiming,
    /// The frame being received started too early: its bytes go nowhere.
    dropping: bool,
}

impl Line {
    fn now(&self) -> Duration {
        self.origin.elapsed()
    }

    /// Takes `n` request bytes that just arrived; false if they belong to an early frame.
    fn hear(&mut self, n: usize) -> bool {
        let sent = self.timeline.send(Side::Master, self.now(), n);
        if sent.started {
            // A pty hands a request over through a kernel worker, so the server sees it late by
            // a delay it cannot measure (milliseconds on a loaded machine). After an answer the
            // server timed itself that only lengthens the silence it measures, and the full
            // silence is required; after a request of the master's that got no answer both ends
            // of the silence carry such a delay, so there only one character of silence is
            // required: a master that keeps none is still caught. (The driver's rule after an
            // unanswered request is pinned exactly in virtual time, in `device::exchange`.)
            let required = match sent.frame.after {
                Some(Side::Master) => self.timeline.wire_time(1).min(self.rules.required),
                _ => self.rules.required,
            };
            self.dropping = sent.frame.silence.is_some_and(|s| s < required);
            if self.dropping {
                self.rules.early.fetch_add(1, Ordering::Relaxed);
            }
        }
        !self.dropping
    }
}

impl PtyServer {
    /// Creates the pty and, when `link` is given, a symlink to it (removed on drop). A symlink
    /// already there whose pty is gone (a simulator killed with `kill -9`) is stale and
    /// replaced; one whose pty lives is refused, naming its holders (it may be another
    /// simulator's, still serving); anything else at that path is refused.
    pub fn open(link: Option<&Path>) -> Result<Self, PtyError> {
        let (master, slave) = TTYPort::pair().map_err(|e| PtyError::Open(e.description))?;
        let path = slave
            .name()
            .ok_or_else(|| PtyError::Open("the pty has no name".into()))?;
        let mut replaced_stale = false;
        let link = match link {
            Some(at) => {
                replaced_stale = make_link(&path, at)?;
                Some(at.to_path_buf())
            }
            None => None,
        };
        Ok(Self {
            master,
            _slave: slave,
            path,
            link,
            replaced_stale,
            strict: None,
        })
    }

    /// Whether `open` replaced a stale link (the caller says so).
    pub fn replaced_stale_link(&self) -> bool {
        self.replaced_stale
    }

    /// Times the line as `timing` says from now on.
    pub fn strict_timing(&mut self, timing: StrictTiming) {
        self.strict = Some(timing);
    }

    /// The path clients open, such as `/dev/pts/7`.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// Serves `device` until `stop` is set. `gap` is the silence after which the line counts
    /// as idle (the Modbus frame gap).
    pub fn serve(
        &mut self,
        device: &mut dyn ByteDevice,
        faults: &Drawn,
        gap: Duration,
        stop: &AtomicBool,
    ) -> Result<(), PtyError> {
        let mut rng = faults.rng();
        let poll = Duration::from_millis(50);
        let mut buf = [0u8; 1024];
        let mut heard_since_idle = false;
        if self.strict.is_some() {
            prefer_realtime();
        }
        let mut line = self.strict.clone().map(|rules| Line {
            origin: Instant::now(),
            timeline: Timeline::new(rules.baud),
            rules,
            dropping: false,
        });
        while !stop.load(Ordering::Relaxed) {
            let wait = if heard_since_idle { gap } else { poll };
            self.master
                .set_timeout(wait)
                .map_err(|e| io::Error::other(e.description))?;
            match self.master.read(&mut buf) {
                Ok(n) => {
                    let received = buf.get(..n).unwrap_or_default();
                    heard_since_idle = true;
                    if line.as_mut().is_some_and(|l| !l.hear(n)) {
                        continue;
                    }
                    let answer = device.receive(received);
                    if !answer.is_empty() {
                        self.answer(answer, faults, &mut rng, line.as_mut())?;
                    }
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock
                    ) =>
                {
                    if heard_since_idle {
                        heard_since_idle = false;
                        let answer = device.line_idle();
                        if !answer.is_empty() {
                            self.answer(answer, faults, &mut rng, line.as_mut())?;
                        }
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e.into()),
            }
        }
        Ok(())
    }

    fn answer(
        &mut self,
        answer: Vec<u8>,
        faults: &Drawn,
        rng: &mut fastrand::Rng,
        line: Option<&mut Line>,
    ) -> Result<(), PtyError> {
        // Under strict timing the answer starts once the request has left the wire and is
        // handed over when its own last byte would arrive.
        let timed = line.map(|l| {
            let now = l.now();
            let start = l
                .timeline
                .busy_until(Side::Master)
                .map_or(now, |end| end.max(now))
                .saturating_add(faults.late);
            let end = start.saturating_add(l.timeline.wire_time(answer.len()));
            (l, start, end)
        });
        match &timed {
            Some((l, _, end)) => std::thread::sleep(end.saturating_sub(l.now())),
            None if !faults.late.is_zero() => std::thread::sleep(faults.late),
            None => {}
        }
        let Some(answer) = faults.apply(rng, answer) else {
            return Ok(());
        };
        // The frame ends as its last byte is handed over: the master can have it before the
        // write returns.
        if let Some((l, start, _)) = timed {
            let end = l.now();
            l.timeline.frame(Side::Slave, start, end, answer.len());
        }
        self.master.write_all(&answer)?;
        Ok(())
    }
}

/// Best effort for a thread that times a line: prompt timers, and a real-time priority where
/// the system allows it (a simulator starved by other work would misjudge the line).
pub fn prefer_realtime() {
    let _ = crate::time::clock::prefer_prompt_wakeups();
    let param = libc::sched_param { sched_priority: 10 };
    // SAFETY: a valid sched_param for the calling thread; a refusal (no privilege) is harmless.
    let _ = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
}

/// Makes the symlink `at` to the pty `pty`; true when it replaced a stale one.
fn make_link(pty: &str, at: &Path) -> Result<bool, PtyError> {
    let refused = |source| PtyError::Link {
        path: at.to_path_buf(),
        source,
    };
    // symlink(2) fails with EEXIST on any existing path, dangling links included.
    let err = match std::os::unix::fs::symlink(pty, at) {
        Ok(()) => return Ok(false),
        Err(e) if e.kind() == io::ErrorKind::AlreadyExists => e,
        Err(e) => return Err(refused(e)),
    };
    let Ok(target) = std::fs::read_link(at) else {
        return Err(refused(err));
    };
    let target = if target.is_relative() {
        at.parent().unwrap_or(Path::new("")).join(target)
    } else {
        target
    };
    // A pty's node lives as long as its master is open: a link to one that is there is
    // still served, unless it is the one just opened (the dead simulator's number, reused).
    if target == Path::new(pty) {
        return Ok(true);
    }
    match std::fs::metadata(&target) {
        Ok(meta) if meta.file_type().is_char_device() => {
            return Err(PtyError::LinkInUse {
                path: at.to_path_buf(),
                holders: Box::new(holders_of(&target)),
                target,
            })
        }
        Err(e) if e.kind() == io::ErrorKind::NotFound && target.starts_with("/dev/pts") => {}
        _ => return Err(refused(err)),
    }
    std::fs::remove_file(at).map_err(refused)?;
    std::os::unix::fs::symlink(pty, at).map_err(refused)?;
    Ok(true)
}

impl Drop for PtyServer {
    fn drop(&mut self) {
        // Only the link this server made: if something else has been put there since, it stays.
        if let Some(link) = &self.link {
            if std::fs::read_link(link).is_ok_and(|to| to == Path::new(&self.path)) {
                let _ = std::fs::remove_file(link);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::serial::SerialLink;
    use crate::link::ByteLink;
    use std::sync::Arc;

    /// Answers each line with the line reversed; counts idle notices.
    struct Reverser {
        line: Vec<u8>,
        idles: Arc<std::sync::atomic::AtomicUsize>,
    }

    impl ByteDevice for Reverser {
        fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
            let mut out = Vec::new();
            for &b in bytes {
                if b == b'\r' {
                    out.extend(self.line.drain(..).rev());
                    out.push(b'\r');
                } else {
                    self.line.push(b);
                }
            }
            out
        }

        fn line_idle(&mut self) -> Vec<u8> {
            self.idles.fetch_add(1, Ordering::Relaxed);
            Vec::new()
        }
    }

    fn run_server(
        faults: Drawn,
        link: Option<PathBuf>,
    ) -> (
        String,
        Arc<AtomicBool>,
        Arc<std::sync::atomic::AtomicUsize>,
        std::thread::JoinHandle<()>,
    ) {
        run_timed_server(faults, link, None)
    }

    fn run_timed_server(
        faults: Drawn,
        link: Option<PathBuf>,
        strict: Option<StrictTiming>,
    ) -> (
        String,
        Arc<AtomicBool>,
        Arc<std::sync::atomic::AtomicUsize>,
        std::thread::JoinHandle<()>,
    ) {
        let mut server = PtyServer::open(link.as_deref()).unwrap();
        if let Some(strict) = strict {
            server.strict_timing(strict);
        }
        let path = server.path().to_string();
        let stop = Arc::new(AtomicBool::new(false));
        let idles = Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let (stop2, idles2) = (Arc::clone(&stop), Arc::clone(&idles));
        let handle = std::thread::spawn(move || {
            let mut dev = Reverser {
                line: Vec::new(),
                idles: idles2,
            };
            server
                .serve(&mut dev, &faults, Duration::from_millis(5), &stop2)
                .unwrap();
        });
        (path, stop, idles, handle)
    }

    fn ask(link: &mut SerialLink, q: &[u8], want: usize) -> Vec<u8> {
        link.write_all(q).unwrap();
        let mut got = Vec::new();
        let mut buf = [0u8; 64];
        while got.len() < want {
            let n = link.read(&mut buf, Duration::from_millis(300)).unwrap();
            if n == 0 {
                break;
            }
            got.extend_from_slice(&buf[..n]);
        }
        got
    }

    #[test]
    fn serves_answers_reports_idle_and_removes_its_link() {
        let link_path =
            std::env::temp_dir().join(format!("rigscript-pty-test-{}", std::process::id()));
        let (path, stop, idles, handle) = run_server(Drawn::default(), Some(link_path.clone()));
        assert_eq!(
            std::fs::read_link(&link_path).unwrap(),
            PathBuf::from(&path)
        );
        let mut link = SerialLink::open(link_path.to_str().unwrap(), 9600).unwrap();
        assert_eq!(ask(&mut link, b"abc\r", 4), b"cba\r");
        // A second client after the first closes: the pty stays usable.
        drop(link);
        let mut link = SerialLink::open(&path, 9600).unwrap();
        assert_eq!(ask(&mut link, b"xy\r", 3), b"yx\r");
        std::thread::sleep(Duration::from_millis(30));
        assert!(
            idles.load(Ordering::Relaxed) >= 1,
            "line_idle after silence"
        );
        stop.store(true, Ordering::Relaxed);
        handle.join().unwrap();
        assert!(
            !link_path.exists() && !link_path.is_symlink(),
            "symlink removed on exit"
        );
    }

    #[test]
    fn drop_and_flip_faults_change_answers() {
        let faults = Drawn {
            drop: 1.0,
            seed: Some(1),
            ..Drawn::default()
        };
        let (path, stop, _, handle) = run_server(faults, None);
        let mut link = SerialLink::open(&path, 9600).unwrap();
        assert_eq!(ask(&mut link, b"abc\r", 4), b"", "every answer dropped");
        stop.store(true, Ordering::Relaxed);
        handle.join().unwrap();

        let faults = Drawn {
            flip: 1.0,
            seed: Some(2),
            ..Drawn::default()
        };
        let (path, stop, _, handle) = run_server(faults, None);
        let mut link = SerialLink::open(&path, 9600).unwrap();
        let got = ask(&mut link, b"abc\r", 4);
        assert_eq!(got.len(), 4);
        assert_ne!(got, b"cba\r", "one bit flipped");
        let differing: u32 = got
            .iter()
            .zip(b"cba\r")
            .map(|(a, b)| (a ^ b).count_ones())
            .sum();
        assert_eq!(differing, 1);
        stop.store(true, Ordering::Relaxed);
        handle.join().unwrap();
    }

    #[test]
    fn strict_timing_drops_and_counts_requests_that_follow_too_soon() {
        let early = Arc::new(AtomicU64::new(0));
        let required = Duration::from_millis(20);
        let strict = StrictTiming {
            baud: 9600,
            required,
            early: Arc::clone(&early),
        };
        let (path, stop, _, handle) = run_timed_server(Drawn::default(), None, Some(strict));
        let mut link = SerialLink::open(&path, 9600).unwrap();
        let started = Instant::now();
        assert_eq!(ask(&mut link, b"abc\r", 4), b"cba\r");
        assert!(
            started.elapsed() >= crate::link::line::wire_time(8, 9600),
            "the answer took its time on the wire"
        );
        // At once after the answer: a module on a shared line hears one merged frame.
        assert_eq!(ask(&mut link, b"xy\r", 3), b"", "dropped");
        assert_eq!(early.load(Ordering::Relaxed), 1);
        std::thread::sleep(required * 2);
        assert_eq!(ask(&mut link, b"xy\r", 3), b"yx\r");
        assert_eq!(early.load(Ordering::Relaxed), 1);
        stop.store(true, Ordering::Relaxed);
        handle.join().unwrap();
    }

    #[test]
    fn a_live_link_is_refused_with_its_holder_a_stale_one_replaced_and_only_its_own_removed() {
        let dir = std::env::temp_dir().join(format!("rigscript-pty-link-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("file");
        std::fs::write(&file, "keep").unwrap();
        let to_file = dir.join("to-file");
        std::os::unix::fs::symlink(&file, &to_file).unwrap();
        let other = PtyServer::open(Some(&dir.join("other"))).unwrap();
        for (at, was) in [(&file, None), (&to_file, Some(file.clone()))] {
            let err = PtyServer::open(Some(at)).err().expect("refused");
            assert!(matches!(err, PtyError::Link { .. }), "{err}");
            let text = err.to_string();
            assert!(
                text.contains("File exists") && text.contains("pick another path"),
                "{text}"
            );
            assert_eq!(
                std::fs::read_link(at).ok(),
                was,
                "{} untouched",
                at.display()
            );
        }
        // Another server's link: refused, naming who holds its pty (this process).
        let err = PtyServer::open(Some(&dir.join("other")))
            .err()
            .expect("refused");
        let text = err.to_string();
        assert!(matches!(err, PtyError::LinkInUse { .. }), "{text}");
        assert!(
            text.contains(&format!("it points to {}", other.path()))
                && text.contains(&format!("this process, pid {}", std::process::id())),
            "{text}"
        );
        assert_eq!(
            std::fs::read_link(dir.join("other")).ok(),
            Some(PathBuf::from(other.path()))
        );
        // A link to a pty that is gone is stale: replaced.
        let dangling = dir.join("dangling");
        std::os::unix::fs::symlink("/dev/pts/rigscript-gone", &dangling).unwrap();
        let taker = PtyServer::open(Some(&dangling)).unwrap();
        assert!(taker.replaced_stale_link());
        assert!(!other.replaced_stale_link());
        assert_eq!(
            std::fs::read_link(&dangling).ok(),
            Some(PathBuf::from(taker.path()))
        );
        drop(taker);
        assert!(!dangling.is_symlink(), "the link it made is removed");
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "keep");

        // A link replaced behind the server's back is not the server's to remove.
        let mine = dir.join("mine");
        let server = PtyServer::open(Some(&mine)).unwrap();
        std::fs::remove_file(&mine).unwrap();
        std::os::unix::fs::symlink(&file, &mine).unwrap();
        drop(server);
        assert_eq!(std::fs::read_link(&mine).unwrap(), file);
        drop(other);
        assert!(!dir.join("other").is_symlink(), "its own link is removed");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
