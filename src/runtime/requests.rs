//! The one way into a running loop: a bounded queue of typed requests, drained by the loop at
//! tick boundaries and in its sleep slices, each answered (`Answer`). Whoever asks (the
//! control socket, later the web page or the broker) holds a `Requester` and never touches the
//! runtime.
//!
//! A stop is urgent and may come from a signal handler, which can only set a word: stops go
//! through the run's stop flag (`RunOptions::stop_flag`: it also cuts an exchange under way
//! short), signals by their number, a requested stop as `SIGTERM` with who asked kept beside
//! it. Everything else waits in the queue for the loop.

use super::devices::SimRig;
use super::forcing::ForceOrder;
use super::remote::RemoteState;
use super::snapshot::RigSnapshot;
use crate::sync::lock;
use crate::time::doorbell::Doorbell;
use serde::{Deserialize, Serialize};
use signal_hook::consts::SIGTERM;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Duration;

/// Requests waiting for the loop at most; one more is refused at once (`AskError::Busy`).
pub const QUEUE: usize = 64;

/// Requests the loop answers in one go at most, so a flood costs one slice a bounded time.
pub const PER_TURN: usize = 16;

/// What can be asked of a running loop.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Request {
    /// The run as it stands.
    Snapshot,
    /// An action on a simulated device's field, applied at a tick boundary.
    Drive(Drive),
    /// Forces a point for a while (`runtime::forcing`), asked by `by`.
    Force {
        /// The point, the value and how long.
        order: ForceOrder,
        /// Who asks, for the log and the record.
        by: String,
    },
    /// Ends the force on `point`, asked by `by`.
    Unforce {
        /// `DEVICE.POINT`.
        point: String,
        /// Who asks.
        by: String,
    },
    /// What a remote consumer (the MQTT client) asks: a log line, a command, a message.
    Remote(super::remote::Remote),
    /// Replaces the script at a tick boundary, outputs and devices kept (`runner::reload`):
    /// `source` was read from `file` and passed `check` (and the reload tests) off the loop.
    /// Answered once the swap is done or refused.
    Reload {
        /// The new script's text.
        source: String,
        /// Its file, as the log and the snapshot name it.
        file: String,
        /// Who asks.
        by: String,
    },
}

/// The most pulses one `pulse` action gives (a counter counts to 65535 and wraps).
pub const MAX_PULSES: u32 = 65_536;

/// An action on a simulated device, named as the scenario API names it (`r.press`, ...).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Drive {
    /// The device's name in the rig.
    pub device: String,
    /// What to do to it.
    #[serde(flatten)]
    pub action: FieldAction,
}

/// What can be done to a simulated device's field.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "action", rename_all = "snake_case")]
pub enum FieldAction {
    /// Presses a TRC1000 switch (`S12`).
    Press {
        /// The switch.
        name: String,
    },
    /// Releases a TRC1000 switch.
    Release {
        /// The switch.
        name: String,
    },
    /// Turns a TRC1000 rotary (`S41A`) by half turns (negative: the other way).
    Turn {
        /// The rotary.
        name: String,
        /// How far.
        half_turns: i32,
    },
    /// Sets a TRP-C29U's energized inputs (bit n: DIn).
    SetInputs {
        /// The byte.
        value: u8,
    },
    /// Energizes or releases one TRP-C29U input.
    SetInput {
        /// The channel, 0-7.
        channel: u8,
        /// Energized or not.
        on: bool,
    },
    /// Gives pulses to one TRP-C29U input (its counter counts them).
    Pulse {
        /// The channel, 0-7.
        channel: u8,
        /// How many (at most `MAX_PULSES`).
        count: u32,
    },
    /// Makes the device stop answering (a pulled cable).
    Fail,
    /// Makes it answer again.
    Restore,
}

impl Drive {
    /// Does it to `field`'s simulator of the device; says why not when it cannot be done.
    pub fn apply(&self, field: &SimRig) -> Result<(), String> {
        let d = self.device.as_str();
        if field.get(d).is_err() {
            return Err(if field.is_empty() {
                "this run drives real devices: drive acts on simulators only (run --sim, \
                 --sim-device, or sim = true in rig.toml)"
                    .to_string()
            } else {
                let known = field.names().join(", ");
                format!("{d} is not a simulated device of this rig (simulated: {known})")
            });
        }
        let done = match &self.action {
            FieldAction::Press { name } => field.set_switch(d, name, true),
            FieldAction::Release { name } => field.set_switch(d, name, false),
            FieldAction::Turn { name, half_turns } => field.turn(d, name, *half_turns),
            FieldAction::SetInputs { value } => field.set_inputs(d, *value),
            FieldAction::SetInput { channel, on } => field.set_input(d, *channel, *on),
            FieldAction::Pulse { count, .. } if *count > MAX_PULSES => {
                return Err(format!("at most {MAX_PULSES} pulses at once"))
            }
            FieldAction::Pulse { channel, count } => field.pulse(d, *channel, *count),
            FieldAction::Fail => field.set_gone(d, true),
            FieldAction::Restore => field.set_gone(d, false),
        };
        done.map_err(|e| e.to_string())
    }
}

