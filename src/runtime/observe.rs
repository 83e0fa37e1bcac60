//! The run's typed event stream: what happened in the scan loop, published without ever
//! blocking to any number of consumers, each on its own thread behind its own bounded queue.
//! A consumer that falls behind loses events, counted (`Subscription::dropped`, and in the
//! run's snapshot), never a tick.
//!
//! Publishing costs one atomic load while nobody listens: the event is not even built.

use crate::sync::lock;
use chrono::{DateTime, Utc};
use serde::Serialize;
use std::sync::atomic::{AtomicU32, AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex, Weak};
use std::time::Duration;

/// The most consumers attached at once; one more is refused (`Events::subscribe`).
pub const MAX_SUBSCRIBERS: usize = 64;

/// The queue of a consumer that gives no size: about two seconds of a busy run.
pub const DEFAULT_QUEUE: usize = 1024;

/// Bytes a consumer's queue holds per event of its capacity, unless it says otherwise
/// (`Bound`): the queue is also bounded by the text its events carry (a record's line can
/// be long).
pub const BYTES_PER_EVENT: usize = 1024;

/// How much a consumer's queue holds: events, and bytes of them (`RunEvent`'s text and a
/// fixed part each); past either, events are lost and counted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Bound {
    /// Events queued at most.
    pub events: usize,
    /// Bytes queued at most.
    pub bytes: usize,
}

impl Bound {
    /// `events` events, and `BYTES_PER_EVENT` bytes for each.
    pub fn events(events: usize) -> Self {
        Self {
            events,
            bytes: events.saturating_mul(BYTES_PER_EVENT),
        }
    }
}

