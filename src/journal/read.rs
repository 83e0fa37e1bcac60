//! Reads a journal back: its version line, its header, its entries. A last line without its
//! line break (a power cut while it was written) is left out and said; a journal of another
//! version, a header or an entry that does not read, is refused naming its line. A part that
//! rotation started is read after the part before it (`FILE.1`), back to the run's start.

use super::entry::Entry;
use super::{Header, MAGIC, VERSION};
use std::path::{Path, PathBuf};

/// A journal as read.
#[derive(Debug, Clone)]
pub struct Journal {
    /// The header (of the last part, the one named).
    pub header: Header,
    /// Every entry, in order.
    pub entries: Vec<Entry>,
    /// What reading it noticed that a reader should know (a torn last line).
    pub notes: Vec<String>,
}

/// Why a journal could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// A line is not what it should be.
    #[error("{path}:{line}: {why}")]
    Line {
        /// The file.
        path: String,
        /// Its line, from 1.
        line: usize,
        /// What is wrong.
        why: String,
    },
    /// The run's start is not in the parts kept.
    #[error(
        "{path} starts at tick {from_tick} and the part before it is not there (rotated \
         away): a replay needs the run from its start (a larger --journal-size keeps more)"
    )]
    StartGone {
        /// The earliest part found.
        path: String,
        /// The tick it starts at.
        from_tick: u64,
    },
}

/// One part as read.
fn read_part(path: &Path) -> Result<Journal, ReadError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| ReadError::Io {
        path: name.clone(),
        source,
    })?;
    let bad = |line: usize, why: String| ReadError::Line {
        path: name.clone(),
        line,
        why,
    };
    let mut lines: Vec<&[u8]> = bytes.split(|b| *b == b'\n').collect();
    let mut notes = Vec::new();
    // The piece after the last line break: empty when the file ends with one.
    let torn = lines.pop().filter(|l| !l.is_empty());
    if let Some(t) = torn {
        notes.push(format!(
            "{name}:{}: the last line is cut short ({} bytes, no line break: the run \
             stopped while writing it); read up to it",
            lines.len() + 1,
            t.len()
        ));
    }
    let text = |n: usize, l: &[u8]| -> Result<String, ReadError> {
        String::from_utf8(l.to_vec()).map_err(|_| bad(n, "not UTF-8 text".into()))
    };
    let first = match lines.first() {
        Some(l) => text(1, l)?,
        None if torn.is_some() => {
            return Err(bad(1, "the journal ends inside its first line".into()))
        }
        None => return Err(bad(1, "the file is empty: not a rigscript journal".into())),
    };
    let version = first
        .strip_prefix(MAGIC)
        .and_then(|v| v.strip_prefix(' '))
        .ok_or_else(|| {
            bad(
                1,
                format!("{first:?} is not a rigscript journal's first line"),
            )
        })?;
    match version.parse::<u32>() {
        Ok(VERSION) => {}
        Ok(v) => {
            return Err(bad(
                1,
                format!("a journal of version {v}: this rigscript reads version {VERSION} only"),
            ))
        }
        Err(_) => return Err(bad(1, format!("{version:?} is not a version"))),
    }
    let header = match lines.get(1) {
        Some(l) => {
            let l = text(2, l)?;
            let json = l
                .strip_prefix("H ")
                .ok_or_else(|| bad(2, "the header (H {...}) should be here".into()))?;
            serde_json::from_str::<Header>(json).map_err(|e| bad(2, format!("the header: {e}")))?
        }
        None => return Err(bad(2, "the journal ends inside its header".into())),
    };
    let mut entries = Vec::with_capacity(lines.len().saturating_sub(2));
    for (i, l) in lines.iter().enumerate().skip(2) {
        let l = text(i + 1, l)?;
        entries.push(Entry::parse(&l).map_err(|why| bad(i + 1, why))?);
    }
    Ok(Journal {
        header,
        entries,
        notes,
    })
}

/// The part rotation moved aside before `path`.
pub fn older_part(path: &Path) -> PathBuf {
    let mut p = path.as_os_str().to_owned();
    p.push(".1");
    PathBuf::from(p)
}

/// Reads the journal at `path`, with the part before it if it starts after tick 0.
pub fn read_journal(path: &Path) -> Result<Journal, ReadError> {
    let mut journal = read_part(path)?;
    if journal.header.from_tick == 0 {
        return Ok(journal);
    }
    let older = older_part(path);
    let before = match read_part(&older) {
        Ok(b) if b.header.run == journal.header.run && b.header.from_tick == 0 => b,
        Ok(_) | Err(ReadError::Io { .. }) => {
            return Err(ReadError::StartGone {
                path: path.display().to_string(),
                from_tick: journal.header.from_tick,
            })
        }
        Err(e) => return Err(e),
    };
    // A part opens with the last readings before it, which the part before holds already;
    // and names the script that ran when it began (after a reload, not the one the run
    // started with, which a replay from the start runs).
    journal.header.script = before.header.script;
    journal.header.script_file = before.header.script_file;
    journal.header.hash = before.header.hash;
    let from = journal.header.from_tick;
    let mut entries = before.entries;
    entries.extend(journal.entries.into_iter().filter(|e| e.tick >= from));
    journal.entries = entries;
    let mut notes = before.notes;
    notes.append(&mut journal.notes);
    journal.notes = notes;
    Ok(journal)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header() -> String {
        let h = Header {
            script_file: "t.rhai".into(),
            script: "let io = device(\"io\");\n".into(),
            hash: crate::content_hash::content_hash("x"),
            config_file: None,
            config: None,
            simulated: vec![],
            period_us: 20_000,
            run_for_ms: None,
            operations: 1000,
            zone: "UTC".into(),
            part: 0,
            from_tick: 0,
            run: "r".into(),
            rollback_ms: None,
        };
        format!("H {}\n", serde_json::to_string(&h).unwrap())
    }

    fn file(text: &str) -> (tempfile::TempDir, PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("j");
        std::fs::write(&p, text).unwrap();
        (dir, p)
    }

    #[test]
    fn a_torn_last_line_is_left_out_and_said() {
        let text = format!("{MAGIC} 1\n{}3 i io 0f\n4 i io 0", header());
        let (_d, p) = file(&text);
        let j = read_journal(&p).unwrap();
        assert_eq!(j.entries.len(), 1);
        assert!(
            j.notes[0].contains(":4: the last line is cut short"),
            "{:?}",
            j.notes
        );
    }

    #[test]
    fn another_version_or_a_corrupt_line_is_refused_naming_the_line() {
        let (_d, p) = file(&format!("{MAGIC} 2\n{}", header()));
        let e = read_journal(&p).unwrap_err().to_string();
        assert!(
            e.ends_with(":1: a journal of version 2: this rigscript reads version 1 only"),
            "{e}"
        );
        let (_d, p) = file(&format!(
            "{MAGIC} 1\n{}3 i io 0f\n4 i io zz\n5 i io 00\n",
            header()
        ));
        let e = read_journal(&p).unwrap_err().to_string();
        assert!(e.contains(":4: i: \"zz\""), "{e}");
        let (_d, p) = file("hello\n");
        assert!(read_journal(&p).unwrap_err().to_string().contains(":1:"));
        let (_d, p) = file(&format!("{MAGIC} 1\nH {{\"script\n"));
        assert!(read_journal(&p)
            .unwrap_err()
            .to_string()
            .contains(":2: the header"));
    }
}
