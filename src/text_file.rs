//! Reading the files a user names (scripts, rig.toml, test files) with a size limit, so that a
//! device or a pipe given by mistake (`/dev/zero`, a FIFO) is refused instead of read until
//! memory runs out.

use crate::heap::format_bytes;
use std::io::Read;
use std::path::Path;

/// The most a script (`.rhai`) may be: far beyond any real script.
pub const SCRIPT_LIMIT: u64 = 4 << 20;
/// The most a scenario test file (`.test.rhai`) may be.
pub const TEST_FILE_LIMIT: u64 = 4 << 20;
/// The most a rig.toml may be.
pub const CONFIG_LIMIT: u64 = 1 << 20;

/// What kind of file is read: its limit and its name in messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TextKind {
    /// A script (`SCRIPT_LIMIT`).
    Script,
    /// A scenario test file (`TEST_FILE_LIMIT`).
    TestFile,
    /// A rig.toml (`CONFIG_LIMIT`).
    Config,
}

impl TextKind {
    /// The most a file of this kind may be, in bytes.
    pub fn limit(self) -> u64 {
        match self {
            TextKind::Script => SCRIPT_LIMIT,
            TextKind::TestFile => TEST_FILE_LIMIT,
            TextKind::Config => CONFIG_LIMIT,
        }
    }

    fn name(self) -> &'static str {
        match self {
            TextKind::Script => "script",
            TextKind::TestFile => "test file",
            TextKind::Config => "rig.toml",
        }
    }
}

/// Why a file could not be read (its path is the caller's to name).
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The system refused (missing, no permission, a directory...).
    #[error("{0}")]
    Io(#[from] std::io::Error),
    /// More bytes than the kind's limit.
    #[error(
        "it holds more than {}, the most a {} may be (a device or a pipe that never ends?); \
         give the {} as a file",
        format_bytes(kind.limit()),
        kind.name(),
        kind.name()
    )]
    TooLarge {
        /// What the file was read as.
        kind: TextKind,
    },
    /// Not UTF-8 text.
    #[error("it is not UTF-8 text (byte {offset} is not)")]
    NotText {
        /// Where the first byte that is not UTF-8 is.
        offset: usize,
    },
}

/// The text of the file at `path`, read as a `kind`: at most its limit and one byte more
/// are ever read, whatever the file is.
pub fn read_text(path: &Path, kind: TextKind) -> Result<String, ReadError> {
    read_limited(std::fs::File::open(path)?, kind)
}

fn read_limited(source: impl Read, kind: TextKind) -> Result<String, ReadError> {
    let mut bytes = Vec::new();
    source
        .take(kind.limit().saturating_add(1))
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > kind.limit() {
        return Err(ReadError::TooLarge { kind });
    }
    String::from_utf8(bytes).map_err(|e| ReadError::NotText {
        offset: e.utf8_error().valid_up_to(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_at_its_limit_is_read_and_one_byte_more_is_refused() {
        let limit = usize::try_from(CONFIG_LIMIT).unwrap();
        let at_limit = vec![b'#'; limit];
        let text = read_limited(at_limit.as_slice(), TextKind::Config).unwrap();
        assert_eq!(text.len(), limit);
        let over = vec![b'#'; limit + 1];
        let e = read_limited(over.as_slice(), TextKind::Config).unwrap_err();
        assert_eq!(
            e.to_string(),
            "it holds more than 1 MiB, the most a rig.toml may be (a device or a pipe that \
             never ends?); give the rig.toml as a file"
        );
    }

    #[test]
    fn an_endless_device_is_read_only_to_the_limit() {
        let e = read_text(Path::new("/dev/zero"), TextKind::Script).unwrap_err();
        assert!(matches!(e, ReadError::TooLarge { .. }), "{e}");
        assert!(e.to_string().contains("more than 4 MiB"), "{e}");
    }

    #[test]
    fn bytes_that_are_not_utf8_are_named() {
        let e = read_limited(&b"ok\xff"[..], TextKind::Script).unwrap_err();
        assert_eq!(e.to_string(), "it is not UTF-8 text (byte 2 is not)");
    }
}
