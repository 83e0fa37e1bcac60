//! The client's own thread: follows the event stream, keeps the outbox, keeps a connection to
//! the broker (retried with back-off), publishes status, state, records, log lines and
//! replies, and hands inbound commands and messages to the loop. It never waits on the loop
//! for long (a snapshot at most `SNAPSHOT_WAIT`) and the loop never waits on it.

use super::health::{ClientHealth, Loss};
use super::link::{Link, NetEvent, Respond, Sent};
use super::outbox::{Outbox, Pushed};
use super::topics::{self, log_payload, reply_payload, MAX_PAYLOAD};
use super::{discovery, failure, Settings, FLUSH_WAIT};
use crate::runtime::log::Level;
use crate::runtime::observe::{RunEvent, Subscription};
use crate::runtime::remote::{Command, Remote, Reply, ReplyTo};
use crate::runtime::requests::{Answer, AskError, Request, Requester};
use crate::runtime::snapshot::RigSnapshot;
use rumqttc::v5::mqttbytes::v5::PubAckReason;
use rumqttc::v5::mqttbytes::QoS;
use rumqttc::v5::ConnectionError;
use std::collections::{BTreeMap, BTreeSet, HashMap, VecDeque};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, TryRecvError};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Records in flight (sent, not yet acknowledged) at most.
pub const WINDOW: usize = 64;

/// Commands waiting for the loop's answer at most; one more gets an error reply at once.
const MAX_PENDING_COMMANDS: usize = 16;

/// Replies waiting for room in the client's queue at most (a burst of refused commands
/// makes many at once); one more is counted lost, and told.
const MAX_REPLIES: usize = 1024;

/// How long a command may wait for its handler's reply.
const COMMAND_WAIT: Duration = Duration::from_secs(10);

/// Watched-topic messages handed to the loop per second at most (a neighbour flooding a
/// topic costs the loop that much); the rest are dropped, counted.
const MESSAGES_PER_SECOND: u32 = 100;

/// The longest wait for the loop's snapshot.
const SNAPSHOT_WAIT: Duration = Duration::from_millis(250);

/// State is refreshed at most this often on events, and at least this often anyway (latches
/// and online reasons come with no event).
const STATE_MIN_GAP: Duration = Duration::from_millis(50);
const STATE_REFRESH: Duration = Duration::from_secs(5);

/// The acknowledged seq goes to disk at most this often.
const COMMIT_EVERY: Duration = Duration::from_millis(200);

/// The first retry after a failed connection, and the longest.
const FIRST_RETRY: Duration = Duration::from_millis(500);
const MAX_RETRY: Duration = Duration::from_secs(5);

/// The same notice is told at most this often (then with the count since).
const NOTICE_GAP: Duration = Duration::from_secs(60);

/// The client's state.
pub struct Pump {
    s: Settings,
    sub: Subscription,
    ask: Requester,
    outbox: Outbox,
    closing: Arc<AtomicBool>,
    link: Option<Link>,
    retry_at: Instant,
    backoff: Duration,
    was_connected: bool,
    state_due: bool,
    state_asked: Instant,
    state_sent: BTreeMap<String, String>,
    /// Each device's state as last known: the loop's last snapshot, with the outputs written
    /// since (the end's safe state comes after the last snapshot the loop answers).
    state_known: BTreeMap<String, serde_json::Map<String, serde_json::Value>>,
    discovered: bool,
    watched: BTreeSet<String>,
    watched_asked: Instant,
    commands: Vec<(ReplyAddress, Receiver<Reply>, Instant)>,
    /// Replies not yet taken by the client's queue, oldest first.
    replies: VecDeque<(ReplyAddress, String)>,
    messages_this_second: (Instant, u32),
    committed: Instant,
    /// The last record sent, and whether it is still to be published as the last one.
    last_record: Option<(u64, String)>,
    last_record_sent: (Instant, u64),
    loop_gone: bool,
    /// The highest record seq counted as too large (a record met again is not counted again).
    too_large_through: u64,
    notices: HashMap<&'static str, (Instant, u64)>,
    /// What was lost and how the connection goes, shared with the loop's snapshot.
    health: ClientHealth,
}

