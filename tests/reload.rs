//! `rigscript reload` against a real `rigscript run` on the pty simulator while the script
//! toggles the module's outputs: the module never sees a write neither script decided (no
//! safe value, no zero, its watchdog fed) across reloads, the top-level variables carry over,
//! and a script `check` rejects or whose scenario test fails is refused, the old one running on.

use crate::common::rigs::{Rigs, Run};
use crate::common::{stderr, until, SimProcess};
use serde_json::Value;
use std::process::{Output, Stdio};
use std::time::Duration;

const V1: &str = "let n = 0;\nif !is_reload() { io.outputs = 1; }\n\
                  every(\"100ms\", || { n += 1; io.outputs = if io.outputs == 1 { 2 } else { 1 }; });\n";

const V2: &str = "let n = 0;\nlet seen = -1;\non_reload(|| { seen = n; });\n\
                  if !is_reload() { io.outputs = 1; }\n\
                  every(\"100ms\", || { n += 1; io.outputs = (n % 2) + 1; });\n";

/// Runs `rigscript reload bench-r` while watching the module's outputs: its result and every
/// DO byte seen meanwhile.
fn reload_watching(rig: &Rigs, sim: &mut SimProcess) -> (Output, Vec<u64>) {
    let mut child = rig
        .command(&["reload", "bench-r"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut seen = Vec::new();
    while child.try_wait().unwrap().is_none() {
        seen.push(sim.state()["do"].as_u64().unwrap());
    }
    // A little longer: the swap's tick and the new script's first timers.
    for _ in 0..20 {
        seen.push(sim.state()["do"].as_u64().unwrap());
    }
    (child.wait_with_output().unwrap(), seen)
}

#[test]
fn reloads_keep_the_outputs_carry_the_variables_and_refuse_a_bad_script() {
    let rig = Rigs::new("reload");
    let mut sim = SimProcess::start(&["--protocol", "modbus", "--id", "1"]);
    let config = rig.dir.file(
        "rig.toml",
        &format!(
            "name = \"bench-r\"\nperiod = \"20ms\"\n[devices.io]\nkind = \"trp-c29u\"\n\
             port = \"{}\"\nsafe_value = 0x40\nwatchdog = \"1s\"\n",
            sim.path
        ),
    );
    let script = rig.dir.file("work.rhai", V1);
    let mut run = Run(rig
        .command(&["run", "--config", &config, &script])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap());
    let first = rig.status("bench-r");
    sim.wait_for(Duration::from_secs(10), |s| s["do"] == 2);
    // The same script's next version: swapped with the outputs as they are.
    rig.dir.file("work.rhai", V2);
    let (out, seen) = reload_watching(&rig, &mut sim);
    assert!(out.status.success(), "{out:?}");
    assert!(
        seen.iter().all(|v| *v == 1 || *v == 2),
        "only what a script decided: {seen:?}"
    );
    let now = rig.status("bench-r");
    assert_eq!(now["script"]["reloads"], 1, "{now}");
    assert_ne!(now["script"]["hash"], first["script"]["hash"]);
    assert_eq!(now["script"]["hash"].as_str().unwrap().len(), 64);
    // A script check rejects: refused, the old one runs on.
    rig.dir.file("work.rhai", "let n = ;\n");
    let (out, seen) = reload_watching(&rig, &mut sim);
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    assert!(stderr(&out).contains("rigscript check"), "{}", stderr(&out));
    assert!(seen.iter().all(|v| *v == 1 || *v == 2), "{seen:?}");
    // A script whose scenario test fails: refused.
    rig.dir.file("work.rhai", V1);
    std::fs::create_dir(rig.dir.path("tests")).unwrap();
    rig.dir.file(
        "tests/work.test.rhai",
        "fn test_never() { let r = rig(\"../work.rhai\"); r.advance(300); \
         assert_eq(r.outputs(\"io\"), 99); }\n",
    );
    let (out, seen) = reload_watching(&rig, &mut sim);
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    assert!(stderr(&out).contains("scenario test"), "{}", stderr(&out));
    assert!(seen.iter().all(|v| *v == 1 || *v == 2), "{seen:?}");
    assert_eq!(
        rig.status("bench-r")["script"]["hash"],
        now["script"]["hash"]
    );
    let state = sim.state();
    assert_eq!(
        state["watchdog"]["expired"], false,
        "fed throughout: {state}"
    );
    let stop = rig.output(&["stop", "bench-r"]);
    assert!(stop.status.success(), "{stop:?}");
    let _ = until(Duration::from_secs(20), || run.0.try_wait().unwrap());
    let log = crate::common::read_stderr(&mut run.0);
    assert!(log.contains("reloaded "), "{log}");
    assert!(log.contains("variables carried: n"), "{log}");
    assert!(log.contains("refused: "), "{log}");
    let reloading = log.split("reloaded ").nth(1).unwrap_or_default();
    let until_stop = reloading.split("stopping").next().unwrap_or_default();
    assert!(!until_stop.contains("-> 0x40"), "{log}");
}

#[test]
fn run_watch_reloads_the_script_once_its_file_has_settled() {
    let rig = Rigs::new("reload-watch");
    let script = rig.dir.file("watched.rhai", V1);
    let mut run = Run(rig
        .command(&["run", "--sim", "--watch", &script])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap());
    let status_of = |rig: &Rigs| {
        let out = rig.output(&["status", "watched", "--json"]);
        out.status
            .success()
            .then(|| serde_json::from_slice::<Value>(&out.stdout).unwrap())
    };
    let first = until(Duration::from_secs(10), || status_of(&rig)).expect("the run answers");
    assert_eq!(first["script"]["reloads"], 0);
    rig.dir.file("watched.rhai", V2);
    let reloaded = until(Duration::from_secs(20), || {
        status_of(&rig).filter(|s| s["script"]["reloads"] == 1)
    })
    .expect("the change was reloaded");
    assert_ne!(reloaded["script"]["hash"], first["script"]["hash"]);
    let stop = rig.output(&["stop", "watched"]);
    assert!(stop.status.success(), "{stop:?}");
    let _ = until(Duration::from_secs(20), || run.0.try_wait().unwrap());
    let log = crate::common::read_stderr(&mut run.0);
    assert!(
        log.contains("asked by run --watch; variables carried: n"),
        "{log}"
    );
}
