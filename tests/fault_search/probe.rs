//! What the fault search watches besides the simulators: the heap this thread holds (a
//! counting allocator, so a script whose memory only grows is caught before it takes the
//! machine down) and the panics raised while a case runs (kept quiet and recorded).

use rigscript::heap::CountingAlloc;
use std::alloc::{GlobalAlloc, Layout};
use std::any::Any;
use std::cell::{Cell, RefCell};
use std::panic::Location;
use std::sync::Once;

/// The runner's own counting allocator (`rigscript::heap::CountingAlloc`, as the `rigscript`
/// binary installs it, so the run's memory limit applies here as there), counting besides the
/// bytes each thread has allocated and not freed.
pub struct Counting;

thread_local! {
    static LIVE: Cell<i64> = const { Cell::new(0) };
    static IN_CASE: Cell<bool> = const { Cell::new(false) };
    static PANICS: RefCell<Vec<String>> = const { RefCell::new(Vec::new()) };
}

fn count(delta: i64) {
    // `try_with`: a thread being torn down has no counter any more, and needs none.
    let _ = LIVE.try_with(|c| c.set(c.get().saturating_add(delta)));
}

fn size(bytes: usize) -> i64 {
    i64::try_from(bytes).unwrap_or(i64::MAX)
}

// SAFETY: every call is passed on to `CountingAlloc` (the system allocator) unchanged; the counter is a
// thread-local integer with a const initializer (it neither allocates nor has a destructor).
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: the caller's contract is CountingAlloc's (System's).
        let p = unsafe { CountingAlloc.alloc(layout) };
        if !p.is_null() {
            count(size(layout.size()));
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: as for `alloc`.
        let p = unsafe { CountingAlloc.alloc_zeroed(layout) };
        if !p.is_null() {
            count(size(layout.size()));
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as for `alloc`.
        unsafe { CountingAlloc.dealloc(ptr, layout) };
        count(-size(layout.size()));
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: as for `alloc`.
        let p = unsafe { CountingAlloc.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            count(size(new_size) - size(layout.size()));
        }
        p
    }
}

/// Bytes this thread has allocated and not freed (frees by other threads make it drift; the
/// search only compares readings taken during one case).
pub fn live_bytes() -> i64 {
    LIVE.with(Cell::get)
}

/// Marks the start of a case on this thread: panics from here on are recorded, not printed.
pub fn begin_case() {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let default = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if IN_CASE.with(Cell::get) {
                let text = describe(info.payload(), info.location());
                PANICS.with(|p| p.borrow_mut().push(text));
            } else {
                default(info);
            }
        }));
    });
    PANICS.with(|p| p.borrow_mut().clear());
    IN_CASE.with(|c| c.set(true));
}

/// Marks the end of a case; returns the panics raised during it.
pub fn end_case() -> Vec<String> {
    IN_CASE.with(|c| c.set(false));
    PANICS.with(|p| std::mem::take(&mut *p.borrow_mut()))
}

fn describe(payload: &(dyn Any + Send), location: Option<&Location<'_>>) -> String {
    let message = payload
        .downcast_ref::<&str>()
        .map(|s| (*s).to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(no message)".into());
    match location {
        Some(at) => format!("{message} (at {}:{})", at.file(), at.line()),
        None => message,
    }
}
