//! Faults planned in virtual time (the words are `sim::faults`'s): a byte link to a simulated
//! device that drops, flips, delays or cuts answers as a `FaultPlan` says (`FaultyLink`), and a virtual
//! clock that runs scheduled actions as time passes (`EventClock`: a signal, a stalled
//! process, a module unplugged by hand).
//!
//! How a fault plays out on the line:
//! - Answer faults (`Drop`, `Flip`, `Late`) take the next answer(s) the device gives at or
//!   after their time. The request always reaches the device: only what comes back suffers.
//! - The line is a queue: an answer can never overtake one sent before it (and comes
//!   `ANSWER_SPACING` after one still on its way), so a late answer holds up the answers behind
//!   it and arrives inside a later exchange's window, as on a wire where the module answers one
//!   request at a time.
//! - `Disconnect` makes every write and read fail as an unplugged USB-serial adapter does;
//!   `Silence` keeps the link but the device hears and says nothing (a cut RS-485 pair, a
//!   module without power); each lasts the time it is given. Overlapping ones nest: the line
//!   is back only when every one holding it down has ended, and while a `Disconnect` holds it
//!   the calls fail whatever else does. Powering the module off and on again is the model's
//!   business (`C29u::power_cycle`), not the link's.
//! - The plan records each answer an answer fault acted on, and when (`FaultPlan::hits`): a
//!   fault armed at one time can act much later, at the next exchange that is answered.
//! - `Stall` blocks the next link call for a while (flow control, a hung driver): virtual time
//!   passes inside the call.
//! - `Panic` makes the next link call panic: a bug anywhere under the runner, to test that a
//!   panic still leaves the outputs safe.

use crate::link::far_end::ByteDevice;
use crate::link::line;
use crate::link::{ByteLink, LinkError};
use crate::time::clock::{Clock, SharedClock, VirtualClock};
use chrono::{DateTime, Utc};
use std::collections::VecDeque;
use std::fmt;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

/// How long after an answer still on the wire the next one can arrive at the earliest (the
/// module answers one request at a time; about a short answer's length at 9600 baud).
pub const ANSWER_SPACING: Duration = Duration::from_millis(5);

/// The text every injected panic starts with, so a test can tell it from a real one.
pub const INJECTED_PANIC: &str = "fault injection: injected panic";

/// One fault on a line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkFault {
    /// The next `answers` answers are lost (the requests still reach the device).
    Drop {
        /// How many answers in a row.
        answers: u8,
    },
    /// The next answer arrives with the byte at `at` (modulo its length) XORed with `xor`.
    Flip {
        /// Which byte.
        at: u8,
        /// What to flip (0 flips bit 0).
        xor: u8,
    },
    /// The next answer arrives this much later than the device gave it.
    Late(Duration),
    /// Writes and reads fail as on an unplugged adapter, for this long.
    Disconnect(Duration),
    /// The device hears and says nothing, for this long.
    Silence(Duration),
    /// The next link call takes this much longer.
    Stall(Duration),
    /// The next link call panics.
    Panic,
}

impl fmt::Display for LinkFault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LinkFault::Drop { answers } => write!(f, "drop {answers} answer(s)"),
            LinkFault::Flip { at, xor } => write!(f, "flip byte {at} (xor {xor:#04x})"),
            LinkFault::Late(d) => write!(f, "next answer {d:?} late"),
            LinkFault::Disconnect(d) => write!(f, "disconnect for {d:?}"),
            LinkFault::Silence(d) => write!(f, "silence for {d:?}"),
            LinkFault::Stall(d) => write!(f, "stall the next call {d:?}"),
            LinkFault::Panic => f.write_str("panic in the next call"),
        }
    }
}

/// Whether the line carries anything (up, unplugged, or connected to a module that says nothing).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Connection {
    /// Requests reach the device and answers come back.
    #[default]
    Up,
    /// The link fails every write and read.
    Disconnected,
    /// The link works; the device hears and says nothing.
    Silent,
}

/// An answer fault's act: the answer it dropped, flipped or delayed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FaultHit {
    /// When the fault was planned for.
    pub planned: Duration,
    /// The fault.
    pub fault: LinkFault,
    /// When the answer it acted on was given.
    pub at: Duration,
}

