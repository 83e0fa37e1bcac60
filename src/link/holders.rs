//! Which processes hold a device, for the message of a port that is busy: those with an
//! exclusive lock on it (`/proc/locks`; `serialport`, and so rigscript, takes one), else those
//! that have it open (`/proc/*/fd`). Linux only; elsewhere nobody is found and the message
//! says the holder cannot be told.

use std::fmt;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

/// A process that holds a device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Holder {
    /// Its process ID.
    pub pid: u32,
    /// Its command line (or name), shortened for messages.
    pub command: String,
}

/// Who holds a device, as far as this process can see.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Holders {
    /// The device as it was looked for (symlinks resolved).
    pub device: PathBuf,
    /// Processes with an exclusive lock on it.
    pub locking: Vec<Holder>,
    /// Processes with it open (when none was found locking it).
    pub open: Vec<Holder>,
    /// Processes whose open files this user may not see.
    pub hidden: usize,
}

impl Holders {
    /// The processes that hold it: those locking it, else those with it open.
    pub fn pids(&self) -> Vec<u32> {
        let holders = if self.locking.is_empty() {
            &self.open
        } else {
            &self.locking
        };
        holders.iter().map(|h| h.pid).collect()
    }
}

/// Longest command line shown for a holder.
const MAX_COMMAND: usize = 80;

/// Looks for the processes that hold `path`.
pub fn holders_of(path: &Path) -> Holders {
    let device = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf());
    let mut holders = Holders {
        device: device.clone(),
        ..Holders::default()
    };
    if let Ok(meta) = std::fs::metadata(&device) {
        let locks = std::fs::read_to_string("/proc/locks").unwrap_or_default();
        let (major, minor) = (rustix::fs::major(meta.dev()), rustix::fs::minor(meta.dev()));
        holders.locking = lock_pids(&locks, major, minor, meta.ino())
            .into_iter()
            .map(holder)
            .collect();
    }
    if !holders.locking.is_empty() {
        return holders;
    }
    let Ok(procs) = std::fs::read_dir("/proc") else {
        return holders;
    };
    for entry in procs.flatten() {
        let Some(pid) = entry
            .file_name()
            .to_str()
            .and_then(|n| n.parse::<u32>().ok())
        else {
            continue;
        };
        let Ok(fds) = std::fs::read_dir(entry.path().join("fd")) else {
            holders.hidden += 1;
            continue;
        };
        let has_it = fds
            .flatten()
            .any(|fd| std::fs::read_link(fd.path()).is_ok_and(|to| to == device));
        if has_it {
            holders.open.push(holder(pid));
        }
    }
    holders
}

/// The processes `/proc/locks` (`text`) lists as holding a write (exclusive) lock on the
/// inode `inode` of the file system `major:minor`.
pub fn lock_pids(text: &str, major: u32, minor: u32, inode: u64) -> Vec<u32> {
    // "1: FLOCK  ADVISORY  WRITE 1234 00:19:3 0 EOF"; blocked waiters are marked "->".
    let wanted = format!("{major:02x}:{minor:02x}:{inode}");
    let mut pids: Vec<u32> = text
        .lines()
        .filter(|line| !line.contains("->"))
        .filter_map(|line| {
            let fields: Vec<&str> = line.split_whitespace().collect();
            match fields.as_slice() {
                [_, _, _, "WRITE", pid, file, ..] if *file == wanted => pid.parse().ok(),
                _ => None,
            }
        })
        .collect();
    pids.sort_unstable();
    pids.dedup();
    pids
}

fn holder(pid: u32) -> Holder {
    let proc = PathBuf::from(format!("/proc/{pid}"));
    let cmdline = std::fs::read(proc.join("cmdline")).unwrap_or_default();
    let mut command = cmdline
        .split(|b| *b == 0)
        .filter(|part| !part.is_empty())
        .map(|part| String::from_utf8_lossy(part).into_owned())
        .collect::<Vec<_>>()
        .join(" ");
    if command.is_empty() {
        command = std::fs::read_to_string(proc.join("comm"))
            .map(|c| c.trim().to_string())
            .unwrap_or_default();
    }
    if command.chars().count() > MAX_COMMAND {
        command = command.chars().take(MAX_COMMAND - 3).collect::<String>() + "...";
    }
    Holder { pid, command }
}

