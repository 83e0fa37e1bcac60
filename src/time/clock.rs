//! Clocks: the one source of time for devices models, drivers and the scan loop.
//!
//! Monotonic time is a `Duration` since the clock's origin, so virtual time is just a number
//! that tests move forward; wall time (for records and cron) comes from the same clock.

use super::doorbell::Doorbell;
use chrono::{DateTime, Utc};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// A source of monotonic and wall time that can also wait.
pub trait Clock: Send + Sync {
    /// Monotonic time since this clock's origin.
    fn now(&self) -> Duration;
    /// Wall-clock time, for timestamps and calendars.
    fn wall(&self) -> DateTime<Utc>;
    /// Waits until monotonic time `deadline` (returns at once if it has passed).
    fn sleep_until(&self, deadline: Duration);
    /// As `sleep_until`, returning early when `bell` rings (real time; virtual time has no
    /// one to ring during a jump, so it just jumps).
    fn sleep_until_rung(&self, deadline: Duration, bell: &Doorbell) {
        let _ = bell;
        self.sleep_until(deadline);
    }
    /// Whether this is virtual time (scenario tests, `verify`): what a run on it says is
    /// made up and must never reach a rig's production records file or broker.
    fn is_virtual(&self) -> bool {
        false
    }
}

/// The monotonic clock in nanoseconds. Read about fifteen times a scan tick: `Instant`'s
/// `elapsed` costs twice the instructions (two checked timespec subtractions), measured with
/// callgrind on a polling run.
fn monotonic_nanos() -> u64 {
    // A vDSO call, as `Instant::now`'s.
    let ts = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
    u64::try_from(ts.tv_sec)
        .unwrap_or(0)
        .saturating_mul(1_000_000_000)
        .saturating_add(u64::try_from(ts.tv_nsec).unwrap_or(0))
}

/// A shared handle to any clock.
pub type SharedClock = Arc<dyn Clock>;

/// Real time: the monotonic clock (`CLOCK_MONOTONIC`, as `Instant` uses) for monotonic time,
/// the system clock for wall time.
#[derive(Debug, Clone)]
pub struct SystemClock {
    /// The monotonic clock's reading at the origin, in nanoseconds.
    origin: u64,
}

impl SystemClock {
    /// A system clock whose origin is now.
    pub fn new() -> Self {
        Self {
            origin: monotonic_nanos(),
        }
    }

    /// A system clock behind a shared handle.
    pub fn shared() -> SharedClock {
        Arc::new(Self::new())
    }
}

impl Default for SystemClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for SystemClock {
    fn now(&self) -> Duration {
        Duration::from_nanos(monotonic_nanos().saturating_sub(self.origin))
    }

    fn wall(&self) -> DateTime<Utc> {
        Utc::now()
    }

    fn sleep_until(&self, deadline: Duration) {
        let now = self.now();
        if deadline > now {
            std::thread::sleep(deadline - now);
        }
    }

    fn sleep_until_rung(&self, deadline: Duration, bell: &Doorbell) {
        let now = self.now();
        if deadline > now {
            bell.wait(deadline - now);
        }
    }
}

/// The time slice the scan loop's thread asks the scheduler for (`sched_setattr`'s
/// `sched_runtime`, honoured for normal tasks since Linux 6.12): a task asking for a short
/// slice gets an earlier virtual deadline under EEVDF, so when its timer fires it preempts a
/// CPU-bound task at once instead of waiting out that task's slice (about 1.4 ms on two CPUs,
/// several milliseconds under load). 100 µs is the shortest the kernel accepts; a tick's work
/// is a few tens of µs.
pub const PROMPT_SLICE: Duration = Duration::from_micros(100);

/// Asks the OS to wake the calling thread as close to its deadlines as it can: timer slack
/// of 1 ns instead of the default 50 µs (`PR_SET_TIMERSLACK`), and a short scheduler slice
/// (`PROMPT_SLICE`). Both are unprivileged, per-thread hints; a thread under a real-time or
/// batch policy is left as it is, and so is its nice value. Linux only (elsewhere a no-op).
pub fn prefer_prompt_wakeups() -> std::io::Result<()> {
    #[cfg(target_os = "linux")]
    {
        linux::prefer_prompt_wakeups()
    }
    #[cfg(not(target_os = "linux"))]
    {
        Ok(())
    }
}

#[cfg(target_os = "linux")]
mod linux {
    use std::io;

