//! The run's typed event stream: what happened in the scan loop, published without ever
//! blocking to any number of consumers, each on its own thread behind its own bounded queue.
//! A consumer that falls behind loses events, counted (`Subscription::dropped`, and in the
//! run's snapshot), never a tick.
//!
//! Publishing costs one atomic load while nobody listens: the event is not even built.

use crate::sync::lock;
use serde::Serialize;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// The most consumers attached at once; one more is refused (`Events::subscribe`).
pub const MAX_SUBSCRIBERS: usize = 64;

/// The queue of a consumer that gives no size: about two seconds of a busy run.
pub const DEFAULT_QUEUE: usize = 1024;

/// One thing that happened in a run, as values (no borrow of the runtime).
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum RunEvent {
    /// The script's top level ran to its end: first at start, then after each restart.
    ScriptStarted {
        /// The script's file.
        script: String,
        /// Starts before this one (0 at the first).
        restarts: u64,
    },
    /// A handler or the top level failed (`message` carries file:line:column).
    ScriptFailed {
        /// What failed and where.
        message: String,
    },
    /// Policy restart: the script starts again after this long, outputs safe meanwhile.
    ScriptRestarting {
        /// The wait before the restart, in milliseconds.
        after_ms: u64,
    },
    /// A tick ran.
    Tick {
        /// Its number.
        tick: u64,
        /// How late it started after its deadline, in microseconds.
        late_us: u64,
        /// How long its work took, in microseconds.
        work_us: u64,
        /// Whether it ran past the next deadline.
        overrun: bool,
    },
    /// A reading of a device's inputs differs from the one before.
    Inputs {
        /// The device's name in the rig.
        device: String,
        /// What was read.
        reading: Reading,
    },
    /// Outputs (a TRP-C29U's DO byte, a TRC1000's relay) were written.
    Outputs {
        /// The device's name in the rig.
        device: String,
        /// The value written.
        value: u8,
        /// What wrote it (a handler's label, "safe state", ...).
        cause: String,
    },
    /// A device stopped answering.
    DeviceLost {
        /// The device's name in the rig.
        device: String,
        /// Why, in words.
        cause: String,
    },
    /// A lost device answers again and is under control.
    DeviceBack {
        /// The device's name in the rig.
        device: String,
    },
    /// A log line.
    Log {
        /// How much it matters: info, notice, warning or error (syslog's names).
        level: &'static str,
        /// The line's message.
        message: String,
    },
    /// A record or measurement: its line in the records file.
    Record {
        /// The JSON object, as written to the records file.
        line: String,
    },
    /// The run ended.
    Ended {
        /// Its exit status.
        status: i32,
        /// Why, in words.
        reason: String,
        /// The devices whose safe state the end confirmed.
        safe: Vec<String>,
        /// The devices it could not confirm.
        unconfirmed: Vec<String>,
    },
    /// The script asked for a message on the broker (`mqtt_publish`): the MQTT client sends it.
    Published {
        /// The topic.
        topic: String,
        /// The payload: the value as JSON (a string as itself).
        payload: String,
    },
}

/// A reading of one kind of input.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Reading {
    /// A TRP-C29U's DI byte (bit n: channel n on).
    DigitalInputs {
        /// The byte.
        value: u8,
    },
    /// A TRP-C29U's eight counters.
    Counters {
        /// The counts, channel 0 first.
        values: [u16; 8],
    },
    /// A TRC1000's switches.
    Switches {
        /// The switches pressed, by name.
        pressed: Vec<&'static str>,
    },
}

/// The publishing end: cheap to clone, shared by everything in the run that tells of events.
#[derive(Clone, Default)]
pub struct Events {
    fanout: Arc<Fanout>,
}

#[derive(Default)]
struct Fanout {
    /// Consumers attached: read without the lock, so a run nobody watches pays one load.
    attached: AtomicUsize,
    consumers: Mutex<Vec<Consumer>>,
}

struct Consumer {
    name: String,
    queue: SyncSender<Arc<RunEvent>>,
    dropped: Arc<AtomicU64>,
}

/// Why a consumer could not attach.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{MAX_SUBSCRIBERS} consumers are attached to the run's events already")]
pub struct TooManySubscribers;

/// The receiving end of one consumer.
pub struct Subscription {
    events: Receiver<Arc<RunEvent>>,
    dropped: Arc<AtomicU64>,
    told: u64,
}

