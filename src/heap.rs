//! The heap in use, counted by a global allocator, so that each run can bound its memory
//! (`memory` under `[limits]`) and stop a script that grows it without end.
//!
//! `CountingAlloc` wraps the system allocator and keeps two counts of the bytes allocated and
//! not yet freed: the whole process's (a relaxed atomic) and each thread's (a const
//! thread-local integer: allocated minus freed by that thread). A thread running a run
//! (`RunHeap`) adds to the process's count only once its own has moved by `BATCH` bytes: an
//! atomic per allocation cost a scan loop about a sixth of its time, more with two runs on two
//! cores contending for it. A run reads the counts through `RunHeap`. Only a program that
//! installs the allocator (`#[global_allocator]`, as `rigscript` does) is counted; elsewhere
//! nothing is, and no memory limit applies.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::marker::PhantomData;
use std::sync::atomic::{AtomicUsize, Ordering};

static LIVE: AtomicUsize = AtomicUsize::new(0);

/// Runs (`RunHeap`s) alive in the process.
static RUNS: AtomicUsize = AtomicUsize::new(0);

/// How far a run's thread lets its count move before adding it to the process's: the
/// process's count lags by less than this for each run going (the least memory limit is
/// 256 times as much). Threads without a run add every allocation at once: one that ends
/// takes nothing uncounted with it.
const BATCH: usize = 64 << 10;

/// One thread's counts.
struct ThreadCount {
    /// Allocated minus freed by this thread.
    balance: Cell<isize>,
    /// Counted in `balance`, not yet in `LIVE` (only while a run is on this thread).
    pending: Cell<isize>,
    /// `RunHeap`s alive on this thread.
    runs: Cell<u32>,
}

thread_local! {
    // Const-initialised and without a destructor: reading it never allocates (it is read inside
    // the allocator) and it is there until the thread's last allocation.
    static THREAD: ThreadCount = const {
        ThreadCount {
            balance: Cell::new(0),
            pending: Cell::new(0),
            runs: Cell::new(0),
        }
    };
}

/// Adds `delta` to the process's count (two's complement: a negative delta's bit pattern
/// subtracts, with no branch).
fn add_live(delta: isize) {
    LIVE.fetch_add(delta as usize, Ordering::Relaxed);
}

/// Counts `delta` bytes more (fewer, when negative) in use, on the process and on this thread.
fn count(delta: isize) {
    // `try_with` and wrapping: the allocator must never panic.
    let batched = THREAD
        .try_with(|t| {
            t.balance.set(t.balance.get().wrapping_add(delta));
            if t.runs.get() == 0 {
                return false;
            }
            let pending = t.pending.get().wrapping_add(delta);
            if pending.unsigned_abs() < BATCH {
                t.pending.set(pending);
            } else {
                t.pending.set(0);
                add_live(pending);
            }
            true
        })
        .unwrap_or(false);
    if !batched {
        add_live(delta);
    }
}

/// What this thread has counted and not yet added to the process's count.
fn pending() -> isize {
    THREAD.try_with(|t| t.pending.get()).unwrap_or(0)
}

/// A `Layout`'s size, which always fits an isize.
fn signed(size: usize) -> isize {
    size as isize
}

/// The system allocator, counting the bytes in use (the process's and each thread's).
pub struct CountingAlloc;

