//! The loop's watch where no guardian process runs (`run --sim`, a rig of simulated devices,
//! `--no-guardian`): a thread of the runner's own watches the pulse with the same limit, and
//! ends the process when the loop is stuck. It cannot make real devices safe (the stuck
//! thread holds them, and a stuck thread cannot be unwound from outside): a simulated device
//! ends with the process, and for a real one (`--no-guardian`) the message says that each
//! module's own host watchdog is what is left.

use super::pulse::{stalled, Pulse, StallWatch};
use super::GuardianLog;
use crate::runtime::exit;
use crate::runtime::log::Logger;
use crate::time::clock::SystemClock;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

/// A watching thread, stopped when this is dropped.
pub struct LoneWatch {
    pulse: Arc<Pulse>,
    done: Arc<AtomicBool>,
}

impl LoneWatch {
    /// Starts the thread; `real_devices`: the run drives devices outside the process.
    pub fn start(settings: GuardianLog, real_devices: bool) -> std::io::Result<LoneWatch> {
        let pulse = Arc::new(Pulse::default());
        let done = Arc::new(AtomicBool::new(false));
        let (p, d) = (Arc::clone(&pulse), Arc::clone(&done));
        std::thread::Builder::new()
            .name("rigscript-stall".into())
            .spawn(move || watch(&p, &d, settings, real_devices))
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

fn watch(pulse: &Pulse, done: &AtomicBool, settings: GuardianLog, real_devices: bool) {
    let mut watch = StallWatch::new(settings.stall);
    while !done.load(Ordering::SeqCst) {
        std::thread::sleep(watch.every());
        let Some(silent) = watch.check(pulse, Instant::now()) else {
            continue;
        };
        let mut log = Logger::new(SystemClock::shared(), settings.zone, true);
        log.set_format(settings.format);
        let left = if real_devices {
            "no guardian (--no-guardian): the devices' outputs stay as the loop left them \
             until each module's own host watchdog acts"
        } else {
            "the simulated devices end with it"
        };
        log.error(&format!(
            "{}: the run is ended (rig.toml's `stall`); {left}",
            stalled(silent, &pulse.doing())
        ));
        log.close();
        // The loop's thread is stuck and holds what the run has: nothing of it can be unwound
        // or flushed from here.
        // SAFETY: ends the process at once; nothing is touched after it.
        unsafe { libc::_exit(exit::STALLED) };
    }
}