impl Pump {
    /// A client for `s`, not yet connected.
    pub fn new(
        s: Settings,
        sub: Subscription,
        ask: Requester,
        outbox: Outbox,
        closing: Arc<AtomicBool>,
        health: ClientHealth,
    ) -> Self {
        let now = Instant::now();
        Self {
            s,
            sub,
            ask,
            outbox,
            closing,
            link: None,
            retry_at: now,
            backoff: FIRST_RETRY,
            was_connected: false,
            state_due: true,
            state_asked: now - STATE_REFRESH,
            state_sent: BTreeMap::new(),
            state_known: BTreeMap::new(),
            discovered: false,
            watched: BTreeSet::new(),
            watched_asked: now - STATE_REFRESH,
            commands: Vec::new(),
            replies: VecDeque::new(),
            messages_this_second: (now, 0),
            committed: now,
            last_record: None,
            last_record_sent: (now, 0),
            loop_gone: false,
            too_large_through: 0,
            notices: HashMap::new(),
            health,
        }
    }

    /// Runs until the run has ended (or `closing`), then flushes.
    pub fn run(mut self) {
        let waiting = self.outbox.waiting().len();
        self.info(&format!(
            "mqtt: broker {} as rig {} (topics {}/...; outbox {}{})",
            self.s.broker,
            self.s.rig,
            self.s.topics.prefix(),
            self.s.outbox_dir.display(),
            if waiting > 0 {
                format!(", {waiting} records from before to deliver")
            } else {
                String::new()
            }
        ));
        loop {
            let ended = self.take_events(Duration::from_millis(10));
            self.turn();
            if ended || self.closing.load(Ordering::SeqCst) {
                break;
            }
        }
        self.loop_gone = true;
        self.flush();
    }

    /// One turn of everything but the events.
    fn turn(&mut self) {
        self.keep_link();
        self.send_records();
        self.health.waiting(self.outbox.waiting().len());
        self.refresh_state();
        self.refresh_watched();
        self.answer_commands();
        self.send_replies();
        self.publish_last_record(false);
        if self.committed.elapsed() >= COMMIT_EVERY {
            self.commit();
        }
    }

    /// Takes what the run told, waiting at most `wait` for the first; true once it ended.
    fn take_events(&mut self, wait: Duration) -> bool {
        let mut wait = wait;
        // A bounded turn, so the connection is served while a burst comes.
        for _ in 0..4096 {
            let event = match self.sub.next(wait) {
                Ok(e) => e,
                Err(mpsc::RecvTimeoutError::Timeout) => break,
                Err(mpsc::RecvTimeoutError::Disconnected) => return true,
            };
            wait = Duration::ZERO;
            if self.on_event(&event) {
                return true;
            }
        }
        let lost = self.sub.newly_dropped();
        if lost > 0 {
            self.warn_counted(
                "events",
                lost,
                "mqtt: events lost: the client fell behind the run (records among them are \
                 missing from the broker; the records file has them)",
            );
        }
        false
    }

    /// Handles one event; true for the run's end.
    fn on_event(&mut self, event: &RunEvent) -> bool {
        match event {
            RunEvent::Record { line } => match self.outbox.push(line) {
                Ok(Pushed::Kept(_)) => {}
                Ok(Pushed::Full) => {
                    self.health.lost(Loss::OutboxFull);
                    self.warn_counted(
                        "outbox-full",
                        1,
                        &format!(
                            "mqtt: OUTBOX FULL ({} holds its outbox_max): records dropped, not \
                         delivered to broker {} until it takes the waiting ones",
                            self.s.outbox_dir.display(),
                            self.s.broker
                        ),
                    );
                }
                Err(e) => {
                    self.health.lost(Loss::OutboxWrite);
                    self.warn_counted("outbox-write", 1, &format!("mqtt: {e}"));
                }
            },
            RunEvent::Outputs { device, value, .. } => {
                if let Some(fields) = self.state_known.get_mut(device) {
                    written(fields, *value);
                }
                self.state_due = true;
            }
            RunEvent::Inputs { .. }
            | RunEvent::Shown { .. }
            | RunEvent::DeviceLost { .. }
            | RunEvent::DeviceBack { .. }
            | RunEvent::ScriptStarted { .. } => self.state_due = true,
            RunEvent::Published { topic, payload } => {
                let sent = match self.link.as_mut() {
                    Some(l) if l.connected() => {
                        l.send(topic, QoS::AtLeastOnce, false, payload.as_bytes())
                    }
                    _ => false,
                };
                if !sent {
                    self.health.lost(Loss::Publish);
                    self.warn_counted(
                        "publish",
                        1,
                        &format!(
                            "mqtt: mqtt_publish to {topic} dropped: not connected to broker {}",
                            self.s.broker
                        ),
                    );
                }
            }
            _ => {}
        }
        if let Some(payload) = log_payload(event, &now_text()) {
            let topic = self.s.topics.log();
            match self.link.as_mut() {
                Some(l) if l.connected() => {
                    if !l.send(&topic, QoS::AtMostOnce, false, payload.as_bytes()) {
                        self.health.lost(Loss::Log);
                    }
                }
                _ => self.health.lost(Loss::Log),
            }
        }
        matches!(event, RunEvent::Ended { .. })
    }

