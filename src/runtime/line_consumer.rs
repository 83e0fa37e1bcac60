//! Lines written off the scan loop by consumers of the run's event stream: a thread follows
//! a subscription, makes lines of the events it takes and writes them in batches, so an
//! output that blocks (stderr nobody reads, a pipe nobody reads, a hung network mount) costs
//! events, lost from the subscription's bounded queue and counted there, and never a tick.
//! The log and the records file are two such consumers.

use super::observe::{Detacher, Losses, Next, RunEvent, Subscription};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

/// The most lines written in one batch (a queue that filled while the output was stuck goes
/// out in a few writes, not one of megabytes).
const MAX_BATCH: usize = 1024;

/// Where a consumer's lines go.
pub trait LineSink {
    /// Writes `batch`: `count` whole lines, each ending in a newline. What it cannot write it
    /// accounts for itself (the consumer only ever gives each line once).
    fn write_batch(&mut self, batch: &str, count: usize);
}

/// What a consumer makes of the events it is handed.
pub trait Lines: Send + 'static {
    /// The line `event` is written as (`None`: it is not written).
    fn line(&mut self, event: &RunEvent) -> Option<String>;
    /// The line that tells of `lost` events lost just before `next` (`None`: not told).
    fn lost(&mut self, lost: u64, next: &RunEvent) -> Option<String>;
}

/// A thread writing one subscription's events out as lines.
pub struct LineConsumer {
    detacher: Detacher,
    losses: Losses,
    /// Events taken off the queue whose lines the sink has had.
    handled: Arc<AtomicU64>,
    done: Arc<(Mutex<bool>, Condvar)>,
}

impl LineConsumer {
    /// Starts the thread `name` following `subscription`; `open` makes its sink on that
    /// thread (`None`: no sink, the consumer lets go of the stream at once).
    pub fn spawn<S: LineSink, L: Lines>(
        name: &str,
        subscription: Subscription,
        lines: L,
        open: impl FnOnce() -> Option<S> + Send + 'static,
    ) -> Self {
        let detacher = subscription.detacher();
        let losses = subscription.losses();
        let handled = Arc::new(AtomicU64::new(0));
        let done = Arc::new((Mutex::new(false), Condvar::new()));
        let (theirs, finished) = (Arc::clone(&handled), Arc::clone(&done));
        let spawned = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || {
                if let Some(sink) = open() {
                    write_out(subscription, lines, sink, &theirs);
                }
                mark_done(&finished);
            });
        if spawned.is_err() {
            // No thread, no output: events are lost (counted) rather than block the loop.
            detacher.detach();
            mark_done(&done);
        }
        Self {
            detacher,
            losses,
            handled,
            done,
        }
    }

    /// Events the queue could not take, so far.
    pub fn losses(&self) -> &Losses {
        &self.losses
    }

    /// Events whose lines the sink has had.
    pub fn handled(&self) -> u64 {
        self.handled.load(Ordering::Relaxed)
    }

    /// Takes the consumer off the stream (no later event reaches it) and waits up to `wait`
    /// for it to write what is queued; whether it did.
    pub fn close(&self, wait: Duration) -> bool {
        self.detacher.detach();
        let (lock, changed) = &*self.done;
        let deadline = Instant::now() + wait;
        let mut done = crate::sync::lock(lock);
        while !*done {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return false;
            }
            done = match changed.wait_timeout(done, left) {
                Ok((g, _)) => g,
                Err(e) => e.into_inner().0,
            };
        }
        true
    }
}

fn mark_done(done: &(Mutex<bool>, Condvar)) {
    *crate::sync::lock(&done.0) = true;
    done.1.notify_all();
}

/// The thread: waits for events, writes each batch that came meanwhile, until the stream ends
/// (the consumer was let go, or the run is gone) and what was queued is written.
fn write_out(
    mut subscription: Subscription,
    mut lines: impl Lines,
    mut sink: impl LineSink,
    handled: &AtomicU64,
) {
    let mut batch = String::new();
    let mut lost = 0u64;
    loop {
        let first = match subscription.handover(Duration::from_secs(3600)) {
            Ok(next) => next,
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => continue,
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => return,
        };
        batch.clear();
        let (mut count, mut events) = (0, 0u64);
        let mut next = Some(first);
        while let Some(n) = next.take() {
            match n {
                Next::Dropped(n) => lost = lost.saturating_add(n),
                Next::Quiet => {}
                Next::Event(event) => {
                    events += 1;
                    let told = std::mem::take(&mut lost);
                    if told > 0 {
                        if let Some(line) = lines.lost(told, &event) {
                            push(&mut batch, &line, &mut count);
                        }
                    }
                    if let Some(line) = lines.line(&event) {
                        push(&mut batch, &line, &mut count);
                    }
                }
            }
            if count < MAX_BATCH {
                next = subscription.handover(Duration::ZERO).ok();
            }
        }
        if count > 0 {
            sink.write_batch(&batch, count);
        }
        handled.fetch_add(events, Ordering::Relaxed);
    }
}

