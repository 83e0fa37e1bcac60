//! The guardian process: `guard` forks; the child goes on as the runner, the parent (the pid
//! the user or systemd started) stays behind, forwards ending signals to the runner, waits for
//! it, and makes the rig safe when it ended without confirming its safe state.
//!
//! The runner confirms over a pipe (`Confirmation::confirm`, one byte at its end); any other
//! end (a signal it could not handle, an abort, a status without the byte) leaves the guardian
//! to act. The runner is in a process group of its own, so a terminal's Ctrl-C reaches the
//! guardian alone and is forwarded once; it dies with the guardian (`PR_SET_PDEATHSIG`:
//! SIGTERM, an orderly stop), so `kill -9` of the pid that was started ends the rig safe too.

use super::pulse::{stalled, Pulse, StallWatch};
use super::safe::{make_safe, DeviceOutcome};
use crate::config::RigConfig;
use crate::runtime::exit;
use crate::runtime::log::{LogFormat, Logger};
use crate::runtime::signals;
use crate::time::clock::SystemClock;
use crate::time::zone::Zone;
use rustix::io::Errno;
use rustix::process::{kill_process, waitpid, Pid, Signal, WaitOptions};
use std::io;
use std::os::fd::OwnedFd;
use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};
use std::time::{Duration, Instant};

/// The byte the runner sends when its end confirmed the safe state (or it drove nothing).
const CONFIRMED: u8 = b'C';

/// The runner's pid, for the signal handlers (0: none yet).
static RUNNER: AtomicI32 = AtomicI32::new(0);

/// Set when SIGABRT reached the guardian (systemd's watchdog): the runner's end is told as a
/// stall.
static ABORTED: AtomicBool = AtomicBool::new(false);

/// A SIGABRT that killed the runner is told as systemd's watchdog when the loop had been
/// silent this long (it feeds the watchdog every half of its timeout while it turns); sooner,
/// it was an abort of the runner's own (a stack overflow).
const WATCHDOG_SILENCE: Duration = Duration::from_secs(1);

/// Which side of the fork this process is on.
pub enum Guarded {
    /// The runner: go on with the run, and confirm its end.
    Runner(Confirmation),
    /// The guardian, done: the runner has ended; exit with this status.
    Guardian(i32),
}

/// The runner's end of the pipe to its guardian, and the pulse its loop beats.
pub struct Confirmation {
    pipe: OwnedFd,
    pulse: &'static Pulse,
}

impl Confirmation {
    /// The pulse the guardian watches: the loop thread beats it (`pulse::attach`).
    pub fn pulse(&self) -> &'static Pulse {
        self.pulse
    }

    /// Tells the guardian that the run's end confirmed the safe state of every device (or that
    /// it drove none): it then exits with the runner's status and does nothing else.
    pub fn confirm(self) {
        // A pipe with room for 64 KiB never blocks on one byte; a failure leaves the guardian
        // to act, which is safe.
        let _ = rustix::io::write(&self.pipe, &[CONFIRMED]);
    }
}

/// Why the guardian could not be started.
#[derive(Debug, thiserror::Error)]
pub enum GuardError {
    /// No memory to share with it.
    #[error("cannot start the guardian process: no memory to share with it: {0}")]
    Pulse(#[source] io::Error),
    /// No pipe or no fork (the system is out of processes or descriptors).
    #[error("cannot start the guardian process: {0}")]
    Start(#[source] io::Error),
    /// The process already runs other threads: a fork would copy it with locks they may hold.
    #[error(
        "cannot start the guardian process: {0} threads run already (a bug: it must fork first)"
    )]
    Threads(usize),
}

/// How many threads this process runs (`None` where /proc does not say).
fn threads() -> Option<usize> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("Threads:"))
        .and_then(|n| n.trim().parse().ok())
}