/// The loop's answer to a request.
#[derive(Debug, Clone, PartialEq)]
pub enum Answer {
    /// The snapshot asked for.
    Snapshot(Arc<RigSnapshot>),
    /// Done as asked.
    Accepted,
    /// Not done, and why.
    Refused(String),
}

/// Why a request got no answer.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AskError {
    /// The queue is full: the loop is behind on requests.
    #[error("the run has {QUEUE} requests waiting already; try again")]
    Busy,
    /// The run has ended (or is ending) and answers nothing more.
    #[error("the run has ended")]
    Gone,
    /// No answer in time.
    #[error("no answer from the run within {}", crate::time::duration::format_duration(*.0))]
    NoAnswer(Duration),
}

struct Envelope {
    request: Request,
    reply: SyncSender<Answer>,
}

/// A request the loop answers later (a reload waits for the next tick).
pub struct Later {
    /// What was asked.
    pub request: Request,
    reply: SyncSender<Answer>,
}

impl Later {
    /// Answers it (an asker that gave up is no concern of the loop's).
    pub fn answer(self, answer: Answer) {
        let _ = self.reply.try_send(answer);
    }
}

/// What asks: cheap to clone, `Send`, one per service.
#[derive(Clone)]
pub struct Requester {
    queue: SyncSender<Envelope>,
    stop: Arc<AtomicUsize>,
    stopped_by: Arc<Mutex<Option<String>>>,
    bell: Doorbell,
    remote: Shared,
}

/// What the loop drains.
pub struct Requests {
    queue: Receiver<Envelope>,
    stopped_by: Arc<Mutex<Option<String>>>,
    bell: Doorbell,
    remote: Shared,
}

/// The remote consumer's state, once it shared it.
type Shared = Arc<OnceLock<Box<dyn RemoteState>>>;

/// A queue into a loop whose stop flag is `stop`.
pub fn queue(stop: &Arc<AtomicUsize>) -> (Requester, Requests) {
    let (tx, rx) = mpsc::sync_channel(QUEUE);
    let stopped_by = Arc::new(Mutex::new(None));
    let bell = Doorbell::default();
    let remote = Shared::default();
    (
        Requester {
            queue: tx,
            stop: Arc::clone(stop),
            stopped_by: Arc::clone(&stopped_by),
            bell: bell.clone(),
            remote: Arc::clone(&remote),
        },
        Requests {
            queue: rx,
            stopped_by,
            bell,
            remote,
        },
    )
}

impl Requester {
    /// Asks `request` and waits at most `wait` for the answer.
    pub fn ask(&self, request: Request, wait: Duration) -> Result<Answer, AskError> {
        let (reply, answer) = mpsc::sync_channel(1);
        match self.queue.try_send(Envelope { request, reply }) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => return Err(AskError::Busy),
            Err(TrySendError::Disconnected(_)) => return Err(AskError::Gone),
        }
        self.bell.ring();
        match answer.recv_timeout(wait) {
            Ok(a) => Ok(a),
            Err(RecvTimeoutError::Timeout) => Err(AskError::NoAnswer(wait)),
            Err(RecvTimeoutError::Disconnected) => Err(AskError::Gone),
        }
    }

    /// Asks the run to stop as SIGTERM would (on_stop, the safe state, exit status 143),
    /// saying who asked (`by`, for the log); an ending already under way is left as it is.
    pub fn stop(&self, by: &str) {
        *lock(&self.stopped_by) = Some(by.to_string());
        let first = self
            .stop
            .compare_exchange(
                0,
                usize::try_from(SIGTERM).unwrap_or(15),
                Ordering::SeqCst,
                Ordering::SeqCst,
            )
            .is_ok();
        if !first {
            // A signal (or an earlier request) is ending the run: the log names that one.
            *lock(&self.stopped_by) = None;
        }
        self.bell.ring();
    }
}

impl Requester {
    /// Shares the remote consumer's `state` with the loop (once: a second is ignored).
    pub fn share(&self, state: Box<dyn RemoteState>) {
        let _ = self.remote.set(state);
    }
}

