//! The records' outbox: every record, numbered (`seq`), kept on disk until the broker has
//! acknowledged it, so a broker away for a while or a restart of the runner loses none.
//!
//! Two files in the outbox directory: `RIG.records`, one JSON line a record as published
//! (the records file's object plus `seq`), appended as records come; `RIG.acked`, the highest
//! `seq` the broker acknowledged with all before it, replaced whole (written aside, renamed).
//! At start the records after the acknowledged one are sent again, in order; the numbering goes
//! on from the highest seen. A record acknowledged whose `acked` was not yet written when the
//! process died is sent twice: its `seq` lets a consumer drop the second.

use std::collections::VecDeque;
use std::fs::{self, File, OpenOptions};
use std::io::{self, BufRead, BufReader, Write};
use std::path::{Path, PathBuf};

/// The journal is rewritten with only what waits once it is this much larger than that.
const COMPACT_AT: u64 = 1 << 20;

/// A record waiting for the broker's acknowledgement.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Pending {
    /// Its number.
    pub seq: u64,
    /// Its payload: the records file's line with `seq` added.
    pub payload: String,
}

/// Why the outbox cannot be used.
#[derive(Debug, thiserror::Error)]
#[error("outbox {path}: {source}")]
pub struct OutboxError {
    /// The file or directory.
    pub path: PathBuf,
    /// What the system said.
    #[source]
    pub source: io::Error,
}

/// What `Outbox::push` did with a record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pushed {
    /// Kept, under this number.
    Kept(u64),
    /// Dropped: the outbox holds `outbox_max` bytes already.
    Full,
}

/// The on-disk outbox of one rig.
pub struct Outbox {
    journal_path: PathBuf,
    acked_path: PathBuf,
    journal: File,
    journal_len: u64,
    waiting: VecDeque<Pending>,
    waiting_bytes: u64,
    max: u64,
    next_seq: u64,
    acked: u64,
    acked_written: u64,
}

impl Outbox {
    /// Opens (or makes) the outbox of `rig` in `dir`, bounded to `max` bytes of waiting records.
    pub fn open(dir: &Path, rig: &str, max: u64) -> Result<Self, OutboxError> {
        let at = |path: &Path| {
            let path = path.to_path_buf();
            move |source| OutboxError { path, source }
        };
        fs::create_dir_all(dir).map_err(at(dir))?;
        let journal_path = dir.join(format!("{rig}.records"));
        let acked_path = dir.join(format!("{rig}.acked"));
        let acked = match fs::read_to_string(&acked_path) {
            Ok(text) => text.trim().parse().unwrap_or(0),
            Err(e) if e.kind() == io::ErrorKind::NotFound => 0,
            Err(e) => return Err(at(&acked_path)(e)),
        };
        let mut waiting = VecDeque::new();
        let mut waiting_bytes = 0;
        let mut highest = acked;
        match File::open(&journal_path) {
            Ok(f) => {
                for line in BufReader::new(f).lines() {
                    let line = line.map_err(at(&journal_path))?;
                    // A line cut short by a crash or a full disk has no seq to go by: skipped.
                    let Some(seq) = seq_of(&line) else { continue };
                    highest = highest.max(seq);
                    if seq > acked {
                        waiting_bytes += line.len() as u64 + 1;
                        waiting.push_back(Pending { seq, payload: line });
                    }
                }
            }
            Err(e) if e.kind() == io::ErrorKind::NotFound => {}
            Err(e) => return Err(at(&journal_path)(e)),
        }
        let mut outbox = Self {
            journal: open_journal(&journal_path, false).map_err(at(&journal_path))?,
            journal_len: 0,
            journal_path,
            acked_path,
            waiting,
            waiting_bytes,
            max,
            next_seq: highest + 1,
            acked,
            acked_written: acked,
        };
        // Start from a journal holding only what waits (and no half line at its end).
        outbox.compact().map_err(at(&outbox.journal_path.clone()))?;
        Ok(outbox)
    }

    /// Numbers `line` (a records file line: a JSON object) and keeps it until acknowledged.
    pub fn push(&mut self, line: &str) -> Result<Pushed, OutboxError> {
        let seq = self.next_seq;
        let payload = with_seq(line, seq);
        let size = payload.len() as u64 + 1;
        if self.waiting_bytes + size > self.max {
            return Ok(Pushed::Full);
        }
        self.next_seq += 1;
        let mut bytes = payload.clone().into_bytes();
        bytes.push(b'\n');
        self.journal
            .write_all(&bytes)
            .map_err(|source| OutboxError {
                path: self.journal_path.clone(),
                source,
            })?;
        self.journal_len += size;
        self.waiting_bytes += size;
        self.waiting.push_back(Pending { seq, payload });
        Ok(Pushed::Kept(seq))
    }

    /// The records waiting, oldest first.
    pub fn waiting(&self) -> &VecDeque<Pending> {
        &self.waiting
    }

    /// The highest seq acknowledged with all before it.
    pub fn acked(&self) -> u64 {
        self.acked
    }

    /// The broker acknowledged every record up to `seq`.
    pub fn ack_through(&mut self, seq: u64) {
        while self.waiting.front().is_some_and(|p| p.seq <= seq) {
            if let Some(p) = self.waiting.pop_front() {
                self.waiting_bytes -= p.payload.len() as u64 + 1;
            }
        }
        self.acked = self.acked.max(seq);
    }

