//! The scan loop's pulse: how the runner shows whoever watches it (the guardian process, or a
//! thread of its own where there is no guardian) that its loop still turns, and what it was
//! doing last, at the cost of a few stores and no system call.
//!
//! What counts as alive: the loop thread beats when a tick begins, at every slice of its wait
//! between ticks (`runner::wait::SLEEP_SLICE`), at every slice of a device exchange's waits
//! (`device::exchange`, at most `CANCEL_SLICE`), and every few dozen operations of the script
//! (where the guard reads the clock for the handler's time). Each of these ends within its own
//! bound (a tick's exchanges and a handler's operations and time have limits of their own), so
//! a loop that does not beat for the rig's `stall` limit is stuck in something that has no
//! bound: one script operation that does not return, or a bug. A blocking step known to take
//! longer than a slice (a TCP connection, bounded by the device's timeout) says so first
//! (`allow`), and the watcher adds that to the limit.
//!
//! The pulse is a small fixed-size block of atomics: in a `MAP_SHARED` anonymous mapping made
//! before the guardian's fork (both processes see the same page), or on the heap for a watcher
//! thread. The loop thread finds it through a thread-local pointer set by `attach`, so the
//! device code beats without being handed anything; on other threads (and before `attach`)
//! every call here is a no-op.

use std::cell::Cell;
use std::sync::atomic::{fence, AtomicU32, AtomicU64, AtomicU8, Ordering};
use std::time::{Duration, Instant};

/// The longest label kept, in bytes (a longer one is cut at a character boundary).
pub const LABEL_BYTES: usize = 56;

/// What the loop was doing at its last beat.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum Phase {
    /// Starting: opening the devices, the script's top level.
    Starting = 0,
    /// In the handler (or top level, invariant, `on_stop`) named by the label.
    Handler = 1,
    /// The tick's own work: supervision, reading inputs, writing outputs, checks.
    Tick = 2,
    /// Waiting for the next tick (feeds, retries and requests meanwhile).
    Waiting = 3,
    /// The loop has ended: what follows (the end's report, closing the log) is not watched.
    Ended = 4,
}

impl Phase {
    fn from_u32(n: u32) -> Phase {
        match n {
            1 => Phase::Handler,
            2 => Phase::Tick,
            3 => Phase::Waiting,
            4 => Phase::Ended,
            _ => Phase::Starting,
        }
    }
}

/// The block the loop writes and its watcher reads.
#[repr(C)]
pub struct Pulse {
    /// Beats so far (only the loop thread writes it).
    beats: AtomicU64,
    /// Extra time the step after the last beat may take, in microseconds (`allow`).
    allowance_us: AtomicU64,
    /// `Phase` as a number.
    phase: AtomicU32,
    /// Even when the label is whole; odd while it is being written.
    seq: AtomicU32,
    /// The label's length in bytes.
    len: AtomicU32,
    label: [AtomicU8; LABEL_BYTES],
}

impl Default for Pulse {
    fn default() -> Self {
        Pulse {
            beats: AtomicU64::new(0),
            allowance_us: AtomicU64::new(0),
            phase: AtomicU32::new(Phase::Starting as u32),
            seq: AtomicU32::new(0),
            len: AtomicU32::new(0),
            label: [const { AtomicU8::new(0) }; LABEL_BYTES],
        }
    }
}

