//! What the MQTT client asks of a loop (`Request::Remote`), through the library in virtual
//! time: a command answered by its `on_command` handler's value in a tick, an error reply for
//! a command with no handler or one that throws (the run goes on), one that loops past its
//! budget (a runaway under `on_error`: the run ends safe, or restarts), one command a tick
//! however many wait, bounded waiting messages, a watched topic's message handed to
//! `on_message`, and a command whose handler sets an output the invariant forbids: the output
//! is never written, the safe state is.

use crate::common;

use rigscript::config::RigConfig;
use rigscript::runtime::remote::{Command, Remote, Reply, ReplyTo};
use rigscript::runtime::requests::{Request, Requester};
use std::sync::mpsc;
use std::time::Duration;

const SCRIPT: &str = r#"
invariant("DO7 never on", || (io.outputs & 0x80) == 0);
let heard = [];
on_command("set", |p| { io.outputs = p.value; io.outputs });
on_command("fail", |p| { throw "not today: " + p; });
on_command("spin", |p| { loop {} });
on_message("lab/+/status", |topic, payload| { heard.push(topic + "=" + payload); });
on_command("heard", |p| heard);
on_command("heard_count", |p| heard.len());
let ticks = 0;
every("20ms", || { ticks += 1; });
on_command("ticks", |p| ticks);
let flood = [];
on_message("flood/#", |topic, payload| { flood.push(ticks); });
on_command("flood", |p| flood);
"#;

fn started() -> (rigscript::Rig, Requester) {
    started_with(RigConfig::simulated_default())
}

fn started_with(config: RigConfig) -> (rigscript::Rig, Requester) {
    let (rig, ask, _flag) = common::served(config, SCRIPT, "remote.rhai");
    (rig, ask)
}

/// Sends command `name` with `payload`; its reply comes on the receiver.
fn send(ask: &Requester, name: &str, payload: &str) -> mpsc::Receiver<Reply> {
    let (tx, rx) = mpsc::sync_channel(1);
    let c = Command {
        name: name.into(),
        payload: payload.into(),
        reply: ReplyTo(tx),
    };
    let _ = ask.ask(Request::Remote(Remote::Command(c)), Duration::ZERO);
    rx
}

/// Sends a message on a watched (or unwatched) `topic`.
fn message(ask: &Requester, topic: &str, payload: &str) {
    let _ = ask.ask(
        Request::Remote(Remote::Message {
            topic: topic.into(),
            payload: payload.into(),
        }),
        Duration::ZERO,
    );
}

/// Sends command `name` with `payload` and runs ticks until its reply comes.
fn command(rig: &mut rigscript::Rig, ask: &Requester, name: &str, payload: &str) -> Reply {
    let rx = send(ask, name, payload);
    for _ in 0..100 {
        rig.runner.advance(Duration::from_millis(20));
        if let Ok(reply) = rx.try_recv() {
            return reply;
        }
    }
    panic!("no reply to {name}: {:?}", rig.log());
}

/// What the simulated module drives.
fn written(rig: &rigscript::Rig) -> Option<u8> {
    rig.sim.outputs("io").ok()
}

#[test]
fn a_command_is_answered_by_its_handler_and_failures_are_error_replies_while_the_run_goes_on() {
    let (mut rig, ask) = started();
    assert_eq!(
        command(&mut rig, &ask, "set", "{\"value\":3}"),
        Ok("3".into())
    );
    rig.runner.advance(Duration::from_millis(40));
    assert_eq!(
        written(&rig),
        Some(3),
        "the next tick wrote what the handler set"
    );
    let none = command(&mut rig, &ask, "nope", "{}").unwrap_err();
    assert!(none.contains("no handler for command \"nope\""), "{none}");
    let thrown = command(&mut rig, &ask, "fail", "\"x\"").unwrap_err();
    assert!(
        thrown.contains("not today: x") && thrown.contains("remote.rhai:"),
        "{thrown}"
    );
    assert_eq!(rig.runner.status(), None, "a throw is the asker's to hear");
    message(&ask, "lab/bench2/status", "offline");
    message(&ask, "elsewhere/status", "x");
    assert_eq!(
        command(&mut rig, &ask, "heard", ""),
        Ok("[\"lab/bench2/status=offline\"]".into())
    );
}

#[test]
fn a_command_whose_handler_breaks_the_interlock_never_reaches_the_output() {
    let (mut rig, ask) = started();
    assert_eq!(
        command(&mut rig, &ask, "set", "{\"value\":128}"),
        Ok("128".into())
    );
    rig.runner.advance(Duration::from_millis(100));
    assert_eq!(rig.runner.status(), Some(1), "the invariant ended the run");
    assert_eq!(
        written(&rig),
        Some(0),
        "DO7 was never written: the safe state was"
    );
}

