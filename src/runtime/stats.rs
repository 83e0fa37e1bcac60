//! Scan-loop statistics for `--stats`: ticks, period jitter (how late each tick started),
//! work per tick, overruns and device transactions per tick, in constant memory.

use std::fmt;
use std::time::Duration;

const SUB_BUCKETS: usize = 16;
const BUCKETS: usize = 61 * SUB_BUCKETS;

/// A log-linear histogram of microsecond values: exact below 16 µs, then 16 steps per power of
/// two (within about 6%), so a day of ticks costs a few kilobytes.
#[derive(Clone)]
pub struct Histogram {
    counts: Box<[u64; BUCKETS]>,
    total: u64,
    max: u64,
    sum: u128,
}

impl Default for Histogram {
    fn default() -> Self {
        Self {
            counts: Box::new([0; BUCKETS]),
            total: 0,
            max: 0,
            sum: 0,
        }
    }
}

impl fmt::Debug for Histogram {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Histogram")
            .field("total", &self.total)
            .field("max", &self.max)
            .finish_non_exhaustive()
    }
}

fn bucket_of(v: u64) -> usize {
    if v < SUB_BUCKETS as u64 {
        return v as usize;
    }
    let e = 63 - v.leading_zeros() as usize; // >= 4
    let m = (v >> (e - 4)) as usize; // 16..=31
    ((e - 4) * SUB_BUCKETS + m).min(BUCKETS - 1)
}

/// The highest value that falls in bucket `i`.
fn bucket_top(i: usize) -> u64 {
    if i < SUB_BUCKETS {
        return i as u64;
    }
    let k = i / SUB_BUCKETS;
    let m = (i % SUB_BUCKETS + SUB_BUCKETS) as u128;
    let top = ((m + 1) << (k - 1)).saturating_sub(1);
    u64::try_from(top).unwrap_or(u64::MAX)
}

impl Histogram {
    /// Counts one value.
    pub fn add(&mut self, value: Duration) {
        let us = u64::try_from(value.as_micros()).unwrap_or(u64::MAX);
        if let Some(c) = self.counts.get_mut(bucket_of(us)) {
            *c = c.saturating_add(1);
        }
        self.total = self.total.saturating_add(1);
        self.max = self.max.max(us);
        self.sum = self.sum.saturating_add(u128::from(us));
    }

    /// How many values were counted.
    pub fn count(&self) -> u64 {
        self.total
    }

    /// The value at quantile `q` (0-1), rounded up to its bucket's top; zero when empty.
    pub fn quantile(&self, q: f64) -> Duration {
        if self.total == 0 {
            return Duration::ZERO;
        }
        let rank = ((q.clamp(0.0, 1.0) * self.total as f64).ceil() as u64).max(1);
        let mut seen = 0u64;
        for (i, c) in self.counts.iter().enumerate() {
            seen = seen.saturating_add(*c);
            if seen >= rank {
                return Duration::from_micros(bucket_top(i).min(self.max));
            }
        }
        Duration::from_micros(self.max)
    }

    /// The values at or below each of `bounds_us` (microseconds, rising), as a Prometheus
    /// histogram's cumulative buckets: a value counts below a bound when its whole bucket
    /// does (so within a bucket's width, about 6 %, low).
    pub fn cumulative(&self, bounds_us: &[u64]) -> Vec<u64> {
        bounds_us
            .iter()
            .map(|&bound| {
                self.counts
                    .iter()
                    .enumerate()
                    .take_while(|(i, _)| bucket_top(*i) <= bound)
                    .map(|(_, c)| *c)
                    .fold(0u64, u64::saturating_add)
            })
            .collect()
    }

    /// The sum of the values counted, in microseconds.
    pub fn sum_us(&self) -> u64 {
        u64::try_from(self.sum).unwrap_or(u64::MAX)
    }

    /// The largest value counted.
    pub fn max(&self) -> Duration {
        Duration::from_micros(self.max)
    }

    /// The mean of the values counted.
    pub fn mean(&self) -> Duration {
        if self.total == 0 {
            return Duration::ZERO;
        }
        let us = self.sum / u128::from(self.total);
        Duration::from_micros(u64::try_from(us).unwrap_or(u64::MAX))
    }
}

