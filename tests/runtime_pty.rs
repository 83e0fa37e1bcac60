//! `rigscript run` against the TRP-C29U simulator on a real pseudo-terminal: SIGTERM leaves
//! the module at its safe value; after `kill -9` of a run without its guardian the module's own
//! host watchdog, enabled and fed by the runner, drives it there (tests/guardian.rs: with it).

use crate::common::{
    kill, lose_a_module, read_stderr, start_run, watched_rig, Cut, SimProcess, TempDir,
};
use std::time::Duration;

#[test]
fn sigterm_leaves_the_module_at_its_safe_value() {
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let (_dir, config, script) = watched_rig(&sim, "pty-term");
    let mut run = start_run(&["--quiet", "--config", &config, &script]);
    let s = sim.wait_for(Duration::from_secs(10), |s| s["do"] == 0xF0);
    assert_eq!(s["do"], 0xF0, "the script drives the module: {s}");
    assert_eq!(s["safe_value"], 0x05);
    assert_eq!(s["watchdog"]["enabled"], true);
    kill(run.id(), "-TERM");
    let status = run.wait().unwrap();
    let err = read_stderr(&mut run);
    assert_eq!(status.code(), Some(143), "128 + SIGTERM: {err}");
    let s = sim.state();
    assert_eq!(s["do"], 0x05, "{s}\n{err}");
    assert_eq!(
        s["watchdog"]["enabled"], false,
        "a clean end turns it off: {s}"
    );
}

#[test]
fn after_kill_9_without_the_guardian_the_modules_own_watchdog_drives_it_safe() {
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let (_dir, config, script) = watched_rig(&sim, "pty-kill");
    let mut run = start_run(&["--quiet", "--config", &config, &script, "--no-guardian"]);
    let s = sim.wait_for(Duration::from_secs(10), |s| s["do"] == 0xF0);
    assert_eq!(s["do"], 0xF0, "{s}");
    kill(run.id(), "-KILL");
    run.wait().unwrap();
    let s = sim.wait_for(Duration::from_secs(10), |s| {
        s["watchdog"]["expired"] == true
    });
    assert_eq!(s["watchdog"]["expired"], true, "{s}");
    assert_eq!(s["do"], 0x05, "{s}");
}

/// SIGTERM with the module in a state the end must not take on its word: the end reads the
/// outputs back, names the module, exits 5, and leaves its host watchdog on, which then
/// drives it safe.
fn sigterm_with_a_faulty_output_stage(fault: &str, tag: &str) {
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let (_dir, config, script) = watched_rig(&sim, &format!("pty-{tag}"));
    let mut run = start_run(&["--quiet", "--config", &config, &script]);
    let s = sim.wait_for(Duration::from_secs(10), |s| s["do"] == 0xF0);
    assert_eq!(s["do"], 0xF0, "{s}");
    assert_eq!(sim.control(fault), "ok");
    kill(run.id(), "-TERM");
    let status = run.wait().unwrap();
    let err = read_stderr(&mut run);
    assert_eq!(status.code(), Some(5), "{err}");
    assert!(
        err.contains("io: the safe state did not reach it: ") && err.contains("outputs read 0xf0"),
        "{err}"
    );
    let s = sim.state();
    assert_eq!(s["watchdog"]["enabled"], true, "left on: {s}\n{err}");
    let s = sim.wait_for(Duration::from_secs(10), |s| s["do"] == 0x05);
    assert_eq!(s["do"], 0x05, "its watchdog drove it safe: {s}");
}

#[test]
fn sigterm_with_a_module_that_ignores_writes_exits_5_and_leaves_its_watchdog_on() {
    sigterm_with_a_faulty_output_stage("ignore-writes", "ignore");
}

#[test]
fn sigterm_with_a_module_that_refuses_writes_with_ff_exits_5_and_leaves_its_watchdog_on() {
    sigterm_with_a_faulty_output_stage("refuse-writes 0xFF", "refuse");
}

