//! Fail-safe supervision, all in one place: taking control of every device (at start, when it
//! comes back, when a module went safe), keeping it (host watchdogs fed, outputs read back),
//! noticing a loss between exchanges, losing devices and trying them again, holding every output
//! safe while one has been lost for longer than its grace time, and the safe state at the end.
//! The state it keeps is the `Safety` part of `Runtime` (hold.rs).

mod confirm;
mod control;
mod hold;
mod liveness;
mod loss;
mod safe_state;
mod upkeep;

pub use confirm::{confirm_safe_state, SafeDriver, SafeReading, Unconfirmed};
pub use control::Unavailable;
pub use hold::Safety;
pub use safe_state::{DeviceEnd, END_TRIES};
