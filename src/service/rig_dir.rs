//! Where the running rigs of this machine are found: one control socket per rig, named after
//! it, in the rig directory (`$RUNTIME_DIRECTORY` under systemd's `RuntimeDirectory=`, else
//! `$XDG_RUNTIME_DIR/rigscript`, else `/tmp/rigscript-UID`), private to its owner. Systemd's
//! units' directories (`SYSTEM_RIGS`) are searched first, then this user's; a directory or
//! socket `authority` does not trust is refused, and told, never searched.

use super::authority::{self, Untrusted};
use super::control_client::Connection;
use super::control_protocol::Hello;
use std::io;
use std::os::unix::fs::{DirBuilderExt, MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// How long a knock waits for a run's `hello`.
pub const KNOCK_WAIT: Duration = Duration::from_secs(1);

/// The rig directory, made (mode 0700) if it is not there; refused (`authority::own_dir`) if
/// someone else owns it or is a link, by root too.
pub fn rig_dir() -> io::Result<PathBuf> {
    let dir = match (
        std::env::var_os("RUNTIME_DIRECTORY"),
        std::env::var_os("XDG_RUNTIME_DIR"),
    ) {
        // systemd may give several, separated by ':': the first is this unit's.
        (Some(d), _) if !d.is_empty() => {
            let text = d.to_string_lossy().into_owned();
            PathBuf::from(text.split(':').next().unwrap_or_default())
        }
        (_, Some(d)) if !d.is_empty() => PathBuf::from(d).join("rigscript"),
        _ => PathBuf::from(format!("/tmp/rigscript-{}", authority::me())),
    };
    match std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(&dir)
    {
        Ok(()) => {}
        Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {}
        Err(e) => return Err(e),
    }
    let meta = std::fs::symlink_metadata(&dir)?;
    // Our own directory left open (an old umask): closed again; anyone else's is refused.
    if meta.is_dir() && meta.uid() == authority::me() && meta.mode() & 0o077 != 0 {
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o700))?;
    }
    authority::own_dir(&dir)?;
    Ok(dir)
}

/// Where systemd's units keep their rigs' directories (`RuntimeDirectory=rigscript/%i`).
pub const SYSTEM_RIGS: &str = "/run/rigscript";

/// A directory searched for rigs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Searched {
    /// The directory.
    pub dir: PathBuf,
    /// Its owner: whom its rigs must answer as.
    pub owner: u32,
}

/// The directories searched, and the ones refused, in words.
#[derive(Debug, Default)]
pub struct Search {
    /// Trusted directories, in the order searched.
    pub dirs: Vec<Searched>,
    /// Why each refused one was.
    pub refused: Vec<String>,
}

/// Every rig directory this user can look into: each unit's under `SYSTEM_RIGS` it may read
/// (root may read them all), then its own (`rig_dir`).
pub fn search() -> Search {
    let mut search = Search::default();
    let system = Path::new(SYSTEM_RIGS);
    if let Ok(entries) = std::fs::read_dir(system) {
        let mut units: Vec<PathBuf> = entries
            .flatten()
            .map(|e| e.path())
            .filter(|p| std::fs::read_dir(p).is_ok())
            .collect();
        units.sort();
        for dir in units {
            match authority::unit_dir(system, &dir) {
                Ok(owner) => search.dirs.push(Searched { dir, owner }),
                Err(e) => search.refused.push(e.to_string()),
            }
        }
    }
    match rig_dir() {
        Ok(dir) => search.dirs.push(Searched {
            dir,
            owner: authority::me(),
        }),
        Err(e) if e.kind() == io::ErrorKind::PermissionDenied => search.refused.push(e.to_string()),
        Err(_) => {}
    }
    search.dirs.dedup_by(|a, b| a.dir == b.dir);
    search
}

/// The socket of rig `name`: in the first searched directory that has one, with the user its
/// rig must answer as. None: why, with the directories refused on the way.
pub fn find_socket(name: &str) -> Result<(PathBuf, u32), Vec<String>> {
    let search = search();
    search
        .dirs
        .iter()
        .map(|d| (socket_path(&d.dir, name), d.owner))
        .find(|(p, _)| std::fs::symlink_metadata(p).is_ok())
        .ok_or(search.refused)
}

/// A rig found running.
#[derive(Debug, Clone)]
pub struct Found {
    /// Who it said it is.
    pub hello: Hello,
    /// Its socket.
    pub socket: PathBuf,
    /// The user it answered as.
    pub owner: u32,
}

/// The rigs running in every searched directory, each name once (the first found, as
/// `find_socket` finds it), by name; and the directories and sockets refused, in words.
pub fn survey() -> (Vec<Found>, Vec<String>) {
    let search = search();
    let mut refused = search.refused;
    let mut rigs: Vec<Found> = Vec::new();
    for d in &search.dirs {
        let (found, why) = running(d);
        refused.extend(why);
        for f in found {
            if !rigs.iter().any(|r| r.hello.rig == f.hello.rig) {
                rigs.push(f);
            }
        }
    }
    rigs.sort_by(|a, b| a.hello.rig.cmp(&b.hello.rig));
    (rigs, refused)
}

/// The rigs running in every searched directory, by name (`survey` without what it refused).
pub fn running_anywhere() -> Vec<Hello> {
    survey().0.into_iter().map(|f| f.hello).collect()
}

