//! A journal written by its real writer from a run in virtual time on a random field, read
//! back and replayed: every script of scripts/ comes out as it ran, an edited one at the tick
//! it first writes otherwise, a journal cut anywhere replays up to the cut.

use super::replay::{replay, Options};
use super::write::{Prepared, Settings};
use super::{read_journal, Header, What};
use crate::config::RigConfig;
use crate::runtime::observe::Bound;
use crate::script::builder::RigBuilder;
use crate::time::clock::{Clock, VirtualClock};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

const SCRIPTS: [(&str, &str); 5] = [
    (
        "interlock.rhai",
        include_str!("../../scripts/interlock.rhai"),
    ),
    (
        "counter_threshold.rhai",
        include_str!("../../scripts/counter_threshold.rhai"),
    ),
    ("cron_rig.rhai", include_str!("../../scripts/cron_rig.rhai")),
    (
        "rotary_relay.rhai",
        include_str!("../../scripts/rotary_relay.rhai"),
    ),
    (
        "safe_values.rhai",
        include_str!("../../scripts/safe_values.rhai"),
    ),
];

/// A run journaled as `run --journal` writes it: `source` (as `file`) on the rig `toml`
/// describes (`None`: `--sim`'s default rig; given, kept in the header as `--config` keeps
/// it), in virtual time on `clock`, to `path` bounded at `size`; `image` as
/// `--journal-image`.
struct Journaled {
    rig: crate::script::rig::Rig,
    running: Arc<Mutex<Option<super::write::Running>>>,
}

impl Journaled {
    fn start(
        toml: Option<&str>,
        (source, file): (&str, &str),
        (path, size, image): (&Path, u64, bool),
        clock: &VirtualClock,
    ) -> Self {
        let config = toml.map_or_else(RigConfig::simulated_default, |t| {
            RigConfig::parse(t, "rig.toml").unwrap()
        });
        let mut header = Header::first(file, source, None, &config, config.period, None).unwrap();
        header.zone = "UTC".into();
        header.config = toml.map(String::from);
        let mut settings = Settings::new(path, size);
        // The run in virtual time outpaces any disk: a queue that holds all of it.
        settings.bound = Bound::events(1 << 20);
        settings.image = image;
        let prepared = Prepared::new(settings, header).unwrap();
        let running = Arc::new(Mutex::new(None));
        let slot = Arc::clone(&running);
        let rig = RigBuilder::from_config(config)
            .simulated()
            .clock(Arc::new(clock.clone()))
            .log_to_stderr(false)
            .quiet()
            .attach(move |events| *slot.lock().unwrap() = Some(prepared.start(events).unwrap()))
            .start(source, file)
            .unwrap();
        Self { rig, running }
    }

    /// Stops the run (if it runs) and waits for the journal to be written.
    fn finish(mut self) -> super::write::Report {
        if self.rig.runner.status().is_none() {
            self.rig.runner.signal_stop();
        }
        let report = self.running.lock().unwrap().take().unwrap().finish();
        assert!(report.failed.is_none(), "{report:?}");
        report
    }
}

/// Runs `source` for `length` of virtual time on a field that changes at random (seeded),
/// journaled to `path`.
fn journaled_run(source: &str, file: &str, path: &Path, length: Duration, seed: u64) {
    journaled_run_reloading(source, file, path, length, seed, None);
}

/// `journaled_run`, reloaded with `reload`'s text once its time has come.
fn journaled_run_reloading(
    source: &str,
    file: &str,
    path: &Path,
    length: Duration,
    seed: u64,
    mut reload: Option<(Duration, &str)>,
) {
    let wall = chrono::DateTime::parse_from_rfc3339("2026-03-28T11:58:00.013Z")
        .unwrap()
        .to_utc();
    let clock = VirtualClock::new(wall);
    let mut j = Journaled::start(None, (source, file), (path, 1 << 30, false), &clock);
    let rig = &mut j.rig;
    let mut rng = fastrand::Rng::with_seed(seed);
    while clock.now() < length && rig.runner.status().is_none() {
        rig.runner.advance(Duration::from_millis(rng.u64(10..400)));
        if let Some((_, text)) = reload.filter(|(at, _)| clock.now() >= *at) {
            // As `rigscript reload` does: swapped in at the next tick's boundary.
            rig.runner.reload_at_next_tick(text.into(), file.into());
            reload = None;
        }
        let sim = &rig.sim;
        let _ = match rng.u8(0..8) {
            0 => sim.set_inputs("io", rng.u8(..) | 0x0F),
            1 => sim.set_inputs("io", rng.u8(..)),
            2 => sim.set_switch(
                "panel",
                ["S1", "S10", "S11", "S12"][rng.usize(0..4)],
                rng.bool(),
            ),
            3 => sim.turn("panel", "S41A", rng.i32(-5..=5)),
            4 => sim.pulse("io", rng.u8(0..3), rng.u32(1..40)),
            5 => sim.set_input("io", 7, rng.bool()),
            6 => sim.set_switch("panel", "S12", true),
            _ => sim.set_switch("panel", "S12", false),
        };
    }
    assert_eq!(j.finish().lost, 0);
}