/// A consumer's count of lost events.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, serde::Deserialize)]
pub struct Dropped {
    /// The consumer's name.
    pub consumer: String,
    /// Events it lost because its queue was full.
    pub events: u64,
}

impl Events {
    /// Whether any consumer is attached (an event nobody would get need not be built).
    pub fn watched(&self) -> bool {
        self.fanout.attached.load(Ordering::Relaxed) != 0
    }

    /// Gives the event `make` builds to every consumer, never waiting: one whose queue is
    /// full loses it (counted); one that went away is let go.
    pub fn publish(&self, make: impl FnOnce() -> RunEvent) {
        if !self.watched() {
            return;
        }
        let event = Arc::new(make());
        let mut consumers = lock(&self.fanout.consumers);
        consumers.retain(|c| {
            c.attached()
                && match c.queue.try_send(Arc::clone(&event)) {
                    Ok(()) => true,
                    Err(TrySendError::Full(_)) => {
                        c.dropped.fetch_add(1, Ordering::Relaxed);
                        true
                    }
                    Err(TrySendError::Disconnected(_)) => false,
                }
        });
        self.fanout
            .attached
            .store(consumers.len(), Ordering::Relaxed);
    }

    /// Attaches a consumer called `name` with a queue of `capacity` events.
    pub fn subscribe(
        &self,
        name: &str,
        capacity: usize,
    ) -> Result<Subscription, TooManySubscribers> {
        let mut consumers = lock(&self.fanout.consumers);
        consumers.retain(Consumer::attached);
        if consumers.len() >= MAX_SUBSCRIBERS {
            return Err(TooManySubscribers);
        }
        let (queue, events) = mpsc::sync_channel(capacity.max(1));
        let dropped = Arc::new(AtomicU64::new(0));
        consumers.push(Consumer {
            name: name.to_string(),
            queue,
            dropped: Arc::clone(&dropped),
        });
        self.fanout
            .attached
            .store(consumers.len(), Ordering::Relaxed);
        Ok(Subscription {
            events,
            dropped,
            told: 0,
        })
    }

    /// Every attached consumer's count of lost events.
    pub fn dropped(&self) -> Vec<Dropped> {
        lock(&self.fanout.consumers)
            .iter()
            .map(|c| Dropped {
                consumer: c.name.clone(),
                events: c.dropped.load(Ordering::Relaxed),
            })
            .collect()
    }
}

impl Consumer {
    /// Whether its `Subscription` is still held: it shares the count of drops, so a count
    /// held here alone is a consumer gone (told without sending it anything).
    fn attached(&self) -> bool {
        Arc::strong_count(&self.dropped) > 1
    }
}

/// What a consumer following the stream is handed (`Subscription::follow`).
#[derive(Debug, Clone, PartialEq)]
pub enum Next {
    /// The next event.
    Event(Arc<RunEvent>),
    /// This many events were lost since the last hand-over (told before the event after them).
    Dropped(u64),
    /// A wait slice went by without an event (a time to send a keep-alive).
    Quiet,
}

impl Subscription {
    /// Hands `each` the events in order, losses as `Next::Dropped`, and `Next::Quiet` after each
    /// `slice` without an event, until `each` says stop (false), the run's `Ended` was handed
    /// over, the run is gone, or `closing()` says so (what is queued by then still goes).
    pub fn follow(
        &mut self,
        slice: Duration,
        closing: impl Fn() -> bool,
        mut each: impl FnMut(Next) -> bool,
    ) {
        loop {
            let closing = closing();
            let next = self.next(if closing { Duration::ZERO } else { slice });
            let lost = self.newly_dropped();
            if lost > 0 && !each(Next::Dropped(lost)) {
                return;
            }
            match next {
                Ok(event) => {
                    let end = matches!(*event, RunEvent::Ended { .. });
                    if !each(Next::Event(event)) || end {
                        return;
                    }
                }
                Err(RecvTimeoutError::Timeout) if !closing => {
                    if !each(Next::Quiet) {
                        return;
                    }
                }
                Err(_) => return,
            }
        }
    }

    /// The next event, waiting at most `wait`; `Err(Disconnected)` once the run is gone.
    pub fn next(&self, wait: Duration) -> Result<Arc<RunEvent>, RecvTimeoutError> {
        self.events.recv_timeout(wait)
    }