    /// Opens a connection when none is up and the back-off allows; handles what it tells.
    fn keep_link(&mut self) {
        if self.link.is_none() && Instant::now() >= self.retry_at {
            self.link = Some(Link::open(self.s.options()));
        }
        for _ in 0..1024 {
            let Some(event) = self.link.as_mut().and_then(Link::poll) else {
                break;
            };
            match event {
                NetEvent::Connected => self.on_connected(),
                NetEvent::Acked(seq) => self.outbox.ack_through(seq),
                NetEvent::Refused {
                    topic,
                    acked,
                    reason,
                } => self.on_refused(&topic, acked, reason),
                NetEvent::TooLarge {
                    topic,
                    size,
                    max,
                    record,
                } => self.on_too_large(&topic, size, max, record),
                NetEvent::Message {
                    topic,
                    payload,
                    respond,
                } => self.on_message(topic, payload, respond),
                NetEvent::Failed(e) => {
                    self.on_failed(&e);
                    break;
                }
                NetEvent::Panicked(why) => {
                    self.on_net_panic(&why);
                    break;
                }
            }
        }
    }

    fn on_connected(&mut self) {
        self.health.connected();
        self.backoff = FIRST_RETRY;
        let waiting = self.outbox.waiting().len();
        let again = if self.was_connected { "again " } else { "" };
        self.info(&format!(
            "mqtt: connected {again}to broker {} as {} (user {}){}",
            self.s.broker,
            self.s.rig,
            self.s.user(),
            if waiting > 0 {
                format!("; delivering {waiting} records from the outbox")
            } else {
                String::new()
            }
        ));
        self.was_connected = true;
        let asked = self.link.as_ref().and_then(Link::server_keep_alive);
        if asked == Some(Duration::ZERO) {
            self.info(&format!(
                "mqtt: broker {} turns keep-alive off (Server Keep Alive 0): it calls the rig \
                 offline only when its connection closes, not when it goes silent; the rig \
                 still pings every {} to notice a broker gone silent",
                self.s.broker,
                crate::time::duration::format_duration(self.s.keepalive)
            ));
        } else if let Some(k) = asked.filter(|k| *k != self.s.keepalive) {
            // rumqttc pings at the broker's keep-alive from now on: it says when a frozen rig
            // is called offline, not rig.toml.
            self.info(&format!(
                "mqtt: broker {} asks for a keep-alive of {} (rig.toml's keepalive is {}): a \
                 frozen rig is called offline within {}",
                self.s.broker,
                crate::time::duration::format_duration(k),
                crate::time::duration::format_duration(self.s.keepalive),
                crate::time::duration::format_duration(k * 3 / 2)
            ));
        }
        let status = self.s.topics.status();
        let commands = self.s.topics.commands();
        if let Some(l) = self.link.as_mut() {
            l.send(&status, QoS::AtLeastOnce, true, topics::ONLINE.as_bytes());
            l.subscribe(&commands);
        }
        self.state_sent.clear();
        self.state_due = true;
        self.discovered = false;
        self.watched.clear();
        self.watched_asked = Instant::now() - STATE_REFRESH;
    }

