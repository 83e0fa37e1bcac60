//! The signals that end a run, and what the runner does with them: each ending signal sets the
//! run's stop flag to its number (an orderly stop: `on_stop`, the safe state, exit status
//! 128 + the signal), and the signals that would stop or kill the runner behind its back
//! (a closed pipe, job control on its terminal) are ignored. Per process: whoever sends them
//! (a shell, systemd, a supervising process) is no concern here.

use signal_hook::consts::{
    SIGALRM, SIGHUP, SIGINT, SIGPIPE, SIGQUIT, SIGTERM, SIGTTIN, SIGTTOU, SIGUSR1, SIGUSR2, SIGXFSZ,
};
use std::sync::atomic::AtomicUsize;
use std::sync::Arc;

/// Every signal whose default would end the process without the safe state, and that can be
/// caught: each is an orderly stop.
pub const ENDING: [i32; 8] = [
    SIGINT, SIGTERM, SIGHUP, SIGQUIT, SIGUSR1, SIGUSR2, SIGALRM, SIGXFSZ,
];

/// Signals that must not stop or end the runner at all: SIGPIPE (a reader of stdout or stderr
/// went away: the write fails instead, and the log counts it), SIGTTOU and SIGTTIN (a run in a
/// background process group whose terminal has `tostop`: its log writes go on).
pub const IGNORED: [i32; 3] = [SIGPIPE, SIGTTOU, SIGTTIN];

/// A signal by name, for the log ("SIGHUP"; "signal 34" for one without a name here).
pub fn name(signal: i32) -> String {
    let known = match signal {
        SIGINT => "SIGINT",
        SIGTERM => "SIGTERM",
        SIGHUP => "SIGHUP",
        SIGQUIT => "SIGQUIT",
        SIGUSR1 => "SIGUSR1",
        SIGUSR2 => "SIGUSR2",
        SIGALRM => "SIGALRM",
        SIGXFSZ => "SIGXFSZ",
        _ => return format!("signal {signal}"),
    };
    known.to_string()
}

/// Who likely sent `signal`, in a few words, for the log.
pub fn likely_cause(signal: i32) -> &'static str {
    match signal {
        SIGINT => "Ctrl-C, or kill -INT",
        SIGTERM => "systemctl stop, kill, or a shutdown",
        SIGHUP => "the terminal or SSH session the run was started from was closed",
        SIGQUIT => "Ctrl-\\ on the terminal, or kill -QUIT",
        SIGUSR1 | SIGUSR2 => "sent by another program (rigscript gives it no other meaning)",
        SIGALRM => "a timer another program set (timeout --signal=ALRM, alarm)",
        SIGXFSZ => {
            "a write went past the file size limit RLIMIT_FSIZE, ulimit -f: the records file?"
        }
        _ => "sent by another program",
    }
}

/// Makes every `ENDING` signal set `flag` to its number (the last one received wins) and
/// ignores the `IGNORED` ones. Call it before any device is opened: from then on a signal cuts
/// the start's exchanges short too.
pub fn watch(flag: &Arc<AtomicUsize>) -> std::io::Result<()> {
    for signal in ENDING {
        let number = usize::try_from(signal).unwrap_or(1);
        signal_hook::flag::register_usize(signal, Arc::clone(flag), number)?;
    }
    for signal in IGNORED {
        // libc's: neither signal-hook nor rustix (outside its runtime for a process without a C
        // library) sets a disposition.
        // SAFETY: setting a signal's disposition to "ignore" touches no Rust state; a caught
        // SIGTTOU would restart the write that raised it, for ever, so it must be ignored.
        if unsafe { libc::signal(signal, libc::SIG_IGN) } == libc::SIG_ERR {
            return Err(std::io::Error::last_os_error());
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_ending_signal_has_a_name_and_a_cause_of_its_own() {
        // Not the fallback for a signal without a name here: each one ENDING lists is known.
        let names: Vec<String> = ENDING.iter().map(|&s| name(s)).collect();
        assert_eq!(
            names,
            [
                "SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT", "SIGUSR1", "SIGUSR2", "SIGALRM",
                "SIGXFSZ"
            ]
        );
        assert_eq!(name(34), "signal 34");
        let fallback = likely_cause(34);
        assert_eq!(fallback, "sent by another program");
        for (signal, words) in [
            (SIGINT, "Ctrl-C"),
            (SIGTERM, "systemctl stop"),
            (SIGHUP, "SSH session"),
            (SIGQUIT, "Ctrl-\\"),
            (SIGUSR1, "no other meaning"),
            (SIGUSR2, "no other meaning"),
            (SIGALRM, "timeout --signal=ALRM"),
            (SIGXFSZ, "RLIMIT_FSIZE"),
        ] {
            let cause = likely_cause(signal);
            assert!(cause.contains(words), "{}: {cause}", name(signal));
            assert_ne!(cause, fallback, "{}", name(signal));
        }
    }
}
