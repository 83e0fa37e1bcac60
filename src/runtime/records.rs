//! Records for test rigs: `record(name, value)` and `measure(name, value, limits)` append one
//! JSON object per line, with a timestamp, to the records file, and are kept in memory.
//!
//! Each record is a `RunEvent::Record` on the run's event stream; the file is one consumer of
//! it (`runtime::line_consumer`, as the log's output is), on its own thread behind a bounded
//! queue, so a file that does not take them (a pipe nobody reads, a hung mount, a full disk)
//! never holds the scan loop: records it cannot take are counted, told in the log once it
//! takes them again, and make the run's exit status 5 (`close`).

use super::line_consumer::{LineConsumer, Lines};
use super::log::{Level, Logger};
use super::observe::{Bound, EventKind, Events, Kinds, RunEvent};
pub use super::records_file::RecordError;
use super::records_file::{open_for_appending, refusals, RecordSink, RecordTarget, SharedRefusals};
use serde_json::{json, Map, Value};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Records kept in memory at most (the oldest go first); the file keeps them all.
pub const MAX_KEPT_RECORDS: usize = 100_000;

/// Records waiting for the file at most: their bytes, and their count; past either, records
/// are dropped, counted and told. Four times the log's: a test rig's records are its results.
pub const QUEUE: Bound = Bound {
    events: 16_384,
    bytes: 4 * 1024 * 1024,
};

/// How long opening the records file may take at start (a hung network mount never returns).
pub const OPEN_WAIT: Duration = Duration::from_secs(2);

/// How long the end of a run waits for the records queued to be written.
pub const CLOSE_WAIT: Duration = Duration::from_secs(1);

/// The limits a measurement must keep; either may be absent.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Limits {
    /// Lowest acceptable value.
    pub min: Option<f64>,
    /// Highest acceptable value.
    pub max: Option<f64>,
    /// Unit, for people.
    pub unit: Option<String>,
}

impl Limits {
    /// Whether `value` lies within the limits (a NaN never does).
    pub fn pass(&self, value: f64) -> bool {
        !value.is_nan()
            && self.min.map_or(true, |min| value >= min)
            && self.max.map_or(true, |max| value <= max)
    }
}

/// The records of one run.
#[derive(Default)]
pub struct Records {
    file: Option<RecordsFile>,
    kept: Vec<Value>,
    failed: u64,
}

/// The records file: its writer thread and what the log has been told of it.
struct RecordsFile {
    path: PathBuf,
    writer: LineConsumer,
    refusals: SharedRefusals,
    /// Records published for the file.
    sent: u64,
    /// Records its queue had lost at the last record.
    lost_seen: u64,
    /// Whether records were lost since the last one the queue took (the log is told once
    /// it takes one again).
    losing: bool,
    /// Records the file refused that the log has told of.
    refused_told: u64,
    /// Whether the log has said the file is refusing records now.
    refusing_told: bool,
}

impl Records {
    /// Records kept in memory only.
    pub fn in_memory() -> Self {
        Self::default()
    }

    /// Records appended to `path` too (created if missing), written by a consumer of
    /// `events` (the run's, which the records are published to). Opening it never waits
    /// long: a named pipe nobody reads is `NoReader`, an open that has not come back after
    /// `OPEN_WAIT` is `OpenHung`.
    pub fn to_file(path: &Path, events: &Events) -> Result<Self, RecordError> {
        Self::to_target(path, events, OPEN_WAIT, open_for_appending)
    }

