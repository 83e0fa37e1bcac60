//! The integration suite, linked as one binary (`cargo test --test integration NAME::`): each
//! module is one area's tests, driving the real `rigscript` binary, the simulators on ptys and
//! the system tools `.ci/run` installs. A test that needs such a tool, or root, is tier 2:
//! ignored by a plain `cargo test`, saying what it needs, and run by `.ci/run`
//! (`-- --include-ignored`); tests/README.md has the tiers. `tests/held_device.rs` links on its
//! own: it sets the process's environment, which would leak into every other test here.

mod c29_cli;
mod cli_conventions;
mod common;
mod control_socket;
mod debian_package;
mod fault_search;
mod guardian;
mod guide_reference;
mod journal_cli;
mod junit_cli;
mod late_answers;
mod line_timing;
mod mqtt;
mod port_in_use;
mod reload;
mod run_remote;
mod run_seams;
mod runtime_cli;
mod runtime_pty;
mod runtime_scenarios;
mod scan_cli;
mod signals_cli;
mod sim_mbpoll;
mod stop_mid_wait;
mod systemd_notify;
mod systemd_units;
mod tcp_link;
mod trc_umockdev;
mod verify_cli;
mod verify_exhaustive;
mod version;
mod web_ui;
