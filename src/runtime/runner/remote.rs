//! The loop's side of `Request::Remote`: a remote consumer's log line written, a command
//! answered by the script's `on_command` handler, a watched topic's message handed to the
//! `on_message` handlers. A command or a message waits in a bounded queue (`Waiting`) and runs
//! in a tick, with the tick's handlers: at most one command and `MESSAGES_PER_TICK` messages
//! a tick, so however many an asker sends, every tick between them reads inputs, checks the
//! invariants and writes; what a handler sets is written by that tick after its invariants,
//! like any handler's: a command never drives an output by itself. A handler past its limits
//! is a script fault under `on_error`, whoever sent what it handled.

use super::contract::{describe, HandlerFault, Program};
use super::{Runner, State};
use crate::runtime::handlers::{Arg, Source};
use crate::runtime::observe::{EventKind, OperatorAct, RunEvent};
use crate::runtime::remote::{Command, Remote, TurnedAway};
use crate::runtime::requests::Request;
use crate::runtime::topic_filter::filter_matches;
use std::collections::VecDeque;
use std::time::Duration;

/// Commands that may wait for a tick (the MQTT client holds at most 16 unanswered).
pub const WAITING_COMMANDS: usize = 16;
/// Watched messages that may wait for a tick; more are dropped and counted.
pub const WAITING_MESSAGES: usize = 64;
/// Watched messages handed to the script in one tick (with at most one command).
pub const MESSAGES_PER_TICK: usize = 8;
/// How often dropped messages are told in the log at most (each is counted at once).
const TELL_DROPS_EVERY: Duration = Duration::from_secs(60);

/// What waits for a tick to run its handler, in the order it came.
#[derive(Debug, Default)]
pub(super) struct Waiting {
    queue: VecDeque<Waiter>,
    commands: usize,
    /// Messages dropped since the last time that was told.
    dropped: u64,
    /// When dropped messages were last told in the log.
    told: Option<Duration>,
}

/// One command or message waiting.
#[derive(Debug)]
enum Waiter {
    Command(Command),
    Message { topic: String, payload: String },
}

impl Waiting {
    /// Whether nothing waits.
    pub(super) fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }

    fn messages(&self) -> usize {
        self.queue.len() - self.commands
    }

    fn push(&mut self, waiter: Waiter) {
        if matches!(waiter, Waiter::Command(_)) {
            self.commands += 1;
        }
        self.queue.push_back(waiter);
    }

    /// What one tick runs, in order: up to the second command or the `MESSAGES_PER_TICK`+1st
    /// message, whichever comes first.
    fn take_for_a_tick(&mut self) -> Vec<Waiter> {
        let (mut commands, mut messages) = (0, 0);
        let mut taken = Vec::new();
        while let Some(next) = self.queue.front() {
            match next {
                Waiter::Command(_) if commands == 1 => break,
                Waiter::Command(_) => commands += 1,
                Waiter::Message { .. } if messages == MESSAGES_PER_TICK => break,
                Waiter::Message { .. } => messages += 1,
            }
            taken.extend(self.queue.pop_front());
        }
        self.commands -= commands;
        taken
    }

    fn take_all(&mut self) -> Vec<Waiter> {
        self.commands = 0;
        self.queue.drain(..).collect()
    }
}

impl<P: Program> Runner<P> {
    /// Takes what `remote` asks: a log line or the watched filters at once, a command or a
    /// message into the queue for the next tick (refused or dropped when it is full, or when
    /// no handler can run now); `answer_requests` then brings that tick near.
    pub(super) fn take_remote(&mut self, remote: Remote) {
        match remote {
            Remote::Log { level, message } => self.rt.borrow_mut().log_mut().line(level, &message),
            Remote::Watched(reply) => {
                let rt = self.rt.borrow();
                let filters: Vec<&str> = rt
                    .handlers()
                    .remote_calls(|s| matches!(s, Source::Message(_)))
                    .into_iter()
                    .filter_map(|s| match &s.source {
                        Source::Message(f) => Some(f.as_str()),
                        _ => None,
                    })
                    .collect();
                reply.send(Ok(serde_json::Value::from(filters).to_string()));
            }
            Remote::Command(command) => self.queue_command(command),
            Remote::Message { topic, payload } => self.queue_message(topic, payload),
        }
    }

    fn queue_command(&mut self, command: Command) {
        let refused = match (self.refusal(), &self.served) {
            (Some(why), _) => Some(why),
            (None, None) => Some("the run has ended".to_string()),
            (None, Some(s)) if s.waiting.commands >= WAITING_COMMANDS => Some(format!(
                "{WAITING_COMMANDS} commands wait for the rig already; try again"
            )),
            (None, Some(_)) => None,
        };
        if let Some(why) = refused {
            self.count_loss(TurnedAway::Command);
            command.reply.send(Err(why));
            return;
        }
        if let Some(s) = self.served.as_mut() {
            s.waiting.push(Waiter::Command(command));
        }
    }