impl Requests {
    /// The state the remote consumer shared, if it did.
    pub fn remote(&self) -> Option<&dyn RemoteState> {
        self.remote.get().map(Box::as_ref)
    }

    /// Answers the requests waiting (at most `PER_TURN`), each with `answer`; those it gives
    /// no answer to yet (`None`) are returned, to be answered later (`Later::answer`).
    pub fn drain(&self, mut answer: impl FnMut(&Request) -> Option<Answer>) -> Vec<Later> {
        let mut later = Vec::new();
        for envelope in self.queue.try_iter().take(PER_TURN) {
            match answer(&envelope.request) {
                // An asker that gave up is no concern of the loop's.
                Some(a) => {
                    let _ = envelope.reply.try_send(a);
                }
                None => later.push(Later {
                    request: envelope.request,
                    reply: envelope.reply,
                }),
            }
        }
        later
    }

    /// Who asked for the stop under way, if it was asked for rather than signalled.
    pub fn stopped_by(&self) -> Option<String> {
        lock(&self.stopped_by).clone()
    }

    /// What wakes the loop's sleep when a request comes.
    pub fn bell(&self) -> &Doorbell {
        &self.bell
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_request_is_answered_by_whoever_drains_the_queue() {
        let stop = Arc::new(AtomicUsize::new(0));
        let (ask, requests) = queue(&stop);
        let loop_side = std::thread::spawn(move || {
            while !requests.bell().wait(Duration::from_secs(10)) {}
            requests.drain(|_| Some(Answer::Refused("not today".into())));
        });
        let answer = ask.ask(Request::Snapshot, Duration::from_secs(10));
        assert_eq!(answer, Ok(Answer::Refused("not today".into())));
        loop_side.join().unwrap();
    }

    #[test]
    fn a_request_left_for_later_is_answered_when_the_loop_gets_to_it() {
        let stop = Arc::new(AtomicUsize::new(0));
        let (ask, requests) = queue(&stop);
        let asking = std::thread::spawn(move || {
            let reload = Request::Reload {
                source: "x".into(),
                file: "a.rhai".into(),
                by: "me".into(),
            };
            ask.ask(reload, Duration::from_secs(10))
        });
        let mut later = Vec::new();
        while later.is_empty() {
            requests.bell().wait(Duration::from_secs(10));
            later = requests.drain(|r| match r {
                Request::Reload { .. } => None,
                _ => Some(Answer::Accepted),
            });
        }
        assert!(matches!(later[0].request, Request::Reload { .. }));
        later.remove(0).answer(Answer::Refused("not now".into()));
        assert_eq!(
            asking.join().unwrap(),
            Ok(Answer::Refused("not now".into()))
        );
    }

    #[test]
    fn a_full_queue_refuses_at_once_and_a_gone_loop_is_told() {
        let stop = Arc::new(AtomicUsize::new(0));
        let (ask, requests) = queue(&stop);
        // Askers that gave up at once leave their requests queued, unanswered.
        for _ in 0..QUEUE {
            assert_eq!(
                ask.ask(Request::Snapshot, Duration::ZERO),
                Err(AskError::NoAnswer(Duration::ZERO))
            );
        }
        assert_eq!(
            ask.ask(Request::Snapshot, Duration::from_secs(10)),
            Err(AskError::Busy)
        );
        requests.drain(|_| Some(Answer::Accepted));
        let waiting = {
            let ask = ask.clone();
            std::thread::spawn(move || ask.ask(Request::Snapshot, Duration::from_secs(10)))
        };
        drop(requests);
        assert_eq!(waiting.join().unwrap(), Err(AskError::Gone));
        assert_eq!(
            ask.ask(Request::Snapshot, Duration::from_secs(1)),
            Err(AskError::Gone)
        );
    }

    #[test]
    fn a_stop_sets_the_flag_as_sigterm_says_who_asked_and_leaves_a_signal_as_it_is() {
        let stop = Arc::new(AtomicUsize::new(0));
        let (ask, requests) = queue(&stop);
        ask.stop("rigscript stop (pid 7)");
        assert_eq!(stop.load(Ordering::SeqCst), SIGTERM as usize);
        assert_eq!(
            requests.stopped_by().as_deref(),
            Some("rigscript stop (pid 7)")
        );
        assert!(requests.bell().wait(Duration::ZERO), "the loop is woken");
        stop.store(2, Ordering::SeqCst);
        ask.stop("again");
        assert_eq!(stop.load(Ordering::SeqCst), 2);
        assert_eq!(
            requests.stopped_by(),
            None,
            "the signal's stop is told as the signal's"
        );
    }
}
