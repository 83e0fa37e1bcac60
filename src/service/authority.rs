//! Who speaks for a rig, decided in one place: only its owner acts on it. A rig directory or
//! socket is trusted only when its owner is this user (or, under systemd's `/run/rigscript/`,
//! the unit's user, that directory being root's) and nobody else may write it; whoever answers
//! on a socket must be that owner and the very process its `hello` names; a peer of the control
//! socket must be the run's user or root; a web request that changes anything must carry the
//! run's key (`RunKey`, kept beside the socket, readable only by whoever may open the socket)
//! or the control token; and every token is checked the same way wherever it comes from.

use std::io::{self, Read, Write};
use std::os::unix::fs::{FileTypeExt, MetadataExt, OpenOptionsExt};
use std::os::unix::io::AsRawFd;
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};

/// The shortest token accepted (`ui_token`, `ui_read_token` and their environment variables).
pub const MIN_TOKEN: usize = 8;

/// Why a rig directory or socket is not trusted.
#[derive(Debug, thiserror::Error)]
pub enum Untrusted {
    /// Someone else owns it: whatever listens there is not this user's rig.
    #[error(
        "{} belongs to uid {owner} (mode {mode:04o}), not to this user (uid {me}): refused, \
         a rig there could be anyone's; remove it (as root) if no rig of that user runs",
        path.display()
    )]
    Foreign {
        /// The directory or socket.
        path: PathBuf,
        /// Its owner.
        owner: u32,
        /// Its permission bits.
        mode: u32,
        /// This process's user.
        me: u32,
    },
    /// Others may write it (put a socket of theirs there, replace ours).
    #[error(
        "{} is writable by others (mode {mode:04o}, owner uid {owner}): refused; a rig's \
         directory and socket are its owner's alone (chmod 700 the directory, 600 the socket)",
        path.display()
    )]
    Open {
        /// The directory or socket.
        path: PathBuf,
        /// Its owner.
        owner: u32,
        /// Its permission bits.
        mode: u32,
    },
    /// A symbolic link where a directory or socket should be.
    #[error("{} is a symbolic link: refused (a rig's directory is a real one)", path.display())]
    Link {
        /// The link.
        path: PathBuf,
    },
    /// It could not be looked at.
    #[error("{}: {source}", path.display())]
    Io {
        /// The directory or socket.
        path: PathBuf,
        /// What failed.
        source: io::Error,
    },
}

impl From<Untrusted> for io::Error {
    fn from(e: Untrusted) -> Self {
        let kind = match &e {
            Untrusted::Io { source, .. } => source.kind(),
            _ => io::ErrorKind::PermissionDenied,
        };
        io::Error::new(kind, e.to_string())
    }
}

/// This process's user.
pub fn me() -> u32 {
    rustix::process::geteuid().as_raw()
}

/// Whether `path` is a directory a rig of this user's may live in: a real directory this user
/// owns, nobody else may write. Its owner, when it is.
pub fn own_dir(path: &Path) -> Result<u32, Untrusted> {
    let (owner, mode) = looked_at(path)?;
    if owner != me() {
        return Err(Untrusted::Foreign {
            path: path.into(),
            owner,
            mode,
            me: me(),
        });
    }
    closed(path, owner, mode)?;
    Ok(owner)
}

/// Whether `path`, a unit's directory under root's `parent` (systemd's `/run/rigscript/`), may
/// be searched: `parent` is root's and nobody else may write it; `path` is a real directory
/// only its owner (the unit's user) may write. Its owner: who its rigs must answer as.
pub fn unit_dir(parent: &Path, path: &Path) -> Result<u32, Untrusted> {
    let (root, mode) = looked_at(parent)?;
    if root != 0 {
        return Err(Untrusted::Foreign {
            path: parent.into(),
            owner: root,
            mode,
            me: 0,
        });
    }
    closed(parent, root, mode)?;
    let (owner, mode) = looked_at(path)?;
    closed(path, owner, mode)?;
    Ok(owner)
}

