//! Lines written off the scan loop: a bounded queue in front of a writer thread, so an output
//! that blocks (stderr nobody reads, a pipe nobody reads, a hung network mount) costs lines,
//! counted, and never a tick. The log and the records file both go through here.

use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// Where a writer thread's lines go.
pub trait LineSink {
    /// Writes `batch`: `count` whole lines, each ending in a newline. What it cannot write it
    /// accounts for itself (the writer thread only ever gives each line once).
    fn write_batch(&mut self, batch: &str, count: usize);
}

/// What became of a line given to `LineWriter::push`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pushed {
    /// Queued; `dropped_before` lines were dropped since the last line that was queued (and
    /// not told of by a notice queued ahead of this line).
    Queued {
        /// Lines dropped just before, untold.
        dropped_before: u64,
    },
    /// Dropped (and counted): the queue was full, or the writer closed.
    Dropped,
}

/// The queue between the scan loop and a thread that writes its lines out.
pub struct LineWriter {
    shared: Arc<Shared>,
    capacity: usize,
}

struct Shared {
    queue: Mutex<Queue>,
    /// Signalled when lines are queued or the writer closes (to the thread), and when the
    /// thread has written everything after closing (to `close`).
    changed: Condvar,
}

#[derive(Default)]
struct Queue {
    lines: VecDeque<String>,
    /// Bytes queued or being written.
    bytes: usize,
    /// Lines taken by the thread and not yet written.
    in_flight: usize,
    /// Dropped since the last line queued.
    unreported: u64,
    /// Dropped in all.
    dropped: u64,
    closing: bool,
    done: bool,
}

impl LineWriter {
    /// Starts the writer thread `name`, with at most `capacity` bytes of lines queued; `open`
    /// makes its sink on that thread (`None`: no sink, every line is dropped and counted).
    pub fn spawn<S: LineSink>(
        name: &str,
        capacity: usize,
        open: impl FnOnce() -> Option<S> + Send + 'static,
    ) -> Self {
        let shared = Arc::new(Shared {
            queue: Mutex::new(Queue::default()),
            changed: Condvar::new(),
        });
        let theirs = Arc::clone(&shared);
        let spawned = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || match open() {
                Some(sink) => write_out(&theirs, sink),
                None => finish(&theirs),
            });
        if spawned.is_err() {
            // No thread, no output: lines are counted as dropped rather than block the loop.
            let mut q = lock(&shared);
            q.closing = true;
            q.done = true;
        }
        Self { shared, capacity }
    }

    /// Queues `line`, or drops and counts it when the queue is full. After drops, `notice`
    /// is given their count and may give a line to queue first, once there is room for both
    /// (then `Pushed::Queued` says 0 dropped); `None` leaves telling of them to the caller.
    pub fn push(&self, line: String, notice: impl FnOnce(u64) -> Option<String>) -> Pushed {
        let mut q = lock(&self.shared);
        if q.closing {
            q.dropped = q.dropped.saturating_add(1);
            return Pushed::Dropped;
        }
        let told = match q.unreported {
            0 => None,
            n => notice(n),
        };
        let extra = told.as_ref().map_or(0, |t| t.len() + 1);
        if q.bytes + extra + line.len() + 1 > self.capacity {
            q.unreported = q.unreported.saturating_add(1);
            q.dropped = q.dropped.saturating_add(1);
            return Pushed::Dropped;
        }
        // The thread waits only for an empty queue: lines behind others need no wake-up.
        let wake = q.lines.is_empty();
        let dropped_before = match told {
            Some(text) => {
                q.bytes += text.len() + 1;
                q.lines.push_back(text);
                0
            }
            None => q.unreported,
        };
        q.unreported = 0;
        q.bytes += line.len() + 1;
        q.lines.push_back(line);
        drop(q);
        if wake {
            self.shared.changed.notify_all();
        }
        Pushed::Queued { dropped_before }
    }

    /// Lines dropped so far.
    pub fn dropped(&self) -> u64 {
        lock(&self.shared).dropped
    }

    /// Asks the thread to finish and waits up to `wait` for it to write what is queued;
    /// returns the lines it did not get written in that time (queued or being written).
    pub fn close(&self, wait: Duration) -> u64 {
        let mut q = lock(&self.shared);
        q.closing = true;
        self.shared.changed.notify_all();
        let deadline = Instant::now() + wait;
        while !q.done {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            q = match self.shared.changed.wait_timeout(q, left) {
                Ok((g, _)) => g,
                Err(e) => e.into_inner().0,
            };
        }
        if q.done {
            0
        } else {
            (q.lines.len() + q.in_flight) as u64
        }
    }
}

