//! The exit statuses of `rigscript run`, for cron, systemd and shell scripts: 0 only when the
//! run ended as planned with nothing wrong on the way; 1-5 for what went wrong, worst first;
//! 70 for a bug in rigscript (sysexits' EX_SOFTWARE); 128 + the signal for a run stopped by
//! SIGINT (130), SIGTERM (143) or any other ending signal (`runtime::signals::ENDING`: SIGHUP
//! 129, SIGQUIT 131, SIGUSR1 138, SIGUSR2 140, SIGALRM 142, SIGXFSZ 153), as shells report it (a unit lists them in systemd's
//! `SuccessExitStatus=` to count `systemctl stop` as success). `stop(code)` ends with its code.
//!
//! A stalled loop (`STALLED`, 6) is ended from outside it, by the guardian, which says so.
//!
//! Where several apply, the first of: 70, 1, `stop(code)` (not 0), 5, 4, 128 + signal, 0. A
//! signal stop is not a failure in itself, so what went wrong before it still shows.

/// The run ended as planned, nothing went wrong.
pub const OK: i32 = 0;
/// A script or runtime error ended the run (`on_error = "stop"`, a top level that failed, a
/// handler over its operation budget), or an invariant was found false.
pub const ERROR: i32 = 1;
/// Usage or configuration error: nothing was started.
pub const USAGE: i32 = 2;
/// A device did not answer at start (those that did were left in their safe state).
pub const UNAVAILABLE: i32 = 3;
/// A measurement was out of its limits.
pub const MEASUREMENT_FAILED: i32 = 4;
/// The run went on to its end, but something failed on the way: script errors recovered under
/// `on_error = "restart"` or `"skip"`, a device lost and not back at the end, an output write
/// refused, a device whose safe state the end did not confirm (read back), an `on_stop`
/// handler that failed, records the records file did not take.
pub const TROUBLE: i32 = 5;
/// The scan loop stalled: no sign of life for rig.toml's `stall` (a handler stuck in one
/// operation), or systemd's watchdog ended the runner; its watcher ended it and wrote the safe
/// state.
pub const STALLED: i32 = 6;
/// A bug in rigscript (a panic); the safe state was written to every device that answered
/// and the host watchdogs left on.
pub const INTERNAL: i32 = 70;

/// The status of a run stopped by signal `signal` (SIGINT: 130, SIGTERM: 143, SIGHUP: 129).
pub fn signal(signal: i32) -> i32 {
    128 + signal
}

/// The table, for `run --help` and the README.
pub const TABLE: &str = "\
Exit status (the first that applies):
   70  a bug in rigscript (a panic): safe state written, host watchdogs left on
    6  the scan loop stalled (no sign of life for rig.toml's `stall`: a handler
       stuck in one operation), or systemd's watchdog ended the runner: the
       guardian killed it and wrote and read back the safe state (the log says
       in which handler)
    1  a script or runtime error ended the run (on_error = \"stop\", the top level
       failed, a handler over one of its limits, an invariant found false)
    N  the script called stop(N) with N from 1 to 255
    5  the run ended, but something failed on the way: script errors recovered
       (on_error = \"restart\" or \"skip\"), a device lost and not back at the end,
       an output write refused, a device whose safe state the end did not
       confirm (read back), an on_stop handler that failed, records the
       records file did not take (a full disk, a pipe nobody reads)
    4  a measurement out of its limits
  130  stopped by SIGINT (128 + 2); 143: stopped by SIGTERM (128 + 15) or by
       `rigscript stop`; any other
       ending signal 128 + its number: 129 SIGHUP, 131 SIGQUIT, 138 SIGUSR1,
       140 SIGUSR2, 142 SIGALRM, 153 SIGXFSZ (a file past ulimit -f)
    0  the run ended as planned (--for, stop(), nothing left to do)
  128 + N  the runner died of signal N (137 kill -9 or the OOM killer, 134 an abort,
       139 a crash): its guardian wrote and read back the safe state (the log says)
Before the run starts: 2 usage or rig.toml error, or a script `rigscript check`
rejects; 3 a device not available (missing, busy, no answer), or a run of the
same rig already running.";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn signals_follow_the_shell_convention() {
        assert_eq!(signal(2), 130);
        assert_eq!(signal(15), 143);
        for (n, status) in [
            (1, 129),
            (3, 131),
            (10, 138),
            (12, 140),
            (14, 142),
            (25, 153),
        ] {
            assert_eq!(signal(n), status);
            assert!(TABLE.contains(&status.to_string()), "{status} in the table");
        }
    }

    #[test]
    fn the_readme_shows_the_table() {
        let readme = include_str!("../../README.md");
        assert!(
            readme.contains(TABLE),
            "README.md must show runtime::exit::TABLE as is"
        );
    }
}
