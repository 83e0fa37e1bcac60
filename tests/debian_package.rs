//! The Debian package (`sh packaging/deb/build`): what it holds and where the system looks for
//! it, and a round trip through dpkg in a scratch root as a bench PC would make it:
//! install and reinstall (the maintainer scripts make the rigscript user, in dialout and
//! plugdev), the installed binary's `--version`, `systemd-analyze verify` on the installed
//! units, remove (the operator's config stays), purge (nothing is left).

use crate::common::{
    assert_systemd_accepts, both, require_tool, rigscript, stdout, TempDir, UNITS,
};
use std::collections::BTreeSet;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::Command;

const MANIFEST: &str = env!("CARGO_MANIFEST_DIR");

fn ok(cmd: &mut Command) -> String {
    let o = cmd.output().unwrap_or_else(|e| panic!("{cmd:?}: {e}"));
    assert!(o.status.success(), "{cmd:?}: {}", both(&o));
    stdout(&o)
}

/// Builds the package as a release would, around the binary the suite built (a release build
/// would take minutes; the release's sizes are benches/package_size.sh's); returns the .deb's
/// path, in `target`.
fn build_package(target: &Path) -> PathBuf {
    let found = Command::new("sh")
        .args(["-c", "command -v cargo-deb"])
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        found,
        "cargo-deb is not installed: this test builds the Debian package with it. Run .ci/run \
         (it installs the version it pins), or the `cargo install cargo-deb` line in it."
    );
    let out = ok(Command::new("sh")
        .arg("packaging/deb/build")
        .env("RIGSCRIPT_BIN", rigscript())
        .env("CARGO_TARGET_DIR", target)
        .current_dir(MANIFEST));
    let deb = PathBuf::from(MANIFEST).join(out.lines().last().unwrap_or_default().trim());
    let name = deb.file_name().unwrap().to_string_lossy().into_owned();
    let arch = ok(Command::new("dpkg").arg("--print-architecture"));
    assert_eq!(
        name,
        format!(
            "rigscript_{}_{}.deb",
            env!("CARGO_PKG_VERSION"),
            arch.trim()
        )
    );
    deb
}

/// Every file (not directory) the package holds, as absolute paths.
fn contents(deb: &Path) -> BTreeSet<String> {
    ok(Command::new("dpkg-deb").arg("--contents").arg(deb))
        .lines()
        .filter(|l| !l.starts_with('d'))
        .map(|l| {
            let path = l.split_whitespace().last().unwrap();
            path.trim_start_matches('.').to_string()
        })
        .collect()
}

/// The files the package must hold: a manual page for each page `rigscript man` writes.
fn expected_contents() -> BTreeSet<String> {
    let pages = TempDir::new("deb-pages");
    ok(Command::new(rigscript())
        .args(["man", "--out"])
        .arg(pages.root()));
    let mut expected: BTreeSet<String> = std::fs::read_dir(pages.root())
        .unwrap()
        .map(|e| {
            let name = e.unwrap().file_name().to_string_lossy().into_owned();
            format!("/usr/share/man/man1/{name}.gz")
        })
        .collect();
    assert!(expected.len() > 10, "{expected:?}");
    let doc = |dir: &str, ext: &str| -> Vec<String> {
        std::fs::read_dir(Path::new(MANIFEST).join(dir))
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(ext))
            .collect()
    };
    for name in doc("docs/guide", ".md") {
        expected.insert(format!("/usr/share/doc/rigscript/guide/{name}"));
    }
    for name in doc("scripts", ".rhai") {
        expected.insert(format!("/usr/share/doc/rigscript/examples/{name}"));
    }
    for unit in UNITS {
        expected.insert(format!("/usr/lib/systemd/system/{unit}"));
    }
    expected.extend(
        [
            "/usr/bin/rigscript",
            "/usr/lib/udev/rules.d/60-rigscript.rules",
            "/usr/lib/udev/rules.d/61-rigscript-wake-latency.rules",
            "/usr/lib/sysusers.d/rigscript.conf",
            "/etc/rigscript/README",
            "/usr/share/bash-completion/completions/rigscript",
            "/usr/share/zsh/vendor-completions/_rigscript",
            "/usr/share/fish/vendor_completions.d/rigscript.fish",
            "/usr/share/doc/rigscript/README.md",
            "/usr/share/doc/rigscript/copyright",
            "/usr/share/doc/rigscript/examples/bench-check.rhai",
            "/usr/share/doc/rigscript/examples/rig.toml",
        ]
        .map(String::from),
    );
    expected
}

/// A scratch system for `dpkg --root`: its database and the accounts a Debian base has.
struct ScratchRoot {
    dir: TempDir,
}

/// The account files of a fresh Debian base, as far as the package touches them.
const ACCOUNTS: [(&str, &str); 4] = [
    ("etc/passwd", "root:x:0:0:root:/root:/bin/sh\n"),
    ("etc/shadow", "root:*:19000:0:99999:7:::\n"),
    ("etc/group", "root:x:0:\ndialout:x:20:\nplugdev:x:46:\n"),
    ("etc/gshadow", "root:*::\ndialout:*::\nplugdev:*::\n"),
];

