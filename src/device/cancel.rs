//! A request to stop waiting that a driver's waits can see: a flag someone else sets (a run's
//! stop flag, set by its signal handler), looked at before each request and between slices of
//! every long wait, so a silent device holds a stopping caller for one slice at most.
//!
//! Looking costs one atomic load and no system call: a wait that ends sooner than a slice (an
//! answer that comes) is made exactly as without a token.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// How long a wait goes at most before it looks at its `Cancel` again.
pub const CANCEL_SLICE: Duration = Duration::from_millis(100);

/// A cancellation token, cheap to clone; the default one never cancels.
#[derive(Debug, Clone, Default)]
pub struct Cancel {
    flag: Option<Arc<AtomicUsize>>,
}

impl Cancel {
    /// A token that never cancels: waits run their full length, in one piece.
    pub fn never() -> Self {
        Self::default()
    }

    /// A token that cancels once `flag` holds anything but 0.
    pub fn when_set(flag: Arc<AtomicUsize>) -> Self {
        Self { flag: Some(flag) }
    }

    /// Whether the wait should give up now.
    pub fn is_cancelled(&self) -> bool {
        self.flag
            .as_ref()
            .is_some_and(|f| f.load(Ordering::Relaxed) != 0)
    }

    /// How much of `wait` to wait before looking again: all of it when nothing can cancel,
    /// else at most `CANCEL_SLICE`.
    pub fn slice(&self, wait: Duration) -> Duration {
        match self.flag {
            Some(_) => wait.min(CANCEL_SLICE),
            None => wait,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_token_on_a_flag_cancels_once_it_is_set_and_cuts_waits_into_slices() {
        let flag = Arc::new(AtomicUsize::new(0));
        let cancel = Cancel::when_set(Arc::clone(&flag));
        assert!(!cancel.is_cancelled());
        assert_eq!(cancel.slice(Duration::from_secs(1)), CANCEL_SLICE);
        assert_eq!(
            cancel.slice(Duration::from_millis(3)),
            Duration::from_millis(3),
            "a short wait stays whole"
        );
        flag.store(15, Ordering::SeqCst);
        assert!(cancel.is_cancelled());
        assert!(cancel.clone().is_cancelled(), "clones share the flag");
    }

    #[test]
    fn the_never_token_neither_cancels_nor_slices() {
        let never = Cancel::never();
        assert!(!never.is_cancelled());
        assert_eq!(never.slice(Duration::from_secs(5)), Duration::from_secs(5));
    }
}