/// How the guardian speaks: the run's log format, and the zone of its times; and how long
/// the loop may be silent.
#[derive(Debug, Clone, Copy)]
pub struct GuardianLog {
    /// Text or JSON lines, as the run's own log.
    pub format: LogFormat,
    /// The zone of the times.
    pub zone: Zone,
    /// The rig's stall limit (`RigConfig::stall_limit`).
    pub stall: Duration,
}

/// Splits this process into the guardian and the runner. Must be called while the process has
/// one thread (before the log's writer or any other is started). The guardian's side returns
/// only once the runner has ended (and the rig was made safe if it had to be).
pub fn guard(config: &RigConfig, log: GuardianLog) -> Result<Guarded, GuardError> {
    if let Some(n) = threads().filter(|&n| n > 1) {
        return Err(GuardError::Threads(n));
    }
    let pulse = Pulse::shared().map_err(GuardError::Pulse)?;
    let (read, write) = rustix::pipe::pipe_with(rustix::pipe::PipeFlags::CLOEXEC)
        .map_err(|e| GuardError::Start(e.into()))?;
    let guardian = rustix::process::getpid();
    // rustix forks only for a process without a C library (its `runtime` module): libc's
    // fork runs the C library's own fork handlers.
    // SAFETY: the process has one thread (the caller's contract), so the child starts as a
    // full copy with no lock held by a thread that does not exist there.
    let child = unsafe { libc::fork() };
    if child == -1 {
        return Err(GuardError::Start(io::Error::last_os_error()));
    }
    match Pid::from_raw(child) {
        None => {
            drop(read);
            become_runner(guardian);
            Ok(Guarded::Runner(Confirmation { pipe: write, pulse }))
        }
        Some(child) => {
            drop(write);
            RUNNER.store(child.as_raw_nonzero().get(), Ordering::SeqCst);
            // Also here, so that a signal before the child has done it cannot find it in our
            // group (the usual race of setpgid, done on both sides).
            let _ = rustix::process::setpgid(Some(child), Some(child));
            forward_signals();
            let end = watch(child, pulse, log.stall);
            let confirmed = read_confirmation(&read);
            Ok(Guarded::Guardian(finish(
                end, confirmed, child, config, log, pulse,
            )))
        }
    }
}

/// The child's set-up: its own process group, SIGTERM when the guardian dies, and systemd's
/// service watchdog (`$WATCHDOG_PID` names the pid systemd started, the guardian) passed on.
fn become_runner(guardian: Pid) {
    let _ = rustix::process::setpgid(None, None);
    let _ = rustix::process::set_parent_process_death_signal(Some(Signal::TERM));
    // The guardian may have died before the prctl took effect: then nobody will send it.
    if rustix::process::getppid() != Some(guardian) {
        let _ = kill_process(rustix::process::getpid(), Signal::TERM);
    }
    if std::env::var("WATCHDOG_PID").ok() == Some(guardian.to_string()) {
        std::env::set_var("WATCHDOG_PID", std::process::id().to_string());
    }
}

/// Passes each ending signal on to the runner; SIGABRT (what systemd's service watchdog sends
/// when the loop stopped turning) kills the runner, which is stuck, so the guardian can act.
/// Job-control signals are ignored: a rig does not pause because a terminal asks it to.
fn forward_signals() {
    // rustix's kill is one system call, which a signal handler may make (and it leaves errno
    // alone).
    fn kill_runner(signal: Option<Signal>) {
        if let (Some(runner), Some(signal)) = (Pid::from_raw(RUNNER.load(Ordering::SeqCst)), signal)
        {
            let _ = kill_process(runner, signal);
        }
    }
    extern "C" fn forward(signal: libc::c_int) {
        kill_runner(Signal::from_named_raw(signal));
    }
    extern "C" fn stuck(_: libc::c_int) {
        ABORTED.store(true, Ordering::SeqCst);
        kill_runner(Some(Signal::KILL));
    }
    // The runner's own list: what ends a run in order ends it whichever process it reached.
    for signal in signals::ENDING {
        set_handler(signal, forward as *const () as libc::sighandler_t);
    }
    set_handler(libc::SIGABRT, stuck as *const () as libc::sighandler_t);
    for signal in signals::IGNORED.into_iter().chain([libc::SIGTSTP]) {
        set_handler(signal, libc::SIG_IGN);
    }
}