/// Faults that have come due and wait for the answer or the call they act on; each answer
/// fault with its index in `PlanState::applied`, taken in the order they came due.
#[derive(Debug, Default)]
struct Armed {
    drop: VecDeque<(usize, u32)>,
    flip: VecDeque<(usize, u8, u8)>,
    late: VecDeque<(usize, Duration)>,
    stall: Duration,
    panic: bool,
}

#[derive(Debug, Default)]
struct PlanState {
    /// Faults not yet due, by time (stable for equal times).
    schedule: VecDeque<(Duration, LinkFault)>,
    armed: Armed,
    /// The `Disconnect`s and `Silence`s that came due, each with the time it ends.
    holds: Vec<(Duration, Connection)>,
    /// The host is gone (killed): nothing it sends arrives, whatever else is planned.
    cut: bool,
    /// Faults that came due, with their times.
    applied: Vec<(Duration, LinkFault)>,
    /// The answers the answer faults acted on: when, and the fault's index in `applied`.
    hits: Vec<(Duration, usize)>,
}

/// The faults of one line on the virtual clock, shared between the `FaultyLink` that suffers
/// them and the test that plans and watches them.
#[derive(Debug, Clone, Default)]
pub struct FaultPlan(Arc<Mutex<PlanState>>);

impl FaultPlan {
    /// A plan without faults.
    pub fn new() -> Self {
        Self::default()
    }

    fn lock(&self) -> MutexGuard<'_, PlanState> {
        // A poisoned plan only means a panicking caller (an injected panic); the state is whole.
        crate::sync::lock(&self.0)
    }

    /// Adds `fault` at virtual time `at` (after any fault already planned for the same time).
    pub fn add(&self, at: Duration, fault: LinkFault) {
        let mut p = self.lock();
        let pos = p.schedule.partition_point(|(t, _)| *t <= at);
        p.schedule.insert(pos, (at, fault));
    }

    /// Applies the faults due at `now`; returns the line's state then.
    pub fn state_at(&self, now: Duration) -> Connection {
        let mut p = self.lock();
        p.apply_due(now);
        p.current()
    }

    /// From now on nothing the host sends reaches the line and nothing comes back, whatever
    /// else is planned: the host process was killed, and the devices are on their own.
    pub fn cut_off(&self) {
        self.lock().cut = true;
    }

    /// The faults that have come due so far, with their times.
    pub fn applied(&self) -> Vec<(Duration, LinkFault)> {
        self.lock().applied.clone()
    }

    /// Every answer the answer faults (`Drop`, `Flip`, `Late`) have acted on so far, in
    /// order.
    pub fn hits(&self) -> Vec<FaultHit> {
        let p = self.lock();
        p.hits
            .iter()
            .filter_map(|&(at, i)| {
                let &(planned, fault) = p.applied.get(i)?;
                Some(FaultHit { planned, fault, at })
            })
            .collect()
    }
}

impl PlanState {
    /// The state the host sees: a disconnect held wins over a silence held.
    fn current(&self) -> Connection {
        let held = |c| self.holds.iter().any(|&(_, h)| h == c);
        if held(Connection::Disconnected) {
            Connection::Disconnected
        } else if self.cut || held(Connection::Silent) {
            Connection::Silent
        } else {
            Connection::Up
        }
    }

    fn apply_due(&mut self, now: Duration) {
        while self.schedule.front().is_some_and(|(t, _)| *t <= now) {
            let Some((at, fault)) = self.schedule.pop_front() else {
                break;
            };
            let i = self.applied.len();
            let a = &mut self.armed;
            match fault {
                LinkFault::Drop { answers } if answers > 0 => {
                    a.drop.push_back((i, answers.into()));
                }
                LinkFault::Drop { .. } => {}
                LinkFault::Flip { at, xor } => a.flip.push_back((i, at, xor)),
                LinkFault::Late(d) => a.late.push_back((i, d)),
                LinkFault::Disconnect(d) => self
                    .holds
                    .push((at.saturating_add(d), Connection::Disconnected)),
                LinkFault::Silence(d) => {
                    self.holds.push((at.saturating_add(d), Connection::Silent));
                }
                LinkFault::Stall(d) => a.stall = a.stall.saturating_add(d),
                LinkFault::Panic => a.panic = true,
            }
            self.applied.push((at, fault));
        }
        self.holds.retain(|&(end, _)| end > now);
    }
}

