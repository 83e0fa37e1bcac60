//! Device drivers: a protocol codec plus a link, with retries, framing by time and typed errors.

pub mod c29u;
pub mod cancel;
pub mod exchange;
pub mod trc1000;
