//! A doorbell: wakes a thread's timed wait early when something comes for it (a request for a
//! sleeping scan loop). Rings are not counted: any number before a wait wake it once.

use crate::sync::lock;
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

/// Wakes a sleeping loop early: rung by an asker, waited on by the loop's sleep slices.
#[derive(Clone, Default)]
pub struct Doorbell {
    inner: Arc<(Mutex<bool>, Condvar)>,
}

impl Doorbell {
    /// Rings: the waiter, if any, wakes now; else its next wait returns at once.
    pub fn ring(&self) {
        let (rung, cv) = &*self.inner;
        *lock(rung) = true;
        cv.notify_all();
    }

    /// Waits up to `wait` or until rung; true if it was rung (the ring is used up).
    pub fn wait(&self, wait: Duration) -> bool {
        let (rung, cv) = &*self.inner;
        let until = Instant::now() + wait;
        let mut flag = lock(rung);
        loop {
            if *flag {
                *flag = false;
                return true;
            }
            let now = Instant::now();
            if now >= until {
                return false;
            }
            flag = cv
                .wait_timeout(flag, until - now)
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_doorbell_wakes_a_waiter_early_and_times_out_otherwise() {
        let bell = Doorbell::default();
        assert!(!bell.wait(Duration::from_millis(1)));
        let ringer = bell.clone();
        let t = std::thread::spawn(move || ringer.ring());
        assert!(bell.wait(Duration::from_secs(10)));
        t.join().unwrap();
    }
}