fn dir() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

#[test]
fn a_replay_of_each_script_writes_exactly_what_the_run_wrote() {
    let d = dir();
    for (i, (file, source)) in SCRIPTS.iter().enumerate() {
        let path = d.path().join(format!("{file}.journal"));
        // Long enough for cron_rig's first run (at 12:00:00, two minutes in) and its answer.
        let length = if *file == "cron_rig.rhai" { 150 } else { 60 };
        journaled_run(source, file, &path, Duration::from_secs(length), i as u64);
        let journal = read_journal(&path).unwrap();
        assert!(journal.notes.is_empty(), "{:?}", journal.notes);
        let outcome = replay(&journal, &Options::default()).unwrap();
        assert!(outcome.same_script);
        assert!(
            outcome.recorded.len() >= 2,
            "{file}: the run wrote too little to tell: {:?}",
            outcome.recorded
        );
        assert_eq!(outcome.divergence, None, "{file}");
        assert_eq!(outcome.recorded, outcome.replayed, "{file}");
        assert!(
            outcome.unrecorded.is_empty(),
            "{file}: {:?}",
            outcome.unrecorded
        );
    }
}

#[test]
fn an_edited_script_diverges_at_the_first_tick_it_writes_otherwise() {
    let d = dir();
    let path = d.path().join("j");
    let (file, source) = SCRIPTS[0];
    journaled_run(source, file, &path, Duration::from_secs(120), 7);
    let journal = read_journal(&path).unwrap();
    // Armed power is DO0-DO2 only in the edit: the first arming differs, nothing before it.
    let edited = source.replace("const POWER = 0x0F;", "const POWER = 0x07;");
    let first_armed = journal
        .entries
        .iter()
        .find(|e| matches!(&e.what, What::Outputs { value: 0x0F, .. }))
        .expect("the random field armed the interlock")
        .tick;
    let options = Options {
        script: Some((edited, "edited.rhai".into())),
        ..Options::default()
    };
    let outcome = replay(&journal, &options).unwrap();
    assert!(!outcome.same_script);
    let d = outcome.divergence.expect("the edit writes otherwise");
    assert_eq!(d.tick, first_armed);
    assert!(matches!(
        d.replayed.map(|e| e.what),
        Some(What::Outputs { value: 0x07, .. })
    ));
    assert!(!d.around.is_empty(), "the field around it is shown");
}

#[test]
fn a_journal_cut_at_any_byte_replays_up_to_the_cut() {
    let d = dir();
    let path = d.path().join("j");
    let (file, source) = SCRIPTS[0];
    journaled_run(source, file, &path, Duration::from_secs(60), 3);
    let whole = std::fs::read(&path).unwrap();
    let header_end = whole
        .iter()
        .enumerate()
        .filter(|(_, b)| **b == b'\n')
        .nth(1)
        .unwrap()
        .0;
    let mut rng = fastrand::Rng::with_seed(11);
    let cut_path = d.path().join("cut");
    for _ in 0..5 {
        let cut = rng.usize(header_end + 1..whole.len());
        std::fs::write(&cut_path, &whole[..cut]).unwrap();
        let journal = read_journal(&cut_path).unwrap();
        let torn = whole[cut - 1] != b'\n';
        assert_eq!(
            journal.notes.len(),
            usize::from(torn),
            "{:?}",
            journal.notes
        );
        let Some(last) = journal.entries.last().map(|e| e.tick) else {
            continue;
        };
        let outcome = replay(
            &journal,
            &Options {
                until: Some(last),
                ..Options::default()
            },
        )
        .unwrap();
        assert_eq!(outcome.divergence, None, "cut at byte {cut}");
    }
}