    /// Events lost so far.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Events lost since the last call (0 if none): what a consumer tells its own output.
    pub fn newly_dropped(&mut self) -> u64 {
        let now = self.dropped();
        let new = now.saturating_sub(self.told);
        self.told = now;
        new
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tick(n: u64) -> RunEvent {
        RunEvent::Tick {
            tick: n,
            late_us: 0,
            work_us: 1,
            overrun: false,
        }
    }

    #[test]
    fn nothing_is_built_while_nobody_listens() {
        let events = Events::default();
        let mut built = false;
        events.publish(|| {
            built = true;
            tick(1)
        });
        assert!(!built);
        assert!(!events.watched());
    }

    #[test]
    fn every_consumer_gets_every_event_in_order() {
        let events = Events::default();
        let a = events.subscribe("a", 8).unwrap();
        let b = events.subscribe("b", 8).unwrap();
        for n in 1..=3 {
            events.publish(|| tick(n));
        }
        for s in [&a, &b] {
            for n in 1..=3 {
                assert_eq!(*s.next(Duration::ZERO).unwrap(), tick(n));
            }
            assert!(s.next(Duration::ZERO).is_err());
        }
    }

    #[test]
    fn a_consumer_that_falls_behind_loses_events_counted_and_the_others_lose_none() {
        let events = Events::default();
        let mut slow = events.subscribe("slow", 2).unwrap();
        let fast = events.subscribe("fast", 100).unwrap();
        for n in 1..=10 {
            events.publish(|| tick(n));
        }
        assert_eq!(slow.dropped(), 8);
        assert_eq!(slow.newly_dropped(), 8);
        assert_eq!(slow.newly_dropped(), 0);
        assert_eq!(*slow.next(Duration::ZERO).unwrap(), tick(1));
        let got: Vec<_> = std::iter::from_fn(|| fast.next(Duration::ZERO).ok()).collect();
        assert_eq!(got.len(), 10);
        let counts = events.dropped();
        assert_eq!(
            counts,
            vec![
                Dropped {
                    consumer: "slow".into(),
                    events: 8
                },
                Dropped {
                    consumer: "fast".into(),
                    events: 0
                }
            ]
        );
    }

    #[test]
    fn a_consumer_that_went_away_is_let_go_and_the_count_is_bounded() {
        let events = Events::default();
        let gone = events.subscribe("gone", 4).unwrap();
        drop(gone);
        events.publish(|| tick(1));
        assert!(!events.watched());
        let kept: Vec<_> = (0..MAX_SUBSCRIBERS)
            .map(|n| events.subscribe(&n.to_string(), 1).unwrap())
            .collect();
        assert_eq!(
            events.subscribe("one more", 1).err(),
            Some(TooManySubscribers)
        );
        // Let go at once, without an event to find them gone by.
        drop(kept);
        assert!(events.subscribe("after", 1).is_ok());
    }

    #[test]
    fn following_hands_over_losses_before_the_next_event_and_ends_with_the_run() {
        let events = Events::default();
        let mut s = events.subscribe("f", 2).unwrap();
        for n in 1..=3 {
            events.publish(|| tick(n));
        }
        let ended = RunEvent::Ended {
            status: 0,
            reason: "done".into(),
            safe: vec![],
            unconfirmed: vec![],
        };
        let mut got = Vec::new();
        s.follow(
            Duration::ZERO,
            || false,
            |n| {
                if got.len() == 2 {
                    events.publish(|| ended.clone());
                }
                got.push(n);
                true
            },
        );
        assert_eq!(
            got,
            vec![
                Next::Dropped(1),
                Next::Event(Arc::new(tick(1))),
                Next::Event(Arc::new(tick(2))),
                Next::Event(Arc::new(ended.clone())),
            ]
        );
        // Closing: what is queued goes, then it stops without waiting.
        let mut s = events.subscribe("g", 4).unwrap();
        events.publish(|| tick(9));
        let mut got = Vec::new();
        s.follow(
            Duration::from_secs(60),
            || true,
            |n| {
                got.push(n);
                true
            },
        );
        assert_eq!(got, vec![Next::Event(Arc::new(tick(9)))]);
    }

    #[test]
    fn events_serialize_with_their_kind() {
        let json = serde_json::to_value(RunEvent::Inputs {
            device: "io".into(),
            reading: Reading::DigitalInputs { value: 5 },
        })
        .unwrap();
        assert_eq!(
            json,
            serde_json::json!({"event": "inputs", "device": "io",
                               "reading": {"kind": "digital_inputs", "value": 5}})
        );
    }
}
