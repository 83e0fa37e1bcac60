//! The guardian: a small process beside the runner that knows the rig's devices and their safe
//! state, and writes and confirms that state when the runner dies without having confirmed its
//! own end (kill -9, the out-of-memory killer, an abort, a fault in a C library).
//!
//! It runs no script and no Rhai: it waits in `waitpid` and allocates nothing until it acts.
//! What it cannot cover: the guardian and the runner killed at once (`kill -9` of both, a
//! power cut); there each TRP-C29U's own host watchdog, where rig.toml turns it on, is what is
//! left. `pulse` is how the runner's loop shows it still turns (the guardian ends a stuck
//! one). `safe` holds what it does to the devices, shared with `rigscript safe`.

pub mod lone;
pub mod pulse;
pub mod safe;
mod watch;

pub use watch::{guard, Confirmation, Guarded, GuardianLog};