    /// `struct sched_attr` as of `SCHED_ATTR_SIZE_VER0` (the kernel accepts any known size).
    #[repr(C)]
    struct SchedAttr {
        size: u32,
        policy: u32,
        flags: u64,
        nice: i32,
        priority: u32,
        runtime: u64,
        deadline: u64,
        period: u64,
    }

    pub(super) fn prefer_prompt_wakeups() -> io::Result<()> {
        rustix::thread::set_current_timer_slack(std::num::NonZeroU64::new(1))?;
        // rustix has no sched_getscheduler.
        // SAFETY: a query of the calling thread's own scheduling, no pointers.
        let policy = unsafe { libc::sched_getscheduler(0) };
        if policy != libc::SCHED_OTHER {
            return Ok(());
        }
        // `None` (0) is the calling thread: on Linux the nice value is a thread's own.
        let nice = rustix::process::getpriority_process(None)?;
        let attr = SchedAttr {
            size: std::mem::size_of::<SchedAttr>() as u32,
            policy: libc::SCHED_OTHER as u32,
            flags: 0,
            nice,
            priority: 0,
            runtime: super::PROMPT_SLICE.as_nanos() as u64,
            deadline: 0,
            period: 0,
        };
        // SAFETY: `attr` is a valid, initialised sched_attr for the calling thread (pid 0); rustix
        // has no sched_setattr.
        let r = unsafe { libc::syscall(libc::SYS_sched_setattr, 0, &attr as *const SchedAttr, 0) };
        if r != 0 {
            return Err(io::Error::last_os_error());
        }
        Ok(())
    }
}

#[derive(Debug)]
struct VirtualState {
    now: Duration,
    wall_origin: DateTime<Utc>,
    /// Flags to set once time reaches a moment (`set_at`), soonest last.
    alarms: Vec<(Duration, Arc<AtomicUsize>, usize)>,
}

impl VirtualState {
    fn move_to(&mut self, to: Duration) {
        self.now = to;
        while let Some((at, flag, value)) = self.alarms.pop() {
            if at > to {
                self.alarms.push((at, flag, value));
                break;
            }
            flag.store(value, Ordering::SeqCst);
        }
    }
}

/// Virtual time for tests: it only moves when told to, and sleeping jumps straight to the deadline.
#[derive(Debug, Clone)]
pub struct VirtualClock {
    shared: Arc<Shared>,
}

#[derive(Debug)]
struct Shared {
    state: Mutex<VirtualState>,
    /// `state.now` in nanoseconds, set after each move and read without the lock (a scan
    /// loop reads the time many times a tick); `u64::MAX` when it does not fit: read the lock.
    now_nanos: AtomicU64,
}

impl VirtualClock {
    /// A virtual clock at monotonic zero whose wall time starts at `wall_origin`.
    pub fn new(wall_origin: DateTime<Utc>) -> Self {
        Self {
            shared: Arc::new(Shared {
                state: Mutex::new(VirtualState {
                    now: Duration::ZERO,
                    wall_origin,
                    alarms: Vec::new(),
                }),
                now_nanos: AtomicU64::new(0),
            }),
        }
    }

    /// A virtual clock starting at the Unix epoch.
    pub fn at_epoch() -> Self {
        Self::new(DateTime::<Utc>::UNIX_EPOCH)
    }

    /// Moves time forward by `by`.
    pub fn advance(&self, by: Duration) {
        let mut s = self.lock();
        let to = s.now.saturating_add(by);
        s.move_to(to);
        self.publish(to);
    }

    /// Moves time forward to `to` (never backwards).
    pub fn advance_to(&self, to: Duration) {
        let mut s = self.lock();
        if to > s.now {
            s.move_to(to);
            self.publish(to);
        }
    }

    /// Stores `value` in `flag` once time reaches `at`, whoever moves it there: a signal that
    /// arrives in the middle of a wait (a sleep that jumps past `at` sets it on the way, as a
    /// real wait would see it only when it ends).
    pub fn set_at(&self, at: Duration, flag: Arc<AtomicUsize>, value: usize) {
        let mut s = self.lock();
        if at <= s.now {
            flag.store(value, Ordering::SeqCst);
            return;
        }
        s.alarms.push((at, flag, value));
        s.alarms.sort_by_key(|a| std::cmp::Reverse(a.0));
    }