// SAFETY: every call goes straight to `System` with the caller's own arguments; the counts are
// kept beside it and never touch the memory.
unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: as the caller promised for `layout`.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            count(signed(layout.size()));
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: as the caller promised for `layout`.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            count(signed(layout.size()));
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` was allocated by this allocator (that is, by `System`) with `layout`.
        unsafe { System.dealloc(ptr, layout) };
        count(-signed(layout.size()));
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: as the caller promised for `ptr`, `layout` and `new_size`.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            count(signed(new_size) - signed(layout.size()));
        }
        p
    }
}

/// Bytes of heap the process has allocated and not freed, if `CountingAlloc` is the global
/// allocator (`None` otherwise: nothing was ever counted, and a running program always holds
/// some heap); less than `BATCH` off for each run going.
pub fn in_use() -> Option<usize> {
    match LIVE.load(Ordering::Relaxed) {
        0 => None,
        n => Some(n),
    }
}

/// Bytes this thread has allocated minus the bytes it has freed, if `CountingAlloc` is the
/// global allocator (0 otherwise). Memory freed on another thread than the one that allocated
/// it moves the two threads' counts apart (see `RunHeap`): compare readings of one thread.
pub fn thread_balance() -> isize {
    THREAD.try_with(|t| t.balance.get()).unwrap_or(0)
}

/// The heap one run holds, for its memory limit: made on the run's thread as the run starts,
/// kept there (it is not `Send`) until the run ends.
///
/// While it is the process's only run (`rigscript run`, `verify --jobs 1`), the run holds the
/// whole process's heap, counted exactly. While other runs share the process (`verify --jobs
/// N`, tests on parallel threads), it holds what its thread has allocated and not freed since
/// the run started, so that one run's growth never counts against its neighbours. That count
/// drifts when memory crosses threads: a log line or a record made here is freed by its writer
/// thread, a buffer a device thread filled is freed here. It is a fair measure of a run still:
/// the script's values (Rhai's, `Rc`-based, neither `Send` nor `Sync`) are made and dropped on
/// the run's thread and cannot cross to another, so what a growing script keeps is counted
/// here; what crosses is the runtime's own bounded traffic, and a run is short while others
/// share its process. Drift alone stops nothing: a run is over only when the whole process is
/// over too. A run's count alone would not do for `rigscript run`, whose log lines, made on
/// the run's thread and freed on the writer's, would add up over days to a false breach.
pub struct RunHeap {
    baseline: isize,
    // The baseline is this thread's count: the run must stay on its thread.
    _on_this_thread: PhantomData<*const ()>,
}

impl RunHeap {
    /// A run starts on this thread.
    pub fn start() -> Self {
        RUNS.fetch_add(1, Ordering::Relaxed);
        let _ = THREAD.try_with(|t| t.runs.set(t.runs.get().saturating_add(1)));
        Self {
            baseline: thread_balance(),
            _on_this_thread: PhantomData,
        }
    }

    /// The bytes the run holds when they are more than `limit` (`None` when they are not, or
    /// when the heap is not counted). Cheap while the process is under `limit`: one atomic
    /// load (and this thread's own count not yet added to it).
    pub fn over(&self, limit: u64) -> Option<u64> {
        let process = (in_use()? as u64).saturating_add_signed(pending() as i64);
        if process <= limit {
            return None;
        }
        if RUNS.load(Ordering::Relaxed) <= 1 {
            return Some(process);
        }
        let grown = thread_balance().wrapping_sub(self.baseline);
        u64::try_from(grown).ok().filter(|&g| g > limit)
    }
}

impl Drop for RunHeap {
    fn drop(&mut self) {
        // What the run counted goes to the process now: the thread may end without a run.
        let _ = THREAD.try_with(|t| {
            t.runs.set(t.runs.get().saturating_sub(1));
            add_live(t.pending.replace(0));
        });
        RUNS.fetch_sub(1, Ordering::Relaxed);
    }
}

