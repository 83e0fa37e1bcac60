//! Configuration errors that name the file, the line and the key, for people to fix.

use std::fmt;
use std::path::PathBuf;

/// A configuration that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("{}: cannot read: {source}", path.display())]
    Read {
        /// The file as given.
        path: PathBuf,
        /// Why not.
        source: crate::text_file::ReadError,
    },
    /// The text is not TOML.
    #[error("{file}:{line}:{column}: not valid TOML: {message}")]
    Syntax {
        /// The file name used in messages.
        file: String,
        /// 1-based line of the fault.
        line: usize,
        /// 1-based column (in characters) of the fault.
        column: usize,
        /// The TOML parser's description.
        message: String,
    },
    /// The TOML is well formed but some keys or values are wrong; every problem found, in
    /// the order of the file.
    #[error("{}", Lines(.0))]
    Invalid(Vec<Problem>),
}

impl ConfigError {
    /// The problems of an `Invalid` error (empty for the other kinds).
    pub fn problems(&self) -> &[Problem] {
        match self {
            ConfigError::Invalid(problems) => problems,
            _ => &[],
        }
    }
}

struct Lines<'a>(&'a [Problem]);

impl fmt::Display for Lines<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, p) in self.0.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            write!(f, "{p}")?;
        }
        Ok(())
    }
}

/// One wrong key or value: `rig.toml:9: devices.io.protocol: "modbsu" is not a protocol; ...`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    /// The file name used in messages.
    pub file: String,
    /// 1-based line of the key or value at fault.
    pub line: usize,
    /// Dotted path of the key (`devices.io.protocol`).
    pub key: String,
    /// What is wrong.
    pub kind: ProblemKind,
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}:{}: {}: {}",
            self.file, self.line, self.key, self.kind
        )
    }
}

/// What is wrong with a key or its value.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ProblemKind {
    /// A key that has no meaning here.
    UnknownKey {
        /// The keys that do.
        known: &'static [&'static str],
        /// The known key nearest to it, when it looks like a slip of the keyboard.
        near: Option<&'static str>,
    },
    /// A required key is absent.
    Missing {
        /// What to write.
        hint: &'static str,
    },
    /// The value has the wrong TOML type.
    WrongType {
        /// What the key takes.
        expected: &'static str,
        /// What it got (a TOML type name).
        found: &'static str,
    },
    /// The value has the right type but is not acceptable.
    BadValue {
        /// The value as written in the file (strings quoted).
        value: String,
        /// Why not, and what to use: `is not a protocol; use "modbus" or "ascii"`.
        reason: String,
    },
    /// Two keys that exclude each other were both given.
    Conflict {
        /// The other key.
        other: &'static str,
    },
    /// A key of a device's `names` table that is no point of the device.
    UnknownPoint {
        /// The kind of device, with its article ("a TRP-C29U").
        device: &'static str,
        /// Its points, as people are told them ("DI0-DI7 and DO0-DO7").
        points: &'static str,
        /// The point nearest to the key, when it looks like a slip of the keyboard.
        near: Option<String>,
    },
    /// Two entries that would reach the same device (or share a line at two speeds).
    Clash {
        /// How this entry stands to the other: "is the same module as".
        relation: &'static str,
        /// The dotted path of the earlier entry.
        other: String,
        /// The earlier entry's line.
        other_line: usize,
        /// What they share, and what to do.
        detail: String,
    },
}

impl fmt::Display for ProblemKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ProblemKind::UnknownKey { known, near } => {
                f.write_str("unknown key")?;
                if let Some(near) = near {
                    write!(f, " (did you mean `{near}`?)")?;
                }
                write!(f, "; known keys here: {}", known.join(", "))
            }
            ProblemKind::Missing { hint } => write!(f, "missing; {hint}"),
            ProblemKind::WrongType { expected, found } => {
                write!(f, "expected {expected}, found {found}")
            }
            ProblemKind::BadValue { value, reason } => write!(f, "{value} {reason}"),
            ProblemKind::Conflict { other } => {
                write!(f, "cannot be given together with {other}; use one of them")
            }
            ProblemKind::UnknownPoint {
                device,
                points,
                near,
            } => {
                write!(f, "not a point of {device}")?;
                if let Some(near) = near {
                    write!(f, " (did you mean `{near}`?)")?;
                }
                write!(f, "; its points are {points}")
            }
            ProblemKind::Clash {
                relation,
                other,
                other_line,
                detail,
            } => write!(f, "{relation} {other} (line {other_line}): {detail}"),
        }
    }
}