    /// As `to_file`, with the file opened by `open` on the writer thread.
    fn to_target<F: RecordTarget + 'static>(
        path: &Path,
        events: &Events,
        wait: Duration,
        open: impl FnOnce(&Path) -> Result<F, RecordError> + Send + 'static,
    ) -> Result<Self, RecordError> {
        let subscription = events
            .subscribe_to("records", QUEUE, Kinds::of(&[EventKind::Record]))
            .map_err(|e| RecordError::File {
                path: path.to_path_buf(),
                source: std::io::Error::other(e),
            })?;
        let refusals = SharedRefusals::default();
        let (opened, outcome) = std::sync::mpsc::sync_channel(1);
        let theirs = std::sync::Arc::clone(&refusals);
        let target = path.to_path_buf();
        let writer = LineConsumer::spawn(
            "rigscript-records",
            subscription,
            RecordLines,
            move || match open(&target) {
                Ok(file) => {
                    let _ = opened.send(Ok(()));
                    Some(RecordSink::new(file, theirs))
                }
                Err(e) => {
                    let _ = opened.send(Err(e));
                    None
                }
            },
        );
        let result = match outcome.recv_timeout(wait) {
            Ok(result) => result,
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => Err(RecordError::OpenHung {
                path: path.to_path_buf(),
                wait,
            }),
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => Err(RecordError::File {
                path: path.to_path_buf(),
                source: std::io::Error::other("its writer thread could not be started"),
            }),
        };
        if let Err(e) = result {
            // The thread ends once the open comes back, if ever.
            let _ = writer.close(Duration::ZERO);
            return Err(e);
        }
        let mut records = Self::default();
        records.file = Some(RecordsFile {
            path: path.to_path_buf(),
            writer,
            refusals,
            sent: 0,
            lost_seen: 0,
            losing: false,
            refused_told: 0,
            refusing_told: false,
        });
        Ok(records)
    }

    /// Appends `{"time", "name", "value"}`; never waits for the file (see the module doc), and
    /// tells `log` what became of records the file did not take.
    pub fn record(&mut self, time: &str, name: &str, value: Value, log: &mut Logger) {
        self.append(json!({ "time": time, "name": name, "value": value }), log);
    }

    /// Appends `{"time", "name", "value", "min", "max", "unit", "pass"}` (absent limits left
    /// out) and returns whether the value passed; a failure is counted for the exit status,
    /// whether or not the file took the record.
    pub fn measure(
        &mut self,
        time: &str,
        name: &str,
        value: f64,
        limits: &Limits,
        log: &mut Logger,
    ) -> bool {
        let pass = limits.pass(value);
        let mut object = Map::new();
        object.insert("time".into(), json!(time));
        object.insert("name".into(), json!(name));
        // JSON has no NaN: a NaN measurement is recorded as null (and fails).
        object.insert(
            "value".into(),
            serde_json::Number::from_f64(value).map_or(Value::Null, Value::Number),
        );
        if let Some(min) = limits.min {
            object.insert("min".into(), json!(min));
        }
        if let Some(max) = limits.max {
            object.insert("max".into(), json!(max));
        }
        if let Some(unit) = &limits.unit {
            object.insert("unit".into(), json!(unit));
        }
        object.insert("pass".into(), json!(pass));
        if !pass {
            self.failed = self.failed.saturating_add(1);
        }
        self.append(Value::Object(object), log);
        pass
    }

    /// Measurements that failed their limits so far.
    pub fn failed(&self) -> u64 {
        self.failed
    }

    /// Records the file has not taken so far: dropped by its queue or refused by the file
    /// (a full disk), for `status`, `--json` and `/metrics` while the loss goes on. Records
    /// still queued are not counted (`close` counts those it could not write).
    pub fn lost_so_far(&self) -> u64 {
        self.file.as_ref().map_or(0, |f| {
            f.writer
                .losses()
                .count()
                .saturating_add(refusals(&f.refusals).total)
        })
    }

    /// The records kept in memory, oldest first.
    pub fn kept(&self) -> &[Value] {
        &self.kept
    }

    /// Ends the records file: waits up to `CLOSE_WAIT` for what is queued, tells `log` of the
    /// records it did not take, and returns how many (0 without a file). Records after it
    /// are kept in memory only.
    pub fn close(&mut self, log: &mut Logger) -> u64 {
        let Some(mut f) = self.file.take() else {
            return 0;
        };
        let finished = f.writer.close(CLOSE_WAIT);
        f.tell(log);
        let dropped = f.writer.losses().count();
        // What the queue took and the file has not had (the file accounts for what it refused).
        let waiting = if finished {
            0
        } else {
            f.sent
                .saturating_sub(dropped)
                .saturating_sub(f.writer.handled())
        };
        let refused = refusals(&f.refusals).total;
        let lost = dropped.saturating_add(refused).saturating_add(waiting);
        let path = f.path.display();
        if dropped > 0 {
            log.warn(&format!(
                "records file {path}: {dropped} records dropped: the file was not taking them \
                 as fast as they came"
            ));
        }
        if refused > 0 {
            let cause = refusals(&f.refusals).cause.clone();
            log.warn(&format!(
                "records file {path}: {cause}, {refused} records not written"
            ));
        }
        if waiting > 0 {
            log.error(&format!(
                "records file {path}: {waiting} records not written at the end: the file did \
                 not take them within {}s (a pipe nobody reads, a mount that does not answer?)",
                CLOSE_WAIT.as_secs()
            ));
        }
        if lost > 0 {
            log.warn(&format!(
                "records file {path}: {lost} of {} records not written",
                f.sent
            ));
        }
        lost
    }

    fn append(&mut self, record: Value, log: &mut Logger) {
        // The one place a record is told: the file is a consumer of it like any other.
        log.events().publish(|| RunEvent::Record {
            line: record.to_string(),
        });
        if let Some(f) = &mut self.file {
            f.sent = f.sent.saturating_add(1);
            // The loop is the one publisher: a count that grew means this record was lost.
            let lost = f.writer.losses().count();
            if lost > f.lost_seen {
                f.lost_seen = lost;
                f.losing = true;
            } else if std::mem::take(&mut f.losing) {
                {
                    // Once, then counted: a file a little slower than the records comes back
                    // here every few records. The end gives the count.
                    log.repeating(
                        "records/dropped",
                        Level::Warn,
                        &format!(
                            "records file {}: records dropped: the file is not taking them as \
                             fast as they come (a pipe read slowly or not at all, a slow or \
                             hung mount?); the count comes at the end",
                            f.path.display()
                        ),
                    );
                }
            }
            f.tell(log);
        }
        if self.kept.len() >= MAX_KEPT_RECORDS {
            self.kept.remove(0);
        }
        self.kept.push(record);
    }
}

