//! Pure wire codecs for both devices: bytes in, typed values out, and back. No clocks, no I/O.

pub mod c29u;
pub mod c29u_ascii;
pub mod c29u_modbus;
pub mod trc1000;
