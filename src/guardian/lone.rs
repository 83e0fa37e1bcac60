//! The loop's watch where no guardian process runs (`run --sim`, a rig of simulated devices,
//! `--no-guardian`; `rigscript test` and `verify`, whose runs are in the process, in virtual
//! time): a thread of the process's own watches the pulse with the same limit, and ends the
//! process when the loop is stuck, naming the handler. It cannot make real devices safe (the
//! stuck thread holds them), and it cannot end only the stuck run: what stalls is one script
//! operation that does not return (the guard's limits are looked at between operations, and
//! a Rust thread cannot be unwound from outside), so the process is the smallest thing that
//! can be ended. A simulated device ends with the process, and for a real one
//! (`--no-guardian`) the message says that each module's own host watchdog is what is left.
//!
//! Why not bound the operation itself: the report's example (a handler building 50,000
//! nested closures) does not stall on this build: building the chain is linear (0.1 s in a
//! release build, stopped at its 1 s `handler_time` in a debug one), and dropping it is
//! linear on the stack `script::stack` sizes for it. No single Rhai operation reachable from
//! a script was found to run unbounded (the size limits bound what one operation can touch:
//! a container's strings count together), so this watch is the backstop for one that does.

use super::pulse::{stalled, Pulse, StallWatch};
use super::GuardianLog;
use crate::runtime::exit;
use crate::runtime::log::Logger;
use crate::time::clock::SystemClock;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

/// What a stall ends, for its message and exit status.
#[derive(Debug, Clone, Copy)]
pub enum Ending {
    /// `rigscript run` without a guardian; `real_devices`: it drives devices outside the
    /// process (`--no-guardian`). Exits `exit::STALLED`.
    Run {
        /// The run drives devices outside the process.
        real_devices: bool,
    },
    /// An in-process command (`rigscript test`, `rigscript verify`): exits 1.
    Command(&'static str),
}

/// A watching thread, stopped when this is dropped.
pub struct LoneWatch {
    pulse: Arc<Pulse>,
    done: Arc<AtomicBool>,
}

impl LoneWatch {
    /// Starts the thread.
    pub fn start(settings: GuardianLog, ending: Ending) -> std::io::Result<LoneWatch> {
        let pulse = Arc::new(Pulse::default());
        let done = Arc::new(AtomicBool::new(false));
        let (p, d) = (Arc::clone(&pulse), Arc::clone(&done));
        std::thread::Builder::new()
            .name("rigscript-stall".into())
            .spawn(move || watch(&p, &d, settings, ending))
            .map_err(|e| std::io::Error::new(e.kind(), format!("cannot watch the loop: {e}")))?;
        Ok(LoneWatch { pulse, done })
    }

    /// The pulse the loop thread beats (`pulse::attach`).
    pub fn pulse(&self) -> &Pulse {
        &self.pulse
    }
}

impl Drop for LoneWatch {
    fn drop(&mut self) {
        self.done.store(true, Ordering::SeqCst);
    }
}

fn watch(pulse: &Pulse, done: &AtomicBool, settings: GuardianLog, ending: Ending) {
    let mut watch = StallWatch::new(settings.stall);
    while !done.load(Ordering::SeqCst) {
        std::thread::sleep(watch.every());
        let Some(silent) = watch.check(pulse, Instant::now()) else {
            continue;
        };
        if done.load(Ordering::SeqCst) {
            return;
        }
        let what = stalled(silent, &pulse.doing());
        let status = match ending {
            Ending::Run { real_devices } => {
                let mut log = Logger::new(SystemClock::shared(), settings.zone, true);
                log.set_format(settings.format);
                let left = if real_devices {
                    "no guardian (--no-guardian): the devices' outputs stay as the loop left \
                     them until each module's own host watchdog acts"
                } else {
                    "the simulated devices end with it"
                };
                log.error(&format!(
                    "{what}: the run is ended (rig.toml's `stall`); {left}"
                ));
                log.close();
                exit::STALLED
            }
            Ending::Command(name) => {
                use std::io::Write;
                let _ = writeln!(
                    std::io::stderr(),
                    "{name}: {what}: ended, as `run` would be (one script operation cannot be \
                     cut short inside the process)"
                );
                1
            }
        };
        // The loop's thread is stuck and holds what the run has: nothing of it can be unwound
        // or flushed from here.
        // libc's: rustix has `_exit` only for a process without a C library.
        // SAFETY: ends the process at once; nothing is touched after it.
        unsafe { libc::_exit(status) };
    }
}

/// The stall limit of an in-process command: longer than a run's, because the same thread
/// also does the command's own work between its rigs' beats (a test building or dropping
/// thousands of rigs in one script operation, `verify`'s bookkeeping), which is bounded but
/// not the loop.
pub const COMMAND_STALL: std::time::Duration = std::time::Duration::from_secs(10);

/// Runs `work` on this thread watched as a loop (`Ending::Command(name)`, `COMMAND_STALL`);
/// where no watching thread can be had, unwatched.
pub fn watched<T>(name: &'static str, work: impl FnOnce() -> T) -> T {
    let settings = GuardianLog {
        format: crate::runtime::log::LogFormat::Text,
        zone: crate::time::zone::Zone::Local,
        stall: COMMAND_STALL,
    };
    let watch = LoneWatch::start(settings, Ending::Command(name)).ok();
    let _beating = watch.as_ref().map(|w| super::pulse::attach(w.pulse()));
    work()
}