/// A byte link to a simulated device with faults from a `FaultPlan` on the way, in the link's
/// clock's time. Otherwise as `MemoryByteLink`: a write hands the device a whole frame and
/// then tells it the line fell silent; a read with nothing to hand waits (on the clock) for
/// the next answer on the wire or the timeout, whichever comes first.
pub struct FaultyLink<D: ByteDevice> {
    device: D,
    name: String,
    clock: SharedClock,
    plan: FaultPlan,
    /// Answers on their way, with the time each arrives, in order.
    wire: VecDeque<(Duration, Vec<u8>)>,
    /// Bytes that have arrived and not been read.
    arrived: VecDeque<u8>,
    /// The line's timing as the exchange layer keeps it (untimed: memory has no wire).
    line: line::LineState,
}

impl<D: ByteDevice> FaultyLink<D> {
    /// A link called `name` to `device`, suffering `plan` on `clock`.
    pub fn new(device: D, name: impl Into<String>, clock: SharedClock, plan: FaultPlan) -> Self {
        Self {
            device,
            name: name.into(),
            clock,
            plan,
            wire: VecDeque::new(),
            arrived: VecDeque::new(),
            line: line::LineState::untimed(),
        }
    }

    /// The simulated device at the far end.
    pub fn device(&mut self) -> &mut D {
        &mut self.device
    }

    /// Applies the due faults and runs those that act on a call (panic, stall); the state.
    fn begin_call(&mut self) -> Connection {
        let now = self.clock.now();
        let (state, stall, panic) = {
            let mut p = self.plan.lock();
            p.apply_due(now);
            let stall = std::mem::take(&mut p.armed.stall);
            let panic = std::mem::take(&mut p.armed.panic);
            (p.current(), stall, panic)
        };
        // Never while unwinding already: a second panic would abort the process.
        if panic && !std::thread::panicking() {
            panic!("{INJECTED_PANIC} on {}", self.name);
        }
        if !stall.is_zero() {
            self.clock.sleep_until(now.saturating_add(stall));
        }
        if state == Connection::Disconnected {
            self.wire.clear();
            self.arrived.clear();
        }
        state
    }

    fn unplugged(&self) -> LinkError {
        LinkError::Disconnected {
            what: self.describe(),
            detail: "unplugged (fault injection)".into(),
        }
    }

    /// Puts an answer on the wire, as the armed faults make it.
    fn send_back(&mut self, mut answer: Vec<u8>) {
        if answer.is_empty() {
            return;
        }
        let now = self.clock.now();
        let mut arrives = now;
        {
            let mut p = self.plan.lock();
            let p = &mut *p;
            let a = &mut p.armed;
            if let Some((i, left)) = a.drop.front_mut() {
                p.hits.push((now, *i));
                *left -= 1;
                if *left == 0 {
                    a.drop.pop_front();
                }
                return;
            }
            if let Some((i, at, xor)) = a.flip.pop_front() {
                p.hits.push((now, i));
                let i = usize::from(at) % answer.len();
                if let Some(b) = answer.get_mut(i) {
                    *b ^= if xor == 0 { 1 } else { xor };
                }
            }
            if let Some((i, d)) = a.late.pop_front() {
                p.hits.push((now, i));
                arrives = now.saturating_add(d);
            }
        }
        if let Some((last, _)) = self.wire.back() {
            arrives = arrives.max(last.saturating_add(ANSWER_SPACING));
        }
        self.wire.push_back((arrives, answer));
    }

    /// Moves the answers that have arrived by `now` off the wire.
    fn land(&mut self, now: Duration) {
        while self.wire.front().is_some_and(|(t, _)| *t <= now) {
            if let Some((_, bytes)) = self.wire.pop_front() {
                self.arrived.extend(bytes);
            }
        }
    }
}

