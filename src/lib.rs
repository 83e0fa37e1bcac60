//! rigscript: scripted, supervised, fail-safe control of TRC1000 panels and TRP-C29U I/O modules.
//!
//! Data flows one way: `script` -> `runtime` -> `device` -> (`protocol`, `link`); `sim` answers
//! at the far end of a link. See DESIGN.md for the whole picture.

pub mod cli;
pub mod config;
pub mod device;
pub mod link;
pub mod protocol;
pub mod runtime;
pub mod script;
pub mod sim;
pub mod time;
pub mod verify;
