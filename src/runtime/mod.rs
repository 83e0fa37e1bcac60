//! Supervision for everything that runs: timer schedules, the rig's devices, the state scripts
//! act on, the scan loop and its fail-safe supervision.

pub mod core;
pub mod devices;
pub mod error_log;
pub mod invariants;
pub mod log;
pub mod records;
pub mod safety;
pub mod scan;
pub mod schedule;
pub mod stats;
pub mod wake_latency;
