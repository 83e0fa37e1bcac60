//! What the MQTT client asks of a loop (`Request::Remote`), through the library in virtual
//! time: a command answered by its `on_command` handler's value between ticks, an error reply
//! for a command with no handler, one that throws or one that loops past its budget (the run
//! goes on), a watched topic's message handed to `on_message`, and a command whose handler
//! sets an output the invariant forbids: the output is never written, the safe state is.

use rigscript::config::RigConfig;
use rigscript::runtime::remote::{Command, Remote, Reply, ReplyTo};
use rigscript::runtime::requests::{self, Request, Requester};
use rigscript::RigBuilder;
use std::sync::atomic::AtomicUsize;
use std::sync::mpsc;
use std::sync::Arc;
use std::time::Duration;

const SCRIPT: &str = r#"
invariant("DO7 never on", || (io.outputs & 0x80) == 0);
let heard = [];
on_command("set", |p| { io.outputs = p.value; io.outputs });
on_command("fail", |p| { throw "not today: " + p; });
on_command("spin", |p| { loop {} });
on_message("lab/+/status", |topic, payload| { heard.push(topic + "=" + payload); });
on_command("heard", |p| heard);
"#;

fn started() -> (rigscript::Rig, Requester) {
    let flag = Arc::new(AtomicUsize::new(0));
    let mut rig = RigBuilder::from_config(RigConfig::simulated_default())
        .simulated()
        .virtual_time_from(chrono::DateTime::UNIX_EPOCH)
        .keep_log()
        .stop_flag(Arc::clone(&flag))
        .start(SCRIPT, "remote.rhai")
        .unwrap();
    let (ask, requests) = requests::queue(&flag);
    let field = rig.sim.clone();
    rig.runner.serve(requests, "remote.rhai", field);
    (rig, ask)
}

/// Sends command `name` with `payload` and runs ticks until its reply comes.
fn command(rig: &mut rigscript::Rig, ask: &Requester, name: &str, payload: &str) -> Reply {
    let (tx, rx) = mpsc::sync_channel(1);
    let c = Command {
        name: name.into(),
        payload: payload.into(),
        reply: ReplyTo(tx),
    };
    let _ = ask.ask(Request::Remote(Remote::Command(c)), Duration::ZERO);
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
    let spun = command(&mut rig, &ask, "spin", "").unwrap_err();
    assert!(spun.contains("on_command spin"), "{spun}");
    assert_eq!(rig.runner.status(), None, "the run goes on");
    let _ = ask.ask(
        Request::Remote(Remote::Message {
            topic: "lab/bench2/status".into(),
            payload: "offline".into(),
        }),
        Duration::ZERO,
    );
    let _ = ask.ask(
        Request::Remote(Remote::Message {
            topic: "elsewhere/status".into(),
            payload: "x".into(),
        }),
        Duration::ZERO,
    );
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