impl fmt::Display for Holder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let whose = if self.pid == std::process::id() {
            "this process, "
        } else {
            ""
        };
        if self.command.is_empty() {
            write!(f, "{whose}pid {}", self.pid)
        } else {
            write!(f, "{whose}pid {}: {}", self.pid, self.command)
        }
    }
}

fn list(holders: &[Holder]) -> String {
    holders
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join("; ")
}

/// Who holds it, in words: "held by pid 1234: minicom" or why that cannot be told.
impl fmt::Display for Holders {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if !self.locking.is_empty() {
            write!(f, "held by {}", list(&self.locking))
        } else if !self.open.is_empty() {
            write!(f, "open in {}; one of them holds it", list(&self.open))
        } else if self.hidden > 0 {
            write!(
                f,
                "which program cannot be told: this user may not see the files of {} other \
                 processes (`sudo fuser -v {}` names it)",
                self.hidden,
                self.device.display()
            )
        } else {
            write!(f, "which program cannot be told: none has it open any more")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LOCKS: &str = "\
1: FLOCK  ADVISORY  WRITE 4242 00:19:3 0 EOF
1: -> FLOCK  ADVISORY  WRITE 5151 00:19:3 0 EOF
2: FLOCK  ADVISORY  READ 777 00:19:3 0 EOF
3: POSIX  ADVISORY  WRITE 99 fd:01:1234 0 EOF
4: FLOCK  ADVISORY  WRITE 31 00:19:30 0 EOF
";

    #[test]
    fn the_exclusive_lock_holder_of_one_inode_is_found() {
        assert_eq!(lock_pids(LOCKS, 0, 0x19, 3), vec![4242]);
        assert_eq!(lock_pids(LOCKS, 0xfd, 1, 1234), vec![99]);
        assert_eq!(lock_pids(LOCKS, 0, 0x19, 30), vec![31]);
        assert!(lock_pids(LOCKS, 0, 0x19, 4).is_empty());
        assert!(lock_pids("garbage\n\n1:", 0, 0, 0).is_empty());
    }

    #[test]
    fn holders_in_words() {
        let h = |pid, command: &str| Holder {
            pid,
            command: command.to_string(),
        };
        let mut holders = Holders {
            device: PathBuf::from("/dev/ttyUSB0"),
            locking: vec![h(4242, "minicom -D /dev/ttyUSB0")],
            ..Holders::default()
        };
        assert_eq!(
            holders.to_string(),
            "held by pid 4242: minicom -D /dev/ttyUSB0"
        );
        holders.locking.clear();
        holders.open = vec![h(1, "a"), h(2, "")];
        assert_eq!(
            holders.to_string(),
            "open in pid 1: a; pid 2; one of them holds it"
        );
        holders.open.clear();
        holders.hidden = 3;
        assert!(holders.to_string().contains("`sudo fuser -v /dev/ttyUSB0`"));
        holders.hidden = 0;
        assert!(holders.to_string().contains("none has it open any more"));
    }

    #[test]
    fn a_process_holding_a_file_is_found_with_its_command_line() {
        // This process holds an exclusive flock on a file of its own.
        let path = std::env::temp_dir().join(format!("rigscript-holders-{}", std::process::id()));
        let file = std::fs::File::create(&path).unwrap();
        rustix::fs::flock(&file, rustix::fs::FlockOperation::LockExclusive).unwrap();
        let found = holders_of(&path);
        drop(file);
        std::fs::remove_file(&path).unwrap();
        assert_eq!(found.locking.len(), 1, "{found:?}");
        assert_eq!(found.locking[0].pid, std::process::id());
        assert!(found.to_string().starts_with("held by this process, pid "));
    }
}
