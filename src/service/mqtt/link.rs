//! One connection to the broker: rumqttc's MQTT 5 client, its network thread (which drives
//! the connection and hands its events over a channel), and which records are in flight.
//!
//! MQTT 5 because its CONNECT carries a Maximum Packet Size: the broker never sends this
//! client a larger packet (it drops it for this client), so a neighbour's huge retained
//! message on a watched topic cannot end the connection each time it is made.
//!
//! A connection that fails is not reconnected by rumqttc (it would resend what it holds on
//! its own): the link ends, and the next one resends from the outbox, so the outbox alone
//! says what the broker has.

use rumqttc::v5::mqttbytes::v5::{Packet, PubAckReason, Publish, PublishProperties};
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::{Client, ConnectionError, Event, MqttOptions};
use rumqttc::Outgoing;
use std::collections::{BTreeSet, HashMap, VecDeque};
use std::sync::mpsc::{self, Receiver, TryRecvError};
use std::thread;
use std::time::Duration;

/// What a publish was, for when its packet id is known.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Tag {
    /// A record's seq, if it is one.
    record: Option<u64>,
    /// Its topic (for a refusal's message).
    topic: String,
}

/// What the network thread tells.
pub enum NetEvent {
    /// The broker accepted the connection.
    Connected,
    /// The broker acknowledged this record (all before it may still be in flight).
    Acked(u64),
    /// The broker acknowledged a publish with a refusal (its ACL, a quota): it is not
    /// delivered, and sending it again would be refused again.
    Refused {
        /// The publish's topic.
        topic: String,
        /// For a record: the highest seq now done with every one before it (a refused
        /// record is done: the outbox must not wait for ever on what the broker will not
        /// take).
        acked: Option<u64>,
        /// The broker's reason.
        reason: PubAckReason,
    },
    /// A publish over the broker's Maximum Packet Size (its CONNACK's), not sent: the broker
    /// would end the connection on it, and on every resend.
    TooLarge {
        /// The publish's topic.
        topic: String,
        /// Its packet's size in bytes.
        size: usize,
        /// The broker's limit.
        max: u32,
        /// For a record: its seq and the highest seq now done with every one before it (it
        /// is done: it never will be sent).
        record: Option<(u64, u64)>,
    },
    /// A message on a topic the rig subscribed to.
    Message {
        /// Its topic.
        topic: String,
        /// Its payload.
        payload: Vec<u8>,
        /// Where its sender wants an answer, and the data to answer with (MQTT 5's Response
        /// Topic and Correlation Data, if it gave them).
        respond: Respond,
    },
    /// The connection failed or was refused: the link is over.
    Failed(ConnectionError),
    /// The network thread panicked (a fault in the MQTT library), saying this: the link is
    /// over.
    Panicked(String),
}

/// MQTT 5's request/response properties of a message (section 4.10 of the standard).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Respond {
    /// The Response Topic the sender named.
    pub topic: Option<String>,
    /// The Correlation Data the answer must carry.
    pub correlation: Option<Vec<u8>>,
}

/// Requests rumqttc's client may hold before `try_publish` says full.
const CLIENT_QUEUE: usize = 256;

/// A live (or coming) connection.
pub struct Link {
    client: Client,
    net: Receiver<Event2>,
    tags: VecDeque<Tag>,
    by_packet: HashMap<u16, Tag>,
    unacked: BTreeSet<u64>,
    highest_sent: Option<u64>,
    connected: bool,
    /// The broker's Maximum Packet Size (its CONNACK's), if it gave one.
    max_packet: Option<u32>,
    /// The keep-alive the broker asked for (its CONNACK's Server Keep Alive), if it did.
    server_keep_alive: Option<Duration>,
    /// Publishes not sent, to be told by the next `poll`.
    too_large: VecDeque<NetEvent>,
    thread: Option<thread::JoinHandle<()>>,
}

/// What became of a record handed to `send_record`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sent {
    /// Queued for the broker.
    Queued,
    /// Over the broker's limit: not sent, done (`poll` tells a `TooLarge`).
    TooLarge,
    /// The client's queue is full: try again later.
    Full,
}

/// The keep-alive to ping at once the broker's CONNACK said `server` (its Server Keep
/// Alive), if not the one the client library takes from it: 0 turns keep-alive off (MQTT 5,
/// section 3.2.2.3.14), which the library would take as a ping due at every turn (a second
/// ping before the first's answer ends the connection). Off, the broker calls no silent client
/// gone; the client still pings at its own `ours`, to notice a broker gone silent.
pub fn keep_alive_after(server: Option<u16>, ours: Duration) -> Option<Duration> {
    (server == Some(0)).then_some(ours)
}