#[test]
fn a_window_becomes_a_test_that_passes_on_the_script_and_fails_on_an_edit() {
    let d = dir();
    let scripts = d.path().join("scripts");
    std::fs::create_dir(&scripts).unwrap();
    let (file, source) = SCRIPTS[0];
    let script = scripts.join(file);
    std::fs::write(&script, source).unwrap();
    let path = d.path().join("j");
    journaled_run(
        source,
        &script.display().to_string(),
        &path,
        Duration::from_secs(60),
        5,
    );
    let journal = read_journal(&path).unwrap();
    let outcome = replay(
        &journal,
        &Options {
            steps_from: Some(0),
            ..Options::default()
        },
    )
    .unwrap();
    let out: PathBuf = d.path().join("tests").join("night.test.rhai");
    std::fs::create_dir(out.parent().unwrap()).unwrap();
    let text = super::to_test::render(&outcome, &out, &script, None, (0, outcome.ticks));
    assert!(text.contains("assert_eq(r.outputs(\"io\")"), "{text}");
    std::fs::write(&out, &text).unwrap();
    let run = |name: &str| {
        crate::script::scenario::run_file(&out, name, |_| {})
            .into_iter()
            .map(|r| r.failure.is_none())
            .collect::<Vec<bool>>()
    };
    assert_eq!(run("night.test.rhai"), [true], "{text}");
    std::fs::write(
        &script,
        source.replace("const POWER = 0x0F;", "const POWER = 0x07;"),
    )
    .unwrap();
    assert_eq!(run("night.test.rhai"), [false]);
}

#[test]
fn an_edit_that_reads_what_the_run_never_read_is_told_what_was_assumed() {
    let d = dir();
    let path = d.path().join("j");
    let (file, source) = SCRIPTS[0];
    journaled_run(source, file, &path, Duration::from_secs(20), 9);
    let journal = read_journal(&path).unwrap();
    let edited = format!("{source}\nevery(\"1s\", || {{ let parts = io.counter(2); }});\n");
    let options = Options {
        script: Some((edited, "edited.rhai".into())),
        ..Options::default()
    };
    let outcome = replay(&journal, &options).unwrap();
    assert_eq!(
        outcome.unrecorded,
        [super::replay::Unrecorded {
            dev: "io".into(),
            item: "counter DI2".into(),
            assumed: "0".into(),
        }]
    );
    assert_eq!(outcome.divergence, None, "reading a counter writes nothing");
}

#[test]
fn a_run_reloaded_halfway_replays_exactly_across_the_reload() {
    let d = dir();
    let path = d.path().join("reloaded.journal");
    let before = "let io = device(\"io\");\nlet n = 0;\n\
                  io.on_rise(0, || { n += 1; io.outputs = n % 256; });\n";
    // `n` is carried; the new script counts by two and writes otherwise.
    let after = "let io = device(\"io\");\nlet n = 0;\n\
                 io.on_rise(0, || { n += 2; io.outputs = (n * 3) % 256; });\n";
    let half = Duration::from_secs(30);
    journaled_run_reloading(
        before,
        "count.rhai",
        &path,
        Duration::from_secs(60),
        7,
        Some((half, after)),
    );
    let journal = read_journal(&path).unwrap();
    let reloaded = journal
        .entries
        .iter()
        .find_map(|e| match &e.what {
            What::Reloaded { source, hash, .. } => Some((e.tick, source.clone(), hash.clone())),
            _ => None,
        })
        .expect("the reload journaled");
    assert_eq!(reloaded.1, after);
    assert_eq!(reloaded.2, crate::content_hash::content_hash(after));
    let outcome = replay(&journal, &Options::default()).unwrap();
    let written_after = outcome
        .recorded
        .iter()
        .filter(|e| e.tick > reloaded.0)
        .count();
    assert!(written_after >= 2, "too little written after the reload: {outcome:?}");
    assert_eq!(outcome.divergence, None);
    assert_eq!(outcome.recorded, outcome.replayed);
    assert!(
        outcome.notes.iter().any(|n| n.contains("reloaded with count.rhai")),
        "{:?}",
        outcome.notes
    );
}

#[test]
fn a_part_begun_after_a_reload_names_the_script_that_runs_by_then() {
    let d = dir();
    let path = d.path().join("rotated.journal");
    let before = "let io = device(\"io\");\nio.on_rise(0, || { io.outputs = 1; });\n\
                  io.on_fall(0, || { io.outputs = 0; });\n";
    let after = "let io = device(\"io\");\nio.on_rise(0, || { io.outputs = 2; });\n\
                 io.on_fall(0, || { io.outputs = 0; });\n";
    // Parts small enough that the run rotates once, after the reload.
    let clock = VirtualClock::at_epoch();
    let mut j = Journaled::start(None, (before, "flip.rhai"), (&path, 24 * 1024, false), &clock);
    let rig = &mut j.rig;
    for i in 0..400u32 {
        rig.runner.advance(Duration::from_millis(100));
        rig.sim.set_input("io", 0, i % 2 == 0).unwrap();
        if i == 50 {
            rig.runner.reload_at_next_tick(after.into(), "flip.rhai".into());
        }
    }
    let report = j.finish();
    assert_eq!(report.rotations, 1, "{report:?}");
    let text = std::fs::read_to_string(&path).unwrap();
    let first = text.lines().find(|l| l.starts_with("H ")).unwrap();
    let last_part: Header = serde_json::from_str(&first[2..]).unwrap();
    assert_eq!(last_part.script, after, "the part begun after the reload");
    let journal = read_journal(&path).unwrap();
    assert_eq!(journal.header.script, before, "a replay from the start runs the first");
    let outcome = replay(&journal, &Options::default()).unwrap();
    assert_eq!(outcome.divergence, None);
    assert_eq!(outcome.recorded, outcome.replayed);
}