impl RecordsFile {
    /// Tells `log` once when the file starts refusing records, and how many it refused when
    /// it takes them again (a full disk is one line each way, not one a record).
    fn tell(&mut self, log: &mut Logger) {
        let (refusing, total, cause) = {
            let r = refusals(&self.refusals);
            let news = if r.refusing {
                !self.refusing_told
            } else {
                self.refusing_told || r.total > self.refused_told
            };
            if !news {
                return;
            }
            (r.refusing, r.total, r.cause.clone())
        };
        let path = self.path.display();
        if refusing {
            self.refusing_told = true;
            log.error(&format!(
                "records file {path}: {cause}: records are not written until it takes them \
                 again (counted)"
            ));
            return;
        }
        let n = total.saturating_sub(self.refused_told);
        self.refused_told = total;
        self.refusing_told = false;
        if n > 0 {
            log.warn(&format!(
                "records file {path}: {cause}, {n} records not written; written again since"
            ));
        }
    }
}

impl Drop for Records {
    fn drop(&mut self) {
        if let Some(f) = self.file.take() {
            let _ = f.writer.close(CLOSE_WAIT);
        }
    }
}

/// The records file's lines: each record's line as it was published (one line per record:
/// the file writes it whole or not at all). Losses are told by the loop, not in the file.
struct RecordLines;

impl Lines for RecordLines {
    fn line(&mut self, event: &RunEvent) -> Option<String> {
        match event {
            RunEvent::Record { line } => Some(line.clone()),
            _ => None,
        }
    }