    /// The broker refused a publish (its ACL, most likely): counted, told, not sent again.
    fn on_refused(&mut self, topic: &str, acked: Option<u64>, reason: PubAckReason) {
        self.health.lost(Loss::Refused);
        let what = if acked.is_some() {
            "records are not delivered"
        } else {
            "not delivered"
        };
        let message = format!(
            "mqtt: broker {} refused user {}'s publish on {topic}: {reason:?} ({what}; does \
             the broker's ACL let the user write there?)",
            self.s.broker,
            self.s.user()
        );
        self.warn_counted("refused", 1, &message);
        if let Some(seq) = acked {
            self.outbox.ack_through(seq);
        }
    }

    /// A publish over the broker's limit, not sent: counted and told (a record once, though
    /// a connection made again meets it again), a record done with.
    fn on_too_large(&mut self, topic: &str, size: usize, max: u32, record: Option<(u64, u64)>) {
        if let Some((seq, acked)) = record {
            self.outbox.ack_through(acked);
            if seq <= self.too_large_through {
                return;
            }
            self.too_large_through = seq;
        }
        self.health.lost(Loss::TooLarge);
        let what = if record.is_some() {
            "a record"
        } else {
            "a publish"
        };
        let message = format!(
            "mqtt: {what} on {topic} not sent: {size} bytes, over broker {}'s limit of {max} \
             (its Maximum Packet Size); counted as too_large",
            self.s.broker
        );
        self.warn_counted("too-large", 1, &message);
    }

    fn on_failed(&mut self, e: &ConnectionError) {
        let was_up = self.link.as_ref().is_some_and(Link::connected);
        self.link = None;
        let waiting = self.outbox.waiting().len();
        let why = failure::describe(
            e,
            &failure::Peer {
                broker: &self.s.broker,
                user: self.s.user(),
                host: &self.s.host,
                password_from: "password_file / password_env",
            },
        );
        self.health.failed(&why);
        let message = if was_up || self.was_connected && self.backoff == FIRST_RETRY {
            format!(
                "mqtt: lost broker {}: {why}; the run goes on, records wait in the outbox \
                 ({waiting} now), retrying",
                self.s.broker
            )
        } else {
            format!(
                "mqtt: {why}; the run goes on, retrying in {} ({waiting} records waiting)",
                crate::time::duration::format_duration(self.backoff)
            )
        };
        self.warn_counted("connect", 1, &message);
        self.retry_later();
    }

    /// The network thread panicked (a fault in the MQTT library, on what the broker sent,
    /// say): an error in the log, a failed connection in the status, connected again like one.
    fn on_net_panic(&mut self, why: &str) {
        self.link = None;
        let why = format!("the client's network thread panicked: {why}");
        self.health.failed(&why);
        let message = format!(
            "mqtt: {why}; the run goes on, connecting to broker {} again in {} ({} records \
             waiting)",
            self.s.broker,
            crate::time::duration::format_duration(self.backoff),
            self.outbox.waiting().len()
        );
        self.tell_counted(Level::Error, "net-panic", 1, &message);
        self.retry_later();
    }

    /// The next connection after the back-off, which doubles (to `MAX_RETRY`).
    fn retry_later(&mut self) {
        self.retry_at = Instant::now() + self.backoff;
        self.backoff = (self.backoff * 2).min(MAX_RETRY);
    }

    /// Sends the records after the last one sent on this link, up to the window.
    fn send_records(&mut self) {
        let Some(link) = self.link.as_mut().filter(|l| l.connected()) else {
            return;
        };
        let from = link
            .highest_sent()
            .map_or(self.outbox.acked() + 1, |h| h + 1);
        let waiting = self.outbox.waiting();
        let start = waiting.partition_point(|p| p.seq < from);
        let topic = self.s.topics.records();
        for p in waiting.iter().skip(start) {
            if link.in_flight() >= WINDOW {
                break;
            }
            match link.send_record(&topic, p.seq, &p.payload) {
                Sent::Queued => self.last_record = Some((p.seq, p.payload.clone())),
                Sent::TooLarge => {}
                Sent::Full => break,
            }
        }
    }