/// The writer thread: writes batches of queued lines as they come, until closed and empty.
fn write_out(shared: &Shared, mut sink: impl LineSink) {
    let mut batch = String::new();
    loop {
        let mut q = lock(shared);
        while q.lines.is_empty() && !q.closing {
            q = match shared.changed.wait(q) {
                Ok(g) => g,
                Err(e) => e.into_inner(),
            };
        }
        if q.lines.is_empty() {
            drop(q);
            finish(shared);
            return;
        }
        batch.clear();
        let count = q.lines.len();
        for line in q.lines.drain(..) {
            batch.push_str(&line);
            batch.push('\n');
        }
        q.in_flight = count;
        drop(q);
        sink.write_batch(&batch, count);
        let mut q = lock(shared);
        q.in_flight = 0;
        q.bytes = q.bytes.saturating_sub(batch.len());
    }
}

/// Marks the thread done: what is still queued is dropped and counted.
fn finish(shared: &Shared) {
    let mut q = lock(shared);
    let left = q.lines.len() as u64;
    q.dropped = q.dropped.saturating_add(left);
    q.lines.clear();
    q.bytes = 0;
    q.closing = true;
    q.done = true;
    drop(q);
    shared.changed.notify_all();
}

fn lock(shared: &Shared) -> MutexGuard<'_, Queue> {
    // A panic on the other side leaves the queue usable: it only holds lines and counts.
    shared.queue.lock().unwrap_or_else(|e| e.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;

    /// A sink that waits for a go before each batch and hands the batches over.
    struct Gated {
        go: mpsc::Receiver<()>,
        out: mpsc::Sender<String>,
    }

    impl LineSink for Gated {
        fn write_batch(&mut self, batch: &str, _count: usize) {
            let _ = self.go.recv();
            let _ = self.out.send(batch.to_string());
        }
    }

    fn until(what: &str, cond: impl Fn() -> bool) {
        let deadline = Instant::now() + Duration::from_secs(10);
        while !cond() {
            assert!(Instant::now() < deadline, "not within 10 s: {what}");
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    #[test]
    fn a_full_queue_drops_and_counts_and_the_next_line_says_how_many_went() {
        let (go, gate) = mpsc::channel();
        let (sent, batches) = mpsc::channel();
        let w = LineWriter::spawn("test-writer", 9, move || {
            Some(Gated {
                go: gate,
                out: sent,
            })
        });
        // The first line goes to the (blocked) sink; the queue holds 9 bytes, the line being written included.
        assert_eq!(
            w.push("aaaa".into(), |_| None),
            Pushed::Queued { dropped_before: 0 }
        );
        until("the sink takes the first line", || {
            lock(&w.shared).in_flight > 0
        });
        assert_eq!(
            w.push("bbbb".into(), |_| None),
            Pushed::Dropped,
            "5 + 5 > 9"
        );
        assert_eq!(w.push("cccc".into(), |_| None), Pushed::Dropped);
        go.send(()).unwrap();
        let first = batches.recv_timeout(Duration::from_secs(10)).unwrap();
        assert_eq!(first, "aaaa\n");
        until("the first batch is written", || lock(&w.shared).bytes == 0);
        assert_eq!(
            w.push("dd".into(), |_| None),
            Pushed::Queued { dropped_before: 2 }
        );
        assert_eq!(w.dropped(), 2);
        go.send(()).unwrap();
        assert_eq!(w.close(Duration::from_secs(10)), 0);
        assert_eq!(batches.recv().unwrap(), "dd\n");
    }

    #[test]
    fn closing_says_what_a_stuck_sink_did_not_write() {
        let (go, gate) = mpsc::channel();
        let (sent, _batches) = mpsc::channel();
        let w = LineWriter::spawn("test-writer", 1000, move || {
            Some(Gated {
                go: gate,
                out: sent,
            })
        });
        w.push("one".into(), |_| None);
        until("the sink takes the first line", || {
            lock(&w.shared).in_flight > 0
        });
        w.push("two".into(), |_| None);
        w.push("three".into(), |_| None);
        assert_eq!(
            w.close(Duration::from_millis(50)),
            3,
            "one being written, two queued"
        );
        assert_eq!(w.push("four".into(), |_| None), Pushed::Dropped, "closed");
        drop(go);
    }

    #[test]
    fn no_sink_drops_every_line() {
        let w = LineWriter::spawn("test-writer", 1000, || None::<Gated>);
        let _ = w.close(Duration::from_secs(10));
        assert_eq!(w.push("x".into(), |_| None), Pushed::Dropped);
        assert_eq!(w.dropped(), 1);
    }
}