impl<D: ByteDevice> ByteLink for FaultyLink<D> {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        match self.begin_call() {
            Connection::Disconnected => Err(self.unplugged()),
            Connection::Silent => Ok(()),
            Connection::Up => {
                let mut answer = self.device.receive(bytes);
                answer.extend(self.device.line_idle());
                self.send_back(answer);
                Ok(())
            }
        }
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError> {
        if self.begin_call() == Connection::Disconnected {
            return Err(self.unplugged());
        }
        let now = self.clock.now();
        self.land(now);
        if self.arrived.is_empty() {
            let until = now.saturating_add(timeout);
            match self.wire.front() {
                Some((t, _)) if *t <= until => {
                    let t = *t;
                    self.clock.sleep_until(t);
                    self.land(t);
                }
                _ => {
                    self.clock.sleep_until(until);
                    return Ok(0);
                }
            }
        }
        let n = buf.len().min(self.arrived.len());
        for (slot, byte) in buf.iter_mut().zip(self.arrived.drain(..n)) {
            *slot = byte;
        }
        Ok(n)
    }

    fn set_baud(&mut self, _baud: u32) -> Result<(), LinkError> {
        Ok(())
    }

    fn describe(&self) -> String {
        format!("simulated {}", self.name)
    }

    fn line(&mut self) -> Option<&mut line::LineState> {
        Some(&mut self.line)
    }
}

/// Something to do when virtual time reaches a point.
type Action = Box<dyn FnOnce(&VirtualClock) + Send>;

/// A watcher called each time virtual time has moved.
type Watcher = Box<dyn FnMut(Duration) + Send>;

#[derive(Default)]
struct Events {
    /// Actions not yet run, by time (stable for equal times).
    due: VecDeque<(Duration, Action)>,
}

/// A virtual clock that runs scheduled actions when time reaches them: whenever anything
/// sleeps through an action's time, the clock stops there, runs it, and goes on. An action may
/// move time on itself (a stalled process: `|t| t.advance(gap)`), set a stop flag (a signal),
/// or act on a simulator (a module power cycled by hand).
pub struct EventClock {
    time: VirtualClock,
    events: Mutex<Events>,
    watcher: Mutex<Option<Watcher>>,
}

impl EventClock {
    /// A clock over `time` (which the caller may keep to read or move time directly).
    pub fn new(time: VirtualClock) -> Self {
        Self {
            time,
            events: Mutex::new(Events::default()),
            watcher: Mutex::new(None),
        }
    }

    /// The virtual time underneath.
    pub fn virtual_clock(&self) -> &VirtualClock {
        &self.time
    }

    /// Runs `action` when time reaches `at` (after any action already set for that time).
    pub fn at(&self, at: Duration, action: impl FnOnce(&VirtualClock) + Send + 'static) {
        let mut e = crate::sync::lock(&self.events);
        let pos = e.due.partition_point(|(t, _)| *t <= at);
        e.due.insert(pos, (at, Box::new(action)));
    }

    /// Calls `watcher` with the time whenever the clock is read and after every sleep: a test
    /// can bound what a run may do (memory, work) even inside a tick that never sleeps. The
    /// watcher may panic to end the run; it is not called again while it runs.
    pub fn watch(&self, watcher: impl FnMut(Duration) + Send + 'static) {
        *crate::sync::lock(&self.watcher) = Some(Box::new(watcher));
    }

    /// Runs the watcher, if there is one and it is not running already.
    fn run_watcher(&self, now: Duration) {
        let watcher = crate::sync::lock(&self.watcher).take();
        if let Some(mut w) = watcher {
            w(now);
            let mut slot = crate::sync::lock(&self.watcher);
            if slot.is_none() {
                *slot = Some(w);
            }
        }
    }

    /// Drops the actions not yet run (a test ending its run, before it looks at the aftermath).
    pub fn clear(&self) {
        crate::sync::lock(&self.events).due.clear();
    }

    /// The next action due by `until`, taken off the list.
    fn next_due(&self, until: Duration) -> Option<(Duration, Action)> {
        let mut e = crate::sync::lock(&self.events);
        if e.due.front().is_some_and(|(t, _)| *t <= until) {
            e.due.pop_front()
        } else {
            None
        }
    }
}