/// What an event counts for in its queue's byte bound besides its text.
const EVENT_OVERHEAD: usize = 64;

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
        /// The wall time the run's clock read when the run began (its uptime 0): what a
        /// replay starts its virtual clock at.
        #[serde(serialize_with = "rfc3339")]
        since: DateTime<Utc>,
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
    /// This tick was brought to `periods` scan periods after the last tick's boundary for
    /// someone outside the loop (a request waiting, someone watching the rig), sooner than the
    /// script's own schedule had one, and started `late_us` after its boundary: a replay,
    /// which nobody watches, makes the same tick at the same time. Told only by a rig idle
    /// between its timers (one that polls inputs ticks every period anyway).
    Woken {
        /// Scan periods from the last tick's boundary to this one's.
        periods: u64,
        /// How late it started after its boundary, in microseconds.
        late_us: u64,
    },
    /// A tick ran past the next deadline (also told as a `Tick`, for those that take only
    /// overruns: the journal).
    Overrun {
        /// Its number.
        tick: u64,
        /// How late it started after its deadline, in microseconds.
        late_us: u64,
        /// How long its work took, in microseconds.
        work_us: u64,
    },
    /// The script was reloaded: from this tick on the run runs `source` (its content hash
    /// `hash`) from `file`. Built only for a consumer that takes it (the journal).
    Reloaded {
        /// The new script's file.
        file: String,
        /// Its content hash.
        hash: String,
        /// Its text.
        source: String,
    },
    /// Someone outside the loop changed what it does: a force taken or ended, a command or a
    /// watched message run. Built only for a consumer that takes it (the journal, so that a
    /// replay asks the same at the same tick).
    Operated {
        /// What was done.
        act: OperatorAct,
    },
    /// A reading made for those watching the rig (`runtime::watched_image`), of an input the
    /// script did not read lately, differs from what was shown before. Not taken in by the
    /// script: a journal leaves it out, as replay needs only what the loop took in.
    Shown {
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
        /// When it was logged, on the run's clock.
        #[serde(serialize_with = "rfc3339")]
        time: DateTime<Utc>,
        /// Whether it is routine (what the script does, the runner's notices): what
        /// `--quiet` leaves out of the log's output.
        routine: bool,
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

/// What someone outside the loop did to it (`RunEvent::Operated`), as a replay asks it again.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(tag = "act", rename_all = "snake_case")]
pub enum OperatorAct {
    /// A force taken (`rigscript force`, the page), by whom.
    Force {
        /// The order as taken.
        order: super::forcing::ForceOrder,
        /// Who asked.
        by: String,
    },
    /// A force ended on request (`rigscript unforce`, the page), by whom.
    Unforce {
        /// `DEVICE.POINT`.
        point: String,
        /// Who asked.
        by: String,
    },
    /// A command run by the script's `on_command` handler.
    Command {
        /// Its name.
        name: String,
        /// Its payload.
        payload: String,
    },
    /// A watched topic's message handed to the script's `on_message` handler.
    Message {
        /// The topic.
        topic: String,
        /// The payload.
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
    /// A TRC1000's fourteen rotary counters (half-turns, 8 bits, as the script sees them).
    Rotaries {
        /// The counts, in `Rotary::ALL`'s order.
        values: [u8; 14],
    },
}

/// Writes a log line's time as RFC 3339 with milliseconds, as the JSON log does.
fn rfc3339<S: serde::Serializer>(time: &DateTime<Utc>, out: S) -> Result<S::Ok, S::Error> {
    out.serialize_str(&time.to_rfc3339_opts(chrono::SecondsFormat::Millis, true))
}

/// The kinds of `RunEvent`, one per variant: what a consumer may choose to take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EventKind {
    /// `RunEvent::ScriptStarted`.
    ScriptStarted,
    /// `RunEvent::ScriptFailed`.
    ScriptFailed,
    /// `RunEvent::ScriptRestarting`.
    ScriptRestarting,
    /// `RunEvent::Tick`.
    Tick,
    /// `RunEvent::Inputs`.
    Inputs,
    /// `RunEvent::Shown`.
    Shown,
    /// `RunEvent::Overrun`.
    Overrun,
    /// `RunEvent::Woken`.
    Woken,
    /// `RunEvent::Reloaded`.
    Reloaded,
    /// `RunEvent::Operated`.
    Operated,
    /// `RunEvent::Outputs`.
    Outputs,
    /// `RunEvent::DeviceLost`.
    DeviceLost,
    /// `RunEvent::DeviceBack`.
    DeviceBack,
    /// `RunEvent::Log`.
    Log,
    /// `RunEvent::Record`.
    Record,
    /// `RunEvent::Ended`.
    Ended,
    /// `RunEvent::Published`.
    Published,
}

impl EventKind {
    fn bit(self) -> u32 {
        1 << self as u32
    }
}

impl RunEvent {
    /// About how many bytes it holds (its text, and a fixed part).
    fn weight(&self) -> usize {
        EVENT_OVERHEAD
            + match self {
                RunEvent::Log { message, .. } | RunEvent::ScriptFailed { message } => message.len(),
                RunEvent::Record { line } => line.len(),
                RunEvent::Outputs { cause, .. } | RunEvent::DeviceLost { cause, .. } => cause.len(),
                RunEvent::Ended { reason, .. } => reason.len(),
                RunEvent::Published { topic, payload } => topic.len() + payload.len(),
                RunEvent::Reloaded { file, source, .. } => file.len() + source.len(),
                _ => 0,
            }
    }

    /// Which kind of event it is.
    pub fn kind(&self) -> EventKind {
        match self {
            RunEvent::ScriptStarted { .. } => EventKind::ScriptStarted,
            RunEvent::ScriptFailed { .. } => EventKind::ScriptFailed,
            RunEvent::ScriptRestarting { .. } => EventKind::ScriptRestarting,
            RunEvent::Tick { .. } => EventKind::Tick,
            RunEvent::Inputs { .. } => EventKind::Inputs,
            RunEvent::Shown { .. } => EventKind::Shown,
            RunEvent::Overrun { .. } => EventKind::Overrun,
            RunEvent::Woken { .. } => EventKind::Woken,
            RunEvent::Reloaded { .. } => EventKind::Reloaded,
            RunEvent::Operated { .. } => EventKind::Operated,
            RunEvent::Outputs { .. } => EventKind::Outputs,
            RunEvent::DeviceLost { .. } => EventKind::DeviceLost,
            RunEvent::DeviceBack { .. } => EventKind::DeviceBack,
            RunEvent::Log { .. } => EventKind::Log,
            RunEvent::Record { .. } => EventKind::Record,
            RunEvent::Ended { .. } => EventKind::Ended,
            RunEvent::Published { .. } => EventKind::Published,
        }
    }
}

/// The kinds of event a consumer takes (`Events::subscribe_to`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Kinds(u32);

impl Kinds {
    /// Every kind (what `Events::subscribe` takes).
    pub const ALL: Kinds = Kinds(u32::MAX);

    /// Just these kinds.
    pub fn of(kinds: &[EventKind]) -> Self {
        Kinds(kinds.iter().fold(0, |bits, k| bits | k.bit()))
    }

    fn has(self, kind: EventKind) -> bool {
        self.0 & kind.bit() != 0
    }
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
    /// The kinds some attached consumer takes: an event nobody takes costs no allocation
    /// and no lock (the log's and the records file's consumers take no ticks).
    wanted: AtomicU32,
    consumers: Mutex<Vec<Consumer>>,
    next_id: AtomicU64,
    /// Events lost by any consumer, those let go since included.
    lost: AtomicU64,
    /// Turns of the loop so far (`turned`).
    turns: AtomicU64,
    /// `Watching` tokens held: someone looks at the rig's whole I/O image.
    watchers: AtomicUsize,
    /// The tick what is published now belongs to (`Events::in_tick`).
    tick: AtomicU64,
}

struct Consumer {
    id: u64,
    name: String,
    kinds: Kinds,
    queue: SyncSender<Delivery>,
    dropped: Arc<AtomicU64>,
    /// Bytes its queue may hold, and holds (the consumer takes off what it receives).
    budget: usize,
    queued: Arc<AtomicUsize>,
    /// Dead once its `Subscription` is gone (told without sending it anything).
    alive: Weak<()>,
    /// Lost since the last event its queue took: handed over with the next one, so the
    /// consumer can tell the loss where it happened.
    unreported: u64,
}

/// One event in a consumer's queue, with the losses just before it and its tick.
struct Delivery {
    lost_before: u64,
    tick: u64,
    weight: usize,
    event: Arc<RunEvent>,
}

/// Why a consumer could not attach.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{MAX_SUBSCRIBERS} consumers are attached to the run's events already")]
pub struct TooManySubscribers;

/// The receiving end of one consumer.
pub struct Subscription {
    events: Receiver<Delivery>,
    dropped: Arc<AtomicU64>,
    queued: Arc<AtomicUsize>,
    /// Losses handed over or counted as told (`newly_dropped`).
    told: u64,
    /// Losses the events received so far came after (never more than `dropped`).
    accounted: std::cell::Cell<u64>,
    /// The event after a loss handed over first (`handover`).
    held: Option<Arc<RunEvent>>,
    /// The tick the last event received was published in.
    tick: std::cell::Cell<u64>,
    _alive: Arc<()>,
    id: u64,
    fanout: Weak<Fanout>,
}

/// A consumer's count of lost events.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, serde::Deserialize)]
pub struct Dropped {
    /// The consumer's name.
    pub consumer: String,
    /// Events it lost because its queue was full.
    pub events: u64,
}

/// A consumer's count of lost events, readable from anywhere (the loop reads the records
/// file's to tell the log of records dropped).
#[derive(Debug, Clone, Default)]
pub struct Losses(Arc<AtomicU64>);

impl Losses {
    /// Events lost so far.
    pub fn count(&self) -> u64 {
        self.0.load(Ordering::Relaxed)
    }
}

/// Lets a consumer go from outside its thread (`Subscription::detacher`): it gets what is
/// queued, then the end of the stream, so a thread waiting for events wakes at once.
#[derive(Debug, Clone)]
pub struct Detacher {
    fanout: Weak<Fanout>,
    id: u64,
}

impl Detacher {
    /// Takes the consumer off the stream: no event after this reaches it.
    pub fn detach(&self) {
        if let Some(fanout) = self.fanout.upgrade() {
            let mut consumers = lock(&fanout.consumers);
            consumers.retain(|c| c.id != self.id);
            fanout.refresh(&consumers);
        }
    }
}

/// Held while someone looks at the rig live (a page's event stream, MQTT's state): the loop
/// then reads every input for them (`runtime::watched_image`). Let go when dropped.
#[derive(Debug)]
pub struct Watching {
    fanout: Weak<Fanout>,
}

impl Drop for Watching {
    fn drop(&mut self) {
        if let Some(fanout) = self.fanout.upgrade() {
            fanout.watchers.fetch_sub(1, Ordering::Relaxed);
        }
    }
}

impl Fanout {
    fn refresh(&self, consumers: &[Consumer]) {
        self.attached.store(consumers.len(), Ordering::Relaxed);
        let wanted = consumers.iter().fold(0, |bits, c| bits | c.kinds.0);
        self.wanted.store(wanted, Ordering::Relaxed);
    }
}

impl Events {
    /// Whether any consumer is attached (an event nobody would get need not be built).
    pub fn watched(&self) -> bool {
        self.fanout.attached.load(Ordering::Relaxed) != 0
    }

    /// Whether an attached consumer takes events of `kind` (one not taken need not be built).
    pub fn wants(&self, kind: EventKind) -> bool {
        self.watched() && self.fanout.wanted.load(Ordering::Relaxed) & kind.bit() != 0
    }

    /// The loop turned: called from every slice of its wait between ticks (at least once a
    /// tick), never from inside a handler, so a consumer that sees `turns` stand still knows
    /// the loop is stuck (systemd's watchdog, `service::notify`). One store, no event built.
    #[inline]
    pub fn turned(&self) {
        // One writer (the loop thread): a plain increment, no locked instruction.
        let n = self.fanout.turns.load(Ordering::Relaxed);
        self.fanout
            .turns
            .store(n.wrapping_add(1), Ordering::Release);
    }

    /// What is published from now on belongs to tick `n`: the loop says so as each tick ends
    /// (`n` is the next), one store a tick; a consumer reads it with each event
    /// (`Subscription::tick`), so it needs no event a tick to place events in their ticks.
    #[inline]
    pub fn in_tick(&self, n: u64) {
        self.fanout.tick.store(n, Ordering::Relaxed);
    }

    /// Says someone watches the rig live until the token is dropped.
    pub fn watching(&self) -> Watching {
        self.fanout.watchers.fetch_add(1, Ordering::Relaxed);
        Watching {
            fanout: Arc::downgrade(&self.fanout),
        }
    }

    /// How many `Watching` tokens are held.
    pub fn watchers(&self) -> usize {
        self.fanout.watchers.load(Ordering::Relaxed)
    }

    /// Turns of the loop so far (`turned`).
    pub fn turns(&self) -> u64 {
        self.fanout.turns.load(Ordering::Acquire)
    }

    /// Gives the event `make` builds to every consumer that takes its kind, never waiting:
    /// one whose queue is full loses it (counted); one that went away is let go.
    pub fn publish(&self, make: impl FnOnce() -> RunEvent) {
        if !self.watched() {
            return;
        }
        let event = make();
        let kind = event.kind();
        if self.fanout.wanted.load(Ordering::Relaxed) & kind.bit() == 0 {
            return;
        }
        let weight = event.weight();
        let tick = self.fanout.tick.load(Ordering::Relaxed);
        let event = Arc::new(event);
        let mut consumers = lock(&self.fanout.consumers);
        consumers.retain_mut(|c| {
            if !c.attached() {
                return false;
            }
            if !c.kinds.has(kind) {
                return true;
            }
            // Counted before it is sent: the consumer takes it off as it receives it.
            let queued = c.queued.fetch_add(weight, Ordering::Relaxed);
            let sent = if queued.saturating_add(weight) > c.budget {
                Err(TrySendError::Full(()))
            } else {
                let delivery = Delivery {
                    lost_before: c.unreported,
                    tick,
                    weight,
                    event: Arc::clone(&event),
                };
                c.queue.try_send(delivery).map_err(|e| match e {
                    TrySendError::Full(_) => TrySendError::Full(()),
                    TrySendError::Disconnected(_) => TrySendError::Disconnected(()),
                })
            };
            match sent {
                Ok(()) => {
                    c.unreported = 0;
                    true
                }
                Err(TrySendError::Full(())) => {
                    c.queued.fetch_sub(weight, Ordering::Relaxed);
                    c.dropped.fetch_add(1, Ordering::Relaxed);
                    self.fanout.lost.fetch_add(1, Ordering::Relaxed);
                    c.unreported = c.unreported.saturating_add(1);
                    true
                }
                Err(TrySendError::Disconnected(())) => false,
            }
        });
        self.fanout.refresh(&consumers);
    }

    /// Attaches a consumer called `name`, taking every event, with a queue of `capacity` events
    /// (`Bound::events`).
    pub fn subscribe(
        &self,
        name: &str,
        capacity: usize,
    ) -> Result<Subscription, TooManySubscribers> {
        self.subscribe_to(name, Bound::events(capacity), Kinds::ALL)
    }

    /// Attaches a consumer called `name` that takes the events of `kinds` only (what it
    /// loses is then events of those kinds), with a queue that holds `bound`.
    pub fn subscribe_to(
        &self,
        name: &str,
        bound: Bound,
        kinds: Kinds,
    ) -> Result<Subscription, TooManySubscribers> {
        let mut consumers = lock(&self.fanout.consumers);
        consumers.retain(Consumer::attached);
        if consumers.len() >= MAX_SUBSCRIBERS {
            return Err(TooManySubscribers);
        }
        let (queue, events) = mpsc::sync_channel(bound.events.max(1));
        let dropped = Arc::new(AtomicU64::new(0));
        let queued = Arc::new(AtomicUsize::new(0));
        let alive = Arc::new(());
        let id = self.fanout.next_id.fetch_add(1, Ordering::Relaxed);
        consumers.push(Consumer {
            id,
            name: name.to_string(),
            kinds,
            queue,
            dropped: Arc::clone(&dropped),
            budget: bound.bytes,
            queued: Arc::clone(&queued),
            alive: Arc::downgrade(&alive),
            unreported: 0,
        });
        self.fanout.refresh(&consumers);
        Ok(Subscription {
            events,
            dropped,
            queued,
            told: 0,
            accounted: std::cell::Cell::new(0),
            held: None,
            tick: std::cell::Cell::new(0),
            _alive: alive,
            id,
            fanout: Arc::downgrade(&self.fanout),
        })
    }

    /// Events lost by every consumer there has been, those let go since included.
    pub fn dropped_in_all(&self) -> u64 {
        self.fanout.lost.load(Ordering::Relaxed)
    }

    /// Every attached consumer's count of lost events (one gone is not listed, even before
    /// the next event lets it go).
    pub fn dropped(&self) -> Vec<Dropped> {
        lock(&self.fanout.consumers)
            .iter()
            .filter(|c| c.attached())
            .map(|c| Dropped {
                consumer: c.name.clone(),
                events: c.dropped.load(Ordering::Relaxed),
            })
            .collect()
    }
}

impl Consumer {
    /// Whether its `Subscription` is still held.
    fn attached(&self) -> bool {
        self.alive.strong_count() > 0
    }
}

/// What a consumer following the stream is handed (`Subscription::follow`).
#[derive(Debug, Clone, PartialEq)]
pub enum Next {
    /// The next event.
    Event(Arc<RunEvent>),
    /// This many events were lost here, between the event handed over before and the next.
    Dropped(u64),
    /// A wait slice went by without an event (a time to send a keep-alive).
    Quiet,
}

impl Subscription {
    /// Hands `each` the events in order, losses as `Next::Dropped` where they happened, and
    /// `Next::Quiet` after each `slice` without an event, until `each` says stop (false), the
    /// run's `Ended` was handed over, the run is gone, or `closing()` says so (what is queued
    /// by then still goes).
    pub fn follow(
        &mut self,
        slice: Duration,
        closing: impl Fn() -> bool,
        mut each: impl FnMut(Next) -> bool,
    ) {
        loop {
            let closing = closing();
            match self.handover(if closing { Duration::ZERO } else { slice }) {
                Ok(Next::Event(event)) => {
                    let end = matches!(*event, RunEvent::Ended { .. });
                    if !each(Next::Event(event)) || end {
                        return;
                    }
                }
                Ok(next) => {
                    if !each(next) {
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

    /// The next thing to hand over, waiting at most `wait`: a loss (`Next::Dropped`) where it
    /// happened, before the event after it, else the next event; losses after the last event
    /// are handed over once nothing else comes. `Err(Disconnected)` once the stream is gone.
    pub fn handover(&mut self, wait: Duration) -> Result<Next, RecvTimeoutError> {
        if let Some(event) = self.held.take() {
            return Ok(Next::Event(event));
        }
        match self.next(wait) {
            Ok(event) => {
                let accounted = self.accounted.get();
                if accounted > self.told {
                    let lost = accounted - self.told;
                    self.told = accounted;
                    self.held = Some(event);
                    return Ok(Next::Dropped(lost));
                }
                Ok(Next::Event(event))
            }
            Err(e) => match self.newly_dropped() {
                0 => Err(e),
                lost => Ok(Next::Dropped(lost)),
            },
        }
    }

    /// The next event, waiting at most `wait`; `Err(Disconnected)` once the run is gone.
    pub fn next(&self, wait: Duration) -> Result<Arc<RunEvent>, RecvTimeoutError> {
        let delivery = self.events.recv_timeout(wait)?;
        self.queued.fetch_sub(delivery.weight, Ordering::Relaxed);
        self.accounted
            .set(self.accounted.get().saturating_add(delivery.lost_before));
        self.tick.set(delivery.tick);
        Ok(delivery.event)
    }

    /// Events lost so far.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// The tick the event last handed over was published in (`Events::in_tick`; after a
    /// `Next::Dropped`, the tick of the event after the loss).
    pub fn tick(&self) -> u64 {
        self.tick.get()
    }

    /// This consumer's count of lost events, to read from elsewhere.
    pub fn losses(&self) -> Losses {
        Losses(Arc::clone(&self.dropped))
    }

    /// What takes this consumer off the stream from another thread.
    pub fn detacher(&self) -> Detacher {
        Detacher {
            fanout: Weak::clone(&self.fanout),
            id: self.id,
        }
    }

    /// Events lost since the last call (0 if none): what a consumer tells its own output.
    pub fn newly_dropped(&mut self) -> u64 {
        let now = self.dropped();
        let new = now.saturating_sub(self.told);
        self.told = self.told.max(now);
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
    fn each_event_comes_with_the_tick_it_was_published_in_and_a_loss_with_the_next_one_s() {
        let events = Events::default();
        let mut sub = events
            .subscribe_to("stamps", Bound::events(2), Kinds::of(&[EventKind::Tick]))
            .unwrap();
        events.publish(|| tick(1));
        events.in_tick(2);
        events.publish(|| tick(2));
        events.publish(|| tick(3)); // lost: the queue holds two
        events.in_tick(7);
        let first = sub.handover(Duration::ZERO).unwrap();
        assert_eq!(first, Next::Event(Arc::new(tick(1))));
        assert_eq!(sub.tick(), 0);
        sub.handover(Duration::ZERO).unwrap();
        assert_eq!(sub.tick(), 2);
        events.publish(|| tick(4));
        assert_eq!(sub.handover(Duration::ZERO).unwrap(), Next::Dropped(1));
        assert_eq!(sub.tick(), 7, "the loss, in the tick of the event after it");
        assert_eq!(
            sub.handover(Duration::ZERO).unwrap(),
            Next::Event(Arc::new(tick(4)))
        );
        assert_eq!(sub.tick(), 7);
    }

    #[test]
    fn a_watching_token_counts_while_it_is_held() {
        let events = Events::default();
        assert_eq!(events.watchers(), 0);
        let a = events.watching();
        let b = events.clone().watching();
        assert_eq!(events.watchers(), 2);
        drop(a);
        assert_eq!(events.watchers(), 1);
        drop(b);
        assert_eq!(events.watchers(), 0);
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
        // Tick 3 was lost after tick 2: the loss is told there, not ahead of tick 1.
        assert_eq!(
            got,
            vec![
                Next::Event(Arc::new(tick(1))),
                Next::Event(Arc::new(tick(2))),
                Next::Dropped(1),
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
    fn a_consumer_takes_only_its_kinds_and_its_queue_is_bounded_in_bytes_too() {
        let events = Events::default();
        let records = events
            .subscribe_to(
                "records",
                Bound {
                    events: 100,
                    bytes: 2 * (EVENT_OVERHEAD + 10),
                },
                Kinds::of(&[EventKind::Record]),
            )
            .unwrap();
        // Nobody takes ticks: they are not even built.
        let mut built = false;
        events.publish(|| {
            built = true;
            tick(1)
        });
        assert!(built, "built to learn its kind");
        assert!(!events.wants(EventKind::Tick));
        assert!(events.wants(EventKind::Record));
        let record = |line: &str| RunEvent::Record { line: line.into() };
        events.publish(|| record("0123456789"));
        events.publish(|| record(&"x".repeat(100)));
        events.publish(|| record("abcdefghij"));
        assert_eq!(records.dropped(), 1, "the long one did not fit");
        assert_eq!(*records.next(Duration::ZERO).unwrap(), record("0123456789"));
        assert_eq!(*records.next(Duration::ZERO).unwrap(), record("abcdefghij"));
        // Taken off: room again.
        events.publish(|| record("0123456789"));
        events.publish(|| record("0123456789"));
        assert_eq!(records.dropped(), 1);
    }

    #[test]
    fn a_detached_consumer_gets_what_was_queued_then_the_end_at_once() {
        let events = Events::default();
        let mut s = events.subscribe("d", 8).unwrap();
        events.publish(|| tick(1));
        s.detacher().detach();
        events.publish(|| tick(2));
        assert_eq!(
            s.handover(Duration::from_secs(60)).unwrap(),
            Next::Event(Arc::new(tick(1)))
        );
        assert_eq!(
            s.handover(Duration::from_secs(60)),
            Err(RecvTimeoutError::Disconnected)
        );
        assert!(!events.watched());
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