/// Whether the socket at `path` is one its directory's `owner` made and nobody else may write:
/// a file someone else put there is not the rig.
pub fn trusted_socket(path: &Path, owner: u32) -> Result<(), Untrusted> {
    let meta = std::fs::symlink_metadata(path).map_err(|source| Untrusted::Io {
        path: path.into(),
        source,
    })?;
    let mode = meta.mode() & 0o7777;
    if meta.file_type().is_symlink() {
        return Err(Untrusted::Link { path: path.into() });
    }
    if !meta.file_type().is_socket() || meta.uid() != owner {
        return Err(Untrusted::Foreign {
            path: path.into(),
            owner: meta.uid(),
            mode,
            me: owner,
        });
    }
    closed(path, owner, mode)
}

fn looked_at(path: &Path) -> Result<(u32, u32), Untrusted> {
    let meta = std::fs::symlink_metadata(path).map_err(|source| Untrusted::Io {
        path: path.into(),
        source,
    })?;
    if meta.file_type().is_symlink() {
        return Err(Untrusted::Link { path: path.into() });
    }
    if !meta.is_dir() {
        return Err(Untrusted::Io {
            path: path.into(),
            source: io::Error::other("not a directory"),
        });
    }
    Ok((meta.uid(), meta.mode() & 0o7777))
}

fn closed(path: &Path, owner: u32, mode: u32) -> Result<(), Untrusted> {
    if mode & 0o022 != 0 {
        return Err(Untrusted::Open {
            path: path.into(),
            owner,
            mode,
        });
    }
    Ok(())
}

/// The process at the other end of a Unix socket, as the kernel tells it (`SO_PEERCRED`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Peer {
    /// Its process id (for a server: the one that listens).
    pub pid: u32,
    /// Its user.
    pub uid: u32,
}

/// Who is at the other end of `stream`.
pub fn peer(stream: &UnixStream) -> Option<Peer> {
    // libc, not rustix's `socket_peercred`: the kernel reports pid 0 for a peer outside this
    // pid namespace, and rustix's `UCred` holds a non-zero `Pid`.
    let mut cred = libc::ucred {
        pid: 0,
        uid: 0,
        gid: 0,
    };
    let mut len = libc::socklen_t::try_from(std::mem::size_of::<libc::ucred>()).ok()?;
    // SAFETY: `cred` and `len` are valid for writes of the size passed; the descriptor is
    // the stream's own.
    let got = unsafe {
        libc::getsockopt(
            stream.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_PEERCRED,
            std::ptr::addr_of_mut!(cred).cast(),
            &mut len,
        )
    };
    let pid = u32::try_from(cred.pid).ok().filter(|p| *p != 0)?;
    (got == 0).then_some(Peer { pid, uid: cred.uid })
}

/// Whether `peer`, a client of this run's control socket, may act on the rig: the run's own
/// user, or root.
pub fn may_act(peer: Option<Peer>) -> bool {
    peer.is_some_and(|p| p.uid == me() || p.uid == 0)
}

/// Whether the process answering on a rig's socket is the rig it says it is: the user that
/// owns the rig's directory (`owner`), and the process whose pid its `hello` gives (`pid`).
/// Why not, in words, when not.
pub fn check_answerer(peer: Option<Peer>, owner: u32, pid: u32) -> Result<(), String> {
    match peer {
        Some(p) if p.uid == owner && p.pid == pid => Ok(()),
        Some(p) => Err(format!(
            "the process answering (pid {}, uid {}) is not the rig it names (pid {pid}, uid \
             {owner}): refused",
            p.pid, p.uid
        )),
        None => Err("the system does not tell who answers: refused".into()),
    }
}

/// Why a token is refused; the token itself is never shown.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("is not a token: give at least {MIN_TOKEN} characters, no spaces at either end")]
pub struct BadToken;

/// Checks a token (`ui_token`, `ui_read_token`, `RIGSCRIPT_UI_TOKEN`,
/// `RIGSCRIPT_UI_READ_TOKEN`): long enough to be guessed by nobody, and without spaces at
/// either end (a request's header is read trimmed: such a token could never match).
pub fn check_token(text: &str) -> Result<(), BadToken> {
    if text.chars().count() < MIN_TOKEN || text.trim() != text {
        Err(BadToken)
    } else {
        Ok(())
    }
}

/// Whether `a` and `b` are the same, in a time that does not depend on where they differ.
pub fn same_secret(a: &str, b: &str) -> bool {
    use subtle::ConstantTimeEq;
    bool::from(a.as_bytes().ct_eq(b.as_bytes()))
}