impl Pulse {
    /// A pulse in memory shared with the processes this one forks from now on (an anonymous
    /// `MAP_SHARED` mapping); it lives as long as the process.
    pub fn shared() -> std::io::Result<&'static Pulse> {
        use rustix::mm::{mmap_anonymous, MapFlags, ProtFlags};
        let (size, rw) = (
            std::mem::size_of::<Pulse>(),
            ProtFlags::READ | ProtFlags::WRITE,
        );
        // SAFETY: a new anonymous mapping, not aliased by anything; zeroed by the kernel, which
        // is a valid `Pulse` (every field an atomic integer, zero its initial value).
        let at = unsafe { mmap_anonymous(std::ptr::null_mut(), size, rw, MapFlags::SHARED)? };
        // SAFETY: the mapping is page-aligned, at least `size` bytes, never unmapped, and holds
        // zeroed atomics (a valid value of every field).
        Ok(unsafe { &*at.cast::<Pulse>() })
    }

    /// Beats so far.
    pub fn beats(&self) -> u64 {
        self.beats.load(Ordering::Acquire)
    }

    /// The extra time the step after the last beat may take.
    pub fn allowance(&self) -> Duration {
        Duration::from_micros(self.allowance_us.load(Ordering::Acquire))
    }

    /// What the loop was doing at its last beat.
    pub fn phase(&self) -> Phase {
        Phase::from_u32(self.phase.load(Ordering::Acquire))
    }

    /// The last label published (`None` if it was being written and did not settle).
    pub fn label(&self) -> Option<String> {
        for _ in 0..100 {
            let before = self.seq.load(Ordering::Acquire);
            if before % 2 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let len = (self.len.load(Ordering::Relaxed) as usize).min(LABEL_BYTES);
            let bytes: Vec<u8> = self.label[..len]
                .iter()
                .map(|b| b.load(Ordering::Relaxed))
                .collect();
            fence(Ordering::Acquire);
            if self.seq.load(Ordering::Relaxed) == before {
                return Some(String::from_utf8_lossy(&bytes).into_owned());
            }
        }
        None
    }

    /// What the loop was doing, in words: "in handler `after 500ms`", "in the tick's own
    /// work (...)".
    pub fn doing(&self) -> String {
        match self.phase() {
            Phase::Handler => match self.label() {
                Some(l) if l == "top level" => "in the script's top level".into(),
                Some(l) => format!("in handler `{l}`"),
                None => "in a handler".into(),
            },
            Phase::Starting => "starting: opening the devices".into(),
            Phase::Tick => {
                "in the tick's own work: supervision, reading inputs, writing outputs".into()
            }
            Phase::Waiting => "waiting for the next tick".into(),
            Phase::Ended => "ending".into(),
        }
    }

    fn beat(&self) {
        // One writer (the loop thread): a plain increment, no locked instruction.
        let n = self.beats.load(Ordering::Relaxed);
        self.beats.store(n.wrapping_add(1), Ordering::Release);
    }

    fn set_phase(&self, phase: Phase) {
        self.phase.store(phase as u32, Ordering::Release);
    }

    fn set_label(&self, label: &str) {
        let mut end = label.len().min(LABEL_BYTES);
        while !label.is_char_boundary(end) {
            end -= 1;
        }
        let seq = self.seq.load(Ordering::Relaxed);
        self.seq.store(seq.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        for (slot, &b) in self.label.iter().zip(&label.as_bytes()[..end]) {
            slot.store(b, Ordering::Relaxed);
        }
        self.len.store(end as u32, Ordering::Relaxed);
        self.seq.store(seq.wrapping_add(2), Ordering::Release);
    }
}

/// Decides, from what a watcher sees of a pulse over time, whether the loop is stuck: armed by
/// the first beat, quiet once the loop has ended, and stuck once no beat came for the limit
/// plus whatever the last step asked for (`allow`).
#[derive(Debug)]
pub struct StallWatch {
    limit: Duration,
    beats: u64,
    since: Option<Instant>,
    allowance: Duration,
    /// When it last looked.
    looked: Option<Instant>,
}

impl StallWatch {
    /// A watch with the rig's stall `limit`.
    pub fn new(limit: Duration) -> Self {
        StallWatch {
            limit,
            beats: 0,
            since: None,
            allowance: Duration::ZERO,
            looked: None,
        }
    }

    /// How often a watcher should look: a twentieth of the limit, from 10 to 100 ms.
    pub fn every(&self) -> Duration {
        (self.limit / 20).clamp(Duration::from_millis(10), Duration::from_millis(100))
    }