/// The socket of rig `name` in `dir`.
pub fn socket_path(dir: &Path, name: &str) -> PathBuf {
    dir.join(format!("{name}.sock"))
}

/// The name a run's rig goes by: rig.toml's `name`, else the config file's stem, else the
/// script's; characters a socket name cannot carry become `_`.
pub fn rig_name(configured: Option<&str>, config: Option<&Path>, script: &Path) -> String {
    if let Some(name) = configured {
        return name.to_string();
    }
    let stem = config
        .or(Some(script))
        .and_then(Path::file_stem)
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut name: String = stem
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') {
                c
            } else {
                '_'
            }
        })
        .take(crate::config::MAX_RIG_NAME)
        .collect();
    if name.is_empty() || name.starts_with('.') {
        name.insert(0, 'r');
    }
    name
}

/// What is behind a rig's socket path.
#[derive(Debug)]
pub enum Knock {
    /// A live run, which said who it is and is who it says.
    Answered(Hello),
    /// Something listens but did not say who it is (a run whose clients are all taken, one
    /// too busy to answer in time): not to be removed; why, in words.
    Unanswered(String),
    /// A socket or an answer `authority` does not trust (someone else's file, a process that
    /// is not the rig it names): not to be believed, nor removed; why, in words.
    Refused(String),
    /// A socket nobody listens on: its run died.
    Stale,
    /// Nothing.
    Absent,
}

/// Knocks at `path`, a socket of a directory `owner` owns: who answers there, if anyone.
pub fn knock(path: &Path, owner: u32) -> Knock {
    match open(path, owner, KNOCK_WAIT) {
        Ok((_, hello)) => Knock::Answered(hello),
        Err(knock) => knock,
    }
}

/// Connects to the rig at `path`, a socket of a directory `owner` owns, and asks who it is;
/// every read and write waits at most `wait`. The connection only when the socket is `owner`'s
/// and the process answering is `owner`'s and the one its hello names
/// (`authority::check_answerer`); else what is there instead.
pub fn open(path: &Path, owner: u32, wait: Duration) -> Result<(Connection, Hello), Knock> {
    match authority::trusted_socket(path, owner) {
        Ok(()) => {}
        Err(Untrusted::Io { source, .. }) if source.kind() == io::ErrorKind::NotFound => {
            return Err(Knock::Absent)
        }
        Err(e) => return Err(Knock::Refused(e.to_string())),
    }
    let mut c = match Connection::open(path, wait) {
        Ok(c) => c,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Err(Knock::Absent),
        // Refused: the file is there and nobody listens (ECONNREFUSED).
        Err(e) if e.kind() == io::ErrorKind::ConnectionRefused => return Err(Knock::Stale),
        Err(e) => return Err(Knock::Unanswered(e.to_string())),
    };
    let hello = c.hello().map_err(|e| Knock::Unanswered(e.to_string()))?;
    authority::check_answerer(c.peer(), owner, hello.pid)
        .map_err(|why| Knock::Refused(format!("{}: {why}", path.display())))?;
    Ok((c, hello))
}

/// The rigs running in `searched`, by name, and the sockets refused there, in words; stale
/// sockets found on the way are removed.
pub fn running(searched: &Searched) -> (Vec<Found>, Vec<String>) {
    let Ok(entries) = std::fs::read_dir(&searched.dir) else {
        return (Vec::new(), Vec::new());
    };
    let (mut rigs, mut refused) = (Vec::new(), Vec::new());
    for socket in entries
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "sock"))
    {
        match knock(&socket, searched.owner) {
            Knock::Answered(hello) => rigs.push(Found {
                hello,
                socket,
                owner: searched.owner,
            }),
            Knock::Stale => {
                let _ = std::fs::remove_file(&socket);
                let _ = std::fs::remove_file(authority::key_path(&socket));
            }
            Knock::Refused(why) => refused.push(why),
            Knock::Unanswered(_) | Knock::Absent => {}
        }
    }
    rigs.sort_by(|a: &Found, b| a.hello.rig.cmp(&b.hello.rig));
    (rigs, refused)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rig_is_named_by_its_config_then_its_files() {
        let script = Path::new("scripts/interlock.rhai");
        assert_eq!(rig_name(Some("bench-2"), None, script), "bench-2");
        assert_eq!(
            rig_name(
                None,
                Some(Path::new("/etc/rigscript/press line.toml")),
                script
            ),
            "press_line"
        );
        assert_eq!(rig_name(None, None, script), "interlock");
        assert_eq!(rig_name(None, None, Path::new(".rhai")), "r.rhai");
    }

    #[test]
    fn a_socket_nobody_listens_on_is_stale_and_a_missing_one_absent() {
        let dir = std::env::temp_dir().join(format!("rigscript-knock-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = socket_path(&dir, "gone");
        let _ = std::fs::remove_file(&path);
        let me = authority::me();
        assert!(matches!(knock(&path, me), Knock::Absent));
        drop(std::os::unix::net::UnixListener::bind(&path).unwrap());
        assert!(
            path.exists(),
            "a dropped listener leaves its file, as a killed run does"
        );
        assert!(matches!(knock(&path, me), Knock::Stale));
        let searched = Searched {
            dir: dir.clone(),
            owner: me,
        };
        assert!(running(&searched).0.is_empty());
        assert!(!path.exists(), "listing removed the stale socket");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