#[test]
fn a_module_swapped_behind_the_open_port_is_taken_control_of_and_goes_safe_after_kill_9() {
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let (_dir, config, script) = watched_rig(&sim, "pty-swap");
    // Without the guardian: what is tested is the watchdog the takeover gave the new module.
    let mut run = start_run(&["--quiet", "--config", &config, &script, "--no-guardian"]);
    let s = sim.wait_for(Duration::from_secs(10), |s| s["do"] == 0xF0);
    assert_eq!(s["do"], 0xF0, "{s}");
    // Another module, safe value 0xFF and no watchdog, answers on the same port.
    assert_eq!(sim.control("swap OTHER 0xFF 0xFF"), "ok");
    let s = sim.wait_for(Duration::from_secs(15), |s| {
        s["safe_value"] == 0x05 && s["watchdog"]["enabled"] == true && s["do"] == 0xF0
    });
    assert_eq!(s["safe_value"], 0x05, "taken control of: {s}");
    assert_eq!(s["watchdog"]["enabled"], true, "{s}");
    kill(run.id(), "-KILL");
    run.wait().unwrap();
    let s = sim.wait_for(Duration::from_secs(10), |s| {
        s["watchdog"]["expired"] == true
    });
    assert_eq!(s["do"], 0x05, "its new watchdog drove it safe: {s}");
}

/// A rig in commissioning: the module on its real line, the panel not there yet and simulated
/// (`sim = true` in its table, or `--sim-device panel`); the script uses both.
fn mixed_rig_runs(panel_table: &str, extra: &[&str], tag: &str) {
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let dir = TempDir::new(&format!("pty-{tag}"));
    let config = dir.join("rig.toml");
    std::fs::write(
        &config,
        format!(
            "period = \"20ms\"\n[devices.io]\nkind = \"trp-c29u\"\nport = \"{}\"\n\
             [devices.panel]\nkind = \"trc1000\"\nsafe_relay = 0\n{panel_table}",
            sim.path
        ),
    )
    .unwrap();
    let script = dir.join("both.rhai");
    std::fs::write(
        &script,
        "every(\"50ms\", || { io.outputs = if panel.online && panel.pressed().len() == 0 { 0x3C } else { 0x01 }; });\n",
    )
    .unwrap();
    let (config, script) = (config.display().to_string(), script.display().to_string());
    let mut run = start_run(&[&["--config", &config, &script], extra].concat());
    let s = sim.wait_for(Duration::from_secs(10), |s| s["do"] == 0x3C);
    kill(run.id(), "-TERM");
    let status = run.wait().unwrap();
    let err = read_stderr(&mut run);
    assert_eq!(
        s["do"], 0x3C,
        "the real module driven from the simulated panel: {s}\n{err}"
    );
    assert_eq!(status.code(), Some(143), "{err}");
    assert!(err.contains("panel: simulated TRC1000 panel"), "{err}");
    assert!(err.contains("on serial port"), "io is real: {err}");
    assert!(
        err.contains("safe state (signal): io outputs 0x00, panel relay 0"),
        "{err}"
    );
}

#[test]
fn a_rig_mixes_a_real_module_and_a_panel_marked_sim_in_rig_toml() {
    mixed_rig_runs("sim = true\n", &[], "mixed-toml");
}

#[test]
fn a_rig_mixes_a_real_module_and_a_panel_simulated_by_sim_device() {
    mixed_rig_runs("", &["--sim-device", "panel"], "mixed-flag");
}

/// The lost module's line and the rest of the rig, in the log's order: the loss with the OS's
/// reason, then everything held safe. Told by the OS between exchanges, or by the exchange that
/// was under way when the line went (its read ends at the end of the file): both at once.
fn assert_told_at_once(log: &str, reason: &str) {
    let lost = log
        .find("lost: lost: ")
        .unwrap_or_else(|| panic!("the loss is told: {log}"));
    let line = log[lost..].lines().next().unwrap_or_default();
    assert!(
        (line.contains(reason) && line.contains("(the OS says so between exchanges)"))
            || line.contains("disconnected: unexpected end of file"),
        "the loss names what the OS said: {line}"
    );
    let held = log
        .find(
            "lost lost for longer than the grace time (1s): every output is held at its safe state",
        )
        .unwrap_or_else(|| panic!("held safe: {log}"));
    assert!(lost < held, "{log}");
}

#[test]
fn a_module_whose_line_hangs_up_is_lost_at_once_and_the_rest_goes_safe_after_the_grace_time() {
    let loss = lose_a_module(
        "hangup",
        str::to_string,
        (Cut::Kill, Duration::ZERO),
        Duration::from_secs(10),
    );
    // The identity check every 5 s would notice the loss up to 5 s late, the hang-up tells it
    // at once, and grace is 1 s.
    loss.assert_safe_within(Duration::from_secs(4));
    assert_told_at_once(
        &loss.log,
        "disconnected: hang-up: the other end of the line closed it",
    );
}