/// With libc's sigaction: rustix sets handlers only for a process without a C library.
fn set_handler(signal: libc::c_int, handler: libc::sighandler_t) {
    // SAFETY: a zeroed sigaction is valid; the handlers above only call kill.
    unsafe {
        let mut action: libc::sigaction = std::mem::zeroed();
        action.sa_sigaction = handler;
        action.sa_flags = libc::SA_RESTART;
        libc::sigemptyset(&mut action.sa_mask);
        libc::sigaction(signal, &action, std::ptr::null_mut());
    }
}

/// How the runner ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunnerEnd {
    /// Its loop stopped turning: the guardian (or systemd's watchdog) killed it.
    Stalled {
        /// How long the loop had been silent.
        silent: Duration,
        /// systemd's watchdog ended it (SIGABRT), not the guardian's own limit.
        by_watchdog: bool,
    },
    /// It exited with this status.
    Exited(i32),
    /// A signal killed it.
    Killed {
        /// The signal.
        signal: i32,
        /// It dumped core.
        core: bool,
    },
}

/// Waits for the runner to end, watching its loop meanwhile (see the module's doc).
fn watch(child: Pid, pulse: &Pulse, stall: Duration) -> RunnerEnd {
    let mut watch = StallWatch::new(stall);
    let every = watch.every();
    loop {
        if let Some(end) = reap(child, WaitOptions::NOHANG) {
            let silent = watch.silent(Instant::now());
            return match end {
                RunnerEnd::Killed { signal, .. }
                    if (signal == libc::SIGKILL && ABORTED.load(Ordering::SeqCst))
                        || (signal == libc::SIGABRT && silent >= WATCHDOG_SILENCE) =>
                {
                    RunnerEnd::Stalled {
                        silent,
                        by_watchdog: true,
                    }
                }
                end => end,
            };
        }
        if let Some(silent) = watch.check(pulse, Instant::now()) {
            let _ = kill_process(child, Signal::KILL);
            wait_for(child);
            return RunnerEnd::Stalled {
                silent,
                by_watchdog: false,
            };
        }
        // Interrupted by a signal: looked at again sooner, which is harmless.
        std::thread::sleep(every);
    }
}

fn wait_for(child: Pid) -> RunnerEnd {
    loop {
        if let Some(end) = reap(child, WaitOptions::empty()) {
            return end;
        }
    }
}

/// The runner's end if it has ended (`options`: `NOHANG` not to wait), else `None`.
fn reap(child: Pid, options: WaitOptions) -> Option<RunnerEnd> {
    match waitpid(Some(child), options) {
        Ok(Some((_, status))) => {
            if let Some(code) = status.exit_status() {
                return Some(RunnerEnd::Exited(code));
            }
            status.terminating_signal().map(|signal| RunnerEnd::Killed {
                signal,
                core: libc::WCOREDUMP(status.as_raw()),
            })
        }
        Ok(None) | Err(Errno::INTR) => None,
        // The child cannot be waited for (it never can be lost to us otherwise): act.
        Err(_) => Some(RunnerEnd::Killed {
            signal: 0,
            core: false,
        }),
    }
}

/// Whether the runner sent its confirmation before it ended (its end of the pipe is closed
/// now, so this never waits).
fn read_confirmation(read: &OwnedFd) -> bool {
    let mut buf = [0u8; 16];
    loop {
        match rustix::io::read(read, &mut buf) {
            Ok(0) => return false,
            Ok(n) if buf[..n].contains(&CONFIRMED) => return true,
            Ok(_) | Err(Errno::INTR) => {}
            Err(_) => return false,
        }
    }
}