    /// The last record acknowledged, retained, at most once a second (or now, at the end).
    fn publish_last_record(&mut self, now: bool) {
        let Some((seq, payload)) = &self.last_record else {
            return;
        };
        let due = now || self.last_record_sent.0.elapsed() >= Duration::from_secs(1);
        if *seq <= self.last_record_sent.1 || *seq > self.outbox.acked() || !due {
            return;
        }
        let (seq, topic) = (*seq, self.s.topics.last_record());
        if let Some(l) = self.link.as_mut().filter(|l| l.connected()) {
            if l.send(&topic, QoS::AtMostOnce, true, payload.as_bytes()) {
                self.last_record_sent = (Instant::now(), seq);
            }
        }
    }

    /// Publishes each device's state that changed since it was last published.
    fn refresh_state(&mut self) {
        let connected = self.link.as_ref().is_some_and(Link::connected);
        let since = self.state_asked.elapsed();
        let due = (self.state_due && since >= STATE_MIN_GAP) || since >= STATE_REFRESH;
        if !connected || !due || self.loop_gone {
            return;
        }
        self.state_asked = Instant::now();
        self.state_due = false;
        let snapshot = match self.ask.ask(Request::Snapshot, SNAPSHOT_WAIT) {
            Ok(Answer::Snapshot(s)) => s,
            Err(AskError::Gone) => {
                self.loop_gone = true;
                return;
            }
            // A loop behind on requests: the next turn asks again.
            _ => {
                self.state_due = true;
                return;
            }
        };
        if self.s.ha_discovery && !self.discovered {
            self.discover(&snapshot);
        }
        for (name, device) in &snapshot.devices {
            if let Ok(serde_json::Value::Object(fields)) = serde_json::to_value(device) {
                self.state_known.insert(name.clone(), fields);
            }
        }
        if !self.publish_state() {
            self.state_due = true;
        }
    }

    /// Publishes (retained) each device's known state that differs from the one published;
    /// false if the client's queue had no room for one.
    fn publish_state(&mut self) -> bool {
        let at = now_text();
        let mut all = true;
        for (name, fields) in &self.state_known {
            let plain = serde_json::Value::Object(fields.clone()).to_string();
            if self.state_sent.get(name) == Some(&plain) {
                continue;
            }
            let mut fields = fields.clone();
            fields.insert("at".into(), at.clone().into());
            let payload = serde_json::Value::Object(fields).to_string();
            let topic = self.s.topics.state(name);
            if let Some(l) = self.link.as_mut() {
                if l.send(&topic, QoS::AtLeastOnce, true, payload.as_bytes()) {
                    self.state_sent.insert(name.clone(), plain);
                } else {
                    all = false;
                }
            }
        }
        all
    }

    /// Home Assistant's discovery configs, once a connection.
    fn discover(&mut self, snapshot: &RigSnapshot) {
        let configs = discovery::configs(&self.s.rig, &self.s.topics, snapshot);
        if let Some(l) = self.link.as_mut() {
            self.discovered = configs
                .iter()
                .all(|(topic, payload)| l.send(topic, QoS::AtLeastOnce, true, payload.as_bytes()));
        }
    }

    /// Subscribes to the topics the script's `on_message` handlers watch, and unsubscribes
    /// from those they no longer do.
    fn refresh_watched(&mut self) {
        let connected = self.link.as_ref().is_some_and(Link::connected);
        if !connected || self.loop_gone || self.watched_asked.elapsed() < Duration::from_secs(2) {
            return;
        }
        self.watched_asked = Instant::now();
        let (tx, rx) = mpsc::sync_channel(1);
        match self.ask.ask(
            Request::Remote(Remote::Watched(ReplyTo(tx))),
            Duration::ZERO,
        ) {
            Ok(_) | Err(AskError::NoAnswer(_)) => {}
            Err(_) => return,
        }
        let Ok(Ok(text)) = rx.recv_timeout(SNAPSHOT_WAIT) else {
            return;
        };
        let Ok(filters) = serde_json::from_str::<BTreeSet<String>>(&text) else {
            return;
        };
        let Some(l) = self.link.as_mut() else {
            return;
        };
        // A filter no handler watches any more (cancelled) is left, so its messages stop
        // coming at all: nothing for the loop to take and nothing to count as dropped.
        let gone: Vec<String> = self.watched.difference(&filters).cloned().collect();
        for f in gone {
            if l.unsubscribe(&f) {
                self.watched.remove(&f);
            }
        }
        for f in filters {
            if !self.watched.contains(&f) && l.subscribe(&f) {
                self.watched.insert(f);
            }
        }
    }