    fn queue_message(&mut self, topic: String, payload: String) {
        if self.ending() {
            return;
        }
        let restarting = self.refusal().is_some();
        let now = self.clock.now();
        let Some(waiting) = self.served.as_mut().map(|s| &mut s.waiting) else {
            return;
        };
        if !restarting && waiting.messages() < WAITING_MESSAGES {
            waiting.push(Waiter::Message { topic, payload });
            return;
        }
        waiting.dropped = waiting.dropped.saturating_add(1);
        let tell = waiting
            .told
            .map_or(true, |at| now.saturating_sub(at) >= TELL_DROPS_EVERY);
        let dropped = waiting.dropped;
        if tell {
            waiting.told = Some(now);
            waiting.dropped = 0;
        }
        self.count_loss(TurnedAway::Message);
        if tell {
            let why = if restarting {
                "the script is restarting".to_string()
            } else {
                format!(
                    "{WAITING_MESSAGES} wait for the script already, which takes \
                     {MESSAGES_PER_TICK} a tick"
                )
            };
            self.rt.borrow_mut().log_mut().warn(&format!(
                "on_message: {dropped} message(s) on watched topics dropped ({why}); told at \
                 most once a minute, counted in status"
            ));
        }
    }

    /// Why no command can run now, if none can: the run ends, or the script restarts.
    fn refusal(&self) -> Option<String> {
        if self.ending() {
            return Some("the run is ending".into());
        }
        match self.state {
            State::Restarting { .. } => {
                Some("the script is restarting after an error; try again shortly".into())
            }
            _ => None,
        }
    }

    /// Runs what waits, in the tick after its handlers: the first command, then up to
    /// `MESSAGES_PER_TICK` messages; while the script is not running, refuses the commands
    /// and drops the messages instead.
    pub(super) fn run_waiting(&mut self) {
        let Some(waiting) = self.served.as_mut().map(|s| &mut s.waiting) else {
            return;
        };
        for waiter in waiting.take_for_a_tick() {
            if !self.can_run_remote() {
                self.refuse(waiter);
                continue;
            }
            match waiter {
                Waiter::Command(command) => {
                    self.tell_operated(|| {
                        Some(OperatorAct::Command {
                            name: command.name.clone(),
                            payload: command.payload.clone(),
                        })
                    });
                    self.run_command(&command);
                }
                Waiter::Message { topic, payload } => {
                    self.tell_operated(|| {
                        Some(OperatorAct::Message {
                            topic: topic.clone(),
                            payload: payload.clone(),
                        })
                    });
                    self.hand_message(&topic, &payload);
                }
            }
        }
        if !self.can_run_remote() {
            self.refuse_waiting();
        }
    }

    /// Tells what `act` makes (a consumer that takes `Operated`: the journal).
    pub(super) fn tell_operated(&self, act: impl FnOnce() -> Option<OperatorAct>) {
        if self.events.wants(EventKind::Operated) {
            if let Some(act) = act() {
                self.events.publish(|| RunEvent::Operated { act });
            }
        }
    }

    /// Lets a replay ask what the journal says an operator asked (`act`), through the
    /// control queue `ask` feeds (`serve`), and takes it at once, as the run took it between
    /// ticks: a force now, a command or a message at the next tick.
    pub fn ask_replayed(&mut self, ask: &crate::runtime::requests::Requester, act: &OperatorAct) {
        let by = |by: &str| format!("{by} (replayed)");
        let request = match act {
            OperatorAct::Force { order, by: who } => Request::Force {
                order: order.clone(),
                by: by(who),
            },
            OperatorAct::Unforce { point, by: who } => Request::Unforce {
                point: point.clone(),
                by: by(who),
            },
            OperatorAct::Command { name, payload } => {
                // Nobody waits for the reply.
                let (reply, _) = std::sync::mpsc::sync_channel(1);
                Request::Remote(Remote::Command(Command {
                    name: name.clone(),
                    payload: payload.clone(),
                    reply: crate::runtime::remote::ReplyTo(reply),
                }))
            }
            OperatorAct::Message { topic, payload } => Request::Remote(Remote::Message {
                topic: topic.clone(),
                payload: payload.clone(),
            }),
        };
        // Queued at once: the answer is taken below, on this thread.
        let _ = ask.ask(request, Duration::ZERO);
        self.answer_requests();
    }

    /// Answers every waiting command with why it cannot run and drops the waiting messages
    /// (the run ends or restarts).
    pub(super) fn refuse_waiting(&mut self) {
        let Some(served) = self.served.as_mut() else {
            return;
        };
        for waiter in served.waiting.take_all() {
            self.refuse(waiter);
        }
    }

    /// Tells a waiting command why it does not run, or counts a message dropped.
    fn refuse(&self, waiter: Waiter) {
        match waiter {
            Waiter::Command(command) => {
                self.count_loss(TurnedAway::Command);
                let why = self
                    .refusal()
                    .unwrap_or_else(|| "the run has ended".to_string());
                command.reply.send(Err(why));
            }
            Waiter::Message { .. } => self.count_loss(TurnedAway::Message),
        }
    }

