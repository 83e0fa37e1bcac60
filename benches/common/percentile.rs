//! The p-th percentile of sorted durations (nearest rank), for the benchmarks' tables.

use std::time::Duration;

/// The value at the `p`-th percentile of `sorted` (ascending); `None` when it is empty.
pub fn percentile(sorted: &[Duration], p: f64) -> Option<Duration> {
    if sorted.is_empty() {
        return None;
    }
    let rank = ((sorted.len() - 1) as f64 * p / 100.0).round() as usize;
    sorted.get(rank).copied()
}
