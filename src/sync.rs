//! Locks for state shared with other threads: a thread that panicked while holding one leaves
//! state still worth using here (queues, lists of consumers and connections, a flag), so the
//! poison is looked past rather than spread.

use std::sync::{Mutex, MutexGuard, PoisonError};

/// Locks `m`, past a poisoning.
pub fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}
