//! The journal's writer: a consumer of the run's event stream on a thread of its own behind a
//! bounded queue, like the log and the records file, so the loop never waits for the disk.
//! What its queue loses is written where it was lost (a `gap` entry) and counted: a replay of
//! that journal is not exact from there. Bounded in size: a part that reaches half the bound
//! is moved aside to `FILE.1` (the one before that is deleted) and a new part begins, opening
//! with the last reading of every input.

use super::entry::{Entry, What};
use super::read::older_part;
use super::tally::{Tally, KINDS};
use super::{Header, MAGIC, VERSION};
use crate::runtime::observe::{
    Bound, Detacher, EventKind, Events, Kinds, Next, RunEvent, Subscription,
};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::sync::mpsc::RecvTimeoutError;
use std::thread::JoinHandle;
use std::time::Duration;

/// The journal's bound unless told (`run --journal-size`): with the part before, at most this.
pub const DEFAULT_SIZE: u64 = 64 << 20;

/// The queue of the journal's consumer: some seconds of a busy run.
pub const QUEUE: usize = 4096;

/// Where and how big.
#[derive(Debug, Clone)]
pub struct Settings {
    /// The file.
    pub path: PathBuf,
    /// Bytes kept at most, the part before included.
    pub size: u64,
    /// The consumer's queue.
    pub bound: Bound,
    /// `run --journal-image`: the journal watches the rig, so its whole I/O image is read
    /// (`runtime::watched_image`, at what that costs on the line) and journaled apart.
    pub image: bool,
}

impl Settings {
    /// `path`, bounded at `size` bytes, with the default queue.
    pub fn new(path: impl Into<PathBuf>, size: u64) -> Self {
        Self {
            path: path.into(),
            size,
            bound: Bound::events(QUEUE),
            image: false,
        }
    }
}

/// Why a journal could not be written.
#[derive(Debug, thiserror::Error)]
#[error("journal {path}: {source}")]
pub struct WriteError {
    /// The file.
    pub path: String,
    /// Why.
    #[source]
    pub source: std::io::Error,
}

/// A journal opened with its header written, waiting for the run's events (opened before
/// any device is touched: a file that cannot be written refuses the run at once).
pub struct Prepared {
    settings: Settings,
    header: Header,
    out: BufWriter<File>,
    written: u64,
}

/// What the writer did, told at the end.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Report {
    /// Events its queue lost.
    pub lost: u64,
    /// Entries written.
    pub entries: u64,
    /// Parts moved aside.
    pub rotations: u32,
    /// The write that failed, if one did (nothing is written after it).
    pub failed: Option<String>,
}

impl Report {
    /// What the run's log should say of the journal, if anything.
    pub fn warning(&self, path: &str) -> Option<String> {
        match (&self.failed, self.lost) {
            (Some(e), _) => Some(format!("journal {path}: writing stopped: {e}")),
            (None, 0) => None,
            (None, n) => Some(format!(
                "journal {path}: {n} event(s) lost (its queue was full): a replay is exact \
                 only up to the first gap"
            )),
        }
    }
}

fn start_part(out: &mut impl Write, header: &Header) -> std::io::Result<u64> {
    let json = serde_json::to_string(header).map_err(std::io::Error::other)?;
    let text = format!("{MAGIC} {VERSION}\nH {json}\n");
    out.write_all(text.as_bytes())?;
    Ok(text.len() as u64)
}

impl Prepared {
    /// Creates the file (replacing one there) and writes its header.
    pub fn new(settings: Settings, header: Header) -> Result<Self, WriteError> {
        let fail = |source| WriteError {
            path: settings.path.display().to_string(),
            source,
        };
        let file = File::create(&settings.path).map_err(fail)?;
        let mut out = BufWriter::new(file);
        let written = start_part(&mut out, &header)
            .and_then(|n| out.flush().map(|()| n))
            .map_err(fail)?;
        Ok(Self {
            settings,
            header,
            out,
            written,
        })
    }

    /// The file.
    pub fn path(&self) -> &std::path::Path {
        &self.settings.path
    }

