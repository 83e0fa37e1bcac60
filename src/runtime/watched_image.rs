//! The whole I/O image for those who watch the rig: while someone does (a page, `status
//! --watch`, an event-stream client, MQTT's state), each input of each device that the script
//! did not read lately is read for them, into an image of its own (`Snapshot`s beside the
//! script's), so the script's readings (its edges, a rotary's turn, a counter's re-arming) are
//! what they would be unwatched.
//!
//! The rate is bounded: each part (a module's DI byte, its counters; a panel's switches, its
//! rotaries) at most every `REFRESH` (250 ms), at most one such read a tick, and only when the
//! tick leaves the time it takes (the longer of its time on the line and the last one
//! measured, which is measured again after `MEASURE_AGAIN_AFTER` if it keeps the part out): a
//! watched rig keeps its period whatever the line's speed, and a part that never fits is not
//! shown fresher than the script reads it. Latches are not read for watchers (the page does
//! not show them). A rig nobody watches reads only what the script reads.

use super::devices::{Device, DeviceError};
use super::observe::{EventKind, Reading, RunEvent};
use super::state::Runtime;
use crate::device::c29u::C29uOptions;
use crate::link::line::wire_time;
use crate::protocol::c29u::{frame_gap, Protocol};
use std::time::Duration;

/// Each part of the image is read for watchers at most this often: four times a second, as
/// `status --watch` asks, what a person follows on a lamp; a change the script reads shows at
/// once anyway. Ten times a second cost a `--sim` interlock's ticks 10-15 % more work with a
/// page open (docs/benchmarks.md), over the 5 % viewers may cost.
pub const REFRESH: Duration = Duration::from_millis(250);

/// A snapshot asked for keeps the rig watched this long (a page asks every second, `status
/// --watch` as often as it shows).
pub const LINGER: Duration = Duration::from_secs(3);

/// A part due this long without a tick that has the time for it is said not to be shown
/// (`Runtime::not_shown`).
pub const NOT_SHOWN_AFTER: Duration = Duration::from_secs(1);

/// A part kept out this long by its measured time (longer than its time on the line) is
/// measured again.
pub const MEASURE_AGAIN_AFTER: Duration = Duration::from_secs(10);

/// The time a read for watchers leaves before the next tick's boundary: the tick's own end
/// and the wake-up.
pub const MARGIN: Duration = Duration::from_millis(1);

/// One part of a device's input image, read in one go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Part {
    /// A TRP-C29U's DI byte.
    Inputs,
    /// A TRP-C29U's eight counters.
    Counters,
    /// A TRC1000's switches.
    Switches,
    /// A TRC1000's rotaries.
    Rotaries,
}

/// What is known of one part of one device (a part is one driver read: a module's counters
/// over ASCII are eight exchanges, a panel's rotaries two packets).
#[derive(Debug, Clone, Copy)]
struct PartState {
    device: usize,
    part: Part,
    /// When it was last read, for the script or for watchers.
    read_at: Option<Duration>,
    /// How long its last read for watchers took.
    took: Option<Duration>,
    /// Since when it has been due without a tick leaving the time it takes.
    waiting_since: Option<Duration>,
}

impl Part {
    /// What the snapshot calls it.
    fn name(self) -> &'static str {
        match self {
            Part::Inputs => "inputs",
            Part::Counters => "counters",
            Part::Switches => "switches",
            Part::Rotaries => "rotaries",
        }
    }
}

/// Who watches, and what of the image was read when.
#[derive(Debug, Default)]
pub struct WatchedImage {
    /// A snapshot asked for keeps the rig watched until then.
    asked_until: Option<Duration>,
    /// Whether it was watched when last looked at (`watching_began`).
    was_watched: bool,
    /// Every part of every device, made at the first read for watchers.
    parts: Vec<PartState>,
    /// The part looked at first next time: each gets its turn.
    next: usize,
    /// The loop's period, as last told (`read_for_watchers`).
    period: Duration,
}

