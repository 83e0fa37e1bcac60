//! Supervision for everything that runs: timer schedules, the rig's devices, the state scripts
//! act on, the scan loop and its fail-safe supervision.

pub mod cycle;
pub mod device_view;
pub mod devices;
pub mod error_log;
pub mod exit;
pub mod figures;
pub mod forcing;
pub mod handlers;
mod inputs;
mod invariant_checks;
pub mod invariants;
pub mod line_consumer;
pub mod log;
pub mod observe;
mod outputs;
pub mod program_state;
mod recording;
pub mod records;
mod records_file;
mod registrations;
pub mod registry;
pub mod remote;
pub mod requests;
pub mod runner;
pub mod safety;
pub mod schedule;
pub mod script_context;
pub mod signals;
pub mod snapshot;
pub mod state;
pub mod stats;
#[cfg(test)]
mod testing;
pub mod topic_filter;
mod triggers;
pub mod wake_latency;
pub mod watched_image;
