//! How device commands end: exit statuses, errors for people (standard error) and for `--json`
//! (one JSON document on standard output), and the Ctrl-C flag that ends live views.

use serde_json::json;
use std::fmt::Display;
use std::io::Write;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// Exit status: success.
pub const EXIT_OK: i32 = 0;
/// Exit status: anything not covered below (the device refused, misbehaved, output failed).
pub const EXIT_FAILED: i32 = 1;
/// Exit status: the command line is wrong (clap's own status for usage errors).
pub const EXIT_USAGE: i32 = 2;
/// Exit status: the device cannot be reached (not found, no permission, no answer, gone).
pub const EXIT_UNREACHABLE: i32 = 3;

/// An error that ends a command, and the exit status it stands for.
pub trait CommandError: Display {
    /// One of the `EXIT_*` statuses.
    fn exit_status(&self) -> i32;
    /// The processes that hold the device busy, when that is what went wrong.
    fn held_by(&self) -> Vec<u32> {
        Vec::new()
    }
}

/// For a device file `path` a running rig has open (a TRC1000's usbfs node, a serial port):
/// which rig, and the commands that see and stop it.
pub fn rig_holding_path(path: &std::path::Path) -> Option<String> {
    rig_holding(&crate::link::holders::holders_of(path).pids())
}

/// For a device the processes `pids` hold: the running rig among them, and the commands that
/// see and stop it (each rig's socket says its pid).
pub fn rig_holding(pids: &[u32]) -> Option<String> {
    if pids.is_empty() {
        return None;
    }
    let rig = crate::service::rig_dir::running_anywhere()
        .into_iter()
        .find(|h| pids.contains(&h.pid))?;
    Some(format!(
        "it is held by rig {name} (`rigscript status {name}` shows it, `rigscript stop {name}` \
         stops it)",
        name = rig.rig
    ))
}

/// Prints `e` for people on standard error and, with `json`, as `{"error", "status"}` on `out`;
/// returns the exit status.
pub fn report_error(e: &dyn CommandError, json: bool, out: &mut dyn Write) -> i32 {
    let status = e.exit_status();
    match rig_holding(&e.held_by()) {
        Some(rig) => say(&format!("error: {e}; {rig}")),
        None => say(&format!("error: {e}")),
    }
    if json {
        let _ = writeln!(
            out,
            "{}",
            json!({ "error": e.to_string(), "status": status })
        );
    }
    status
}

/// Writes `line` to standard error for people; a closed or broken standard error (a reader
/// gone: EPIPE; a hung-up terminal: EIO) loses the line instead of panicking as `eprintln!`
/// does, so a run goes on to its safe state whatever became of its terminal.
pub fn say(line: &str) {
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// Runs a command's `body` on standard output, reports its error, and returns the exit status.
pub fn run_command<E: CommandError>(
    json: bool,
    body: impl FnOnce(&mut dyn Write) -> Result<(), E>,
) -> i32 {
    let stdout = std::io::stdout();
    let mut out = stdout.lock();
    let status = match body(&mut out) {
        Ok(()) => EXIT_OK,
        Err(e) => report_error(&e, json, &mut out),
    };
    let _ = out.flush();
    status
}

/// A flag that SIGINT (Ctrl-C) and SIGTERM set, for live views to stop on.
pub fn stop_flag() -> std::io::Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, Arc::clone(&stop))?;
    }
    Ok(stop)
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Failure(i32);
    impl Display for Failure {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            write!(f, "it broke ({})", self.0)
        }
    }
    impl CommandError for Failure {
        fn exit_status(&self) -> i32 {
            self.0
        }
    }

    #[test]
    fn json_error_is_one_document_with_message_and_status() {
        let mut out = Vec::new();
        assert_eq!(report_error(&Failure(3), true, &mut out), 3);
        let text = String::from_utf8(out).unwrap();
        assert_eq!(text.lines().count(), 1);
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(v, json!({ "error": "it broke (3)", "status": 3 }));
    }

    #[test]
    fn text_error_prints_nothing_on_standard_output() {
        let mut out = Vec::new();
        assert_eq!(report_error(&Failure(1), false, &mut out), 1);
        assert!(out.is_empty());
    }
}
