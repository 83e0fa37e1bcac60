//! The stack a script runs on: a thread with room for anything the script can build within its
//! memory limit. Rhai's call-level and expression-depth limits bound the recursion of running a
//! script, but not of dropping what it built: a chain of closures each capturing the one before
//! (`let g = f; f = || g.call() + 1;` 50,000 times, well within the operation budget) is freed
//! one link per stack frame, and 50,000 links overflow the main thread's 8 MiB and abort the
//! process (SIGABRT, no safe state). The depth of such a chain is bounded only by the heap it
//! takes, which the run's memory limit bounds, so the stack is sized from that limit.

use std::sync::Mutex;

/// Stack for everything but a script's deep values: the runner, Rhai's own nesting within its
/// limits, the drivers.
pub const BASE_STACK: u64 = 64 * 1024 * 1024;

/// Stack bytes to reserve per byte of the run's memory limit. A link of a closure chain takes
/// about 220 bytes of heap and about 900 bytes of stack to drop in a debug build (less in a
/// release build): four to one, doubled for what was not measured.
pub const STACK_PER_HEAP_BYTE: u64 = 8;

/// The stack a run with `memory_limit` bytes of heap gets.
pub fn size_for(memory_limit: u64) -> usize {
    let bytes = memory_limit
        .saturating_mul(STACK_PER_HEAP_BYTE)
        .saturating_add(BASE_STACK);
    usize::try_from(bytes).unwrap_or(usize::MAX)
}

/// Runs `work` on a thread whose stack holds any script within `memory_limit` (`size_for`),
/// and returns what it returns (a panic in it goes on in the caller). The stack is address
/// space reserved, not memory used: pages are only taken as the stack grows into them. Where
/// the system refuses a stack that large (a strict overcommit policy, `ulimit -v`), smaller
/// ones are tried down to `BASE_STACK`, said on stderr; last, `work` runs on this thread.
pub fn on_script_stack<T: Send>(memory_limit: u64, work: impl FnOnce() -> T + Send) -> T {
    let wanted = size_for(memory_limit);
    // Where the work waits for the thread that takes it (a refused spawn leaves it here).
    let slot = Mutex::new(Some(work));
    let take_and_run = || {
        let work = crate::sync::lock(&slot).take();
        work.map(|w| w())
    };
    let mut size = wanted;
    let ran = std::thread::scope(|scope| loop {
        let attempt = std::thread::Builder::new()
            .name("rigscript-script".into())
            .stack_size(size)
            .spawn_scoped(scope, take_and_run);
        match attempt {
            Ok(handle) => {
                if size < wanted {
                    note_smaller(size, wanted);
                }
                return match handle.join() {
                    Ok(value) => value,
                    Err(panic) => std::panic::resume_unwind(panic),
                };
            }
            Err(_) if size as u64 > BASE_STACK => size = (size / 2).max(BASE_STACK as usize),
            Err(_) => return None,
        }
    });
    match ran {
        Some(value) => value,
        None => {
            note_smaller(0, wanted);
            take_and_run().expect("no thread took the work: it is still in its slot")
        }
    }
}

fn note_smaller(got: usize, wanted: usize) {
    use std::io::Write;
    let got = crate::heap::format_bytes(got as u64);
    let wanted = crate::heap::format_bytes(wanted as u64);
    let _ = writeln!(
        std::io::stderr(),
        "rigscript: the system refused a {wanted} stack for the script (got {got}): a script \
         that builds values nested very deep may abort instead of failing with a script error"
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_stack_grows_with_the_memory_limit() {
        assert_eq!(size_for(0), BASE_STACK as usize);
        assert_eq!(
            size_for(256 * 1024 * 1024),
            (BASE_STACK + 2048 * 1024 * 1024) as usize
        );
        assert_eq!(size_for(u64::MAX), usize::MAX);
    }

    #[test]
    fn work_runs_on_the_script_thread_and_returns_its_value() {
        let name = on_script_stack(1024, || std::thread::current().name().map(String::from));
        assert_eq!(name.as_deref(), Some("rigscript-script"));
    }
}