impl ScratchRoot {
    fn new() -> Self {
        let dir = TempDir::new("deb-root");
        for sub in ["var/lib/dpkg/info", "var/lib/dpkg/updates", "etc"] {
            std::fs::create_dir_all(dir.path(sub)).unwrap();
        }
        std::fs::write(dir.path("var/lib/dpkg/status"), "").unwrap();
        std::fs::write(dir.path("var/lib/dpkg/available"), "").unwrap();
        for (file, text) in ACCOUNTS {
            std::fs::write(dir.path(file), text).unwrap();
        }
        Self { dir }
    }

    fn path(&self, p: &str) -> PathBuf {
        self.dir.path(p.trim_start_matches('/'))
    }

    fn read(&self, p: &str) -> String {
        std::fs::read_to_string(self.path(p)).unwrap_or_default()
    }

    /// dpkg on this root; the maintainer scripts run on the host with DPKG_ROOT set (nothing
    /// is installed to chroot into), and the base's packages are not in this root's database.
    fn dpkg(&self, args: &[&str]) -> String {
        ok(Command::new("dpkg")
            .arg(format!("--root={}", self.dir.root().display()))
            .args([
                "--force-script-chrootless",
                "--force-depends",
                "--log=/dev/null",
            ])
            .args(args))
    }

    /// Files and directories below the root, dpkg's database left out, and the account tools'
    /// lock and backups (`.pwd.lock`, `passwd-`), which every Debian base has.
    fn files(&self) -> BTreeSet<String> {
        fn walk(base: &Path, dir: &Path, out: &mut BTreeSet<String>) {
            for e in std::fs::read_dir(dir).unwrap() {
                let path = e.unwrap().path();
                let rel = format!("/{}", path.strip_prefix(base).unwrap().display());
                if rel.starts_with("/var/lib/dpkg") {
                    continue;
                }
                if path.is_dir() && !path.is_symlink() {
                    out.insert(format!("{rel}/"));
                    walk(base, &path, out);
                } else if !rel.ends_with('-') && rel != "/etc/.pwd.lock" {
                    out.insert(rel);
                }
            }
        }
        let mut out = BTreeSet::new();
        walk(self.dir.root(), self.dir.root(), &mut out);
        out
    }

    /// The rigscript user's line in etc/passwd, if any.
    fn user(&self) -> Vec<String> {
        self.read("etc/passwd")
            .lines()
            .filter(|l| l.starts_with("rigscript:"))
            .map(String::from)
            .collect()
    }

    /// The members of `group` in etc/group.
    fn members(&self, group: &str) -> Vec<String> {
        let text = self.read("etc/group");
        let line = text
            .lines()
            .find(|l| l.starts_with(&format!("{group}:")))
            .unwrap_or_else(|| panic!("no group {group}: {text}"));
        let list = line.rsplit(':').next().unwrap();
        list.split(',')
            .filter(|m| !m.is_empty())
            .map(String::from)
            .collect()
    }
}

/// `systemd-analyze verify` of the installed units as instances. Their programs are looked up
/// on the host, so /usr/bin/rigscript is pointed into the scratch root (where verify finds no
/// systemd of its own to load them with).
fn verify_units(root: &ScratchRoot) {
    let installed = root.path("usr/bin/rigscript");
    assert_systemd_accepts("deb-verify", |unit| {
        root.read(&format!("usr/lib/systemd/system/{unit}"))
            .replace("/usr/bin/rigscript", installed.to_str().unwrap())
    });
}