    /// An inbound message: a command for the loop, or a watched topic's.
    fn on_message(&mut self, topic: String, payload: Vec<u8>, respond: Respond) {
        if let Some(name) = self.s.topics.command_name(&topic).map(str::to_string) {
            let to = ReplyAddress::of(&self.s.topics, &name, respond);
            return self.on_command(name, payload, to);
        }
        if topic.ends_with("/reply")
            && self
                .s
                .topics
                .command_name(topic.trim_end_matches("/reply"))
                .is_some()
        {
            return;
        }
        let now = Instant::now();
        if now.duration_since(self.messages_this_second.0) >= Duration::from_secs(1) {
            self.messages_this_second = (now, 0);
        }
        if self.messages_this_second.1 >= MESSAGES_PER_SECOND || payload.len() > MAX_PAYLOAD {
            self.health.lost(Loss::Message);
            self.warn_counted(
                "messages",
                1,
                &format!(
                    "mqtt: messages for on_message dropped (more than {MESSAGES_PER_SECOND} a \
                     second, or over {MAX_PAYLOAD} bytes; the last on {topic})"
                ),
            );
            return;
        }
        self.messages_this_second.1 += 1;
        let payload = String::from_utf8_lossy(&payload).into_owned();
        let asked = self.ask.ask(
            Request::Remote(Remote::Message { topic, payload }),
            Duration::ZERO,
        );
        if matches!(asked, Err(AskError::Busy)) {
            self.health.lost(Loss::Message);
        }
    }

    fn on_command(&mut self, name: String, payload: Vec<u8>, to: ReplyAddress) {
        let refuse = |why: String| Err(why);
        let reply = if payload.len() > MAX_PAYLOAD {
            refuse(format!(
                "a payload of {} bytes; at most {MAX_PAYLOAD}",
                payload.len()
            ))
        } else if self.commands.len() >= MAX_PENDING_COMMANDS {
            refuse(format!(
                "{MAX_PENDING_COMMANDS} commands wait for the rig already; try again"
            ))
        } else if self.loop_gone {
            refuse("the run has ended".into())
        } else {
            let (tx, rx) = mpsc::sync_channel(1);
            let command = Command {
                name,
                payload: String::from_utf8_lossy(&payload).into_owned(),
                reply: ReplyTo(tx),
            };
            match self
                .ask
                .ask(Request::Remote(Remote::Command(command)), Duration::ZERO)
            {
                Ok(_) | Err(AskError::NoAnswer(_)) => {
                    self.commands.push((to, rx, Instant::now() + COMMAND_WAIT));
                    return;
                }
                Err(e) => refuse(e.to_string()),
            }
        };
        if reply.is_err() {
            self.health.lost(Loss::Command);
        }
        self.reply(to, reply);
    }

    /// Publishes the replies the loop gave, and the error of those it did not give in time.
    fn answer_commands(&mut self) {
        let mut done = Vec::new();
        for (n, (to, rx, until)) in self.commands.iter().enumerate() {
            match rx.try_recv() {
                Ok(reply) => done.push((n, to.clone(), reply)),
                Err(TryRecvError::Disconnected) => {
                    done.push((n, to.clone(), Err("the run has ended".into())))
                }
                Err(TryRecvError::Empty) if Instant::now() >= *until => done.push((
                    n,
                    to.clone(),
                    Err(format!(
                        "no reply within {}",
                        crate::time::duration::format_duration(COMMAND_WAIT)
                    )),
                )),
                Err(TryRecvError::Empty) => {}
            }
        }
        for (n, _, _) in done.iter().rev() {
            self.commands.remove(*n);
        }
        // In the order they were asked.
        for (_, to, reply) in done {
            self.reply(to, reply);
        }
    }