impl Clock for EventClock {
    fn now(&self) -> Duration {
        let now = self.time.now();
        self.run_watcher(now);
        now
    }

    fn wall(&self) -> DateTime<Utc> {
        self.time.wall()
    }

    fn sleep_until(&self, deadline: Duration) {
        // Locks are not held while an action or the watcher runs: either may panic (a test
        // ending a hung run) or sleep on this clock again.
        while let Some((at, action)) = self.next_due(deadline.max(self.time.now())) {
            self.time.advance_to(at);
            action(&self.time);
        }
        self.time.advance_to(deadline);
        self.run_watcher(self.time.now());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::cancel::Cancel;
    use crate::device::exchange::{exchange, ExchangeError, Timing};
    use crate::link::line::FrameGap;
    use std::sync::atomic::{AtomicU32, Ordering};

    /// Answers each request with "<request>!" and counts what it heard.
    struct Echo(Arc<AtomicU32>);
    impl ByteDevice for Echo {
        fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
            self.0.fetch_add(1, Ordering::SeqCst);
            let mut answer = bytes.to_vec();
            answer.push(b'!');
            answer
        }
    }

    fn rig() -> (FaultyLink<Echo>, FaultPlan, VirtualClock, Arc<AtomicU32>) {
        let clock = VirtualClock::at_epoch();
        let plan = FaultPlan::new();
        let heard = Arc::new(AtomicU32::new(0));
        let link = FaultyLink::new(
            Echo(Arc::clone(&heard)),
            "echo",
            Arc::new(clock.clone()),
            plan.clone(),
        );
        (link, plan, clock, heard)
    }

    fn ask(link: &mut FaultyLink<Echo>, clock: &VirtualClock, req: &[u8]) -> Option<Vec<u8>> {
        let timing = Timing {
            timeout: Duration::from_millis(200),
            gap: None,
            frame_gap: FrameGap::Fixed(Duration::ZERO),
            protocol: crate::protocol::c29u::Protocol::Modbus,
            max_answer: 64,
            answer_len: None,
        };
        let frame = |r: &[u8]| {
            let end = r.iter().position(|&b| b == b'!')?;
            Some(r[..=end].to_vec())
        };
        match exchange(
            link,
            clock,
            req,
            true,
            timing,
            frame,
            &mut None,
            &Cancel::never(),
        ) {
            Ok(a) => Some(a),
            Err(ExchangeError::Timeout { .. }) => None,
            Err(e) => panic!("{e}"),
        }
    }

    const MS: fn(u64) -> Duration = Duration::from_millis;

    #[test]
    fn dropped_answers_cost_a_timeout_and_the_request_still_arrives() {
        let (mut link, plan, clock, heard) = rig();
        plan.add(MS(100), LinkFault::Drop { answers: 2 });
        assert_eq!(ask(&mut link, &clock, b"a").as_deref(), Some(&b"a!"[..]));
        clock.advance(MS(100));
        assert_eq!(ask(&mut link, &clock, b"b"), None);
        assert_eq!(clock.now(), MS(300));
        // After a timeout the line must be silent one more timeout before the next request.
        assert_eq!(ask(&mut link, &clock, b"c"), None);
        assert_eq!(clock.now(), MS(700));
        assert_eq!(ask(&mut link, &clock, b"d").as_deref(), Some(&b"d!"[..]));
        assert_eq!(clock.now(), MS(900));
        assert_eq!(heard.load(Ordering::SeqCst), 4);
        assert_eq!(plan.applied(), [(MS(100), LinkFault::Drop { answers: 2 })]);
    }

    #[test]
    fn a_late_answer_within_the_settling_silence_is_discarded() {
        let (mut link, plan, clock, _) = rig();
        plan.add(MS(0), LinkFault::Late(MS(250)));
        assert_eq!(ask(&mut link, &clock, b"a"), None, "200 ms timeout");
        assert_eq!(clock.now(), MS(200));
        // The late answer lands at 250 while the next request waits for 200 ms of silence:
        // it restarts the count, and b goes out at 450 and gets its own answer.
        assert_eq!(ask(&mut link, &clock, b"b").as_deref(), Some(&b"b!"[..]));
        assert_eq!(clock.now(), MS(450));
    }

