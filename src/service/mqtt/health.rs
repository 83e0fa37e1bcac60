//! The client's troubles as counts the loop reads without waiting on the client: its thread
//! adds to shared atomics, the snapshot loads them (`runtime::snapshot::MqttState`).

use crate::runtime::remote::{RemoteState, TurnedAway};
use crate::runtime::snapshot::{MqttDropped, MqttState};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// What the client lost, by kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Loss {
    /// A record the outbox had no room for (`outbox_max`).
    OutboxFull,
    /// A record the outbox could not write to disk.
    OutboxWrite,
    /// A watched topic's message over the rate, over the size, or the loop too busy.
    Message,
    /// A command refused (too large, too many waiting, the loop too busy or gone).
    Command,
    /// An `mqtt_publish` not sent (not connected, or the client's queue full).
    Publish,
    /// A log line for the broker not sent.
    Log,
    /// A publish the broker refused (its ACL, a quota): a record, a state, a reply...
    Refused,
    /// A publish over the broker's Maximum Packet Size, not sent (a record among them done).
    TooLarge,
    /// A command's reply not sent: the reply queue was full.
    Reply,
}

/// The shared counts: cheap to clone, one for the client's thread, one for the loop.
#[derive(Debug, Clone, Default)]
pub struct ClientHealth(Arc<Counts>);

#[derive(Debug, Default)]
struct Counts {
    broker: String,
    connected: AtomicBool,
    connect_failures: AtomicU64,
    waiting: AtomicU64,
    outbox_full: AtomicU64,
    outbox_write: AtomicU64,
    messages: AtomicU64,
    commands: AtomicU64,
    publishes: AtomicU64,
    log: AtomicU64,
    refused: AtomicU64,
    too_large: AtomicU64,
    replies: AtomicU64,
    /// Held only to swap the text, never across I/O: the loop's read waits on no network.
    last_error: Mutex<Option<String>>,
    /// Why the client stopped for good (its thread panicked), under the same rule.
    stopped: Mutex<Option<String>>,
}

impl ClientHealth {
    /// Counts for the client of `broker` (`host:port`), nothing lost yet.
    pub fn new(broker: &str) -> Self {
        Self(Arc::new(Counts {
            broker: broker.to_string(),
            ..Counts::default()
        }))
    }

    /// One more lost of `kind`.
    pub fn lost(&self, kind: Loss) {
        let c = &self.0;
        let counter = match kind {
            Loss::OutboxFull => &c.outbox_full,
            Loss::OutboxWrite => &c.outbox_write,
            Loss::Message => &c.messages,
            Loss::Command => &c.commands,
            Loss::Publish => &c.publishes,
            Loss::Log => &c.log,
            Loss::Refused => &c.refused,
            Loss::TooLarge => &c.too_large,
            Loss::Reply => &c.replies,
        };
        counter.fetch_add(1, Ordering::Relaxed);
    }

    /// The broker accepted the connection.
    pub fn connected(&self) {
        self.0.connected.store(true, Ordering::Relaxed);
    }

    /// A connection failed (or was refused), for `why`.
    pub fn failed(&self, why: &str) {
        self.0.connected.store(false, Ordering::Relaxed);
        self.0.connect_failures.fetch_add(1, Ordering::Relaxed);
        *crate::sync::lock(&self.0.last_error) = Some(why.to_string());
    }

    /// The client's thread ended for `why` (a panic): nothing more reaches the broker.
    pub fn stopped(&self, why: &str) {
        self.0.connected.store(false, Ordering::Relaxed);
        *crate::sync::lock(&self.0.stopped) = Some(why.to_string());
    }

    /// The connection was closed on purpose (the run's end).
    pub fn disconnected(&self) {
        self.0.connected.store(false, Ordering::Relaxed);
    }

    /// Records waiting in the outbox now.
    pub fn waiting(&self, n: usize) {
        self.0.waiting.store(n as u64, Ordering::Relaxed);
    }

    /// The counts as the snapshot shows them.
    pub fn shown(&self) -> MqttState {
        let c = &self.0;
        let load = |a: &AtomicU64| a.load(Ordering::Relaxed);
        MqttState {
            broker: c.broker.clone(),
            connected: c.connected.load(Ordering::Relaxed),
            connect_failures: load(&c.connect_failures),
            last_error: crate::sync::lock(&c.last_error).clone(),
            failed: crate::sync::lock(&c.stopped).clone(),
            outbox_waiting: load(&c.waiting),
            dropped: MqttDropped {
                outbox_full: load(&c.outbox_full),
                outbox_write: load(&c.outbox_write),
                messages: load(&c.messages),
                commands: load(&c.commands),
                publishes: load(&c.publishes),
                log: load(&c.log),
                refused: load(&c.refused),
                too_large: load(&c.too_large),
                replies: load(&c.replies),
            },
        }
    }
}

impl RemoteState for ClientHealth {
    fn turned_away(&self, what: TurnedAway) {
        self.lost(match what {
            TurnedAway::Command => Loss::Command,
            TurnedAway::Message => Loss::Message,
        });
    }

    fn shown(&self) -> MqttState {
        ClientHealth::shown(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn losses_and_failures_are_counted_by_kind_and_seen_from_another_handle() {
        let client = ClientHealth::new("broker:1883");
        let loop_side = client.clone();
        for _ in 0..3 {
            client.lost(Loss::Message);
        }
        client.lost(Loss::OutboxFull);
        client.lost(Loss::Command);
        client.lost(Loss::Publish);
        client.lost(Loss::Publish);
        client.lost(Loss::Refused);
        client.lost(Loss::TooLarge);
        client.lost(Loss::Reply);
        client.connected();
        client.failed("cannot reach broker broker:1883: refused");
        client.waiting(12);
        let s = loop_side.shown();
        assert_eq!(s.broker, "broker:1883");
        assert!(!s.connected);
        assert_eq!(s.connect_failures, 1);
        assert_eq!(
            s.last_error.as_deref(),
            Some("cannot reach broker broker:1883: refused")
        );
        assert_eq!(s.outbox_waiting, 12);
        assert_eq!(
            s.dropped,
            MqttDropped {
                outbox_full: 1,
                outbox_write: 0,
                messages: 3,
                commands: 1,
                publishes: 2,
                log: 0,
                refused: 1,
                too_large: 1,
                replies: 1,
            }
        );
        assert_eq!(s.dropped.total(), 10);
        client.connected();
        assert!(loop_side.shown().connected);
        assert_eq!(loop_side.shown().failed, None);
        client.stopped("the client's thread panicked: boom");
        let s = loop_side.shown();
        assert!(!s.connected);
        assert_eq!(
            s.failed.as_deref(),
            Some("the client's thread panicked: boom")
        );
    }
}