impl<H: Clone> Runtime<H> {
    /// Someone asked for the rig's snapshot at `now`: it is watched for `LINGER` more.
    pub fn snapshot_asked(&mut self, now: Duration) {
        self.image.asked_until = Some(now.saturating_add(LINGER));
    }

    /// Whether anyone watches the rig at `now`.
    pub fn watched(&self, now: Duration) -> bool {
        self.events().watchers() > 0 || self.image.asked_until.is_some_and(|t| now < t)
    }

    /// Whether watching began since the last call (a loop idle until later then ticks soon).
    /// Asked after each turn's requests: nobody watching costs two loads, not a clock read.
    pub fn watching_began(&mut self) -> bool {
        if self.events().watchers() == 0
            && self.image.asked_until.is_none()
            && !self.image.was_watched
        {
            return false;
        }
        let now = self.now();
        if self.image.asked_until.is_some_and(|t| t <= now) {
            self.image.asked_until = None;
        }
        let watched = self.watched(now);
        let began = watched && !self.image.was_watched;
        self.image.was_watched = watched;
        began
    }

    /// When a tick is next due for the watchers' sake (`None`: nobody watches): at once when a
    /// part is due that an idle tick has the time for (one that did not fit the last tick, a
    /// late one, is tried again at the next), else when the next part falls due.
    pub fn next_watched_read(&self, now: Duration) -> Option<Duration> {
        if !self.watched(now) {
            return None;
        }
        let waiting = self.image.parts.iter().any(|p| {
            p.waiting_since.is_some()
                && self
                    .expected(p)
                    .is_some_and(|t| t.saturating_add(MARGIN) <= self.image.period)
        });
        Some(if waiting {
            now
        } else {
            now.saturating_add(REFRESH)
        })
    }

    /// Reads for watchers the first part due, if anyone watches and the read ends by `until`
    /// (the next tick's boundary); `period` is the loop's.
    pub fn read_for_watchers(&mut self, until: Duration, period: Duration) {
        // A rig nobody watches pays two loads here, not a clock read.
        if self.events().watchers() == 0 && self.image.asked_until.is_none() {
            return;
        }
        let now = self.now();
        if self.image.asked_until.is_some_and(|t| t <= now) {
            self.image.asked_until = None;
        }
        if !self.watched(now) {
            return;
        }
        if self.image.parts.is_empty() {
            self.image.parts = self.every_part();
        }
        self.image.period = period;
        self.note_script_reads(now);
        let left = until.saturating_sub(now);
        let count = self.image.parts.len();
        for turn in 0..count {
            let i = (self.image.next + turn) % count;
            let state = self.image.parts[i];
            let due = state
                .read_at
                .map_or(true, |at| now.saturating_sub(at) >= REFRESH);
            if !due || !self.devices.online(state.device) {
                continue;
            }
            let fits = match self.expected(&state) {
                Some(takes) => takes.saturating_add(MARGIN) <= left,
                // Never read yet and no line to reckon with: tried when half a period is left.
                None => left >= period / 2,
            };
            if !fits {
                let part = &mut self.image.parts[i];
                let since = *part.waiting_since.get_or_insert(now);
                // A measured time that has kept a part out for long is measured again (one slow
                // read must not keep it out for good; a line that is that slow costs a tick's
                // overrun that often).
                if part.took.is_some() && now.saturating_sub(since) >= MEASURE_AGAIN_AFTER {
                    part.took = None;
                    part.waiting_since = Some(now);
                }
                continue;
            }
            self.image.next = (i + 1) % count;
            self.read_part(i);
            return;
        }
    }

