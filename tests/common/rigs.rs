//! Rigs the tests start with a runtime directory of their own (where the control sockets
//! live), and the runs they started, killed if a test fails before they end.

use super::{rigscript, until, TempDir};
use serde_json::Value;
use std::process::{Child, Command, Output, Stdio};
use std::time::Duration;

/// A scratch `XDG_RUNTIME_DIR`: the rigs run in it are found by the commands run in it.
pub struct Rigs {
    /// The directory (rig.toml, scripts and the sockets' `rigscript/` under it).
    pub dir: TempDir,
}

impl Rigs {
    /// A new scratch runtime directory named after `tag`.
    pub fn new(tag: &str) -> Self {
        Self {
            dir: TempDir::new(tag),
        }
    }

    /// `rigscript ARGS` in this runtime directory.
    pub fn command(&self, args: &[&str]) -> Command {
        let mut c = Command::new(rigscript());
        c.args(args).env("XDG_RUNTIME_DIR", self.dir.root());
        c.env_remove("RUNTIME_DIRECTORY");
        c
    }

    /// `rigscript run ARGS`, its stderr piped.
    pub fn run(&self, args: &[&str]) -> Run {
        Run(self
            .command(&[&["run"], args].concat())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap())
    }

    /// `rigscript ARGS`, to its end.
    pub fn output(&self, args: &[&str]) -> Output {
        self.command(args).output().unwrap()
    }

    /// The control socket of `rig`.
    pub fn socket(&self, rig: &str) -> std::path::PathBuf {
        self.dir.path("rigscript").join(format!("{rig}.sock"))
    }

    /// `status RIG --json`, once it answers (the run may still be starting).
    pub fn status(&self, rig: &str) -> Value {
        let out = until(Duration::from_secs(10), || {
            let out = self.output(&["status", rig, "--json"]);
            out.status.success().then_some(out)
        })
        .unwrap_or_else(|| panic!("rig {rig} never answered status"));
        serde_json::from_slice(&out.stdout).unwrap()
    }
}

/// A run a test started, killed if the test fails before it ends.
pub struct Run(pub Child);

impl std::ops::Deref for Run {
    type Target = Child;
    fn deref(&self) -> &Child {
        &self.0
    }
}

impl std::ops::DerefMut for Run {
    fn deref_mut(&mut self) -> &mut Child {
        &mut self.0
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        if let Ok(None) = self.0.try_wait() {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}