/// The run's key: random, made at the start of each run, kept (mode 0600) beside the rig's
/// socket and given in the page's link; a web request that changes the rig carries it.
#[derive(Clone, PartialEq, Eq)]
pub struct RunKey(String);

impl std::fmt::Debug for RunKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("RunKey(..)")
    }
}

/// Bytes of randomness in a run's key (shown as twice as many hex digits).
const KEY_BYTES: usize = 24;

impl RunKey {
    /// A new key from the system's randomness.
    pub fn generate() -> io::Result<Self> {
        let mut bytes = [0u8; KEY_BYTES];
        std::fs::File::open("/dev/urandom")?.read_exact(&mut bytes)?;
        Ok(Self(bytes.iter().map(|b| format!("{b:02x}")).collect()))
    }

    /// The key's text.
    pub fn expose(&self) -> &str {
        &self.0
    }

    /// Writes the key to `path` (replacing a dead run's), readable by this user only.
    pub fn keep(&self, path: &Path) -> io::Result<()> {
        match std::fs::remove_file(path) {
            Ok(()) => {}
            Err(e) if e.kind() == io::ErrorKind::NotFound => {}
            Err(e) => return Err(e),
        }
        let mut file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .mode(0o600)
            .open(path)?;
        file.write_all(self.0.as_bytes())?;
        file.write_all(b"\n")
    }
}

/// Where a rig's key is kept: beside its socket, `NAME.key`.
pub fn key_path(socket: &Path) -> PathBuf {
    socket.with_extension("key")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

    #[test]
    fn tokens_are_checked_alike_wherever_they_come_from() {
        assert_eq!(check_token("abc"), Err(BadToken));
        assert_eq!(check_token(" c0ntrol-token"), Err(BadToken));
        assert_eq!(check_token("c0ntrol-token\n"), Err(BadToken));
        assert_eq!(check_token("c0ntrol-token"), Ok(()));
        assert!(!BadToken.to_string().contains("abc"));
    }

    #[test]
    fn secrets_compare_by_every_byte() {
        assert!(same_secret("abc", "abc"));
        assert!(!same_secret("abc", "abd") && !same_secret("abc", "ab") && !same_secret("", "a"));
    }

    #[test]
    fn a_directory_is_trusted_only_closed_and_owned_by_this_user() {
        let dir = std::env::temp_dir().join(format!("rigscript-trust-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o700)).unwrap();
        assert_eq!(own_dir(&dir).unwrap(), me());
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o777)).unwrap();
        let why = own_dir(&dir).unwrap_err().to_string();
        assert!(
            why.contains(&dir.display().to_string()) && why.contains("0777"),
            "{why}"
        );
        let link = dir.with_extension("link");
        let _ = std::fs::remove_file(&link);
        std::os::unix::fs::symlink(&dir, &link).unwrap();
        assert!(matches!(own_dir(&link), Err(Untrusted::Link { .. })));
        std::fs::remove_file(&link).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn only_the_process_the_hello_names_as_the_directory_s_owner_answers() {
        let (a, _b) = UnixStream::pair().unwrap();
        let p = peer(&a).unwrap();
        assert_eq!((p.pid, p.uid), (std::process::id(), me()));
        assert!(check_answerer(Some(p), me(), std::process::id()).is_ok());
        let why = check_answerer(Some(p), me().wrapping_add(1), std::process::id()).unwrap_err();
        assert!(why.contains("not the rig it names"), "{why}");
        assert!(check_answerer(Some(p), me(), 1).is_err());
        assert!(may_act(Some(p)) && !may_act(None));
    }

    #[test]
    fn a_run_s_key_is_random_and_kept_for_its_user_alone() {
        let (k1, k2) = (RunKey::generate().unwrap(), RunKey::generate().unwrap());
        assert_ne!(k1, k2);
        assert_eq!(k1.expose().len(), 2 * KEY_BYTES);
        assert!(!format!("{k1:?}").contains(k1.expose()));
        let path = std::env::temp_dir().join(format!("rigscript-key-{}.key", std::process::id()));
        k1.keep(&path).unwrap();
        k2.keep(&path).unwrap();
        let meta = std::fs::metadata(&path).unwrap();
        assert_eq!(meta.mode() & 0o777, 0o600);
        assert_eq!(std::fs::read_to_string(&path).unwrap().trim(), k2.expose());
        std::fs::remove_file(&path).unwrap();
    }
}
