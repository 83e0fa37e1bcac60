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

/// Declares modules that are the crate's own: public only with the feature `internals`, which
/// nothing but this package's tests, benchmarks and examples turn on (through their
/// dev-dependency on the package itself). A build without it sees them as private, so the
/// compiler reports what nothing uses, and the library's users see only the facade below.
macro_rules! internal {
    ($($(#[$attr:meta])* mod $name:ident;)*) => {$(
        $(#[$attr])*
        #[cfg(feature = "internals")]
        pub mod $name;
        $(#[$attr])*
        #[cfg(not(feature = "internals"))]
        #[allow(unreachable_pub)]
        pub(crate) mod $name;
    )*};
}

pub mod config;
pub mod device;
pub mod heap;
pub mod link;
pub mod protocol;
pub mod report;
pub mod sim;
pub mod time;

internal! {
    mod cli;
    mod content_hash;
    mod guardian;
    mod journal;
    mod runtime;
    mod script;
    mod service;
    mod suggest;
    mod sync;
    mod text_file;
    mod verify;
}

/// The `rigscript` command: parses `std::env::args` and runs it; the process's exit status.
pub use cli::main;
/// The simulated side of a [`Rig`]: its simulators' fields, by device name.
pub use runtime::devices::SimRig;
/// The exit statuses a run ends with.
pub use runtime::exit;
/// The run's typed event stream, for a program that watches a rig it built.
pub use runtime::observe as events;
/// The scan loop a [`Rig`] runs.
pub use runtime::runner::Runner;
pub use script::builder::RigBuilder;
pub use script::rig::{Rig, RigError};