    /// Writes what was acknowledged since the last call to disk (and compacts the journal
    /// once it is mostly acknowledged records).
    pub fn commit(&mut self) -> Result<(), OutboxError> {
        if self.acked == self.acked_written {
            return Ok(());
        }
        let at = |path: &Path| {
            let path = path.to_path_buf();
            move |source| OutboxError { path, source }
        };
        let aside = self.acked_path.with_extension("acked.new");
        fs::write(&aside, format!("{}\n", self.acked)).map_err(at(&aside))?;
        fs::rename(&aside, &self.acked_path).map_err(at(&self.acked_path))?;
        self.acked_written = self.acked;
        if self.journal_len > self.waiting_bytes + COMPACT_AT || self.waiting.is_empty() {
            let path = self.journal_path.clone();
            self.compact().map_err(at(&path))?;
        }
        Ok(())
    }

    /// Rewrites the journal with only the records waiting.
    fn compact(&mut self) -> io::Result<()> {
        if self.waiting.is_empty() {
            self.journal = open_journal(&self.journal_path, true)?;
            self.journal_len = 0;
            return Ok(());
        }
        let aside = self.journal_path.with_extension("records.new");
        let mut f = File::create(&aside)?;
        let mut len = 0;
        for p in &self.waiting {
            f.write_all(p.payload.as_bytes())?;
            f.write_all(b"\n")?;
            len += p.payload.len() as u64 + 1;
        }
        f.sync_data()?;
        fs::rename(&aside, &self.journal_path)?;
        self.journal = open_journal(&self.journal_path, false)?;
        self.journal_len = len;
        Ok(())
    }
}

fn open_journal(path: &Path, truncate: bool) -> io::Result<File> {
    let mut o = OpenOptions::new();
    o.create(true);
    if truncate {
        o.write(true).truncate(true);
    } else {
        o.append(true);
    }
    o.open(path)
}

/// `line` (a JSON object) with `"seq":N` first; a line that is not an object is wrapped.
pub fn with_seq(line: &str, seq: u64) -> String {
    let body = line.trim();
    match body.strip_prefix('{') {
        Some("}") => format!("{{\"seq\":{seq}}}"),
        Some(rest) => format!("{{\"seq\":{seq},{rest}"),
        None => format!(
            "{{\"seq\":{seq},\"line\":{}}}",
            serde_json::Value::from(body)
        ),
    }
}

/// The `seq` of a journal line, if it is a whole one.
fn seq_of(line: &str) -> Option<u64> {
    let v: serde_json::Value = serde_json::from_str(line).ok()?;
    v.get("seq")?.as_u64()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d =
            std::env::temp_dir().join(format!("rigscript-outbox-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn records_are_numbered_kept_until_acknowledged_and_resumed_after_a_restart() {
        let d = dir("resume");
        let mut o = Outbox::open(&d, "bench", 1 << 20).unwrap();
        for n in 0..5 {
            assert_eq!(
                o.push(&format!("{{\"name\":\"r\",\"value\":{n}}}"))
                    .unwrap(),
                Pushed::Kept(n + 1)
            );
        }
        o.ack_through(2);
        o.commit().unwrap();
        drop(o);
        let mut o = Outbox::open(&d, "bench", 1 << 20).unwrap();
        let seqs: Vec<u64> = o.waiting().iter().map(|p| p.seq).collect();
        assert_eq!(seqs, vec![3, 4, 5]);
        assert_eq!(
            o.waiting()[0].payload,
            "{\"seq\":3,\"name\":\"r\",\"value\":2}"
        );
        assert_eq!(o.push("{}").unwrap(), Pushed::Kept(6));
        o.ack_through(6);
        o.commit().unwrap();
        drop(o);
        let mut o = Outbox::open(&d, "bench", 1 << 20).unwrap();
        assert!(o.waiting().is_empty());
        assert_eq!(o.push("{}").unwrap(), Pushed::Kept(7), "seq goes on");
        let _ = fs::remove_dir_all(&d);
    }

    #[test]
    fn a_full_outbox_refuses_more_and_a_torn_last_line_is_skipped() {
        let d = dir("full");
        let mut o = Outbox::open(&d, "b", 100).unwrap();
        let line = format!("{{\"v\":\"{}\"}}", "x".repeat(30));
        assert!(matches!(o.push(&line).unwrap(), Pushed::Kept(1)));
        assert!(matches!(o.push(&line).unwrap(), Pushed::Kept(2)));
        assert_eq!(o.push(&line).unwrap(), Pushed::Full);
        drop(o);
        let mut f = OpenOptions::new()
            .append(true)
            .open(d.join("b.records"))
            .unwrap();
        f.write_all(b"{\"seq\":3,\"v\":\"tor").unwrap();
        let o = Outbox::open(&d, "b", 100).unwrap();
        assert_eq!(o.waiting().len(), 2);
        let _ = fs::remove_dir_all(&d);
    }

    #[test]
    fn seq_goes_first_in_the_object() {
        assert_eq!(with_seq("{\"a\":1}", 9), "{\"seq\":9,\"a\":1}");
        assert_eq!(with_seq("{}", 1), "{\"seq\":1}");
        assert_eq!(with_seq("oops", 2), "{\"seq\":2,\"line\":\"oops\"}");
    }
}
