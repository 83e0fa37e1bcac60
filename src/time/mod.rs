//! Time at the bottom of the house: the clock every layer takes time from (real, or virtual for
//! tests), durations as people write them, and the time zone of cron, `now()` and the log.

pub mod clock;
pub mod doorbell;
pub mod duration;
pub mod zone;