    /// Queues `reply` for `to`; with the queue at its bound it is counted lost and told
    /// (never silently none).
    fn reply(&mut self, to: ReplyAddress, reply: Reply) {
        let value = reply.and_then(|text| {
            serde_json::from_str::<serde_json::Value>(&text).map_err(|e| e.to_string())
        });
        if self.replies.len() >= MAX_REPLIES {
            self.health.lost(Loss::Reply);
            let what = if value.is_ok() {
                "a reply"
            } else {
                "an error reply"
            };
            self.warn_counted(
                "replies",
                1,
                &format!(
                    "mqtt: {what} on {} not sent: {MAX_REPLIES} replies wait for broker {}                      already (counted as replies)",
                    to.topic, self.s.broker
                ),
            );
            return;
        }
        self.replies.push_back((to, reply_payload(&value)));
    }

    /// Hands the waiting replies to the client, oldest first, as far as its queue takes them.
    fn send_replies(&mut self) {
        let Some(l) = self.link.as_mut().filter(|l| l.connected()) else {
            return;
        };
        while let Some((to, payload)) = self.replies.front() {
            let sent = l.send_with(
                &to.topic,
                QoS::AtLeastOnce,
                false,
                payload.as_bytes(),
                to.correlation.as_deref(),
            );
            if !sent {
                break;
            }
            self.replies.pop_front();
        }
    }

    /// Writes the acknowledged seq to disk.
    fn commit(&mut self) {
        self.committed = Instant::now();
        if let Err(e) = self.outbox.commit() {
            self.warn_counted("outbox-commit", 1, &format!("mqtt: {e}"));
        }
    }

    /// The end: the outbox gets up to `FLUSH_WAIT`, the commands still waiting an error, the
    /// status `offline`; what is left waits in the outbox for the next start.
    fn flush(&mut self) {
        let until = Instant::now() + FLUSH_WAIT;
        while Instant::now() < until
            && !(self.outbox.waiting().is_empty() && self.replies.is_empty())
        {
            // Records told as the run ended are still in the stream.
            self.take_events(Duration::ZERO);
            self.turn();
            std::thread::sleep(Duration::from_millis(5));
        }
        self.take_events(Duration::ZERO);
        self.commit();
        for (to, _, _) in std::mem::take(&mut self.commands) {
            self.reply(to, Err("the run has ended".into()));
        }
        self.send_replies();
        let unsent = self.replies.len();
        if unsent > 0 {
            for _ in 0..unsent {
                self.health.lost(Loss::Reply);
            }
            self.replies.clear();
            self.warn(&format!(
                "mqtt: {unsent} command replies not sent: broker {} did not take them before                  the end",
                self.s.broker
            ));
        }
        let left = self.outbox.waiting().len();
        if left > 0 {
            self.warn(&format!(
                "mqtt: {left} records not delivered to broker {} within {}s: they wait in {} \
                 for the next start",
                self.s.broker,
                FLUSH_WAIT.as_secs(),
                self.s.outbox_dir.display()
            ));
        }
        let dropped = self.health.shown().dropped;
        let lost = [
            (dropped.messages, "watched-topic messages dropped"),
            (dropped.commands, "commands refused"),
            (dropped.publishes, "mqtt_publish messages dropped"),
            (dropped.replies, "command replies not sent"),
            (dropped.refused, "publishes the broker refused"),
            (
                dropped.too_large,
                "publishes over the broker's Maximum Packet Size not sent",
            ),
            (dropped.outbox_full, "records dropped: the outbox was full"),
            (
                dropped.outbox_write,
                "records dropped: the outbox could not write them",
            ),
        ];
        for (n, what) in lost {
            if n > 0 {
                self.warn(&format!("mqtt: {n} {what}"));
            }
        }
        self.publish_last_record(true);
        // The outputs the end left (its safe state) before `offline`: a dashboard must not
        // show the outputs the run last drove as the rig's state once it is gone.
        if self.link.as_ref().is_some_and(Link::connected) && !self.publish_state() {
            self.warn(&format!(
                "mqtt: the end's state not published to broker {}: the client's queue was full                  (its retained state may show the outputs before the end)",
                self.s.broker
            ));
        }
        if let Some(mut l) = self.link.take() {
            if l.connected() {
                let status = self.s.topics.status();
                l.send(&status, QoS::AtLeastOnce, true, topics::OFFLINE.as_bytes());
            }
            l.disconnect(Duration::from_millis(500));
            self.health.disconnected();
        }
    }

