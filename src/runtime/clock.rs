//! Clocks: the one source of time for devices models, drivers and the scan loop.
//!
//! Monotonic time is a `Duration` since the clock's origin, so virtual time is just a number
//! that tests move forward; wall time (for records and cron) comes from the same clock.

use chrono::{DateTime, Utc};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// A source of monotonic and wall time that can also wait.
pub trait Clock: Send + Sync {
    /// Monotonic time since this clock's origin.
    fn now(&self) -> Duration;
    /// Wall-clock time, for timestamps and calendars.
    fn wall(&self) -> DateTime<Utc>;
    /// Waits until monotonic time `deadline` (returns at once if it has passed).
    fn sleep_until(&self, deadline: Duration);
}

/// A shared handle to any clock.
pub type SharedClock = Arc<dyn Clock>;

/// Real time: `Instant` for monotonic time, the system clock for wall time.
#[derive(Debug, Clone)]
pub struct SystemClock {
    origin: Instant,
}

impl SystemClock {
    /// A system clock whose origin is now.
    pub fn new() -> Self {
        Self {
            origin: Instant::now(),
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
        self.origin.elapsed()
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
}

#[derive(Debug)]
struct VirtualState {
    now: Duration,
    wall_origin: DateTime<Utc>,
}

/// Virtual time for tests: it only moves when told to, and sleeping jumps straight to the deadline.
#[derive(Debug, Clone)]
pub struct VirtualClock {
    state: Arc<Mutex<VirtualState>>,
}

impl VirtualClock {
    /// A virtual clock at monotonic zero whose wall time starts at `wall_origin`.
    pub fn new(wall_origin: DateTime<Utc>) -> Self {
        Self {
            state: Arc::new(Mutex::new(VirtualState {
                now: Duration::ZERO,
                wall_origin,
            })),
        }
    }

    /// A virtual clock starting at the Unix epoch.
    pub fn at_epoch() -> Self {
        Self::new(DateTime::<Utc>::UNIX_EPOCH)
    }

    /// Moves time forward by `by`.
    pub fn advance(&self, by: Duration) {
        let mut s = self.lock();
        s.now = s.now.saturating_add(by);
    }

    /// Moves time forward to `to` (never backwards).
    pub fn advance_to(&self, to: Duration) {
        let mut s = self.lock();
        if to > s.now {
            s.now = to;
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, VirtualState> {
        // A poisoned lock only means another test thread panicked; the time value is still valid.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }
}

impl Clock for VirtualClock {
    fn now(&self) -> Duration {
        self.lock().now
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
    }

    #[test]
    fn system_clock_is_monotonic() {
        let c = SystemClock::new();
        let a = c.now();
        c.sleep_until(a + Duration::from_millis(2));
        assert!(c.now() >= a + Duration::from_millis(2));
    }
}
