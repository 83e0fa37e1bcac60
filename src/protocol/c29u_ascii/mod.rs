//! The TRP-C29U's ASCII protocol (manual sections 6-8, as docs/trp-c29u-protocol.md reads
//! them): typed requests and answers, their frames (`lead + ID + body + [checksum] + CR`), for
//! the driver and the simulator.
//!
//! Readings of the manual where it is silent or unclear, each with its section:
//! - 8-9: `$IDL1` ("no use") is read as "latched high", the counterpart of Modbus 10-17's 60.
//! - 8-4: a single-channel write accepts DD `00`/`01` only; any 4-character `#ID` body is an
//!   output write, so a bad PP or DD gets `!ID`. Bad parameters of other commands get `?ID`.
//! - 8-19: in safe mode an output write is answered `!IDWE` ([`Refusal::SafeMode`]); any other
//!   refusal means safe mode only when the watchdog reads as fired ([`AsciiError::means_safe_mode`]).
//! - 8-21: `WD` + NN with NN > 0 is a fired watchdog, `WD00` and a bare `!ID` an off one
//!   ([`WatchdogReading`]).
//! - 8-26: its `###` is the `#**` broadcast of 8-25; both are accepted, `#**` is sent.
//! - 8-1/8-3: the `%` answer `!NN` is framed with the checksum setting the request came with;
//!   reserved format bits 5..1 and a PP other than 40 are refused with `?ID`.
//! - Checksum and ID hex digits are accepted in either case, in requests and answers alike.

mod answer;
mod frame;
mod request;
mod types;
mod watchdog;

#[cfg(test)]
mod manual_tests;
#[cfg(test)]
mod prop_tests;

pub use answer::{encode_answer, encode_refusal, parse_answer, Answer, AsciiError};
pub use frame::{checksum, CR};
pub use request::{decode_request, Refusal, Request, RequestError, LONGEST_REQUEST, MODULE_TYPE};
pub use types::{
    Address, BaudCode, Channel, ConfigReport, DataFormat, FirmwareDate, FirmwareVersion,
    LatchLevel, ModuleName, Preset, SynchronizedData,
};
pub use watchdog::WatchdogReading;
