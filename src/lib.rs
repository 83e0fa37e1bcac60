//! rigscript: scripted, supervised, fail-safe control of TRC1000 panels and TRP-C29U I/O modules.
//!
//! The `rigscript` command is built on this library, and so can your own programs: drive a
//! module or a panel board directly, run a Rhai script on a rig you assemble in code, or test a
//! script against the simulators in virtual time. Everything works without hardware, through
//! the same drivers that talk to the real devices.
//!
//! # Where to start
//!
//! | to | use |
//! |---|---|
//! | read and drive a TRP-C29U (ASCII or Modbus RTU) | [`device::c29u::C29u`], opened on a serial port or `tcp://` with [`C29u::open`](device::c29u::C29u::open) |
//! | read a TRC1000's switches, rotaries and relay | [`device::trc1000::Trc1000`] over [`link::usb::UsbPacketLink`] |
//! | simulate either device | [`sim::c29u_line::SimulatedC29u`] behind [`link::memory::MemoryByteLink`] (or [`sim::pty::PtyServer`] for other programs); [`sim::trc1000::Trc1000Sim`] behind [`link::memory::MemoryPacketLink`] |
//! | run a script on a rig | [`RigBuilder`]: devices in code or from a rig.toml ([`config::RigConfig`]), real or simulated, real or virtual time |
//! | test a script | [`RigBuilder::virtual_time_from`], then [`Rig::sim`] (the field side) and [`Rig::runner`] (`advance`, `status`) |
//! | report to CI | [`report::junit`] |
//!
//! The examples directory holds a runnable program for each (`cargo run --example c29u`,
//! `trc1000_watch`, `script_on_rig`, `scenario_test`).
//!
//! # Example: the real driver against the simulated module
//!
//! ```
//! use rigscript::device::c29u::{share, C29u, C29uOptions, Protocol};
//! use rigscript::link::memory::MemoryByteLink;
//! use rigscript::sim::c29u::{C29uModel as Module, Eeprom};
//! use rigscript::sim::c29u_line::{lock, SimulatedC29u};
//! use rigscript::time::clock::SystemClock;
//!
//! let clock = SystemClock::shared();
//! let module = SimulatedC29u::new(Module::new(Protocol::Modbus, clock.clone(), Eeprom::factory()));
//! let field = module.model(); // the wiring side: inputs, pulses, power cycles
//! let link = MemoryByteLink::new(module, "TRP-C29U");
//! let mut io = C29u::new(share(Box::new(link)), clock, C29uOptions::default())?;
//!
//! io.write_outputs(0x21)?; // DO0 and DO5 on: a Modbus FC15 frame to the module
//! lock(&field).set_inputs(0b0000_0101); // DI0 and DI2 energized
//! let state = io.read_io()?;
//! assert_eq!((state.outputs, state.inputs), (0x21, 0x05));
//! assert_eq!(lock(&field).outputs(), 0x21);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! # Layers
//!
//! Data flows one way: `script` -> `runtime` -> `device` -> (`protocol`, `link`); `sim` answers
//! at the far end of a link. Time comes from a [`time::clock::Clock`] (real, or virtual in
//! tests). See DESIGN.md for the whole picture.
#![deny(missing_docs)]

pub mod cli;
pub mod config;
pub mod content_hash;
pub mod device;
pub(crate) mod guardian;
pub mod heap;
pub mod link;
pub mod protocol;
pub mod report;
pub mod runtime;
pub mod script;
pub(crate) mod service;
pub mod sim;
pub(crate) mod suggest;
pub(crate) mod sync;
pub(crate) mod text_file;
pub mod time;
pub mod verify;

pub use script::builder::RigBuilder;
pub use script::rig::{Rig, RigError};
