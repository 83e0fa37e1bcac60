//! What a remote consumer of the run (the MQTT client, `service::mqtt`) asks of the loop,
//! through the control queue (`Request::Remote`): a line for the run's log, a command or a
//! watched topic's message for the script's handler. Taken between ticks like every
//! request; a command or a message then waits for a tick to run its handler
//! (`runner::remote`), and a command's reply goes back on a channel of its own, so the asker
//! never waits on the loop.

use crate::runtime::log::Level;
use crate::runtime::snapshot::MqttState;
use std::sync::mpsc::SyncSender;

/// What the remote consumer shares with the loop through its `Requester`
/// (`Requester::share`): where the loop counts what it turned away, beside the consumer's own
/// losses, and the consumer's state as the run's snapshot shows it.
pub trait RemoteState: Send + Sync {
    /// The loop turned away a command or a message the consumer sent.
    fn turned_away(&self, what: TurnedAway);
    /// The consumer's state, for the snapshot (`status`, `/metrics`).
    fn shown(&self) -> MqttState;
}

/// What the loop turned away.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TurnedAway {
    /// A command refused (too many waiting, the run ending or restarting).
    Command,
    /// A watched topic's message dropped (too many waiting, the script restarting).
    Message,
}

/// A request from a remote consumer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Remote {
    /// A line for the run's log, from a thread that has no log of its own.
    Log {
        /// How much it matters (info, warning or error).
        level: Level,
        /// The line.
        message: String,
    },
    /// An inbound command for the script's `on_command` handler of its name.
    Command(Command),
    /// The topic filters the script's `on_message` handlers watch, as a JSON array of strings
    /// (the client subscribes to them on the broker).
    Watched(ReplyTo),
    /// A message on a topic the script watches (`on_message`).
    Message {
        /// The topic it came on.
        topic: String,
        /// Its payload, as text.
        payload: String,
    },
}

/// A command: its name, its payload, and where its reply goes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Command {
    /// The command's name (`{prefix}/cmd/NAME`).
    pub name: String,
    /// Its payload, as text (JSON when it parses as JSON).
    pub payload: String,
    /// Where the reply goes.
    pub reply: ReplyTo,
}

/// A command's reply: the handler's return value as JSON text, or why there is none.
pub type Reply = Result<String, String>;

/// The channel a command's reply goes back on (compared as equal whatever it is: a request's
/// identity is its name and payload).
#[derive(Debug, Clone)]
pub struct ReplyTo(pub SyncSender<Reply>);

impl PartialEq for ReplyTo {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl Eq for ReplyTo {}

impl ReplyTo {
    /// Sends the reply; an asker that gave up is no concern of the loop's.
    pub fn send(&self, reply: Reply) {
        let _ = self.0.try_send(reply);
    }
}
