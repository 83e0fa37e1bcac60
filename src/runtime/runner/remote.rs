//! The loop's side of `Request::Remote`: a remote consumer's log line written, a command
//! answered by the script's `on_command` handler, a watched topic's message handed to the
//! `on_message` handlers. Run between ticks; what a handler sets to the outputs is written by
//! the next tick, after its invariants, like any handler's: a command never drives an output
//! by itself.

use super::contract::{describe, Program};
use super::Runner;
use crate::runtime::remote::{Command, Remote};
use crate::runtime::subscriptions::{Arg, Source};
use crate::runtime::topic_filter::filter_matches;

impl<P: Program> Runner<P> {
    /// Does what `remote` asks.
    pub(super) fn answer_remote(&mut self, remote: Remote) {
        match remote {
            Remote::Log { warning, message } => {
                let mut rt = self.rt.borrow_mut();
                if warning {
                    rt.log_mut().warn(&message);
                } else {
                    rt.log_mut().info(&message);
                }
            }
            Remote::Command(command) if self.ending() => {
                command.reply.send(Err("the run is ending".into()));
            }
            Remote::Command(command) => {
                let reply = self.run_command(&command);
                command.reply.send(reply);
                self.tick_soon();
            }
            Remote::Message { .. } if self.ending() => {}
            Remote::Message { topic, payload } => {
                self.hand_message(&topic, &payload);
                self.tick_soon();
            }
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
        }
    }

    /// Whether the run is ending (no handler runs for outside askers then).
    fn ending(&self) -> bool {
        self.status().is_some() || self.stop_signal().is_some()
    }

    /// Brings the next tick to the first period boundary from now: what the handler set is
    /// written there, after the invariants, even in a loop that was idle until a timer.
    fn tick_soon(&mut self) {
        let period = self.options.period.max(std::time::Duration::from_micros(1));
        let now = self.clock.now();
        if self.next_deadline > now {
            let early = (self.next_deadline - now).as_nanos() / period.as_nanos();
            let early = u32::try_from(early).unwrap_or(u32::MAX);
            self.next_deadline = self
                .next_deadline
                .saturating_sub(period.saturating_mul(early));
        }
    }

    fn run_command(&mut self, command: &Command) -> Result<String, String> {
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
            return Err(format!(
                "no handler for command {:?} (the script has no on_command({:?}, ...))",
                command.name, command.name
            ));
        };
        self.rt.borrow_mut().log_mut().info(&format!(
            "command {}: {}",
            command.name,
            shorten(&command.payload)
        ));
        match self.program.answer(&call) {
            Ok(value) => Ok(value),
            Err(fault) => {
                let message = describe(&fault, &call.label);
                // A command's failure is the asker's to hear; the run goes on.
                self.rt.borrow_mut().log_mut().warn(&message);
                Err(message)
            }
        }
    }

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
            if let Err(fault) = self.program.call(&call) {
                let message = describe(&fault, &call.label);
                self.rt.borrow_mut().log_mut().warn(&message);
            }
        }
    }
}

/// A payload as the log shows it: at most 200 characters.
fn shorten(payload: &str) -> String {
    match payload.char_indices().nth(200) {
        Some((at, _)) => format!("{}...", &payload[..at]),
        None => payload.to_string(),
    }
}
