//! Scenario tests written in Rust: scripts/interlock.rhai on simulated devices in virtual time,
//! the field played from the test (guards opening, buttons pressed, the module unplugged), and
//! assertions on what the simulated module drives. The same checks as
//! scripts/tests/interlock.test.rhai, for projects that keep their tests in Rust.
//!
//! ```sh
//! cargo run --example scenario_test        # runs each scenario, prints ok/FAIL
//! cargo test --example scenario_test       # the same scenarios as #[test]s
//! ```
//!
//! Virtual time: `advance` runs every tick due and moves the clock without sleeping, so the
//! six seconds of the lost-module scenario take milliseconds.

use rigscript::config::RigConfig;
use rigscript::{Rig, RigBuilder};
use std::process::ExitCode;
use std::time::Duration;

const INTERLOCK: &str = include_str!("../scripts/interlock.rhai");
const POWER: u8 = 0x0F;
const TRIP_LAMP: u8 = 0x80;

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

/// The interlock on the default simulated rig (`panel`, `io`), its first reading taken.
fn interlock() -> Rig {
    let mut rig = RigBuilder::from_config(RigConfig::simulated_default())
        .simulated()
        .virtual_time_from("2026-03-28T12:00:00Z".parse().expect("a valid time"))
        .log_to_stderr(false)
        .keep_log()
        .start(INTERLOCK, "scripts/interlock.rhai")
        .expect("the interlock starts");
    rig.runner.advance(ms(40));
    rig
}

/// Guards closed, S12 pressed and released: power on.
fn armed() -> Rig {
    let mut rig = interlock();
    rig.sim.set_inputs("io", 0x0F).unwrap();
    rig.runner.advance(ms(40));
    rig.sim.set_switch("panel", "S12", true).unwrap();
    rig.runner.advance(ms(40));
    rig.sim.set_switch("panel", "S12", false).unwrap();
    rig.runner.advance(ms(40));
    rig
}

fn outputs(rig: &Rig) -> u8 {
    rig.sim.outputs("io").unwrap()
}

fn starts_tripped_with_power_off() {
    let mut rig = interlock();
    rig.runner.advance(ms(100));
    assert_eq!(outputs(&rig), TRIP_LAMP);
}

fn reset_arms_only_with_all_guards_closed() {
    let mut rig = interlock();
    rig.sim.set_inputs("io", 0x07).unwrap();
    rig.runner.advance(ms(40));
    rig.sim.set_switch("panel", "S12", true).unwrap();
    rig.runner.advance(ms(40));
    assert_eq!(outputs(&rig), TRIP_LAMP, "guard 3 open: refused");
    assert_eq!(outputs(&armed()), POWER);
}

fn an_opening_guard_trips_until_reset() {
    let mut rig = armed();
    rig.sim.set_input("io", 2, false).unwrap();
    rig.runner.advance(ms(40));
    assert_eq!(outputs(&rig), TRIP_LAMP, "power off at once");
    rig.sim.set_input("io", 2, true).unwrap();
    rig.runner.advance(ms(200));
    assert_eq!(outputs(&rig), TRIP_LAMP, "latched until reset");
    rig.sim.set_switch("panel", "S12", true).unwrap();
    rig.runner.advance(ms(40));
    assert_eq!(outputs(&rig), POWER, "re-armed");
}

fn a_lost_module_trips_and_stays_tripped_when_it_returns() {
    let mut rig = armed();
    rig.sim.set_gone("io", true).unwrap();
    rig.runner.advance(Duration::from_secs(3));
    rig.sim.set_gone("io", false).unwrap();
    rig.runner.advance(Duration::from_secs(3));
    assert_eq!(
        outputs(&rig),
        TRIP_LAMP,
        "back, but tripped until a person resets"
    );
    let records = rig.records();
    let last = records.last().expect("the trip was recorded");
    assert_eq!(last["name"], "trip");
    assert_eq!(last["value"], "I/O module offline");
    assert!(
        rig.log()
            .iter()
            .any(|l| l.contains("TRIP: I/O module offline")),
        "{:#?}",
        rig.log()
    );
}

fn a_stop_signal_ends_with_the_outputs_safe() {
    let mut rig = armed();
    rig.runner.signal_stop();
    assert_eq!(rig.runner.status(), Some(143), "128 + SIGTERM");
    assert_eq!(outputs(&rig), 0x00, "the configured safe value");
}

/// Every scenario, by name.
const SCENARIOS: [(&str, fn()); 5] = [
    (
        "starts_tripped_with_power_off",
        starts_tripped_with_power_off,
    ),
    (
        "reset_arms_only_with_all_guards_closed",
        reset_arms_only_with_all_guards_closed,
    ),
    (
        "an_opening_guard_trips_until_reset",
        an_opening_guard_trips_until_reset,
    ),
    (
        "a_lost_module_trips_and_stays_tripped_when_it_returns",
        a_lost_module_trips_and_stays_tripped_when_it_returns,
    ),
    (
        "a_stop_signal_ends_with_the_outputs_safe",
        a_stop_signal_ends_with_the_outputs_safe,
    ),
];

fn main() -> ExitCode {
    let mut failed = 0;
    for (name, scenario) in SCENARIOS {
        // An assertion that fails panics; catch it to report every scenario.
        match std::panic::catch_unwind(scenario) {
            Ok(()) => println!("ok   {name}"),
            Err(_) => {
                failed += 1;
                println!("FAIL {name}");
            }
        }
    }
    println!("{} passed, {failed} failed", SCENARIOS.len() - failed);
    if failed == 0 {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn starts_tripped_with_power_off() {
        super::starts_tripped_with_power_off();
    }

    #[test]
    fn reset_arms_only_with_all_guards_closed() {
        super::reset_arms_only_with_all_guards_closed();
    }

    #[test]
    fn an_opening_guard_trips_until_reset() {
        super::an_opening_guard_trips_until_reset();
    }

    #[test]
    fn a_lost_module_trips_and_stays_tripped_when_it_returns() {
        super::a_lost_module_trips_and_stays_tripped_when_it_returns();
    }

    #[test]
    fn a_stop_signal_ends_with_the_outputs_safe() {
        super::a_stop_signal_ends_with_the_outputs_safe();
    }
}