fn push(batch: &mut String, line: &str, count: &mut usize) {
    batch.push_str(line);
    batch.push('\n');
    *count += 1;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::observe::{Bound, EventKind, Events, Kinds};
    use std::sync::mpsc;

    /// A sink that says when it has a batch, waits for a go, and hands the batch over.
    struct Gated {
        started: mpsc::Sender<()>,
        go: mpsc::Receiver<()>,
        out: mpsc::Sender<String>,
    }

    impl LineSink for Gated {
        fn write_batch(&mut self, batch: &str, _count: usize) {
            let _ = self.started.send(());
            let _ = self.go.recv();
            let _ = self.out.send(batch.to_string());
        }
    }

    struct Test {
        started: mpsc::Receiver<()>,
        go: mpsc::Sender<()>,
        batches: mpsc::Receiver<String>,
    }

    fn gated() -> (Test, impl FnOnce() -> Option<Gated> + Send + 'static) {
        let (started, has) = mpsc::channel();
        let (go, gate) = mpsc::channel();
        let (sent, batches) = mpsc::channel();
        let test = Test {
            started: has,
            go,
            batches,
        };
        (test, move || {
            Some(Gated {
                started,
                go: gate,
                out: sent,
            })
        })
    }

    impl Test {
        /// Waits for the sink to have a batch, lets it write, and returns the batch.
        fn batch(&self) -> String {
            self.started.recv_timeout(Duration::from_secs(10)).unwrap();
            self.go.send(()).unwrap();
            self.batches.recv_timeout(Duration::from_secs(10)).unwrap()
        }
    }

    /// Records' lines as they are, losses as `lost N`.
    struct Plain;

    impl Lines for Plain {
        fn line(&mut self, event: &RunEvent) -> Option<String> {
            match event {
                RunEvent::Record { line } => Some(line.clone()),
                _ => None,
            }
        }
        fn lost(&mut self, lost: u64, _next: &RunEvent) -> Option<String> {
            Some(format!("lost {lost}"))
        }
    }

    fn record(events: &Events, line: &str) {
        events.publish(|| RunEvent::Record { line: line.into() });
    }

    #[test]
    fn a_full_queue_loses_events_counted_and_the_loss_is_told_where_it_happened() {
        let events = Events::default();
        let (t, open) = gated();
        let sub = events
            .subscribe_to("test", Bound::events(2), Kinds::of(&[EventKind::Record]))
            .unwrap();
        let c = LineConsumer::spawn("test-consumer", sub, Plain, open);
        record(&events, "a");
        // The sink holds "a": the queue takes two more, the next two are lost.
        t.started.recv_timeout(Duration::from_secs(10)).unwrap();
        for line in ["b", "c", "d", "e"] {
            record(&events, line);
        }
        // Ticks are not this consumer's: neither queued nor lost.
        events.publish(|| RunEvent::Tick {
            tick: 1,
            late_us: 0,
            work_us: 0,
            overrun: false,
        });
        assert_eq!(c.losses().count(), 2);
        t.go.send(()).unwrap();
        let mut all = t.batches.recv_timeout(Duration::from_secs(10)).unwrap();
        all += &t.batch();
        record(&events, "f");
        all += &t.batch();
        assert_eq!(all, "a\nb\nc\nlost 2\nf\n");
        assert!(c.close(Duration::from_secs(10)));
        assert_eq!(c.handled(), 4);
        record(&events, "after close");
        assert_eq!(c.losses().count(), 2, "let go: nothing reaches it");
        assert!(!events.watched());
    }

    #[test]
    fn closing_says_whether_a_stuck_sink_wrote_what_was_queued() {
        let events = Events::default();
        let (t, open) = gated();
        let sub = events
            .subscribe_to("test", Bound::events(100), Kinds::ALL)
            .unwrap();
        let c = LineConsumer::spawn("test-consumer", sub, Plain, open);
        record(&events, "one");
        record(&events, "two");
        assert!(!c.close(Duration::from_millis(50)));
        drop(t);
        assert!(c.close(Duration::from_secs(10)), "the sink let go");
        assert_eq!(c.handled(), 2);
    }
}