    #[test]
    fn a_late_answer_arrives_in_the_next_exchange_and_holds_up_the_one_behind_it() {
        let (mut link, plan, clock, _) = rig();
        // Later than the timeout and the settling silence after it together.
        plan.add(MS(0), LinkFault::Late(MS(450)));
        assert_eq!(ask(&mut link, &clock, b"a"), None, "200 ms timeout");
        assert_eq!(clock.now(), MS(200));
        // b goes out after 200 ms of silence, at 400; its window catches the late answer.
        assert_eq!(ask(&mut link, &clock, b"b").as_deref(), Some(&b"a!"[..]));
        assert_eq!(clock.now(), MS(450));
        // The answer to b was behind it on the wire (at 455). An exchange after a timeout may
        // have caught a late answer, so the next request settles too, as long as that answer
        // may have been late (450 ms since a): b's answer is heard and dropped, and c goes out
        // after 450 ms of silence and gets its own answer.
        assert_eq!(ask(&mut link, &clock, b"c").as_deref(), Some(&b"c!"[..]));
        assert_eq!(clock.now(), MS(905));
        assert_eq!(ask(&mut link, &clock, b"d").as_deref(), Some(&b"d!"[..]));
        assert_eq!(
            clock.now(),
            MS(905),
            "nothing on the wire: the answer is there at once"
        );
    }

    #[test]
    fn flipped_answers_have_one_byte_changed() {
        let (mut link, plan, clock, _) = rig();
        plan.add(MS(0), LinkFault::Flip { at: 5, xor: 0x20 });
        // Byte 5 of a 3-byte answer is byte 2; '!' ^ 0x20 is '\x01', so no frame end.
        assert_eq!(ask(&mut link, &clock, b"xy"), None);
        assert_eq!(ask(&mut link, &clock, b"xy").as_deref(), Some(&b"xy!"[..]));
    }

    #[test]
    fn disconnect_fails_calls_and_silence_deafens_for_their_time() {
        let (mut link, plan, clock, heard) = rig();
        plan.add(MS(10), LinkFault::Disconnect(MS(10)));
        plan.add(MS(20), LinkFault::Silence(MS(10)));
        clock.advance(MS(10));
        assert!(matches!(
            link.write_all(b"a"),
            Err(LinkError::Disconnected { .. })
        ));
        let mut buf = [0u8; 8];
        assert!(link.read(&mut buf, MS(5)).is_err());
        assert_eq!(plan.state_at(clock.now()), Connection::Disconnected);
        clock.advance(MS(10));
        assert_eq!(ask(&mut link, &clock, b"b"), None);
        assert_eq!(
            heard.load(Ordering::SeqCst),
            0,
            "a silent device hears nothing"
        );
        assert_eq!(plan.state_at(clock.now()), Connection::Up);
        assert_eq!(ask(&mut link, &clock, b"c").as_deref(), Some(&b"c!"[..]));
        // A killed host: nothing gets through, and the end of a planned fault does not
        // change that.
        plan.cut_off();
        plan.add(clock.now(), LinkFault::Silence(MS(10)));
        clock.advance(MS(20));
        assert_eq!(ask(&mut link, &clock, b"d"), None);
        assert_eq!(plan.state_at(clock.now()), Connection::Silent);
        assert_eq!(heard.load(Ordering::SeqCst), 1);
    }

