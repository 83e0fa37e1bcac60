//! Time and supervision for everything that runs: clocks, durations, timer schedules, the
//! rig's devices, the scan loop and its fail-safe supervision.

pub mod clock;
pub mod devices;
pub mod duration;
pub mod log;
pub mod records;
pub mod schedule;
pub mod stats;
pub mod zone;
