//! The records file on its writer thread: opened without waiting (a named pipe nobody reads
//! is refused at once, an open that hangs is given up), written in whole lines only (a write
//! the file took part of, on a full disk, is cut back, or the next one starts a fresh line
//! where the file cannot be cut), and what the file refused counted with its cause.

use super::line_consumer::LineSink;
use std::fs::{File, OpenOptions};
use std::io::{self, Write};
use std::os::fd::AsRawFd;
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

/// Why the records file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The records file cannot be opened.
    #[error("records file {}: {source}", path.display())]
    File {
        /// The file.
        path: PathBuf,
        /// Why.
        source: io::Error,
    },
    /// A named pipe that no process has open for reading (opening it would wait for one).
    #[error(
        "records file {}: a named pipe (FIFO) that nothing reads; start its reader first \
         (for example `cat {0} > records.jsonl &`), or give a regular file",
        path.display()
    )]
    NoReader {
        /// The pipe.
        path: PathBuf,
    },
    /// Opening it did not come back (a network mount that does not answer).
    #[error(
        "records file {}: opening it did not finish within {}s (a network mount that does \
         not answer?); check the mount, or give a file on a local disk",
        path.display(), wait.as_secs()
    )]
    OpenHung {
        /// The file.
        path: PathBuf,
        /// How long it was given.
        wait: Duration,
    },
}

/// Opens `path` to append records (created if missing) without waiting for a reader: a named
/// pipe with none is `NoReader`. Writes then wait for room again, on the writer thread.
pub fn open_for_appending(path: &Path) -> Result<File, RecordError> {
    let failed = |source| RecordError::File {
        path: path.to_path_buf(),
        source,
    };
    let file = OpenOptions::new()
        .create(true)
        .append(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)
        .map_err(|e| match e.raw_os_error() {
            Some(libc::ENXIO) => RecordError::NoReader {
                path: path.to_path_buf(),
            },
            _ => failed(e),
        })?;
    crate::link::fd::set_blocking(file.as_raw_fd()).map_err(failed)?;
    Ok(file)
}

/// A records file as its writer needs it: written, and cut back where it is a regular file.
pub trait RecordTarget: Write {
    /// Its length now, where it can be cut back to it (a regular file); `None` otherwise.
    fn length(&mut self) -> Option<u64>;
    /// Cuts it back to `length` bytes.
    fn cut_to(&mut self, length: u64) -> io::Result<()>;
}

impl RecordTarget for File {
    fn length(&mut self) -> Option<u64> {
        self.metadata()
            .ok()
            .filter(std::fs::Metadata::is_file)
            .map(|m| m.len())
    }

    fn cut_to(&mut self, length: u64) -> io::Result<()> {
        self.set_len(length)
    }
}

/// What the records file refused, shared between its writer thread and the run.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct Refusals {
    /// Records the file refused, in all.
    pub total: u64,
    /// Whether the latest write failed (it is refusing now).
    pub refusing: bool,
    /// Why, in words ("disk full").
    pub cause: String,
}

/// The shared count of what the file refused.
pub type SharedRefusals = Arc<Mutex<Refusals>>;

/// Reads the shared count.
pub fn refusals(shared: &SharedRefusals) -> MutexGuard<'_, Refusals> {
    // A panic on the writer thread leaves the counts usable.
    crate::sync::lock(shared)
}

/// The records file as the writer thread writes it.
pub struct RecordSink<F> {
    file: F,
    /// Half a line was left that could not be cut back: the next write starts a fresh line.
    fresh_line: bool,
    refusals: SharedRefusals,
}

impl<F: RecordTarget> RecordSink<F> {
    /// Writes to `file`, counting what it refuses in `refusals`.
    pub fn new(file: F, refusals: SharedRefusals) -> Self {
        Self {
            file,
            fresh_line: false,
            refusals,
        }
    }
}

impl<F: RecordTarget> LineSink for RecordSink<F> {
    fn write_batch(&mut self, batch: &str, count: usize) {
        let before = self.file.length();
        let prefixed;
        let (bytes, prefix) = if self.fresh_line {
            prefixed = format!("\n{batch}");
            (prefixed.as_str(), 1)
        } else {
            (batch, 0)
        };
        let (took, failure) = write_counting(&mut self.file, bytes.as_bytes());
        let Some(error) = failure else {
            self.fresh_line = false;
            refusals(&self.refusals).refusing = false;
            return;
        };
        // Only whole lines stay: the part of a line the file took is cut back.
        let taken = bytes.get(..took).unwrap_or(bytes);
        let whole = taken.rfind('\n').map_or(0, |i| i + 1);
        if took > whole {
            let cut = before.map(|len| self.file.cut_to(len + whole as u64));
            self.fresh_line = !matches!(cut, Some(Ok(())));
        } else if whole > 0 {
            self.fresh_line = false;
        }
        let newlines = taken.get(..whole).unwrap_or("").matches('\n').count();
        let written = newlines.saturating_sub(if whole > 0 { prefix } else { 0 });
        let refused = count.saturating_sub(written) as u64;
        let mut r = refusals(&self.refusals);
        r.total = r.total.saturating_add(refused);
        r.refusing = true;
        r.cause = describe(&error);
    }
}