    fn lost(&mut self, _lost: u64, _next: &RunEvent) -> Option<String> {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::records_file::SmallDisk;
    use crate::time::clock::VirtualClock;
    use crate::time::zone::Zone;
    use std::sync::Arc;

    fn log() -> Logger {
        let mut log = Logger::new(Arc::new(VirtualClock::at_epoch()), Zone::utc(), false);
        log.keep_lines();
        log
    }

    fn dir(tag: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("rigscript-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn measurements_pass_within_limits_and_failures_are_counted() {
        let mut r = Records::in_memory();
        let mut log = log();
        let limits = Limits {
            min: Some(1.0),
            max: Some(2.0),
            unit: Some("V".into()),
        };
        assert!(r.measure("t", "v", 1.5, &limits, &mut log));
        assert!(r.measure("t", "v", 2.0, &limits, &mut log));
        assert!(!r.measure("t", "v", 2.5, &limits, &mut log));
        assert!(!r.measure("t", "v", f64::NAN, &limits, &mut log));
        assert_eq!(r.failed(), 2);
        assert_eq!(
            r.kept()[2],
            json!({"time": "t", "name": "v", "value": 2.5, "min": 1.0, "max": 2.0, "unit": "V", "pass": false})
        );
        assert_eq!(r.kept()[3]["value"], Value::Null);
        assert!(Limits::default().pass(-1e9));
        assert_eq!(r.close(&mut log), 0);
    }

    #[test]
    fn records_are_appended_as_json_lines() {
        let dir = dir("records");
        let path = dir.join("r.jsonl");
        let mut log = log();
        let mut r = Records::to_file(&path, log.events()).unwrap();
        r.record("t1", "count", json!(3), &mut log);
        r.measure("t2", "v", 0.5, &Limits::default(), &mut log);
        assert_eq!(r.close(&mut log), 0);
        let mut again = Records::to_file(&path, log.events()).unwrap();
        again.record("t3", "x", json!("y"), &mut log);
        assert_eq!(again.close(&mut log), 0);
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<Value> = text
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(lines.len(), 3);
        assert_eq!(lines[0], json!({"time": "t1", "name": "count", "value": 3}));
        assert_eq!(lines[2]["value"], json!("y"));
        assert!(log.lines().is_empty(), "{:?}", log.lines());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_full_disk_is_told_once_with_the_count_of_records_not_written() {
        let mut log = log();
        let mut r = Records::to_target(Path::new("r.jsonl"), log.events(), OPEN_WAIT, |_| {
            Ok(SmallDisk {
                data: Vec::new(),
                room: 100,
                cuttable: true,
            })
        })
        .unwrap();
        for n in 0..50 {
            r.record("t", "n", json!(n), &mut log);
        }
        let lost = r.close(&mut log);
        // 100 bytes hold 2 records of 35 bytes (and half a third, cut back).
        assert_eq!(lost, 48);
        assert_eq!(r.kept().len(), 50, "all kept in memory");
        let lines = log.lines().join("\n");
        assert_eq!(
            lines
                .matches("records file r.jsonl: disk full: records are not written")
                .count(),
            1,
            "{lines}"
        );
        assert!(
            lines.contains("records file r.jsonl: disk full, 48 records not written"),
            "{lines}"
        );
        assert!(
            lines.contains("records file r.jsonl: 48 of 50 records not written"),
            "{lines}"
        );
        assert_eq!(log.lines().len(), 3, "{lines}");
    }

    /// A `SmallDisk` the test keeps a hand on while the writer thread writes to it.
    #[derive(Clone)]
    struct SharedDisk(Arc<std::sync::Mutex<SmallDisk>>);

    impl std::io::Write for SharedDisk {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().write(buf)
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl RecordTarget for SharedDisk {
        fn length(&mut self) -> Option<u64> {
            self.0.lock().unwrap().length()
        }
        fn cut_to(&mut self, length: u64) -> std::io::Result<()> {
            self.0.lock().unwrap().cut_to(length)
        }
    }

    /// Waits until the records file's writer has done what `done` says, or 10 s.
    fn until(
        r: &Records,
        what: &str,
        done: impl Fn(&crate::runtime::records_file::Refusals) -> bool,
    ) {
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        let f = r.file.as_ref().unwrap();
        while !done(&refusals(&f.refusals)) {
            assert!(
                std::time::Instant::now() < deadline,
                "not within 10 s: {what}"
            );
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    #[test]
    fn a_disk_that_fills_and_empties_is_told_once_each_way_and_keeps_whole_lines() {
        let disk = SharedDisk(Arc::new(std::sync::Mutex::new(SmallDisk {
            data: Vec::new(),
            room: 40,
            cuttable: true,
        })));
        let theirs = disk.clone();
        let mut log = log();
        let mut r = Records::to_target(Path::new("r.jsonl"), log.events(), OPEN_WAIT, move |_| {
            Ok(theirs)
        })
        .unwrap();
        r.record("t", "n", json!(0), &mut log);
        r.record("t", "n", json!(1), &mut log);
        until(&r, "1 refused", |f| f.total == 1);
        r.record("t", "n", json!(2), &mut log);
        until(&r, "2 refused", |f| f.total == 2);
        disk.0.lock().unwrap().room = 1000;
        r.record("t", "n", json!(3), &mut log);
        until(&r, "written again", |f| !f.refusing);
        r.record("t", "n", json!(4), &mut log);
        assert_eq!(r.close(&mut log), 2);
        let lines = log.lines().join("\n");
        assert_eq!(
            lines.matches("disk full: records are not written").count(),
            1,
            "{lines}"
        );
        assert!(
            lines.contains(
                "records file r.jsonl: disk full, 2 records not written; written again since"
            ),
            "{lines}"
        );
        assert!(
            lines.contains("records file r.jsonl: 2 of 5 records not written"),
            "{lines}"
        );
        let data = String::from_utf8(disk.0.lock().unwrap().data.clone()).unwrap();
        let values: Vec<Value> = data
            .lines()
            .map(|l| serde_json::from_str::<Value>(l).unwrap()["value"].clone())
            .collect();
        assert_eq!(values, [json!(0), json!(3), json!(4)]);
    }

    #[test]
    fn an_open_that_does_not_come_back_is_given_up() {
        let (_release, held) = std::sync::mpsc::channel::<()>();
        let e = Records::to_target(
            Path::new("/mnt/nfs/r.jsonl"),
            &Events::default(),
            Duration::from_millis(50),
            move |_| {
                let _ = held.recv();
                Err::<SmallDisk, _>(RecordError::NoReader {
                    path: PathBuf::new(),
                })
            },
        )
        .err()
        .expect("given up");
        assert!(
            e.to_string()
                .starts_with("records file /mnt/nfs/r.jsonl: opening it did not finish within"),
            "{e}"
        );
    }

    #[test]
    fn a_pipe_nobody_reads_never_holds_a_record_and_the_loss_is_told() {
        use std::os::unix::fs::OpenOptionsExt;
        let dir = dir("records-fifo");
        let path = dir.join("r.fifo");
        let c = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: a valid C string.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        // A reader that has the pipe open and never reads.
        let reader = std::fs::OpenOptions::new()
            .read(true)
            .custom_flags(libc::O_NONBLOCK)
            .open(&path)
            .unwrap();
        let (done, finished) = std::sync::mpsc::channel();
        let path_for_run = path.clone();
        let recording = std::thread::spawn(move || {
            let mut log = log();
            let mut r = Records::to_file(&path_for_run, log.events()).unwrap();
            // Far more than a pipe (64 KiB) and the queue (4 MiB) together hold.
            let big = "x".repeat(1000);
            for n in 0..10_000 {
                r.record("t", "n", json!(format!("{n} {big}")), &mut log);
            }
            done.send(()).unwrap();
            let lost = r.close(&mut log);
            (lost, log.lines().join("\n"))
        });
        finished
            .recv_timeout(Duration::from_secs(60))
            .expect("record() waited for a pipe nobody reads");
        let (lost, lines) = recording.join().unwrap();
        assert!(lost > 1000, "{lost}: {lines}");
        assert!(
            lines.contains(&format!(
                "records file {}: {lost} of 10000 records not written",
                path.display()
            )),
            "{lines}"
        );
        assert!(
            lines.contains("records dropped: the file was not taking them"),
            "{lines}"
        );
        assert!(
            lines.lines().count() <= 5,
            "a few lines, not one a record: {lines}"
        );
        drop(reader);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