/// A byte count for people: `256 MiB`, `1.5 GiB`, `512 KiB`, `100 bytes`.
pub fn format_bytes(n: u64) -> String {
    const UNITS: [(u64, &str); 3] = [(1 << 30, "GiB"), (1 << 20, "MiB"), (1 << 10, "KiB")];
    for (size, unit) in UNITS {
        if n >= size {
            let whole = n / size;
            let tenths = (n % size) * 10 / size;
            return if tenths == 0 {
                format!("{whole} {unit}")
            } else {
                format!("{whole}.{tenths} {unit}")
            };
        }
    }
    format!("{n} bytes")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_count_follows_allocations_through_the_allocator() {
        // Called directly (it is not this test binary's global allocator), so only these
        // calls move the count.
        let a = CountingAlloc;
        let layout = Layout::from_size_align(4096, 8).unwrap();
        let before = LIVE.load(Ordering::Relaxed);
        // SAFETY: a valid non-zero layout; each pointer is freed once with its layout.
        unsafe {
            let p = a.alloc(layout);
            assert!(!p.is_null());
            assert_eq!(LIVE.load(Ordering::Relaxed), before + 4096);
            let p = a.realloc(p, layout, 10_000);
            assert_eq!(LIVE.load(Ordering::Relaxed), before + 10_000);
            let grown = Layout::from_size_align(10_000, 8).unwrap();
            let p = a.realloc(p, grown, 100);
            assert_eq!(LIVE.load(Ordering::Relaxed), before + 100);
            a.dealloc(p, Layout::from_size_align(100, 8).unwrap());
            let z = a.alloc_zeroed(layout);
            assert_eq!(*z, 0);
            assert_eq!(LIVE.load(Ordering::Relaxed), before + 4096);
            a.dealloc(z, layout);
        }
        assert_eq!(LIVE.load(Ordering::Relaxed), before);
    }

    #[test]
    fn each_thread_counts_what_it_allocated_and_freed() {
        let a = CountingAlloc;
        let layout = Layout::from_size_align(1 << 16, 8).unwrap();
        let here = thread_balance();
        // SAFETY: a valid non-zero layout; freed once with its layout (on another thread).
        let p = unsafe { a.alloc(layout) } as usize;
        assert_eq!(thread_balance(), here + (1 << 16));
        let there = std::thread::spawn(move || {
            let before = thread_balance();
            // SAFETY: `p` came from `a.alloc(layout)` and is freed only here.
            unsafe { a.dealloc(p as *mut u8, layout) };
            thread_balance() - before
        })
        .join()
        .unwrap();
        // The free is the freeing thread's: the allocating thread's count stays up (drift).
        assert_eq!(there, -(1 << 16));
        assert_eq!(thread_balance(), here + (1 << 16));
    }

    #[test]
    fn a_run_adds_to_the_process_count_in_batches_and_all_of_it_by_its_end() {
        let a = CountingAlloc;
        let small = Layout::from_size_align(4096, 8).unwrap();
        let big = Layout::from_size_align(BATCH, 8).unwrap();
        // On a thread of its own: this thread's counts are the test's alone.
        std::thread::spawn(move || {
            let run = RunHeap::start();
            let here = thread_balance();
            // SAFETY: valid non-zero layouts; each pointer is freed once with its layout.
            unsafe {
                let p = a.alloc(small);
                assert_eq!(thread_balance(), here + 4096);
                assert_eq!(pending(), 4096, "a small allocation waits");
                let q = a.alloc(big);
                assert_eq!(pending(), 0, "a batch's worth goes to the process");
                a.dealloc(q, big);
                assert_eq!(pending(), 0);
                let r = a.alloc(small);
                assert_eq!(pending(), 4096);
                drop(run);
                assert_eq!(pending(), 0, "the run's end adds what waited");
                a.dealloc(r, small);
                a.dealloc(p, small);
                assert_eq!(pending(), 0, "without a run, nothing waits");
                assert_eq!(thread_balance(), here);
            }
        })
        .join()
        .unwrap();
    }

    #[test]
    fn a_run_holds_what_its_own_thread_grew_while_another_shares_the_process() {
        // Direct calls (this test binary's allocator is not counting), so only they move the
        // counts: the process holds 1 MiB, all of it grown by the first run's thread.
        let a = CountingAlloc;
        let layout = Layout::from_size_align(1 << 20, 8).unwrap();
        let (grown, ready) = std::sync::mpsc::channel();
        let (done, finish) = std::sync::mpsc::channel::<()>();
        let grower = std::thread::spawn(move || {
            let run = RunHeap::start();
            // SAFETY: a valid non-zero layout; freed below with it.
            let p = unsafe { a.alloc(layout) };
            grown.send(run.over(512 << 10)).unwrap();
            finish.recv().unwrap();
            // SAFETY: allocated above with `layout`.
            unsafe { a.dealloc(p, layout) };
        });
        let neighbour = RunHeap::start();
        let grower_over = ready.recv().unwrap();
        let neighbour_over = neighbour.over(512 << 10);
        done.send(()).unwrap();
        grower.join().unwrap();
        assert!(grower_over.is_some_and(|b| b >= 1 << 20), "{grower_over:?}");
        assert_eq!(neighbour_over, None);
    }

    #[test]
    fn byte_counts_read_as_people_write_them() {
        assert_eq!(format_bytes(256 << 20), "256 MiB");
        assert_eq!(format_bytes(3 << 29), "1.5 GiB");
        assert_eq!(format_bytes(512 << 10), "512 KiB");
        assert_eq!(format_bytes(100), "100 bytes");
    }
}
