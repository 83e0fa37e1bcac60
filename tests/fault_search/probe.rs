//! What the fault search watches besides the simulators: the heap this thread holds (a
//! counting allocator, so a script whose memory only grows is caught before it takes the
//! machine down) and the panics raised while a case runs (kept quiet and recorded).

use std::any::Any;
use std::cell::{Cell, RefCell};
use std::panic::Location;
use std::sync::Once;

thread_local! {
    static IN_CASE: Cell<bool> = const { Cell::new(false) };
    static PANICS: RefCell<Vec<String>> = const { RefCell::new(Vec::new()) };
}

/// Bytes this thread has allocated and not freed, as the runner's allocator
/// (`rigscript::heap::CountingAlloc`, as the `rigscript` binary installs it, so the run's memory
/// limit applies here as there) counts them: frees by other threads make it drift; the search
/// only compares readings taken during one case.
pub fn live_bytes() -> i64 {
    rigscript::heap::thread_balance() as i64
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