#[test]
#[ignore = "needs cargo-deb, dpkg-deb, xz, man-db and systemd-analyze (tier 2: .ci/run installs them)"]
fn the_package_installs_runs_and_purges_cleanly() {
    for (tool, package) in [
        ("dpkg-deb", "dpkg"),
        ("systemd-analyze", "systemd"),
        ("systemd-sysusers", "systemd"),
        ("userdel", "passwd"),
        ("xz", "xz-utils"),
        ("git", "git"),
    ] {
        require_tool(tool, package);
    }
    let target = TempDir::new("deb-target");
    let deb = build_package(target.root());

    // What it holds, and nothing else.
    let held = contents(&deb);
    let expected = expected_contents();
    assert_eq!(
        held.difference(&expected).collect::<Vec<_>>(),
        Vec::<&String>::new(),
        "files the package should not hold"
    );
    assert_eq!(
        expected.difference(&held).collect::<Vec<_>>(),
        Vec::<&String>::new(),
        "files missing from the package"
    );
    let conffiles = ok(Command::new("dpkg-deb")
        .args(["--info"])
        .arg(&deb)
        .arg("conffiles"));
    assert_eq!(conffiles.trim(), "/etc/rigscript/README");
    let depends = ok(Command::new("dpkg-deb")
        .args(["--field"])
        .arg(&deb)
        .arg("Depends"));
    for needed in ["libc6", "systemd | systemd-sysusers", "passwd"] {
        assert!(depends.contains(needed), "Depends: {depends}");
    }

    let root = ScratchRoot::new();
    let before = root.files();
    let accounts_before: Vec<String> = ACCOUNTS.iter().map(|(f, _)| root.read(f)).collect();
    root.dpkg(&["--install", deb.to_str().unwrap()]);
    // Installed again, as an upgrade to the same version runs the scripts: still one user.
    root.dpkg(&["--install", deb.to_str().unwrap()]);

    let installed = root.path("usr/bin/rigscript");
    let mode = std::fs::metadata(&installed).unwrap().permissions().mode();
    assert_eq!(mode & 0o777, 0o755);
    let version = ok(Command::new(&installed).arg("--version"));
    let head = ok(Command::new("git").args(["-C", MANIFEST, "rev-parse", "--short", "HEAD"]));
    assert!(
        version.starts_with(&format!(
            "rigscript {} (commit {}",
            env!("CARGO_PKG_VERSION"),
            head.trim()
        )),
        "{version}"
    );

    // The units are packaging/systemd's with the package's path, and systemd takes them.
    for unit in UNITS {
        let source =
            std::fs::read_to_string(Path::new(MANIFEST).join("packaging/systemd").join(unit))
                .unwrap();
        let installed = root.read(&format!("usr/lib/systemd/system/{unit}"));
        assert_eq!(
            installed,
            source.replace("/usr/local/bin/rigscript", "/usr/bin/rigscript")
        );
        assert!(!installed.contains("/usr/local"), "{unit}");
    }
    let service = root.read("usr/lib/systemd/system/rigscript@.service");
    assert!(service.contains("\nExecStart=/usr/bin/rigscript run "));
    assert!(service.contains("\nExecStopPost=/usr/bin/rigscript safe "));
    assert!(service.contains("\nUser=rigscript\n"));
    verify_units(&root);

    // The user the units run as, a system account without a login, in the device groups.
    let user = root.user();
    assert_eq!(user.len(), 1, "{user:?}");
    let fields: Vec<&str> = user[0].split(':').collect();
    let uid: u32 = fields[2].parse().unwrap();
    assert!((1..1000).contains(&uid), "a system uid: {user:?}");
    assert!(fields[6].ends_with("nologin"), "{user:?}");
    assert_eq!(root.members("dialout"), ["rigscript"]);
    assert_eq!(root.members("plugdev"), ["rigscript"]);
    assert!(root.read("etc/group").contains("\nrigscript:x:"));

    // The manual pages and completions are what the binary makes.
    let page = root.path("usr/share/man/man1/rigscript-run.1.gz");
    let roff = ok(Command::new("gzip").arg("-dc").arg(&page));
    assert!(roff.contains(".TH rigscript-run 1"), "{roff}");
    let fish = root.read("usr/share/fish/vendor_completions.d/rigscript.fish");
    assert!(fish.contains("complete -c rigscript"), "{fish}");

    // Removed: the package's files go, the operator's rig config and dpkg's conffile stay.
    std::fs::write(
        root.path("etc/rigscript/interlock.toml"),
        "# the operator's\n",
    )
    .unwrap();
    root.dpkg(&["--remove", "rigscript"]);
    assert!(!installed.exists());
    assert!(!root
        .path("usr/lib/systemd/system/rigscript@.service")
        .exists());
    assert!(root.path("etc/rigscript/README").exists());
    assert_eq!(root.user().len(), 1, "the user stays until purge");

    // Purged after the units ran (their state where systemd keeps it for a DynamicUser=
    // unit): the user, the group, the state and the README go; the operator's file stays.
    std::fs::create_dir_all(root.path("var/lib/private/rigscript/interlock")).unwrap();
    std::fs::write(
        root.path("var/lib/private/rigscript/interlock/records.jsonl"),
        "{}\n",
    )
    .unwrap();
    std::fs::create_dir_all(root.path("var/lib/rigscript")).unwrap();
    std::os::unix::fs::symlink(
        "../private/rigscript/interlock",
        root.path("var/lib/rigscript/interlock"),
    )
    .unwrap();
    root.dpkg(&["--purge", "rigscript"]);
    let mut after = root.files();
    assert!(after.remove("/etc/rigscript/interlock.toml"));
    assert!(after.remove("/etc/rigscript/"));
    // systemd's, made above as systemd would.
    assert!(after.remove("/var/lib/private/"));
    assert_eq!(after, before, "left behind by purge");
    let accounts_after: Vec<String> = ACCOUNTS.iter().map(|(f, _)| root.read(f)).collect();
    assert_eq!(accounts_after, accounts_before, "accounts after purge");
    let status = root.read("var/lib/dpkg/status");
    assert!(!status.contains("Package: rigscript"), "{status}");
}
