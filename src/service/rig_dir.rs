//! Where the running rigs of this machine are found: one control socket per rig, named after
//! it, in the rig directory (`$RUNTIME_DIRECTORY` under systemd's `RuntimeDirectory=`, else
//! `$XDG_RUNTIME_DIR/rigscript`, else `/tmp/rigscript-UID`), private to its owner.

use super::control_client::Connection;
use super::control_protocol::Hello;
use std::io;
use std::os::unix::fs::{DirBuilderExt, MetadataExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// How long a knock waits for a run's `hello`.
pub const KNOCK_WAIT: Duration = Duration::from_secs(1);

/// The rig directory, made (mode 0700) if it is not there; refused if someone else owns it.
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
        // SAFETY: getuid has no preconditions and cannot fail.
        _ => PathBuf::from(format!("/tmp/rigscript-{}", unsafe { libc::getuid() })),
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
    let meta = std::fs::metadata(&dir)?;
    // SAFETY: as above.
    let me = unsafe { libc::getuid() };
    if meta.uid() != me && me != 0 {
        return Err(io::Error::new(
            io::ErrorKind::PermissionDenied,
            format!(
                "{} belongs to uid {}, not to this user (uid {me})",
                dir.display(),
                meta.uid()
            ),
        ));
    }
    if meta.permissions().mode() & 0o077 != 0 {
        std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o700))?;
    }
    Ok(dir)
}

/// Where systemd's units keep their rigs' directories (`RuntimeDirectory=rigscript/%i`).
pub const SYSTEM_RIGS: &str = "/run/rigscript";

/// Every rig directory this user can look into: its own (`rig_dir`), then each unit's under
/// `SYSTEM_RIGS` it may read (root may read them all).
pub fn search_dirs() -> Vec<PathBuf> {
    let mut dirs: Vec<PathBuf> = rig_dir().into_iter().collect();
    if let Ok(entries) = std::fs::read_dir(SYSTEM_RIGS) {
        let mut units: Vec<PathBuf> = entries
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.is_dir() && std::fs::read_dir(p).is_ok())
            .collect();
        units.sort();
        dirs.extend(units);
    }
    dirs.dedup();
    dirs
}

/// The socket of rig `name`: in the first searched directory that has one.
pub fn find_socket(name: &str) -> Option<PathBuf> {
    search_dirs()
        .iter()
        .map(|d| socket_path(d, name))
        .find(|p| std::fs::symlink_metadata(p).is_ok())
}

/// The rigs running in every searched directory (`search_dirs`), by name.
pub fn running_anywhere() -> Vec<Hello> {
    let mut rigs: Vec<Hello> = search_dirs().iter().flat_map(|d| running(d)).collect();
    rigs.sort_by(|a, b| a.rig.cmp(&b.rig));
    rigs
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
    /// A live run, which said who it is.
    Answered(Hello),
    /// Something listens but did not say who it is (a run whose clients are all taken, one
    /// too busy to answer in time): not to be removed; why, in words.
    Unanswered(String),
    /// A socket nobody listens on: its run died.
    Stale,
    /// Nothing.
    Absent,
}

/// Knocks at `path`: who answers there, if anyone.
pub fn knock(path: &Path) -> Knock {
    if std::fs::symlink_metadata(path).is_err() {
        return Knock::Absent;
    }
    match Connection::open(path, KNOCK_WAIT) {
        Ok(mut c) => match c.hello() {
            Ok(hello) => Knock::Answered(hello),
            Err(e) => Knock::Unanswered(e.to_string()),
        },
        Err(e) if e.kind() == io::ErrorKind::NotFound => Knock::Absent,
        // Refused: the file is there and nobody listens (ECONNREFUSED).
        Err(e) if e.kind() == io::ErrorKind::ConnectionRefused => Knock::Stale,
        Err(e) => Knock::Unanswered(e.to_string()),
    }
}

/// The rigs running in `dir`, by name; stale sockets found on the way are removed.
pub fn running(dir: &Path) -> Vec<Hello> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut rigs: Vec<Hello> = entries
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "sock"))
        .filter_map(|p| match knock(&p) {
            Knock::Answered(hello) => Some(hello),
            Knock::Stale => {
                let _ = std::fs::remove_file(&p);
                None
            }
            Knock::Unanswered(_) | Knock::Absent => None,
        })
        .collect();
    rigs.sort_by(|a, b| a.rig.cmp(&b.rig));
    rigs
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
        assert!(matches!(knock(&path), Knock::Absent));
        drop(std::os::unix::net::UnixListener::bind(&path).unwrap());
        assert!(
            path.exists(),
            "a dropped listener leaves its file, as a killed run does"
        );
        assert!(matches!(knock(&path), Knock::Stale));
        assert!(running(&dir).is_empty());
        assert!(!path.exists(), "listing removed the stale socket");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