    /// A line for the run's log at info.
    fn info(&mut self, message: &str) {
        self.tell(Level::Info, message);
    }

    /// A warning for the run's log.
    fn warn(&mut self, message: &str) {
        self.tell(Level::Warn, message);
    }

    /// A warning told once, then at most every `NOTICE_GAP` with the count since.
    fn warn_counted(&mut self, key: &'static str, n: u64, message: &str) {
        self.tell_counted(Level::Warn, key, n, message);
    }

    /// A line at `level` told once, then at most every `NOTICE_GAP` with the count since.
    fn tell_counted(&mut self, level: Level, key: &'static str, n: u64, message: &str) {
        let now = Instant::now();
        let (told, count) = self.notices.entry(key).or_insert((now - NOTICE_GAP * 2, 0));
        *count += n;
        if now.duration_since(*told) < NOTICE_GAP {
            return;
        }
        let line = if *count > 1 {
            format!("{message} ({count} times)")
        } else {
            message.to_string()
        };
        *told = now;
        *count = 0;
        self.tell(level, &line);
    }

    /// Through the loop's log while the loop runs; to standard error after.
    fn tell(&mut self, level: Level, message: &str) {
        self.loop_gone = !tell(&self.ask, !self.loop_gone, level, message);
    }
}

/// Where a command's reply goes: the Response Topic its sender named (MQTT 5), with its
/// Correlation Data, else the rig's fixed reply topic (`{prefix}/cmd/NAME/reply`).
#[derive(Debug, Clone, PartialEq, Eq)]
struct ReplyAddress {
    topic: String,
    correlation: Option<Vec<u8>>,
}

impl ReplyAddress {
    /// The address for command `name` asked with `respond`. A Response Topic one could not
    /// publish to, or one under the rig's own prefix (a sender must not have the rig speak on
    /// its status, state or records topics), gives the fixed topic; the data goes along.
    fn of(topics: &topics::Topics, name: &str, respond: Respond) -> Self {
        let fixed = topics.reply(name);
        let own = |t: &str| {
            t.strip_prefix(topics.prefix())
                .is_some_and(|rest| rest.is_empty() || rest.starts_with('/'))
        };
        let topic = respond
            .topic
            .filter(|t| {
                topics::check_topic(t).is_ok() && !t.starts_with('$') && (*t == fixed || !own(t))
            })
            .unwrap_or(fixed);
        Self {
            topic,
            correlation: respond.correlation,
        }
    }
}

/// Tells `message` at `level` through the loop's log (`Remote::Log`) if `loop_runs`, else (or
/// when the loop is gone or its queue full) to standard error; false once the loop is gone.
pub(super) fn tell(ask: &Requester, loop_runs: bool, level: Level, message: &str) -> bool {
    let gone = !loop_runs
        || match ask.ask(
            Request::Remote(Remote::Log {
                level,
                message: message.to_string(),
            }),
            Duration::ZERO,
        ) {
            Ok(_) | Err(AskError::NoAnswer(_)) => return true,
            Err(AskError::Gone) => true,
            Err(AskError::Busy) => false,
        };
    let prefix = match level {
        Level::Warn => "warning: ",
        Level::Error => "error: ",
        _ => "",
    };
    let _ = std::io::Write::write_fmt(&mut std::io::stderr(), format_args!("{prefix}{message}\n"));
    !gone
}

/// A device's state (`DeviceState` as JSON) after its outputs were written `value`: the DO
/// byte of a TRP-C29U, the relay of a TRC1000.
fn written(fields: &mut serde_json::Map<String, serde_json::Value>, value: u8) {
    let keys = match fields.get("kind").and_then(serde_json::Value::as_str) {
        Some("trp-c29u") => ["outputs", "outputs_written"],
        Some("trc1000") => ["relay", "relay_written"],
        _ => return,
    };
    for key in keys {
        fields.insert(key.into(), value.into());
    }
}

/// Wall time now, local, RFC 3339 with milliseconds.
fn now_text() -> String {
    chrono::Local::now().to_rfc3339_opts(chrono::SecondsFormat::Millis, false)
}
