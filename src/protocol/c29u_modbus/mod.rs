//! TRP-C29U Modbus RTU codec (manual sections 9 and 10, as docs/trp-c29u-protocol.md reads
//! them): typed requests and answers, CRC-16/MODBUS, and a frame reader for byte streams. Pure:
//! no clocks, no I/O.
//!
//! Master side: `Request::encode`, then `FrameReader::for_answers` + `expect_answer` to cut the
//! answer out of the byte stream, then `parse_response`. Slave side (the simulator):
//! `FrameReader::for_requests`, `decode_request`, then `encode_response` / `encode_exception` /
//! `encode_vendor_error`.

mod error;
mod frame;
mod reader;
mod request;
mod response;

#[cfg(test)]
mod manual_tests;
#[cfg(test)]
mod proptests;

pub use error::{ExceptionCode, ModbusError, RequestError};
pub use frame::{crc16, open_frame, seal, silence_gap, MAX_FRAME_LEN, MIN_FRAME_LEN, MODBUS_CRC};
pub use reader::{Expectation, FrameReader};
pub use request::{
    decode_request, BitArea, CoilCommand, CoilsTarget, CounterFunction, Request, VendorRequest,
};
pub use response::{
    encode_exception, encode_response, encode_vendor_error, model_name, parse_response, Response,
    VendorResponse,
};

/// Function code 01: read 8 bits (DO, DI, latches) — 10-17.
pub const FC_READ_BITS: u8 = 0x01;
/// Function code 03: read counters — 10-18.
pub const FC_READ_HOLDING: u8 = 0x03;
/// Function code 04: read counters — 10-19.
pub const FC_READ_INPUT: u8 = 0x04;
/// Function code 05: write one coil (DO channel, clear latches, clear one counter) — 10-16.
pub const FC_WRITE_COIL: u8 = 0x05;
/// Function code 0F: write coils (DO byte, clear counters, save counters) — 10-20.
pub const FC_WRITE_COILS: u8 = 0x0F;
/// Vendor function code 46 with a sub-function in byte 2 — 10-1..10-15.
pub const FC_VENDOR: u8 = 0x46;
/// Bit set in the function code of an exception answer (`ID FC|80 CODE`).
pub const EXCEPTION_FLAG: u8 = 0x80;

/// The slave IDs a module can have (9-1, 10-1: "Address of setting module 1~247").
pub const SLAVE_IDS: std::ops::RangeInclusive<u8> = 1..=247;

/// The name code 46 00 answers: the hex digits `0C 29`, read as "C29" by [`model_name`] (10-1).
pub const NAME_CODE: u16 = 0x0C29;
