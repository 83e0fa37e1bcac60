//! Time and supervision for everything that runs: clocks now; the scan loop with the script runtime.

pub mod clock;
pub mod duration;
pub mod schedule;