    /// Looks at `pulse` at `now`: how long the loop has been silent when that is past the
    /// limit (it is stuck), else `None`.
    pub fn check(&mut self, pulse: &Pulse, now: Instant) -> Option<Duration> {
        // A watcher that could not look for half the limit was not running (the whole process
        // stopped and continued, as Ctrl-Z and `fg` do to a run without a guardian): what it
        // missed is not the loop's silence, so the count starts again.
        let absent = self
            .looked
            .replace(now)
            .is_some_and(|t| now.saturating_duration_since(t) > self.limit / 2);
        if absent {
            self.since = self.since.map(|_| now);
        }
        let beats = pulse.beats();
        if beats == 0 || pulse.phase() == Phase::Ended {
            self.since = None;
            return None;
        }
        if self.since.is_none() || beats != self.beats {
            self.beats = beats;
            self.since = Some(now);
            self.allowance = pulse.allowance();
            return None;
        }
        let silent = self.silent(now);
        (silent >= self.limit.saturating_add(self.allowance)).then_some(silent)
    }

    /// How long the loop has been silent at `now` (zero before the first beat).
    pub fn silent(&self, now: Instant) -> Duration {
        self.since
            .map_or(Duration::ZERO, |t| now.saturating_duration_since(t))
    }
}

/// What a stalled loop is told as: "the scan loop stalled for 1.0 s (in handler `after
/// 500ms`)" (the silence cut to a tenth of a second: it was at least that long).
pub fn stalled(silent: Duration, doing: &str) -> String {
    let tenths = silent.as_millis() / 100;
    format!(
        "the scan loop stalled for {}.{} s ({doing})",
        tenths / 10,
        tenths % 10
    )
}

thread_local! {
    /// The pulse this thread beats, if it is a loop thread (`attach`).
    static CURRENT: Cell<*const Pulse> = const { Cell::new(std::ptr::null()) };
}

/// This thread beats `pulse` until the returned value is dropped.
#[must_use = "the thread beats the pulse only while this lives"]
pub struct Attached<'a> {
    previous: *const Pulse,
    _pulse: std::marker::PhantomData<&'a Pulse>,
}

/// Makes this thread (the scan loop's) beat `pulse` while the result lives.
pub fn attach(pulse: &Pulse) -> Attached<'_> {
    let previous = CURRENT.with(|c| c.replace(pulse));
    Attached {
        previous,
        _pulse: std::marker::PhantomData,
    }
}

impl Drop for Attached<'_> {
    fn drop(&mut self) {
        CURRENT.with(|c| c.set(self.previous));
    }
}

fn with(f: impl FnOnce(&Pulse)) {
    let at = CURRENT.with(Cell::get);
    // SAFETY: set by `attach` from a reference that outlives its `Attached`, which resets it
    // on drop; only this thread reads it.
    if let Some(pulse) = unsafe { at.as_ref() } {
        f(pulse);
    }
}

/// The loop is alive (see the module's doc for where this is called).
#[inline]
pub fn beat() {
    with(Pulse::beat);
}

/// The loop is alive and now doing `phase`.
#[inline]
pub fn enter(phase: Phase) {
    with(|p| {
        p.set_phase(phase);
        p.beat();
    });
}

/// The loop is alive and now runs the handler (or top level) named `label`.
pub fn handler(label: &str) {
    with(|p| {
        p.set_label(label);
        p.set_phase(Phase::Handler);
        p.beat();
    });
}

/// Marks the loop ended when dropped (`Phase::Ended`): what this thread does after a run
/// (an in-process one: `verify`'s bookkeeping between runs) is not watched as its loop.
pub struct EndsLoop;

impl Drop for EndsLoop {
    fn drop(&mut self) {
        with(|p| p.set_phase(Phase::Ended));
    }
}