#[test]
fn a_command_whose_handler_loops_is_a_runaway_and_ends_the_run_safe() {
    let (mut rig, ask) = started();
    command(&mut rig, &ask, "set", "{\"value\":5}").unwrap();
    rig.runner.advance(Duration::from_millis(40));
    assert_eq!(written(&rig), Some(5));
    let spin = send(&ask, "spin", "");
    let after = send(&ask, "ticks", "");
    rig.runner.advance(Duration::from_secs(5));
    let spun = spin.try_recv().expect("a reply to spin").unwrap_err();
    assert!(spun.contains("on_command spin"), "{spun}");
    assert_eq!(
        after.try_recv().expect("a reply to the command after it"),
        Err("the run is ending".into()),
        "the command waiting behind the runaway is told, not run"
    );
    assert_eq!(rig.runner.status(), Some(1), "{:?}", rig.log());
    assert_eq!(written(&rig), Some(0), "the safe state was written");
    assert!(
        rig.log()
            .iter()
            .any(|l| l.contains("on_command spin: ran over its operation budget")),
        "{:?}",
        rig.log()
    );
}

#[test]
fn under_on_error_restart_a_looping_command_restarts_the_script_and_commands_are_refused_meanwhile()
{
    let mut config = RigConfig::simulated_default();
    config.on_error = rigscript::config::ErrorPolicy::Restart;
    let (mut rig, ask) = started_with(config);
    let spin = send(&ask, "spin", "");
    rig.runner.advance(Duration::from_millis(40));
    assert!(spin.try_recv().expect("a reply to spin").is_err());
    assert_eq!(rig.runner.status(), None, "the script restarts");
    let meanwhile = send(&ask, "ticks", "");
    rig.runner.advance(Duration::from_millis(20));
    let refused = meanwhile.try_recv().expect("a reply while restarting");
    assert!(
        refused.as_ref().is_err_and(|e| e.contains("restarting")),
        "{refused:?}"
    );
    rig.runner.advance(Duration::from_secs(2));
    assert!(
        command(&mut rig, &ask, "ticks", "").is_ok(),
        "the restarted script answers again: {:?}",
        rig.log()
    );
}

#[test]
fn commands_waiting_together_run_one_a_tick() {
    let (mut rig, ask) = started();
    rig.runner.advance(Duration::from_millis(100));
    let replies: Vec<_> = (0..4).map(|_| send(&ask, "ticks", "")).collect();
    rig.runner.advance(Duration::from_millis(200));
    let seen: Vec<i64> = replies
        .iter()
        .map(|r| r.try_recv().expect("a reply").unwrap().parse().unwrap())
        .collect();
    assert!(
        seen.windows(2).all(|w| w[1] > w[0]),
        "each command saw a tick of its own, after the one before it: {seen:?}"
    );
}

#[test]
fn watched_messages_wait_in_a_bounded_queue_and_reach_the_script_a_few_a_tick() {
    let (mut rig, ask) = started();
    rig.runner.advance(Duration::from_millis(100));
    // The control queue takes 64 at once and the loop drains 16 a turn: between two ticks,
    // turns of 14 fill the loop's own queue past its 64.
    for turn in 0..5 {
        for i in 0..14 {
            message(&ask, "flood/x", &format!("{turn}.{i}"));
        }
        let now = rig.runner.runtime().borrow().now();
        rig.runner
            .wait_between_ticks(now + Duration::from_millis(1));
    }
    rig.runner.advance(Duration::from_millis(400));
    let seen: Vec<i64> = serde_json::from_str(&command(&mut rig, &ask, "flood", "").unwrap())
        .expect("a JSON array of tick counts");
    assert_eq!(
        seen.len(),
        64,
        "the queue's 64 reached the script, the rest were dropped"
    );
    let most_in_a_tick = seen
        .chunk_by(|a, b| a == b)
        .map(<[i64]>::len)
        .max()
        .unwrap_or(0);
    assert_eq!(
        most_in_a_tick, 8,
        "eight a tick, each tick its own timer's count: {seen:?}"
    );
    assert!(
        rig.log()
            .iter()
            .any(|l| l.contains("on_message: 1 message(s) on watched topics dropped")),
        "the first drop is told (the next within the minute only counted): {:?}",
        rig.log()
    );
}