/// Writes `bytes` to `out` as far as it takes them: how many it took, and the error that
/// stopped it (`None`: all of them).
fn write_counting(out: &mut impl Write, bytes: &[u8]) -> (usize, Option<io::Error>) {
    let mut took = 0;
    while let Some(rest) = bytes.get(took..).filter(|r| !r.is_empty()) {
        match out.write(rest) {
            Ok(0) => return (took, Some(io::ErrorKind::WriteZero.into())),
            Ok(n) => took += n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return (took, Some(e)),
        }
    }
    (took, out.flush().err())
}

/// Why a write failed, for people.
fn describe(error: &io::Error) -> String {
    match error.raw_os_error() {
        Some(libc::ENOSPC) => "disk full".into(),
        Some(libc::EDQUOT) => "disk quota exceeded".into(),
        Some(libc::EFBIG) => "file too large (past the file size limit)".into(),
        Some(libc::EPIPE) => "the pipe's reader went away".into(),
        _ => error.to_string(),
    }
}

#[cfg(test)]
/// A file on a disk with `room` bytes left, cut back as a regular file is (or, with
/// `cuttable` false, never, as a pipe cannot be).
pub struct SmallDisk {
    /// What it holds.
    pub data: Vec<u8>,
    /// Bytes it takes in all.
    pub room: usize,
    /// Whether it can be cut back.
    pub cuttable: bool,
}

#[cfg(test)]
impl Write for SmallDisk {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let left = self.room.saturating_sub(self.data.len());
        if left == 0 {
            return Err(io::Error::from_raw_os_error(libc::ENOSPC));
        }
        // As the kernel does: a short write first, the error on the next.
        let n = buf.len().min(left);
        self.data.extend_from_slice(&buf[..n]);
        Ok(n)
    }
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

#[cfg(test)]
impl RecordTarget for SmallDisk {
    fn length(&mut self) -> Option<u64> {
        self.cuttable.then_some(self.data.len() as u64)
    }
    fn cut_to(&mut self, length: u64) -> io::Result<()> {
        self.data.truncate(length as usize);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sink(room: usize, cuttable: bool) -> (RecordSink<SmallDisk>, SharedRefusals) {
        let shared = SharedRefusals::default();
        let disk = SmallDisk {
            data: Vec::new(),
            room,
            cuttable,
        };
        (RecordSink::new(disk, Arc::clone(&shared)), shared)
    }

    fn text(s: &RecordSink<SmallDisk>) -> &str {
        std::str::from_utf8(&s.file.data).unwrap()
    }

    #[test]
    fn a_full_disk_leaves_whole_records_only_and_counts_the_rest() {
        let (mut s, shared) = sink(20, true);
        s.write_batch("{\"a\":1}\n{\"b\":2}\n{\"c\":3}\n{\"d\":4}\n", 4);
        assert_eq!(
            text(&s),
            "{\"a\":1}\n{\"b\":2}\n",
            "the half of c is cut back"
        );
        assert_eq!(
            *refusals(&shared),
            Refusals {
                total: 2,
                refusing: true,
                cause: "disk full".into()
            }
        );
        s.write_batch("{\"e\":5}\n", 1);
        assert_eq!(refusals(&shared).total, 3);
        // Room again: the next record is a line of its own.
        s.file.room = 1000;
        s.write_batch("{\"f\":6}\n", 1);
        assert_eq!(text(&s), "{\"a\":1}\n{\"b\":2}\n{\"f\":6}\n");
        assert!(!refusals(&shared).refusing);
        for line in text(&s).lines() {
            serde_json::from_str::<serde_json::Value>(line).unwrap();
        }
    }

    #[test]
    fn where_the_file_cannot_be_cut_the_next_record_starts_a_fresh_line() {
        let (mut s, shared) = sink(12, false);
        s.write_batch("{\"a\":1}\n{\"b\":2}\n", 2);
        assert_eq!(text(&s), "{\"a\":1}\n{\"b\"");
        assert_eq!(refusals(&shared).total, 1);
        s.file.room = 1000;
        s.write_batch("{\"c\":3}\n", 1);
        assert_eq!(text(&s), "{\"a\":1}\n{\"b\"\n{\"c\":3}\n");
        assert_eq!(refusals(&shared).total, 1, "c was written");
        s.write_batch("{\"d\":4}\n", 1);
        assert!(
            text(&s).ends_with("{\"c\":3}\n{\"d\":4}\n"),
            "one fresh line only"
        );
    }

    #[test]
    fn a_named_pipe_nobody_reads_is_refused_at_once() {
        let dir = std::env::temp_dir().join(format!("rigscript-fifo-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("r.fifo");
        let _ = std::fs::remove_file(&path);
        let c = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: a valid C string.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        let e = open_for_appending(&path).unwrap_err();
        assert!(matches!(e, RecordError::NoReader { .. }), "{e}");
        assert!(e.to_string().contains("start its reader first"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
