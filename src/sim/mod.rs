//! Device models that answer at the far end of a link: in memory, or on a pseudo-terminal.

pub mod c29u;
pub mod c29u_ascii;
pub mod c29u_line;
pub mod c29u_modbus;
pub mod faults;
pub mod pty;
pub mod rig;
pub mod timed_line;
pub mod trc1000;
pub mod wire;
