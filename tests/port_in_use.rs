//! Ports and links that are not free: a simulator's pty held exclusively by another program
//! (`run`, `c29` and `scan` say it is busy and who holds it), a path that is not a serial port,
//! and `sim --link` at a path that already exists.

use crate::common::{rigscript, stderr, SimProcess, TempDir};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

/// `rigscript c29 --port PORT monitor`, holding the port (exclusively, as every rigscript
/// opener does) from its first printed line until dropped. Its standard output stays open, or
/// the monitor would end on a broken pipe.
struct Holder {
    child: Child,
    _stdout: BufReader<std::process::ChildStdout>,
}

impl Holder {
    fn start(port: &str) -> Self {
        let mut child = Command::new(rigscript())
            .args(["c29", "--port", port, "monitor"])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start the monitor");
        let mut out = BufReader::new(child.stdout.take().expect("stdout"));
        let mut first = String::new();
        out.read_line(&mut first)
            .expect("the monitor prints once it has the port");
        assert!(!first.is_empty(), "the monitor ended at once");
        Self {
            child,
            _stdout: out,
        }
    }

    fn pid(&self) -> u32 {
        self.child.id()
    }
}

impl Drop for Holder {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn run(args: &[&str]) -> Output {
    Command::new(rigscript()).args(args).output().unwrap()
}

#[test]
fn a_port_held_by_another_program_is_busy_for_run_c29_and_scan() {
    let sim = SimProcess::start(&[]);
    let holder = Holder::start(&sim.path);
    let busy = format!(
        "serial port {} is busy: another program holds it exclusively (held by pid {}: ",
        sim.path,
        holder.pid()
    );

    let o = run(&["c29", "--port", &sim.path, "status"]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(err.contains(&busy), "{err}");
    assert!(
        err.contains("c29 --port") && err.contains("monitor"),
        "{err}"
    );
    assert!(!err.contains("not found"), "{err}");

    let d = TempDir::new("busy");
    let config = d.path("rig.toml");
    std::fs::write(
        &config,
        format!(
            "[devices.io]\nkind = \"trp-c29u\"\nport = \"{}\"\n",
            sim.path
        ),
    )
    .unwrap();
    let script = d.path("s.rhai");
    std::fs::write(&script, "io.outputs = 1;\n").unwrap();
    let o = run(&[
        "run",
        "--config",
        config.to_str().unwrap(),
        "--for",
        "1s",
        script.to_str().unwrap(),
    ]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(err.contains(&busy), "{err}");

    let o = run(&[
        "scan",
        "--ports",
        &sim.path,
        "--ids",
        "1",
        "--protocols",
        "modbus",
    ]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(err.contains(&busy), "{err}");
    assert!(
        err.contains("end that program (named above) and scan again"),
        "{err}"
    );
    assert!(!err.contains("check the cable"), "{err}");

    drop(holder);
    let o = run(&["c29", "--port", &sim.path, "status"]);
    assert_eq!(o.status.code(), Some(0), "free again: {}", stderr(&o));
}

#[test]
fn a_file_is_not_a_serial_port() {
    let o = run(&["c29", "--port", "/etc/passwd", "status"]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(
        err.contains(
            "/etc/passwd is not a serial port (it is an ordinary file): give a serial device"
        ),
        "{err}"
    );
    assert!(!err.contains("typewriter"), "{err}");
}

/// `sim c29u --link at`: its exit status and standard error.
fn sim_link(at: &Path) -> (Option<i32>, String) {
    let o = Command::new(rigscript())
        .args(["sim", "c29u", "--link", at.to_str().unwrap()])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    (o.status.code(), stderr(&o))
}

#[test]
fn sim_link_refuses_any_existing_path_and_leaves_it_as_it_was() {
    let d = TempDir::new("sim-link");
    let theirs = d.path("c29u");
    let other = SimProcess::start(&["--link", theirs.to_str().unwrap()]);
    let file = d.path("notes.txt");
    std::fs::write(&file, "mine").unwrap();
    let to_file = d.path("to-notes");
    std::os::unix::fs::symlink(&file, &to_file).unwrap();

    // A live simulator's link: the refusal names the process that serves it.
    let (status, err) = sim_link(&theirs);
    assert_eq!(status, Some(1), "{err}");
    assert!(
        err.contains(&format!(
            "cannot create the link {}: it points to {}, which is still in use (",
            theirs.display(),
            other.path
        )),
        "{err}"
    );
    assert!(err.contains(&format!("pid {}", other.pid())), "{err}");
    assert!(err.contains("another simulator serving there?"), "{err}");
    assert_eq!(
        std::fs::read_link(&theirs).ok(),
        Some(PathBuf::from(&other.path))
    );

    for (at, points_to) in [(&to_file, Some(file.clone())), (&file, None)] {
        let (status, err) = sim_link(at);
        assert_eq!(status, Some(1), "{err}");
        assert!(
            err.contains(&format!(
                "cannot create the link {}: File exists (os error 17); pick another path or \
                 remove the file there",
                at.display()
            )),
            "{err}"
        );
        assert_eq!(std::fs::read_link(at).ok(), points_to, "{}", at.display());
    }
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "mine");
    // The other simulator is still reachable through its link.
    let o = run(&["c29", "--port", theirs.to_str().unwrap(), "status"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
}

#[test]
fn sim_link_replaces_the_stale_link_of_a_killed_simulator() {
    let d = TempDir::new("sim-stale-link");
    let at = d.path("c29u");
    // What kill -9 leaves: the link, to a pty that is gone (a number no pty has here; a dead
    // simulator's own number could be taken by another test's pty meanwhile).
    std::os::unix::fs::symlink("/dev/pts/999999", &at).unwrap();
    let mut next = SimProcess::start(&["--link", at.to_str().unwrap()]);
    assert_eq!(
        std::fs::read_link(&at).ok(),
        Some(PathBuf::from(&next.path))
    );
    assert!(next.control("state").starts_with('{'));
    let o = run(&["c29", "--port", at.to_str().unwrap(), "status"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
}