#[test]
fn forces_and_commands_are_journaled_and_asked_again_where_the_run_took_them() {
    use crate::runtime::forcing::{ForceOrder, ForceValue};
    use crate::runtime::observe::OperatorAct;
    use crate::runtime::remote::{Command, Remote, ReplyTo};
    use crate::runtime::requests::Request;
    let d = dir();
    let path = d.path().join("operated.journal");
    let toml = "force = true\n[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/null\"\n";
    let source = "let io = device(\"io\");\nlet n = 0;\n\
                  on_command(\"add\", |p| { n += p; io.outputs = n % 128; n });\n\
                  io.on_rise(0, || { n += 1; io.outputs = n % 128; });\n";
    // As `--config rig.toml` keeps it: the replay's rig allows forcing too.
    let clock = VirtualClock::at_epoch();
    let mut j = Journaled::start(Some(toml), (source, "op.rhai"), (&path, 1 << 30, false), &clock);
    let rig = &mut j.rig;
    let (ask, requests) = crate::runtime::requests::queue(&Arc::default());
    rig.runner.serve(requests, "op.rhai", rig.sim.clone());
    let force = |on: bool| Request::Force {
        order: ForceOrder {
            point: "io.DO7".into(),
            value: ForceValue::On(on),
            duration: "1m".into(),
            overrides: Vec::new(),
        },
        by: "the test".into(),
    };
    let (reply, answers) = std::sync::mpsc::sync_channel(4);
    for step in 0..60u32 {
        rig.runner.advance(Duration::from_millis(230));
        rig.sim.set_input("io", 0, step % 3 == 0).unwrap();
        // Asked as the socket and the MQTT client ask: queued, taken between ticks.
        let request = match step {
            10 => Some(force(true)),
            20 => Some(Request::Remote(Remote::Command(Command {
                name: "add".into(),
                payload: "5".into(),
                reply: ReplyTo(reply.clone()),
            }))),
            30 => Some(Request::Unforce {
                point: "io.DO7".into(),
                by: "the test".into(),
            }),
            _ => None,
        };
        if let Some(r) = request {
            let _ = ask.ask(r, Duration::ZERO);
        }
    }
    assert_eq!(j.finish().lost, 0);
    assert!(answers.try_recv().is_ok_and(|a| a.is_ok()), "the command ran");
    let journal = read_journal(&path).unwrap();
    let acts: Vec<&OperatorAct> = journal
        .entries
        .iter()
        .filter_map(|e| match &e.what {
            What::Operated(act) => Some(act),
            _ => None,
        })
        .collect();
    assert!(
        matches!(
            acts.as_slice(),
            [
                OperatorAct::Force { .. },
                OperatorAct::Command { .. },
                OperatorAct::Unforce { .. }
            ]
        ),
        "{acts:?}"
    );
    let outcome = replay(&journal, &Options::default()).unwrap();
    let forced = outcome.recorded.iter().filter(|e| {
        matches!(&e.what, What::Outputs { value, .. } if value & 0x80 != 0)
    });
    assert!(forced.count() >= 1, "the force wrote DO7: {:?}", outcome.recorded);
    assert_eq!(outcome.divergence, None);
    assert_eq!(outcome.recorded, outcome.replayed);
}

/// A run of `source` on one module at 115200 baud (where a tick has the time for every part
/// of its image) whose DI0 goes on and off and whose DI3 counts, journaled to `path`, with
/// the whole image if `image`.
fn counted_run(source: &str, path: &Path, image: bool) {
    let toml = "[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/null\"\nbaud = 115200\n";
    let clock = VirtualClock::at_epoch();
    let mut j = Journaled::start(Some(toml), (source, "c.rhai"), (path, 1 << 30, image), &clock);
    let rig = &mut j.rig;
    for step in 0..40u32 {
        rig.runner.advance(Duration::from_millis(250));
        rig.sim.set_input("io", 0, step % 2 == 0).unwrap();
        rig.sim.pulse("io", 3, 1 + step % 5).unwrap();
    }
    assert_eq!(j.finish().lost, 0);
}