/// The network thread's raw events (kept apart from `NetEvent` so tags are matched here).
type Event2 = Result<Event, Over>;

/// How the network thread ended.
enum Over {
    /// The connection failed.
    Failed(ConnectionError),
    /// The thread panicked, saying this.
    Panicked(String),
}

impl Link {
    /// Starts connecting with `options`.
    pub fn open(options: MqttOptions) -> Self {
        let ours = options.keep_alive();
        let (client, mut connection) = Client::new(options, CLIENT_QUEUE);
        let (tx, net) = mpsc::sync_channel(1024);
        let thread = thread::Builder::new()
            .name("mqtt-net".into())
            .spawn(move || {
                let ran = super::catching(|| loop {
                    match connection.recv() {
                        Ok(Ok(event)) => {
                            // Before the next poll, whose first ping timer is already set:
                            // it fires once, then at the keep-alive set here.
                            if let Event::Incoming(Packet::ConnAck(ack)) = &event {
                                let server =
                                    ack.properties.as_ref().and_then(|p| p.server_keep_alive);
                                if let Some(k) = keep_alive_after(server, ours) {
                                    connection.eventloop.options.set_keep_alive(k);
                                }
                            }
                            if tx.send(Ok(event)).is_err() {
                                return;
                            }
                        }
                        Ok(Err(e)) => {
                            let _ = tx.send(Err(Over::Failed(e)));
                            return;
                        }
                        Err(_) => return,
                    }
                });
                if let Err(why) = ran {
                    let _ = tx.send(Err(Over::Panicked(why)));
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
            max_packet: None,
            server_keep_alive: None,
            too_large: VecDeque::new(),
            thread,
        }
    }

    /// Whether the broker has accepted the connection.
    pub fn connected(&self) -> bool {
        self.connected
    }

    /// The keep-alive the broker asked for as it accepted the connection, if it did (rumqttc
    /// pings at it instead of the one asked for; zero: off, `keep_alive_after`).
    pub fn server_keep_alive(&self) -> Option<Duration> {
        self.server_keep_alive
    }

    /// The next thing the connection tells, if any; `Failed` when it is over.
    pub fn poll(&mut self) -> Option<NetEvent> {
        if let Some(told) = self.too_large.pop_front() {
            return Some(told);
        }
        loop {
            let event = match self.net.try_recv() {
                Ok(e) => e,
                Err(TryRecvError::Empty) => return None,
                Err(TryRecvError::Disconnected) => {
                    return Some(NetEvent::Failed(ConnectionError::RequestsDone))
                }
            };
            match event {
                Err(over) => {
                    self.connected = false;
                    return Some(match over {
                        Over::Failed(e) => NetEvent::Failed(e),
                        Over::Panicked(why) => NetEvent::Panicked(why),
                    });
                }
                Ok(Event::Incoming(Packet::ConnAck(ack))) => {
                    // rumqttc ends the connection on a larger publish (as the broker would):
                    // known here, such a publish is never handed to it.
                    let properties = ack.properties.as_ref();
                    self.max_packet = properties.and_then(|p| p.max_packet_size);
                    // rumqttc takes it as its own keep-alive (the broker's wins).
                    self.server_keep_alive = properties
                        .and_then(|p| p.server_keep_alive)
                        .map(|k| Duration::from_secs(k.into()));
                    self.connected = true;
                    return Some(NetEvent::Connected);
                }
                Ok(Event::Outgoing(Outgoing::Publish(pkid))) => {
                    // QoS 0 publishes get packet id 0 and no acknowledgement.
                    if let Some(tag) = self.tags.pop_front().filter(|_| pkid != 0) {
                        self.by_packet.insert(pkid, tag);
                    }
                }
                Ok(Event::Incoming(Packet::PubAck(ack))) => {
                    let refused = !matches!(
                        ack.reason,
                        PubAckReason::Success | PubAckReason::NoMatchingSubscribers
                    );
                    let Some(tag) = self.by_packet.remove(&ack.pkid) else {
                        continue;
                    };
                    let acked = tag.record.map(|seq| {
                        self.unacked.remove(&seq);
                        self.acked_through()
                    });
                    if refused {
                        return Some(NetEvent::Refused {
                            topic: tag.topic,
                            acked,
                            reason: ack.reason,
                        });
                    }
                    if let Some(seq) = acked {
                        return Some(NetEvent::Acked(seq));
                    }
                }
                Ok(Event::Incoming(Packet::Publish(p))) => {
                    let properties = p.properties.as_ref();
                    return Some(NetEvent::Message {
                        topic: String::from_utf8_lossy(&p.topic).into_owned(),
                        payload: p.payload.to_vec(),
                        respond: Respond {
                            topic: properties.and_then(|p| p.response_topic.clone()),
                            correlation: properties
                                .and_then(|p| p.correlation_data.as_ref())
                                .map(|d| d.to_vec()),
                        },
                    });
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

    /// Publishes a record (QoS 1, not retained), unless it is over the broker's limit.
    pub fn send_record(&mut self, topic: &str, seq: u64, payload: &str) -> Sent {
        let publish = match self.fitting(topic, QoS::AtLeastOnce, payload.as_bytes(), None) {
            Ok(p) => p,
            Err((size, max)) => {
                // Sent as far as the order goes: done with, never waited on.
                self.highest_sent = Some(seq);
                self.too_large.push_back(NetEvent::TooLarge {
                    topic: topic.to_string(),
                    size,
                    max,
                    record: Some((seq, self.acked_through())),
                });
                return Sent::TooLarge;
            }
        };
        if self
            .client
            .try_publish(topic, QoS::AtLeastOnce, false, publish.payload)
            .is_err()
        {
            return Sent::Full;
        }
        self.tags.push_back(Tag {
            record: Some(seq),
            topic: topic.to_string(),
        });
        self.unacked.insert(seq);
        self.highest_sent = Some(seq);
        Sent::Queued
    }

    /// Publishes anything else; false if the client's queue is full (one over the broker's
    /// limit is done with: not sent, `poll` tells a `TooLarge`).
    pub fn send(&mut self, topic: &str, qos: QoS, retain: bool, payload: &[u8]) -> bool {
        self.send_with(topic, qos, retain, payload, None)
    }

    /// As `send`, with `correlation` as the publish's Correlation Data (a reply to an MQTT 5
    /// request).
    pub fn send_with(
        &mut self,
        topic: &str,
        qos: QoS,
        retain: bool,
        payload: &[u8],
        correlation: Option<&[u8]>,
    ) -> bool {
        let properties = correlation.map(|c| PublishProperties {
            correlation_data: Some(c.to_vec().into()),
            ..PublishProperties::default()
        });
        let publish = match self.fitting(topic, qos, payload, properties.clone()) {
            Ok(p) => p,
            Err((size, max)) => {
                self.too_large.push_back(NetEvent::TooLarge {
                    topic: topic.to_string(),
                    size,
                    max,
                    record: None,
                });
                return true;
            }
        };
        let sent = match properties {
            Some(p) => {
                self.client
                    .try_publish_with_properties(topic, qos, retain, publish.payload, p)
            }
            None => self.client.try_publish(topic, qos, retain, publish.payload),
        }
        .is_ok();
        if sent {
            self.tags.push_back(Tag {
                record: None,
                topic: topic.to_string(),
            });
        }
        sent
    }

    /// The publish, if its packet (sized as rumqttc sizes it) is within the broker's limit;
    /// else its size and the limit.
    fn fitting(
        &self,
        topic: &str,
        qos: QoS,
        payload: &[u8],
        properties: Option<PublishProperties>,
    ) -> Result<Publish, (usize, u32)> {
        let mut publish = Publish::new(topic, qos, payload.to_vec(), properties);
        // Room for the packet id rumqttc gives a QoS 1 publish.
        publish.pkid = u16::from(qos != QoS::AtMostOnce);
        let size = publish.size();
        match self.max_packet {
            Some(max) if size > max as usize => Err((size, max)),
            _ => Ok(publish),
        }
    }

    /// Subscribes to `filter` (QoS 1); false if the client's queue is full.
    pub fn subscribe(&mut self, filter: &str) -> bool {
        self.client.try_subscribe(filter, QoS::AtLeastOnce).is_ok()
    }

    /// Unsubscribes from `filter`; false if the client's queue is full.
    pub fn unsubscribe(&mut self, filter: &str) -> bool {
        self.client.try_unsubscribe(filter).is_ok()
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_server_keep_alive_of_zero_is_off_and_the_client_pings_at_its_own() {
        let ours = Duration::from_secs(10);
        assert_eq!(keep_alive_after(Some(0), ours), Some(ours));
        // The library heeds any other the broker gives, and its own when none.
        assert_eq!(keep_alive_after(Some(3), ours), None);
        assert_eq!(keep_alive_after(None, ours), None);
    }
}
