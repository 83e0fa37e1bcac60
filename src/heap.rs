//! The heap in use by the whole process, counted by a global allocator, so that a run can bound
//! its memory (`memory` under `[limits]`) and stop a script that grows it without end.
//!
//! `CountingAlloc` wraps the system allocator and keeps one relaxed atomic count of the bytes
//! allocated and not yet freed: a few nanoseconds an allocation, nothing per script operation.
//! Only a program that installs it (`#[global_allocator]`, as `rigscript` does) is counted;
//! elsewhere `in_use` answers `None` and no memory limit applies.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

static LIVE: AtomicUsize = AtomicUsize::new(0);

/// The system allocator, counting the bytes in use.
pub struct CountingAlloc;

// SAFETY: every call goes straight to `System` with the caller's own arguments; the count is
// kept beside it and never touches the memory.
unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: as the caller promised for `layout`.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            LIVE.fetch_add(layout.size(), Ordering::Relaxed);
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: as the caller promised for `layout`.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            LIVE.fetch_add(layout.size(), Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: `ptr` was allocated by this allocator (that is, by `System`) with `layout`.
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: as the caller promised for `ptr`, `layout` and `new_size`.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            if new_size >= layout.size() {
                LIVE.fetch_add(new_size - layout.size(), Ordering::Relaxed);
            } else {
                LIVE.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
            }
        }
        p
    }
}

/// Bytes of heap the process has allocated and not freed, if `CountingAlloc` is the global
/// allocator (`None` otherwise: nothing was ever counted, and a running program always holds
/// some heap).
pub fn in_use() -> Option<usize> {
    match LIVE.load(Ordering::Relaxed) {
        0 => None,
        n => Some(n),
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
    fn byte_counts_read_as_people_write_them() {
        assert_eq!(format_bytes(256 << 20), "256 MiB");
        assert_eq!(format_bytes(3 << 29), "1.5 GiB");
        assert_eq!(format_bytes(512 << 10), "512 KiB");
        assert_eq!(format_bytes(100), "100 bytes");
    }
}