/// The guardian's exit status, after making the rig safe where the runner's end did not.
fn finish(
    end: RunnerEnd,
    confirmed: bool,
    runner: Pid,
    config: &RigConfig,
    settings: GuardianLog,
    pulse: &Pulse,
) -> i32 {
    let status = exit_status(end);
    if confirmed && matches!(end, RunnerEnd::Exited(_)) {
        return status;
    }
    let mut log = Logger::new(SystemClock::shared(), settings.zone, true);
    log.set_format(settings.format);
    log.set_devices(config.devices.keys().cloned());
    match end {
        RunnerEnd::Stalled { .. } => log.error(&format!(
            "guardian: {}; the runner (pid {runner}) was killed; writing the safe state now",
            describe_stall(end, &pulse.doing())
        )),
        _ => log.warn(&format!(
            "guardian: the runner (pid {runner}) {} before it confirmed the safe state; \
             writing it now",
            describe(end)
        )),
    }
    let outcomes = make_safe(config, &SystemClock::shared());
    report(&mut log, &outcomes);
    log.close();
    status
}

/// The guardian's status: the runner's own, or 128 + the signal that killed it, as a shell
/// reports a process killed by a signal.
pub fn exit_status(end: RunnerEnd) -> i32 {
    match end {
        RunnerEnd::Stalled { .. } => exit::STALLED,
        RunnerEnd::Exited(code) => code,
        RunnerEnd::Killed { signal, .. } => 128 + signal,
    }
}

/// A stalled runner's end in words, with what its loop was doing (`Pulse::doing`): "the scan
/// loop stalled for 1.0 s (in handler `after 500ms`)", and who ended it.
pub fn describe_stall(end: RunnerEnd, doing: &str) -> String {
    match end {
        RunnerEnd::Stalled {
            silent,
            by_watchdog,
        } => {
            let by = if by_watchdog {
                "systemd's watchdog ended it (SIGABRT)"
            } else {
                "the guardian ended it (rig.toml's `stall`)"
            };
            format!("{}: {by}", stalled(silent, doing))
        }
        other => describe(other),
    }
}

/// How the runner ended, in words.
pub fn describe(end: RunnerEnd) -> String {
    match end {
        RunnerEnd::Stalled { silent, .. } => stalled(silent, "doing something"),
        RunnerEnd::Exited(code) => format!("ended with status {code}"),
        RunnerEnd::Killed { signal: 0, .. } => "could not be waited for".into(),
        RunnerEnd::Killed { signal, core } => {
            let what = match signal {
                libc::SIGKILL => {
                    "was killed by SIGKILL (kill -9, or the kernel's out-of-memory killer)"
                }
                libc::SIGABRT => {
                    "aborted (SIGABRT: a stack overflow, an abort, or stuck and killed)"
                }
                libc::SIGSEGV => "crashed (SIGSEGV: a fault in rigscript or a C library)",
                libc::SIGBUS => "crashed (SIGBUS)",
                libc::SIGILL => {
                    "crashed (SIGILL: an illegal instruction, in rigscript or a C library)"
                }
                libc::SIGFPE => "crashed (SIGFPE)",
                _ => "was killed",
            };
            let core = if core { ", core dumped" } else { "" };
            format!("{what} (signal {signal}{core})")
        }
    }
}

/// Logs each device's outcome: a warning for those confirmed (the rig needed the guardian),
/// an error for each that was not.
fn report(log: &mut Logger, outcomes: &[DeviceOutcome]) {
    let (done, failed): (Vec<_>, Vec<_>) = outcomes.iter().partition(|o| o.result.is_ok());
    for o in &failed {
        log.error(&format!("guardian: {o}"));
    }
    if !done.is_empty() {
        let words: Vec<String> = done.iter().map(ToString::to_string).collect();
        log.warn(&format!(
            "guardian: safe state (the runner died): {}",
            words.join(", ")
        ));
    }
}