    /// The parts of the device at `device` that watchers are not shown fresher than the
    /// script reads them, and why: due for `NOT_SHOWN_AFTER` without a tick leaving the time
    /// a read takes (a slow line, a short period).
    pub fn not_shown(&self, device: usize, now: Duration) -> Vec<String> {
        self.image
            .parts
            .iter()
            .filter(|p| p.device == device)
            .filter(|p| {
                p.waiting_since
                    .is_some_and(|t| now.saturating_sub(t) >= NOT_SHOWN_AFTER)
            })
            .map(|p| {
                let takes = self.expected(p).unwrap_or_default();
                format!(
                    "{}: a read takes {:.1} ms on its line, more than a tick leaves of the period",
                    p.part.name(),
                    takes.as_secs_f64() * 1e3
                )
            })
            .collect()
    }

    /// Every part of every device, in the devices' order.
    fn every_part(&self) -> Vec<PartState> {
        let mut parts = Vec::new();
        for device in 0..self.devices.len() {
            let kinds: &[Part] = if let Some(Device::C29u(_)) = self.devices.get(device) {
                &[Part::Inputs, Part::Counters]
            } else {
                &[Part::Switches, Part::Rotaries]
            };
            parts.extend(kinds.iter().map(|&part| PartState {
                device,
                part,
                read_at: None,
                took: None,
                waiting_since: None,
            }));
        }
        parts
    }

    /// A part the script read this tick is fresh for watchers too.
    fn note_script_reads(&mut self, now: Duration) {
        let tick = self.cycle().tick();
        for state in &mut self.image.parts {
            let fresh = match (state.part, self.devices.get(state.device)) {
                (Part::Inputs, Some(Device::C29u(c))) => c.inputs().fresh(tick),
                (Part::Counters, Some(Device::C29u(c))) => c.counters().fresh(tick),
                (Part::Switches, Some(Device::Trc(t))) => t.switches().fresh(tick),
                (Part::Rotaries, Some(Device::Trc(t))) => t.rotaries().fresh(tick),
                _ => false,
            };
            if fresh {
                state.read_at = Some(now);
            }
        }
    }

    /// How long a read of the part takes: the longer of its time on a serial line and the
    /// last one measured (a USB-serial adapter's latency, a slow machine; a panel on USB has
    /// only the measure; `None`: neither is known).
    fn expected(&self, state: &PartState) -> Option<Duration> {
        let on_line = match self.devices.get(state.device) {
            Some(Device::C29u(c)) => Some(line_time(c.line_options(), state.part)),
            _ => None,
        };
        match (on_line, state.took) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (a, b) => a.or(b),
        }
    }

    /// Reads part `i` for watchers: into its device's image for watchers (forces laid over
    /// as on the script's readings), told as `RunEvent::Shown` when it differs from what was
    /// shown before; a failure counts as any read's.
    fn read_part(&mut self, i: usize) {
        let PartState { device, part, .. } = self.image.parts[i];
        let start = self.now();
        let tick = self.cycle().tick();
        let forces = &self.forces;
        let outcome: Result<Option<Reading>, DeviceError> = match self.devices.get_mut(device) {
            None => Ok(None),
            Some(d) => {
                if let Some(c) = d.as_c29u() {
                    match part {
                        Part::Inputs => c.fetch_inputs().map(|v| {
                            let v = forces.inputs(device, v);
                            let before = c.latest_inputs();
                            c.shown_inputs().update(v, tick);
                            (before != Some(v)).then_some(Reading::DigitalInputs { value: v })
                        }),
                        _ => c.fetch_counters().map(|v| {
                            let before = c.latest_counters();
                            c.shown_counters().update(v, tick);
                            (before != Some(v)).then_some(Reading::Counters { values: v })
                        }),
                    }
                } else if let Some(t) = d.as_trc() {
                    match part {
                        Part::Switches => t.fetch_switches().map(|v| {
                            let v = forces.switches(device, v);
                            let before = t.latest_switches();
                            t.shown_switches().update(v, tick);
                            (before != Some(v)).then(|| Reading::Switches {
                                pressed: v.pressed_names(),
                            })
                        }),
                        _ => t.fetch_rotaries().map(|v| {
                            let before = t.latest_rotaries();
                            t.shown_rotaries().update(v, tick);
                            (before != Some(v)).then(|| Reading::Rotaries {
                                values: v.to_array(),
                            })
                        }),
                    }
                } else {
                    Ok(None)
                }
            }
        };
        let end = self.now();
        let state = &mut self.image.parts[i];
        state.read_at = Some(end);
        state.waiting_since = None;
        match outcome {
            Err(e) => self.note_failure(device, &e),
            Ok(changed) => {
                state.took = Some(end.saturating_sub(start));
                self.heard(device, end);
                if let Some(d) = self.devices.get_mut(device) {
                    d.health_mut().note_read(tick);
                }
                if let Some(reading) = changed {
                    self.tell_shown(device, reading);
                }
            }
        }
    }

    fn tell_shown(&self, device: usize, reading: Reading) {
        if !self.events().wants(EventKind::Shown) {
            return;
        }
        let Some(device) = self.devices.get(device).map(|d| d.name().to_string()) else {
            return;
        };
        self.events()
            .publish(|| RunEvent::Shown { device, reading });
    }
}