/// What the scan loop measured.
#[derive(Debug, Clone, Default)]
pub struct Stats {
    /// Ticks run.
    pub ticks: u64,
    /// Ticks that ended after the next tick's deadline.
    pub overruns: u64,
    /// How late each tick started after its deadline.
    pub jitter: Histogram,
    /// How long each tick's work took (reads, handlers, writes, feeding).
    pub work: Histogram,
    /// Requests sent to devices, in all.
    pub transactions: u64,
    /// The most requests in one tick.
    pub max_transactions: u64,
    /// How the run's CPU wake-up latency request went (real-time runs only).
    pub wake_latency: Option<String>,
    /// How the request for prompt wake-ups (timer slack, scheduler slice) went.
    pub prompt_wakeups: Option<String>,
    /// Log lines dropped because stderr was not being read.
    pub log_dropped: u64,
    /// Records the records file did not take (the log says why).
    pub records_lost: u64,
}

impl Stats {
    /// Requests per tick on average.
    pub fn transactions_per_tick(&self) -> f64 {
        if self.ticks == 0 {
            0.0
        } else {
            self.transactions as f64 / self.ticks as f64
        }
    }
}

fn ms(d: Duration) -> String {
    format!("{:.3}ms", d.as_secs_f64() * 1000.0)
}

impl fmt::Display for Stats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "ticks: {}", self.ticks)?;
        if let Some(w) = &self.wake_latency {
            writeln!(f, "wake latency: {w}")?;
        }
        writeln!(
            f,
            "jitter: p50 {} p99 {} max {}",
            ms(self.jitter.quantile(0.5)),
            ms(self.jitter.quantile(0.99)),
            ms(self.jitter.max())
        )?;
        writeln!(
            f,
            "tick work: mean {} p99 {} max {}",
            ms(self.work.mean()),
            ms(self.work.quantile(0.99)),
            ms(self.work.max())
        )?;
        writeln!(f, "overruns: {}", self.overruns)?;
        if let Some(p) = &self.prompt_wakeups {
            writeln!(f, "prompt wake-ups: {p}")?;
        }
        if self.log_dropped > 0 {
            writeln!(
                f,
                "log lines dropped: {} (stderr not being read)",
                self.log_dropped
            )?;
        }
        if self.records_lost > 0 {
            writeln!(
                f,
                "records not written: {} (the log says why)",
                self.records_lost
            )?;
        }
        write!(
            f,
            "transactions per tick: {:.2} (max {})",
            self.transactions_per_tick(),
            self.max_transactions
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn cumulative_buckets_count_what_is_at_or_below_each_bound() {
        let mut h = Histogram::default();
        for us in [10, 40, 90, 900, 3_000_000] {
            h.add(Duration::from_micros(us));
        }
        assert_eq!(
            h.cumulative(&[5, 50, 100, 1_000, 1_000_000]),
            [0, 2, 3, 4, 4]
        );
        assert_eq!(h.sum_us(), 3_001_040);
    }

    #[test]
    fn quantiles_of_a_known_spread() {
        let mut h = Histogram::default();
        for us in 1..=100u64 {
            h.add(Duration::from_micros(us));
        }
        assert_eq!(
            h.quantile(0.5),
            Duration::from_micros(51),
            "50 lies in 48..=51"
        );
        assert!(h.quantile(0.99) >= Duration::from_micros(99));
        assert_eq!(h.max(), Duration::from_micros(100));
        assert_eq!(h.count(), 100);
        assert_eq!(Histogram::default().quantile(0.99), Duration::ZERO);
    }

    proptest! {
        #[test]
        fn a_value_lands_in_a_bucket_whose_top_is_within_seven_percent(v in any::<u64>()) {
            let i = bucket_of(v);
            let top = bucket_top(i);
            prop_assert!(top >= v || i == BUCKETS - 1);
            prop_assert!(v < 16 || top.saturating_sub(v) as f64 <= v as f64 * 0.07);
        }
    }
}
