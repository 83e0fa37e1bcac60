//! The runs every search plays first, whatever its seed: each counter carried to each value the
//! script compares it with and then one above, and from one below stepped over it in one scan; every input, switch and rotary the script reads worked once each way; each
//! device lost past its grace time and back. Randomness comes after (`field::generate`), so
//! whether a default pass finds such a bug does not depend on the seed.

use super::field::Gen;
use super::plan::{Action, Plan};
use super::profile::{Kind, Profile};
use crate::script::reads::Item;
use std::sync::Arc;
use std::time::Duration;

/// The systematic plans for `profile` (once it has learned what the script reads: `probe`),
/// each starting where a random run of `seed` would (its date and zone): their number does
/// not depend on the seed.
pub fn plans(profile: &Profile, seed: u64, faults: bool) -> Vec<Plan> {
    let mut themes: Vec<Vec<(Duration, Action)>> = Vec::new();
    let period = profile.period;
    let settle = period.saturating_mul(3);
    let first = Duration::from_secs(1).min(profile.run_for / 4);
    let modules = profile
        .devices
        .iter()
        .filter(|d| d.kind == Kind::C29u)
        .count();
    for (idx, d) in profile.devices.iter().enumerate() {
        let dev = &d.name;
        let mut exercise = Vec::new();
        let mut at = first;
        for (_, item) in profile.reads.items().into_iter().filter(|(i, _)| *i == idx) {
            for action in work_once(dev, item) {
                exercise.push((at, action));
                at += settle;
            }
        }
        // A counter compared in the text is this module's if it reads it, or if it is the
        // rig's only module (an `on_counter` handler waits without reading between firings).
        for ch in (0..8).filter(|_| d.kind == Kind::C29u) {
            if modules == 1 || profile.reads.contains(idx, Item::Counter(ch)) {
                for mark in profile.facts.counter_values(ch) {
                    themes.extend(around(dev, ch, mark, first, settle));
                }
            }
        }
        if !exercise.is_empty() {
            themes.push(exercise);
        }
        if faults {
            let back = first + profile.grace.saturating_mul(2) + settle;
            themes.push(vec![
                (
                    first,
                    Action::Fail {
                        dev: Arc::clone(dev),
                    },
                ),
                (
                    back,
                    Action::Restore {
                        dev: Arc::clone(dev),
                    },
                ),
            ]);
        }
    }
    themes
        .into_iter()
        .enumerate()
        .map(|(i, theme)| {
            let start = Gen::new(profile, seed ^ i as u64).start;
            let mut plan = Plan {
                start,
                events: theme
                    .into_iter()
                    .filter(|(at, _)| *at < profile.run_for)
                    .map(|(at, action)| super::plan::Event { at, action })
                    .collect(),
            };
            plan.sort();
            plan
        })
        .collect()
}

/// `item` worked once each way: an input on then off, a switch pressed then released, a
/// rotary a detent each way (counters have their own runs; the rest is not the field's).
fn work_once(dev: &Arc<str>, item: Item) -> Vec<Action> {
    let dev = || Arc::clone(dev);
    match item {
        Item::Input(ch) => vec![
            Action::Input {
                dev: dev(),
                ch,
                on: true,
            },
            Action::Input {
                dev: dev(),
                ch,
                on: false,
            },
        ],
        Item::Switch(switch) => vec![
            Action::Press { dev: dev(), switch },
            Action::Release { dev: dev(), switch },
        ],
        Item::Rotary(rotary) => vec![
            Action::Turn {
                dev: dev(),
                rotary,
                half_turns: 1,
            },
            Action::Turn {
                dev: dev(),
                rotary,
                half_turns: -1,
            },
        ],
        _ => Vec::new(),
    }
}

/// Two runs around `mark` on counter `ch`: carried to it, then one above; one below, then two
/// pulses in one scan, stepping over it. (Landing is one event, so a bug at the mark shrinks
/// to the count alone.)
fn around(
    dev: &Arc<str>,
    ch: u8,
    mark: u16,
    first: Duration,
    settle: Duration,
) -> [Vec<(Duration, Action)>; 2] {
    let below = || Action::CounterTo {
        dev: Arc::clone(dev),
        ch,
        value: mark.saturating_sub(1),
    };
    let pulses = |n| Action::Pulse {
        dev: Arc::clone(dev),
        ch,
        n,
    };
    let at = Action::CounterTo {
        dev: Arc::clone(dev),
        ch,
        value: mark,
    };
    [
        vec![(first, at), (first + settle, pulses(1))],
        vec![(first, below()), (first + settle, pulses(2))],
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::RigConfig;

    fn profile(source: &str) -> Profile {
        Profile::new(
            &RigConfig::simulated_default(),
            source,
            Duration::from_millis(20),
            Duration::from_secs(60),
        )
    }

    #[test]
    fn each_compared_count_is_landed_on_and_stepped_over_whatever_the_seed() {
        let p = profile("let io = device(\"io\"); every(\"20ms\", || io.counter(2) == 300);");
        assert!(
            p.reads.items().is_empty(),
            "nothing learned: the counter comes from the text"
        );
        for seed in [1, 2, 99] {
            let first = plans(&p, seed, true);
            let shown: Vec<Vec<String>> = first
                .iter()
                .map(|plan| plan.events.iter().map(|e| e.action.to_string()).collect())
                .collect();
            assert!(
                shown
                    .iter()
                    .any(|s| s.join("; ").contains("counter DI2 carried to 299")
                        && s.last().is_some_and(|l| l == "io DI2 2 pulse(s)")),
                "{shown:?}"
            );
            assert!(
                shown
                    .iter()
                    .any(|s| s.join("; ") == "io counter DI2 carried to 300; io DI2 1 pulse(s)"),
                "{shown:?}"
            );
            assert!(
                shown.iter().any(|s| s.join("; ") == "io lost; io back"),
                "{shown:?}"
            );
            assert_eq!(first.len(), plans(&p, seed + 1, true).len());
        }
    }

    #[test]
    fn without_faults_no_device_is_lost_and_what_the_script_reads_is_worked_each_way() {
        let mut p = profile("panel.on_press(\"S1\", || {});");
        let panel = p.devices.iter().position(|d| d.kind == Kind::Trc).unwrap();
        p.reads.add(
            panel,
            Item::Switch(crate::protocol::trc1000::Switch::from_name("S1").unwrap()),
        );
        let all = plans(&p, 1, false);
        assert!(all
            .iter()
            .flat_map(|p| &p.events)
            .all(|e| !e.action.is_fault()));
        let shown: Vec<String> = all[0].events.iter().map(|e| e.action.to_string()).collect();
        assert_eq!(shown, ["panel S1 pressed", "panel S1 released"]);
    }
}
