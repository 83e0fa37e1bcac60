//! The faults a simulated line or device can suffer: one word for each, with one meaning
//! wherever it is injected (the planned faults of an in-memory link in virtual time, the
//! faults queued for a device's next answers, the faults the pty simulator draws by chance).
//!
//! - drop: an answer never arrives (the request still reached the device).
//! - garble: an answer arrives unreadable: the top bit of its middle byte flipped, which no
//!   frame of either TRP-C29U protocol survives (the CRC or checksum fails, or the ASCII turns
//!   non-ASCII). Queued (`answer::AnswerFault::Garble`; `verify`'s and a scenario's word).
//! - flip: an answer arrives with the bits of one byte flipped, which a frame may survive
//!   (a hex digit of an unchecked ASCII answer): planned at a byte with a mask
//!   (`LinkFault::Flip`), or drawn, one random bit (`drawn::Drawn::flip`, `sim --flip`).
//! - late: an answer is given on time and arrives later (within the driver's timeout a slow
//!   answer, past it one that lands in a later exchange's window); `sim --delay` delays every
//!   answer, the module answering one request at a time.
//! - duplicate: an answer arrives twice, the copy right behind it.
//! - disconnect: every write and read fails, as on an unplugged USB-serial adapter.
//! - silence: the link works, the device hears and says nothing (a cut RS-485 pair).
//! - stall: the next link call takes longer (flow control, a hung driver).
//! - panic: the next link call panics (a bug under the runner).

pub mod answer;
pub mod drawn;
mod plan;

pub use plan::*;
