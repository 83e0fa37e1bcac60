//! A device file a running rig holds is named by its rig: the processes with the file open
//! (the `/proc` scan `link::holders` does for a busy serial port or a claimed TRC1000's usbfs
//! node) are matched to the rigs that answer on their sockets. umockdev's usbfs does not make
//! libusb report a claimed interface as busy, so the lookup is tested with a real `run`
//! holding a file open (its records file), as it holds a board's `/dev/bus/usb/BBB/DDD`.
//! Alone in its binary: it points this process's rig directory at its own.

mod common;

use common::rigs::Run;
use common::{rigscript, until, TempDir};
use rigscript::cli::output::rig_holding_path;
use std::process::{Command, Stdio};
use std::time::Duration;

#[test]
fn a_file_a_running_rig_holds_open_names_the_rig_and_the_commands_that_see_and_stop_it() {
    let dir = TempDir::new("held-device");
    // This process looks for rigs where the run below serves its socket.
    std::env::set_var("XDG_RUNTIME_DIR", dir.root());
    std::env::remove_var("RUNTIME_DIRECTORY");
    let held = dir.path("bench.jsonl");
    let free = dir.file("free.jsonl", "");
    let script = dir.file("holder.rhai", "every(\"50ms\", || record(\"n\", 1));\n");
    let _run = Run(Command::new(rigscript())
        .args(["run", "--sim", "--records"])
        .arg(&held)
        .arg(&script)
        .env("XDG_RUNTIME_DIR", dir.root())
        .env_remove("RUNTIME_DIRECTORY")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap());
    let said = until(Duration::from_secs(10), || rig_holding_path(&held))
        .expect("the rig holding the file is named");
    assert!(said.starts_with("it is held by rig holder "), "{said}");
    assert!(
        said.contains("`rigscript status holder` shows it"),
        "{said}"
    );
    assert!(said.contains("`rigscript stop holder` stops it"), "{said}");
    assert_eq!(rig_holding_path(std::path::Path::new(&free)), None);
}