#[test]
fn a_journal_of_the_whole_image_gives_an_edit_that_reads_more_the_field_s_values() {
    let d = dir();
    let source = "let io = device(\"io\");\nio.on_rise(0, || { io.outputs = 1; });\n\
                  io.on_fall(0, || { io.outputs = 0; });\n";
    // The edit writes DI3's count, which the run's script never read.
    let edit = "let io = device(\"io\");\nevery(\"500ms\", || { io.outputs = io.counter(3) % 128; });\n";
    let options = Options {
        script: Some((edit.into(), "edit.rhai".into())),
        ..Options::default()
    };
    let mut counts = Vec::new();
    for image in [false, true] {
        let path = d.path().join(format!("image-{image}.journal"));
        counted_run(source, &path, image);
        let journal = read_journal(&path).unwrap();
        let shown = journal
            .entries
            .iter()
            .filter(|e| matches!(&e.what, What::Shown(w) if matches!(**w, What::Counters { .. })))
            .count();
        assert_eq!(shown > 0, image, "counters read for the journal: {shown}");
        let same = replay(&journal, &Options::default()).unwrap();
        assert_eq!(same.divergence, None, "the recorded script, image {image}");
        let edited = replay(&journal, &options).unwrap();
        assert_eq!(
            edited.unrecorded.is_empty(),
            image,
            "{:?}",
            edited.unrecorded
        );
        let written: Vec<u8> = edited
            .replayed
            .iter()
            .filter_map(|e| match &e.what {
                What::Outputs { value, .. } => Some(*value),
                _ => None,
            })
            .collect();
        counts.push(written);
    }
    assert!(counts[0].iter().all(|&v| v == 0), "assumed 0: {:?}", counts[0]);
    assert!(
        counts[1].windows(2).any(|w| w[1] > w[0]),
        "the counts as the field counted: {:?}",
        counts[1]
    );
}

#[test]
fn ticks_made_for_those_watching_or_asking_replay_where_the_run_made_them() {
    use crate::runtime::remote::{Command, Remote, ReplyTo};
    use crate::runtime::requests::Request;
    let d = dir();
    let path = d.path().join("watched.journal");
    // A rig idle between its timers: it ticks only when one is due, or when someone outside
    // wants a tick (a status asked, a page watching, a command).
    let source = "let io = device(\"io\");\nlet n = 0;\n\
                  every(\"500ms\", || { n += 1; io.outputs = n % 64; });\n\
                  on_command(\"bump\", |p| { n += p; io.outputs = 0x40 | n % 64;\n\
                  after(\"130ms\", || io.outputs = 0x80 | n % 64); n });\n";
    let clock = VirtualClock::at_epoch();
    let mut j = Journaled::start(None, (source, "w.rhai"), (&path, 1 << 30, false), &clock);
    let rig = &mut j.rig;
    let (ask, requests) = crate::runtime::requests::queue(&Arc::default());
    rig.runner.serve(requests, "w.rhai", rig.sim.clone());
    let (reply, answers) = std::sync::mpsc::sync_channel(8);
    for step in 0..80u64 {
        rig.runner.advance(Duration::from_millis(110 + 37 * (step % 5)));
        // Asked as `rigscript status` and the socket's commands are: taken between ticks.
        let request = match step % 13 {
            0 | 4 => Some(Request::Snapshot),
            9 => Some(Request::Remote(Remote::Command(Command {
                name: "bump".into(),
                payload: step.to_string(),
                reply: ReplyTo(reply.clone()),
            }))),
            _ => None,
        };
        if let Some(r) = request {
            let _ = ask.ask(r, Duration::ZERO);
        }
    }
    assert_eq!(j.finish().lost, 0);
    assert!(answers.try_recv().is_ok_and(|a| a.is_ok()), "a command ran");
    let journal = read_journal(&path).unwrap();
    let woken = journal
        .entries
        .iter()
        .filter(|e| matches!(e.what, What::Woken { .. }))
        .count();
    assert!(woken >= 10, "ticks made for outside askers are journaled: {woken}");
    let outcome = replay(&journal, &Options::default()).unwrap();
    assert!(outcome.recorded.len() > 30, "{:?}", outcome.recorded);
    assert_eq!(outcome.divergence, None);
    assert_eq!(outcome.recorded, outcome.replayed);
}
