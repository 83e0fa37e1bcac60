//! One connection to the broker: rumqttc's client, its network thread (which drives the
//! connection and hands its events over a channel), and which records are in flight.
//!
//! A connection that fails is not reconnected by rumqttc (it would resend what it holds on
//! its own): the link ends, and the next one resends from the outbox, so the outbox alone
//! says what the broker has.

use rumqttc::{Client, ConnectionError, Event, MqttOptions, Outgoing, Packet, QoS};
use std::collections::{BTreeSet, HashMap, VecDeque};
use std::sync::mpsc::{self, Receiver, TryRecvError};
use std::thread;

/// What a publish was, for when its packet id is known.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Tag {
    /// A record with this seq.
    Record(u64),
    /// Anything else.
    Other,
}

/// What the network thread tells.
pub enum NetEvent {
    /// The broker accepted the connection.
    Connected,
    /// The broker acknowledged this record (all before it may still be in flight).
    Acked(u64),
    /// A message on a topic the rig subscribed to.
    Message {
        /// Its topic.
        topic: String,
        /// Its payload.
        payload: Vec<u8>,
    },
    /// The connection failed or was refused: the link is over.
    Failed(ConnectionError),
}

/// Requests rumqttc's client may hold before `try_publish` says full.
const CLIENT_QUEUE: usize = 256;

/// A live (or coming) connection.
pub struct Link {
    client: Client,
    net: Receiver<Event2>,
    tags: VecDeque<Tag>,
    by_packet: HashMap<u16, u64>,
    unacked: BTreeSet<u64>,
    highest_sent: Option<u64>,
    connected: bool,
    thread: Option<thread::JoinHandle<()>>,
}

/// The network thread's raw events (kept apart from `NetEvent` so tags are matched here).
type Event2 = Result<Event, ConnectionError>;

impl Link {
    /// Starts connecting with `options`.
    pub fn open(options: MqttOptions) -> Self {
        let (client, mut connection) = Client::new(options, CLIENT_QUEUE);
        let (tx, net) = mpsc::sync_channel(1024);
        let thread = thread::Builder::new()
            .name("mqtt-net".into())
            .spawn(move || loop {
                match connection.recv() {
                    Ok(Ok(event)) => {
                        if tx.send(Ok(event)).is_err() {
                            return;
                        }
                    }
                    Ok(Err(e)) => {
                        let _ = tx.send(Err(e));
                        return;
                    }
                    Err(_) => return,
                }
            })
            .ok();
        Self {
            client,
            net,
            tags: VecDeque::new(),
            by_packet: HashMap::new(),
            unacked: BTreeSet::new(),
            highest_sent: None,
            connected: false,
            thread,
        }
    }

    /// Whether the broker has accepted the connection.
    pub fn connected(&self) -> bool {
        self.connected
    }

    /// The next thing the connection tells, if any; `Failed` when it is over.
    pub fn poll(&mut self) -> Option<NetEvent> {
        loop {
            let event = match self.net.try_recv() {
                Ok(e) => e,
                Err(TryRecvError::Empty) => return None,
                Err(TryRecvError::Disconnected) => {
                    return Some(NetEvent::Failed(ConnectionError::RequestsDone))
                }
            };
            match event {
                Err(e) => {
                    self.connected = false;
                    return Some(NetEvent::Failed(e));
                }
                Ok(Event::Incoming(Packet::ConnAck(_))) => {
                    self.connected = true;
                    return Some(NetEvent::Connected);
                }
                Ok(Event::Outgoing(Outgoing::Publish(pkid))) => {
                    if let Some(Tag::Record(seq)) = self.tags.pop_front() {
                        self.by_packet.insert(pkid, seq);
                    }
                }
                Ok(Event::Incoming(Packet::PubAck(ack))) => {
                    if let Some(seq) = self.by_packet.remove(&ack.pkid) {
                        self.unacked.remove(&seq);
                        return Some(NetEvent::Acked(self.acked_through()));
                    }
                }
                Ok(Event::Incoming(Packet::Publish(p))) => {
                    return Some(NetEvent::Message {
                        topic: p.topic,
                        payload: p.payload.to_vec(),
                    })
                }
                Ok(_) => {}
            }
        }
    }

    /// The highest seq acknowledged with every one sent before it.
    fn acked_through(&self) -> u64 {
        match (self.unacked.first(), self.highest_sent) {
            (Some(first), _) => first - 1,
            (None, Some(h)) => h,
            (None, None) => 0,
        }
    }

    /// Records sent and not yet acknowledged.
    pub fn in_flight(&self) -> usize {
        self.unacked.len()
    }

    /// The highest record seq handed to the client on this link.
    pub fn highest_sent(&self) -> Option<u64> {
        self.highest_sent
    }

    /// Publishes a record (QoS 1, not retained); false if the client's queue is full.
    pub fn send_record(&mut self, topic: &str, seq: u64, payload: &str) -> bool {
        let sent = self
            .client
            .try_publish(topic, QoS::AtLeastOnce, false, payload.as_bytes().to_vec())
            .is_ok();
        if sent {
            self.tags.push_back(Tag::Record(seq));
            self.unacked.insert(seq);
            self.highest_sent = Some(seq);
        }
        sent
    }

    /// Publishes anything else; false if the client's queue is full.
    pub fn send(&mut self, topic: &str, qos: QoS, retain: bool, payload: &[u8]) -> bool {
        let sent = self
            .client
            .try_publish(topic, qos, retain, payload.to_vec())
            .is_ok();
        if sent {
            self.tags.push_back(Tag::Other);
        }
        sent
    }

    /// Subscribes to `filter` (QoS 1); false if the client's queue is full.
    pub fn subscribe(&mut self, filter: &str) -> bool {
        self.client.try_subscribe(filter, QoS::AtLeastOnce).is_ok()
    }

    /// Says goodbye to the broker (no last will) and lets the network thread end.
    pub fn disconnect(mut self, wait: std::time::Duration) {
        let _ = self.client.try_disconnect();
        let until = std::time::Instant::now() + wait;
        // Whatever the broker says meanwhile is no longer of use; the thread ends when the
        // connection closes.
        while std::time::Instant::now() < until {
            match self.net.recv_timeout(std::time::Duration::from_millis(20)) {
                Ok(Err(_)) | Err(mpsc::RecvTimeoutError::Disconnected) => break,
                _ => {}
            }
        }
        if let Some(t) = self.thread.take() {
            if t.is_finished() {
                let _ = t.join();
            }
        }
    }
}