    /// Attaches to the run's events and writes on a thread of its own.
    pub fn start(self, events: &Events) -> Result<Running, WriteError> {
        let mut kinds = KINDS.to_vec();
        if self.settings.image {
            kinds.push(EventKind::Shown);
        }
        let watching = self.settings.image.then(|| events.watching());
        let sub = events
            .subscribe_to("journal", self.settings.bound, Kinds::of(&kinds))
            .map_err(|e| WriteError {
                path: self.settings.path.display().to_string(),
                source: std::io::Error::other(e),
            })?;
        let detacher = sub.detacher();
        let thread = std::thread::Builder::new()
            .name("journal".into())
            .spawn(move || {
                // Held while the journal is written: the rig reads its whole image for it.
                let _watching = watching;
                self.write_all(sub)
            })
            .map_err(|source| WriteError {
                path: String::new(),
                source,
            })?;
        Ok(Running { thread, detacher })
    }

    fn write_all(mut self, mut sub: Subscription) -> Report {
        let mut tally = Tally::default();
        let mut report = Report::default();
        loop {
            let next = match sub.handover(Duration::ZERO) {
                Err(RecvTimeoutError::Timeout) => {
                    // Nothing queued: what is written reaches the file now, so a power cut
                    // costs at most the line being written.
                    if let Err(e) = self.out.flush() {
                        report.failed = Some(e.to_string());
                        return report;
                    }
                    sub.handover(Duration::from_secs(1))
                }
                other => other,
            };
            let entry = match next {
                Ok(Next::Event(event)) => {
                    let ended = matches!(*event, RunEvent::Ended { .. });
                    let entry = tally.take(sub.tick(), &event);
                    if let Some(e) = entry {
                        if let Err(e) = self.put(&e, &tally) {
                            report.failed = Some(e.to_string());
                            return report;
                        }
                        report.entries += 1;
                    }
                    if ended {
                        break;
                    }
                    continue;
                }
                Ok(Next::Dropped(n)) => {
                    report.lost += n;
                    tally.gap(sub.tick(), n)
                }
                Ok(Next::Quiet) | Err(RecvTimeoutError::Timeout) => continue,
                Err(RecvTimeoutError::Disconnected) => break,
            };
            if let Err(e) = self.put(&entry, &tally) {
                report.failed = Some(e.to_string());
                return report;
            }
            report.entries += 1;
        }
        report.rotations = self.header.part;
        if let Err(e) = self.out.flush() {
            report.failed = Some(e.to_string());
        }
        report
    }

    /// Writes one entry, starting a new part first if this one is full.
    fn put(&mut self, entry: &Entry, tally: &Tally) -> std::io::Result<()> {
        let line = entry.line();
        let len = line.len() as u64 + 1;
        if self.written + len > self.settings.size / 2 {
            self.rotate(tally)?;
        }
        self.out.write_all(line.as_bytes())?;
        self.out.write_all(b"\n")?;
        self.written += len;
        // A part started after a reload names the script that runs by then.
        if let What::Reloaded { hash, file, source } = &entry.what {
            self.header.hash.clone_from(hash);
            self.header.script_file.clone_from(file);
            self.header.script.clone_from(source);
        }
        Ok(())
    }

    fn rotate(&mut self, tally: &Tally) -> std::io::Result<()> {
        self.out.flush()?;
        let path = &self.settings.path;
        std::fs::rename(path, older_part(path))?;
        self.out = BufWriter::new(File::create(path)?);
        self.header.part += 1;
        self.header.from_tick = tally.tick();
        self.written = start_part(&mut self.out, &self.header)?;
        for e in tally.readings() {
            let line = e.line();
            self.out.write_all(line.as_bytes())?;
            self.out.write_all(b"\n")?;
            self.written += line.len() as u64 + 1;
        }
        Ok(())
    }
}

/// The writer at work.
pub struct Running {
    thread: JoinHandle<Report>,
    detacher: Detacher,
}

impl Running {
    /// Waits for the writer to write what the run told (its end included, once it ended)
    /// and says what it did.
    pub fn finish(self) -> Report {
        self.detacher.detach();
        self.thread.join().unwrap_or_else(|_| Report {
            failed: Some("the journal's thread panicked".into()),
            ..Report::default()
        })
    }
}
