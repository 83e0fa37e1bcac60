use super::*;
use crate::config::RigConfig;
use std::collections::BTreeMap;

const SCRIPT: &str = r#"
let io = device("io");
let panel = device("panel");
let armed = false;
panel.on_press("S12", || { if io.inputs == 0x03 { armed = true; io.outputs = 1; } });
invariant("power only with DI0 and DI1", || io.outputs == 0 || (io.inputs & 0x03) == 0x03);
"#;

fn target(source: &str) -> Target {
    Target {
        source: source.into(),
        file: "t.rhai".into(),
        script: "t.rhai".into(),
        config_file: None,
        config: RigConfig::simulated_default(),
        budget: 100_000,
        run_for: Duration::from_secs(60),
        compared: BTreeMap::new(),
    }
}

fn setup(t: &Target) -> (Vocabulary, StartPoint) {
    let mut profile = Profile::new(&t.config, &t.source, t.config.period, t.run_for);
    learn_reads(t, &mut profile);
    (Vocabulary::new(&profile, false), start_point(&profile))
}

fn choice(action: Action, until_ms: u64) -> Choice {
    Choice {
        action: Some(action),
        until: Duration::from_millis(until_ms),
        wait: None,
    }
}

fn input(ch: u8) -> Action {
    Action::Input {
        dev: Arc::from("io"),
        ch,
        on: true,
    }
}

fn state(t: &Target, v: &Vocabulary, s: &StartPoint, c: &[Choice]) -> (u128, Vec<Choice>) {
    match play(t, s, v, c).unwrap() {
        Played::State(fp, next) => (fp, next),
        Played::Failed(f) => panic!("{:?}", f.finding),
    }
}

#[test]
fn the_same_events_in_either_order_reach_one_state_and_a_different_one_another() {
    let t = target(SCRIPT);
    let (v, s) = setup(&t);
    let a = state(&t, &v, &s, &[choice(input(0), 20), choice(input(1), 40)]);
    let b = state(&t, &v, &s, &[choice(input(1), 20), choice(input(0), 40)]);
    assert_eq!(a.0, b.0, "merged");
    assert_eq!(a.1, b.1, "the same choices from there");
    let c = state(&t, &v, &s, &[choice(input(0), 20), choice(input(2), 40)]);
    assert_ne!(a.0, c.0);
    // From either, pressing S12 arms: the captured variable differs from the unarmed state.
    let press = Action::Press {
        dev: Arc::from("panel"),
        switch: Switch::from_name("S12").unwrap(),
    };
    assert!(a.1.iter().any(|c| c.action.as_ref() == Some(&press)));
}

#[test]
fn a_bug_is_found_at_the_depth_it_needs_and_no_earlier() {
    let bug = SCRIPT.replace("io.inputs == 0x03", "io.input(0)");
    let t = target(&bug);
    let opts = |depth| Options {
        depth,
        jobs: 2,
        faults: false,
        interrupt: None,
    };
    let shallow = explore(&t, &opts(1), |_, _| {}).unwrap();
    assert!(shallow.found.is_none());
    assert_eq!(shallow.complete, 1);
    assert!(result_line(&shallow).starts_with("no violation in any sequence of up to 1 events ("));
    let deep = explore(&t, &opts(3), |_, _| {}).unwrap();
    let f = deep.found.expect("DI0 on, S12 pressed");
    assert_eq!(f.choices.len(), 2, "{:?}", f.choices);
    let again = explore(&t, &opts(3), |_, _| {}).unwrap().found.unwrap();
    assert_eq!(f.choices, again.choices);
}