    #[test]
    fn overlapping_line_faults_nest_and_the_line_is_back_when_the_last_one_ends() {
        let (_link, plan, _clock, _) = rig();
        // An 8 s silence and a 1.5 s one from the same moment (the fault search, seed 777
        // case 1079): the shorter one's end must not bring the line back.
        plan.add(MS(1), LinkFault::Silence(MS(8000)));
        plan.add(MS(1), LinkFault::Silence(MS(1500)));
        assert_eq!(plan.state_at(MS(1)), Connection::Silent);
        assert_eq!(plan.state_at(MS(1501)), Connection::Silent);
        assert_eq!(plan.state_at(MS(8000)), Connection::Silent);
        assert_eq!(plan.state_at(MS(8001)), Connection::Up);
        // An unplug with a shorter silence inside it (seed 31337 case 968): unplugged
        // throughout; and a silence that outlasts an unplug keeps the line silent after it.
        let (_link, plan, _clock, _) = rig();
        plan.add(MS(0), LinkFault::Disconnect(MS(8000)));
        plan.add(MS(0), LinkFault::Silence(MS(1500)));
        plan.add(MS(7000), LinkFault::Silence(MS(2000)));
        assert_eq!(plan.state_at(MS(0)), Connection::Disconnected);
        assert_eq!(plan.state_at(MS(1500)), Connection::Disconnected);
        assert_eq!(plan.state_at(MS(7500)), Connection::Disconnected);
        assert_eq!(plan.state_at(MS(8000)), Connection::Silent);
        assert_eq!(plan.state_at(MS(9000)), Connection::Up);
    }

    #[test]
    fn the_plan_records_when_each_answer_fault_acted() {
        let (mut link, plan, clock, _) = rig();
        plan.add(MS(0), LinkFault::Drop { answers: 2 });
        plan.add(MS(0), LinkFault::Late(MS(50)));
        plan.add(MS(0), LinkFault::Drop { answers: 1 });
        assert!(plan.hits().is_empty(), "armed, but no answer yet");
        clock.advance(MS(1000));
        // Faults armed at 0 act on the answers given from 1 s on, in the order they came due.
        for _ in 0..4 {
            ask(&mut link, &clock, b"a");
        }
        let hits: Vec<(Duration, LinkFault, Duration)> = plan
            .hits()
            .iter()
            .map(|h| (h.planned, h.fault, h.at))
            .collect();
        assert_eq!(
            hits,
            [
                (MS(0), LinkFault::Drop { answers: 2 }, MS(1000)),
                (MS(0), LinkFault::Drop { answers: 2 }, MS(1400)),
                (MS(0), LinkFault::Drop { answers: 1 }, MS(1800)),
                (MS(0), LinkFault::Late(MS(50)), MS(2200)),
            ]
        );
    }

    #[test]
    fn a_stall_blocks_the_next_call_and_a_panic_is_injected_once() {
        let (mut link, plan, clock, _) = rig();
        plan.add(MS(0), LinkFault::Stall(MS(700)));
        link.write_all(b"a").unwrap();
        assert_eq!(clock.now(), MS(700));
        plan.add(MS(700), LinkFault::Panic);
        let hit = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            let _ = link.write_all(b"b");
        }));
        let message = hit.unwrap_err();
        let text = message.downcast_ref::<String>().unwrap();
        assert!(text.starts_with(INJECTED_PANIC), "{text}");
        assert_eq!(ask(&mut link, &clock, b"c").as_deref(), Some(&b"c!"[..]));
    }

    #[test]
    fn the_event_clock_runs_actions_in_time_order_while_sleeping() {
        let clock = EventClock::new(VirtualClock::at_epoch());
        let seen = Arc::new(Mutex::new(Vec::new()));
        for (at, tag) in [(300, "c"), (100, "a"), (100, "b")] {
            let s = Arc::clone(&seen);
            clock.at(MS(at), move |t| s.lock().unwrap().push((tag, t.now())));
        }
        // A stalled process: time jumps a second at 150 ms.
        clock.at(MS(150), |t| t.advance(MS(1000)));
        let watched = Arc::new(Mutex::new(Vec::new()));
        let w = Arc::clone(&watched);
        clock.watch(move |now| w.lock().unwrap().push(now));
        clock.sleep_until(MS(120));
        clock.sleep_until(MS(200));
        assert_eq!(clock.now(), MS(1150), "the stall ran past the deadline");
        assert_eq!(
            *seen.lock().unwrap(),
            [("a", MS(100)), ("b", MS(100)), ("c", MS(1150))]
        );
        // After each sleep, and at the read.
        assert_eq!(*watched.lock().unwrap(), [MS(120), MS(1150), MS(1150)]);
        clock.at(MS(2000), |_| panic!("cleared actions never run"));
        clock.clear();
        clock.sleep_until(MS(3000));
        assert_eq!(clock.now(), MS(3000));
    }
}