/// The step that follows may block for up to `extra` beyond the stall limit (a connection
/// with its own timeout); cleared by `allow(Duration::ZERO)` after it.
pub fn allow(extra: Duration) {
    with(|p| {
        let us = u64::try_from(extra.as_micros()).unwrap_or(u64::MAX);
        p.allowance_us.store(us, Ordering::Release);
        p.beat();
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_watch_is_armed_by_the_first_beat_and_trips_after_the_limit_and_allowance() {
        let pulse = Pulse::default();
        let mut watch = StallWatch::new(Duration::from_secs(1));
        let t0 = Instant::now();
        let at = |ms| t0 + Duration::from_millis(ms);
        assert_eq!(
            watch.check(&pulse, at(5000)),
            None,
            "not armed before a beat"
        );
        pulse.beat();
        assert_eq!(watch.check(&pulse, at(5000)), None);
        assert_eq!(watch.check(&pulse, at(5400)), None);
        assert_eq!(watch.check(&pulse, at(5800)), None);
        assert_eq!(watch.check(&pulse, at(6000)), Some(Duration::from_secs(1)));
        // A step that may block longer says so: the limit grows by that much, once.
        {
            let _on = attach(&pulse);
            allow(Duration::from_millis(500));
        }
        assert_eq!(watch.check(&pulse, at(6000)), None);
        for ms in [6400, 6800, 7200, 7400] {
            assert_eq!(watch.check(&pulse, at(ms)), None, "{ms}");
        }
        assert!(watch.check(&pulse, at(7500)).is_some());
        // A watcher that was itself stopped for longer than the limit counts afresh.
        {
            let _on = attach(&pulse);
            allow(Duration::ZERO);
        }
        assert_eq!(watch.check(&pulse, at(8000)), None);
        assert_eq!(
            watch.check(&pulse, at(20_000)),
            None,
            "the watcher was away"
        );
        assert!(watch.check(&pulse, at(20_400)).is_none());
        assert!(watch.check(&pulse, at(20_800)).is_none());
        assert!(watch.check(&pulse, at(21_000)).is_some());
        pulse.set_phase(Phase::Ended);
        assert_eq!(
            watch.check(&pulse, at(60_000)),
            None,
            "an ended loop is not watched"
        );
        assert_eq!(
            stalled(Duration::from_millis(1040), "in handler `after 500ms`"),
            "the scan loop stalled for 1.0 s (in handler `after 500ms`)"
        );
    }

    #[test]
    fn beats_reach_the_attached_pulse_only() {
        let pulse = Pulse::default();
        beat();
        assert_eq!(pulse.beats(), 0);
        {
            let _on = attach(&pulse);
            beat();
            enter(Phase::Tick);
            assert_eq!(pulse.beats(), 2);
            assert_eq!(pulse.phase(), Phase::Tick);
        }
        beat();
        assert_eq!(pulse.beats(), 2);
    }

    #[test]
    fn the_label_reads_back_cut_at_a_character() {
        let pulse = Pulse::default();
        let _on = attach(&pulse);
        handler("after 500ms");
        assert_eq!(pulse.doing(), "in handler `after 500ms`");
        let long = "é".repeat(40);
        handler(&long);
        let got = pulse.label().unwrap();
        assert!(got.len() <= LABEL_BYTES && long.starts_with(&got), "{got}");
        handler("top level");
        assert_eq!(pulse.doing(), "in the script's top level");
    }

    #[test]
    fn a_shared_pulse_is_seen_by_a_forked_child() {
        let pulse = Pulse::shared().unwrap();
        // The child only stores to the mapping and exits: nothing of this process's threads
        // is needed on its side of the fork.
        // SAFETY: fork, then atomics and _exit only in the child.
        let child = unsafe { libc::fork() };
        if child == 0 {
            pulse.beat();
            pulse.set_label("after 500ms");
            // SAFETY: ends the child at once, running nothing of the parent's.
            unsafe { libc::_exit(0) };
        }
        let child = rustix::process::Pid::from_raw(child);
        rustix::process::waitpid(child, rustix::process::WaitOptions::empty()).unwrap();
        assert_eq!(pulse.beats(), 1);
        assert_eq!(pulse.label().as_deref(), Some("after 500ms"));
    }
}