/// How long a read of `part` takes on a module's line: its characters at the line's speed and
/// the silence kept before each request (docs/trp-c29u-protocol.md: a Modbus DI read is 8
/// characters out and 6 back, the counters 8 and 21; an ASCII `$ID6` 5 and 8, each of the
/// eight counters `#IDN` 5 and 9, a checksum 2 more each way).
fn line_time(o: &C29uOptions, part: Part) -> Duration {
    let (exchanges, chars) = match (o.protocol, part) {
        (Protocol::Modbus, Part::Counters) => (1, 8 + 21),
        (Protocol::Modbus, _) => (1, 8 + 6),
        (Protocol::Ascii, Part::Counters) => (8, 8 * (5 + 9)),
        (Protocol::Ascii, _) => (1, 5 + 8),
    };
    let checksums = if o.protocol == Protocol::Ascii && o.checksum {
        4 * exchanges
    } else {
        0
    };
    let gaps = frame_gap(o.protocol, o.frame_gap, o.baud).saturating_mul(exchanges);
    wire_time((chars + checksums) as usize, o.baud).saturating_add(gaps)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::trc1000::Rotary;
    use crate::runtime::testing::{TestRig, IO, PANEL};

    const TICK: Duration = Duration::from_millis(20);
    const ROOMY: Duration = Duration::from_secs(1);

    /// `TestRig::started`, asked for a snapshot just now.
    fn watched() -> TestRig {
        let mut r = TestRig::started();
        let now = r.rt.now();
        r.rt.snapshot_asked(now);
        r
    }

    /// Reads for watchers with `left` before the next boundary.
    fn read(r: &mut TestRig, left: Duration) {
        let until = r.rt.now() + left;
        r.rt.read_for_watchers(until, TICK);
    }

    #[test]
    fn a_rig_nobody_watches_reads_nothing_for_watchers() {
        let mut r = TestRig::started();
        r.next_tick(TICK);
        let before = r.requests();
        read(&mut r, ROOMY);
        assert_eq!(r.requests(), before);
        assert_eq!(r.rt.devices.c29u(IO).unwrap().latest_inputs(), None);
        assert!(!r.rt.watched(r.rt.now()));
    }

    #[test]
    fn a_watched_rig_reads_each_part_in_turn_one_a_tick_into_an_image_of_its_own() {
        let mut r = watched();
        r.sim.set_inputs("io", 0b101).unwrap();
        r.sim.pulse("io", 3, 4).unwrap();
        r.sim.set_switch("panel", "S2", true).unwrap();
        r.sim.turn("panel", "S41A", 3).unwrap();
        for n in 1..=4 {
            r.next_tick(TICK);
            let before = r.requests();
            read(&mut r, ROOMY);
            assert!(r.requests() > before);
            let read = r.rt.image.parts.iter().filter(|p| p.read_at.is_some());
            assert_eq!(read.count(), n, "one part a tick: {:?}", r.rt.image.parts);
        }
        let io = r.rt.devices.c29u(IO).unwrap();
        assert_eq!(io.latest_inputs(), Some(0b101));
        assert_eq!(io.latest_counters().map(|c| c[3]), Some(4));
        assert_eq!(io.inputs().current, None, "the script's readings untouched");
        assert_eq!(io.counters().current, None);
        let panel = r.rt.devices.trc(PANEL).unwrap();
        assert_eq!(panel.latest_switches().unwrap().pressed_names(), ["S2"]);
        let s41a = Rotary::from_name("S41A").unwrap();
        assert_eq!(panel.latest_rotaries().map(|v| v.get(s41a)), Some(3));
        assert_eq!(panel.switches().current, None);
        // Each part at most every REFRESH: until 250 ms after the first read, nothing is due.
        r.next_tick(REFRESH - 4 * TICK);
        let before = r.requests();
        read(&mut r, ROOMY);
        assert_eq!(r.requests(), before);
        r.next_tick(TICK);
        read(&mut r, ROOMY);
        assert_eq!(r.requests(), before + 1, "250 ms on: the first part again");
    }

    #[test]
    fn what_the_script_read_this_tick_is_not_read_again_for_watchers() {
        let mut r = watched();
        r.next_tick(TICK);
        r.rt.inputs(IO);
        r.rt.counters(IO);
        r.rt.switches(PANEL);
        r.rt.rotaries(PANEL);
        let before = r.requests();
        read(&mut r, ROOMY);
        assert_eq!(r.requests(), before);
    }

    #[test]
    fn a_script_sees_the_same_turns_and_edges_whether_or_not_anyone_watches() {
        let s41a = Rotary::from_name("S41A").unwrap();
        let mut seen = Vec::new();
        for watch in [false, true] {
            let mut r = TestRig::started();
            if watch {
                let now = r.rt.now();
                r.rt.snapshot_asked(now);
            }
            r.next_tick(TICK);
            assert_eq!(r.rt.turned(PANEL, s41a), 0, "the first reading is a baseline");
            r.rt.inputs(IO);
            r.sim.turn("panel", "S41A", 2).unwrap();
            r.sim.set_inputs("io", 0b1).unwrap();
            for _ in 0..10 {
                r.next_tick(TICK);
                read(&mut r, ROOMY);
            }
            r.sim.turn("panel", "S41A", 1).unwrap();
            r.next_tick(TICK);
            let turned = r.rt.turned(PANEL, s41a);
            r.rt.inputs(IO);
            let tick = r.rt.cycle().tick();
            let edge = r.rt.devices.c29u(IO).unwrap().inputs().change_at(tick);
            seen.push((turned, edge));
        }
        assert_eq!(seen[0], (3, Some((0, 1))), "every half-turn since the script looked");
        assert_eq!(seen[1], seen[0]);
    }

    /// A rig of one module at 9600 baud (Modbus RTU, its default).
    fn module_alone() -> TestRig {
        let mut r = TestRig::new(
            r#"
            [devices.io]
            kind = "trp-c29u"
            port = "/dev/ttyUSB0"
            baud = 9600
            "#,
        );
        r.rt.start_devices().expect("the simulator answers");
        let now = r.rt.now();
        r.rt.snapshot_asked(now);
        r
    }

    #[test]
    fn a_part_is_read_only_when_the_tick_leaves_its_time_on_the_line() {
        let mut r = module_alone();
        r.next_tick(TICK);
        let before = r.requests();
        // The DI read: 14 characters and t3.5 at 9600 baud, 18.2 ms, and the margin.
        read(&mut r, Duration::from_millis(19));
        assert_eq!(r.requests(), before, "19 ms left: neither part fits");
        let now = r.rt.now();
        assert_eq!(
            r.rt.next_watched_read(now),
            Some(now),
            "the DI read fits an idle tick: the next one tries again"
        );
        read(&mut r, Duration::from_millis(20));
        assert_eq!(r.requests(), before + 1);
        assert_eq!(
            r.rt.next_watched_read(now),
            Some(now + REFRESH),
            "the counters fit no tick: no tick for them"
        );
        let io = r.rt.devices.c29u(0).unwrap();
        assert!(io.latest_inputs().is_some());
        assert_eq!(io.latest_counters(), None, "the counters take 33.9 ms");
        for _ in 0..10 {
            r.next_tick(TICK);
            read(&mut r, Duration::from_millis(30));
        }
        assert_eq!(r.rt.devices.c29u(0).unwrap().latest_counters(), None);
        assert!(r.rt.not_shown(0, r.rt.now()).is_empty(), "due 200 ms: not said yet");
        r.next_tick(NOT_SHOWN_AFTER);
        read(&mut r, Duration::from_millis(30));
        let now = r.rt.now();
        assert_eq!(
            r.rt.not_shown(0, now),
            ["counters: a read takes 33.9 ms on its line, more than a tick leaves of the period"]
        );
        read(&mut r, Duration::from_millis(35));
        assert!(r.rt.devices.c29u(0).unwrap().latest_counters().is_some());
        assert!(r.rt.not_shown(0, now).is_empty());
    }

    #[test]
    fn a_read_s_time_on_the_line_follows_the_protocol_and_the_speed() {
        let modbus = C29uOptions::default();
        let ms = |d: Duration| d.as_micros() as f64 / 1000.0;
        assert_eq!(format!("{:.2}", ms(line_time(&modbus, Part::Inputs))), "18.23");
        assert_eq!(format!("{:.2}", ms(line_time(&modbus, Part::Counters))), "33.85");
        let ascii = C29uOptions {
            protocol: Protocol::Ascii,
            ..C29uOptions::default()
        };
        // Eight exchanges of 14 characters, each after t1.5.
        assert_eq!(format!("{:.1}", ms(line_time(&ascii, Part::Counters))), "129.2");
        let fast = C29uOptions {
            baud: 115_200,
            ..C29uOptions::default()
        };
        assert_eq!(format!("{:.2}", ms(line_time(&fast, Part::Inputs))), "2.96");
    }

    #[test]
    fn a_reading_for_watchers_is_told_as_shown_never_as_taken_in() {
        let mut r = watched();
        let mut sub = r.rt.events().subscribe("test", 64).unwrap();
        r.sim.set_inputs("io", 0b11).unwrap();
        r.next_tick(TICK);
        read(&mut r, ROOMY);
        let event = sub.next(Duration::ZERO).expect("an event");
        assert_eq!(
            *event,
            RunEvent::Shown {
                device: "io".into(),
                reading: Reading::DigitalInputs { value: 0b11 }
            }
        );
        assert!(sub.next(Duration::ZERO).is_err(), "nothing else: {:?}", sub.newly_dropped());
    }

    #[test]
    fn watching_lasts_while_a_token_is_held_or_a_snapshot_was_asked_lately() {
        let mut r = TestRig::started();
        let now = r.rt.now();
        assert!(!r.rt.watching_began());
        let token = r.rt.events().watching();
        assert!(r.rt.watching_began());
        assert!(!r.rt.watching_began(), "began once");
        drop(token);
        assert!(!r.rt.watched(now));
        assert!(!r.rt.watching_began(), "ended");
        r.rt.snapshot_asked(now);
        assert!(r.rt.watching_began());
        assert!(r.rt.watched(now + LINGER - TICK));
        assert!(!r.rt.watched(now + LINGER));
        // A rig idle until later ticks for its watchers every REFRESH.
        assert_eq!(r.rt.next_watched_read(now), Some(now + REFRESH));
    }
}