    /// Whether a remote handler may run now: the script runs and nothing asked it to end.
    fn can_run_remote(&self) -> bool {
        self.state == State::Running
            && !self.ending()
            && self.rt.borrow().stop_requested().is_none()
    }

    /// Counts what was not delivered where `status` and `/metrics` show the client's drops.
    fn count_loss(&self, what: TurnedAway) {
        if let Some(remote) = self.served.as_ref().and_then(|s| s.requests.remote()) {
            remote.turned_away(what);
        }
    }

    /// Whether the run is ending (no handler runs for outside askers then).
    fn ending(&self) -> bool {
        self.status().is_some() || self.stop_signal().is_some()
    }

    /// Brings the next tick to the first period boundary from now, after the last tick's:
    /// what waits runs there, and what its handler set is written there, after the
    /// invariants, even in a loop that was idle until a timer; never a second tick on one
    /// boundary. Told as `RunEvent::Woken` as that tick starts, when it moved it.
    pub fn tick_soon(&mut self) {
        let period = self.options.period.max(Duration::from_micros(1));
        let now = self.clock.now();
        if self.next_deadline > now {
            let early = (self.next_deadline - now).as_nanos() / period.as_nanos();
            let early = u32::try_from(early).unwrap_or(u32::MAX);
            let soon = self
                .next_deadline
                .saturating_sub(period.saturating_mul(early));
            let after_last = self
                .rt
                .borrow()
                .cycle()
                .boundary()
                .map_or(soon, |last| last.saturating_add(period));
            let soon = soon.max(after_last);
            if soon < self.next_deadline {
                self.next_deadline = soon;
                self.woken = Some(self.periods_after_last(soon));
            }
        }
    }

    /// Runs `command`'s handler and sends its reply, before what a runaway handler does to
    /// the run (whose end answers the commands waiting behind it).
    fn run_command(&mut self, command: &Command) {
        match self.answer_command(command) {
            Ok(value) => command.reply.send(Ok(value)),
            Err((message, fault)) => {
                command.reply.send(Err(message.clone()));
                if let Some((fault, label)) = fault {
                    self.remote_fault(&fault, &label, &message);
                }
            }
        }
    }

    /// The command's reply, or why there is none and the handler's fault with its label.
    fn answer_command(&mut self, command: &Command) -> Result<String, Unanswered> {
        let call = {
            let rt = self.rt.borrow();
            let handlers = rt.handlers();
            let found =
                handlers.remote_calls(|s| matches!(s, Source::Command(n) if *n == command.name));
            found
                .last()
                .map(|s| s.call(vec![Arg::Json(command.payload.clone())]))
        };
        let Some(call) = call else {
            let why = format!(
                "no handler for command {:?} (the script has no on_command({:?}, ...))",
                command.name, command.name
            );
            return Err((why, None));
        };
        {
            let mut rt = self.rt.borrow_mut();
            rt.log_mut().info(&format!(
                "command {}: {}",
                command.name,
                shorten(&command.payload)
            ));
            rt.feed_watchdogs();
            rt.set_cause(&call.label);
        }
        match self.program.answer(&call) {
            Ok(value) => Ok(value),
            Err(fault) => Err((
                describe(&fault, &call.label),
                Some((fault, call.label.to_string())),
            )),
        }
    }

    /// Hands one message to the handlers watching its topic, until one of them ends the run
    /// or its script (past its limits).
    fn hand_message(&mut self, topic: &str, payload: &str) {
        let calls: Vec<_> = {
            let rt = self.rt.borrow();
            rt.handlers()
                .remote_calls(|s| matches!(s, Source::Message(f) if filter_matches(f, topic)))
                .into_iter()
                .map(|s| {
                    s.call(vec![
                        Arg::Str(topic.to_string()),
                        Arg::Json(payload.to_string()),
                    ])
                })
                .collect()
        };
        for call in calls {
            {
                let mut rt = self.rt.borrow_mut();
                rt.feed_watchdogs();
                rt.set_cause(&call.label);
            }
            if let Err(fault) = self.program.call(&call) {
                let message = describe(&fault, &call.label);
                self.remote_fault(&fault, &call.label, &message);
            }
            if !self.can_run_remote() {
                return;
            }
        }
    }

    /// What a remote handler's failure (told as `message`) does: one that throws is the
    /// asker's to hear (a warning, the run goes on: a bad payload must not stop the rig); one
    /// past its limits is a runaway, handled by `on_error` as any handler's (never skipped),
    /// so a command cannot hold the loop for a budget after a budget.
    fn remote_fault(&mut self, fault: &HandlerFault, label: &str, message: &str) {
        if fault.over_budget {
            self.handle_fault(fault, label);
        } else {
            self.rt.borrow_mut().log_mut().warn(message);
        }
    }
}

/// Why a command got no value: the error reply, and the handler's fault with its label when
/// its handler ran and failed.
type Unanswered = (String, Option<(HandlerFault, String)>);

/// A payload as the log shows it: at most 200 characters.
fn shorten(payload: &str) -> String {
    match payload.char_indices().nth(200) {
        Some((at, _)) => format!("{}...", &payload[..at]),
        None => payload.to_string(),
    }
}