    /// Steps the wall clock by `by` (forward or back) while monotonic time stays: an NTP step,
    /// a manual clock change. Cron timers see it; `every` and `after` do not.
    pub fn step_wall(&self, by: chrono::TimeDelta) {
        let mut s = self.lock();
        s.wall_origin =
            s.wall_origin
                .checked_add_signed(by)
                .unwrap_or(if by < chrono::TimeDelta::zero() {
                    DateTime::<Utc>::MIN_UTC
                } else {
                    DateTime::<Utc>::MAX_UTC
                });
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, VirtualState> {
        // A poisoned lock only means another test thread panicked; the time value is still valid.
        crate::sync::lock(&self.shared.state)
    }

    /// Makes `now` (just moved to, under the lock) what `now()` reads. After the move's alarms:
    /// who sees the new time sees their flags too.
    fn publish(&self, now: Duration) {
        let nanos = u64::try_from(now.as_nanos()).unwrap_or(u64::MAX);
        self.shared.now_nanos.store(nanos, Ordering::Release);
    }
}

impl Clock for VirtualClock {
    fn is_virtual(&self) -> bool {
        true
    }

    fn now(&self) -> Duration {
        match self.shared.now_nanos.load(Ordering::Acquire) {
            u64::MAX => self.lock().now,
            nanos => Duration::from_nanos(nanos),
        }
    }

    fn wall(&self) -> DateTime<Utc> {
        let s = self.lock();
        let offset = chrono::Duration::from_std(s.now).unwrap_or(chrono::Duration::MAX);
        s.wall_origin
            .checked_add_signed(offset)
            .unwrap_or(DateTime::<Utc>::MAX_UTC)
    }

    fn sleep_until(&self, deadline: Duration) {
        self.advance_to(deadline);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn virtual_clock_moves_only_when_told_and_sleep_jumps() {
        let c = VirtualClock::at_epoch();
        assert_eq!(c.now(), Duration::ZERO);
        c.advance(Duration::from_millis(250));
        assert_eq!(c.now(), Duration::from_millis(250));
        c.sleep_until(Duration::from_secs(2));
        assert_eq!(c.now(), Duration::from_secs(2));
        c.advance_to(Duration::from_secs(1));
        assert_eq!(c.now(), Duration::from_secs(2), "never goes backwards");
        assert_eq!(c.wall().timestamp(), 2);
        c.step_wall(chrono::TimeDelta::hours(-1));
        assert_eq!(c.wall().timestamp(), 2 - 3600, "the wall clock steps back");
        assert_eq!(c.now(), Duration::from_secs(2), "monotonic time does not");
    }

    #[test]
    fn a_flag_set_at_a_moment_is_set_by_whatever_moves_time_past_it() {
        let c = VirtualClock::at_epoch();
        let flag = Arc::new(AtomicUsize::new(0));
        c.set_at(Duration::from_millis(300), Arc::clone(&flag), 15);
        c.set_at(Duration::from_millis(100), Arc::clone(&flag), 2);
        c.advance(Duration::from_millis(99));
        assert_eq!(flag.load(Ordering::SeqCst), 0, "not yet");
        c.sleep_until(Duration::from_millis(250));
        assert_eq!(
            flag.load(Ordering::SeqCst),
            2,
            "a sleep past the moment sets it"
        );
        c.advance_to(Duration::from_millis(300));
        assert_eq!(flag.load(Ordering::SeqCst), 15, "at the moment itself");
        c.set_at(Duration::ZERO, Arc::clone(&flag), 7);
        assert_eq!(
            flag.load(Ordering::SeqCst),
            7,
            "a moment passed already: at once"
        );
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn prompt_wakeups_set_the_timer_slack_and_keep_the_nice_value() {
        // In a thread of its own: the hints are per thread.
        std::thread::spawn(|| {
            use rustix::process::{getpriority_process, setpriority_process};
            setpriority_process(None, 5).unwrap();
            prefer_prompt_wakeups().unwrap();
            assert_eq!(rustix::thread::current_timer_slack().unwrap(), 1);
            assert_eq!(getpriority_process(None).unwrap(), 5);
            // SAFETY: a query of the calling thread's own scheduling.
            assert_eq!(unsafe { libc::sched_getscheduler(0) }, libc::SCHED_OTHER);
        })
        .join()
        .unwrap();
    }

    #[test]
    fn system_clock_is_monotonic() {
        let c = SystemClock::new();
        let a = c.now();
        c.sleep_until(a + Duration::from_millis(2));
        assert!(c.now() >= a + Duration::from_millis(2));
    }
}
