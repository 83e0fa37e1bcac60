//! What fires handlers in a tick: edges between this tick's readings and the last ones
//! (press/release, turn, rise/fall), counters reaching their thresholds and due timers, in
//! that order, one log line per device event handled. Timers are logged the first time they
//! fire, then in a summary at most once per `TIMER_LOG_INTERVAL` (a 20 ms timer fires 4.3
//! million times a day), and when one ends for want of a later time.

use super::devices::Device;
use super::handlers::{Arg, Call, Firings, Source};
use super::schedule::Fired;
use super::state::Runtime;
use crate::config::PointNames;
use crate::device::trc1000::rotary_changes;
use crate::time::duration::format_duration;
use std::time::Duration;

/// A module's eight counters as one reading.
type Counts = [u16; 8];

/// The longest a firing timer goes without a line in the log.
pub const TIMER_LOG_INTERVAL: Duration = Duration::from_secs(3600);

/// The inputs a device must be read for, by what its handlers wait for.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Needs {
    switches: bool,
    rotaries: bool,
    inputs: bool,
    counters: bool,
}

impl<H: Clone> Runtime<H> {
    /// Reads the inputs the handlers wait for and turns what changed, and the timers that are
    /// due, into handler calls, in order: device events (by device, then switch, rotary,
    /// input, counter), then timers (deadline order). Logs one line per event handled.
    pub fn collect_calls(&mut self) -> Vec<Call<H>> {
        let (mut needs, mut calls) = self.program.take_buffers();
        needs.clear();
        needs.resize(self.devices.len(), Needs::default());
        for s in &self.handlers().events {
            let Some(n) = source_device(&s.source).and_then(|dev| needs.get_mut(dev)) else {
                continue;
            };
            match s.source {
                Source::Press { .. } | Source::Release { .. } => n.switches = true,
                Source::Turn { .. } => n.rotaries = true,
                Source::Rise { .. } | Source::Fall { .. } => n.inputs = true,
                Source::Counter { .. } => n.counters = true,
                Source::Timer(_) | Source::Stop | Source::Command(_) | Source::Message(_) => {}
            }
        }
        for (dev, need) in needs.iter().enumerate() {
            if need.switches {
                self.switches(dev);
            }
            if need.rotaries {
                self.rotaries(dev);
            }
            if need.inputs {
                self.inputs(dev);
            }
            if need.counters {
                self.counters(dev);
            }
            let events = self
                .devices
                .get(dev)
                .map(|d| device_events(dev, d, self.cycle().tick()))
                .unwrap_or_default();
            for (event, args) in events {
                self.dispatch(&event, &args, &mut calls);
            }
        }
        self.program.keep_needs(needs);
        self.counter_calls(&mut calls);
        self.timer_calls(&mut calls);
        calls
    }

    /// Takes back the list `collect_calls` gave, once its calls are made, for the next tick.
    pub fn reuse_calls(&mut self, calls: Vec<Call<H>>) {
        self.program.keep_calls(calls);
    }

    /// Adds the calls of the handlers waiting for `event`, logging it once if any.
    fn dispatch(&mut self, event: &Source, args: &[Arg], calls: &mut Vec<Call<H>>) {
        let before = calls.len();
        calls.extend(
            self.handlers()
                .events
                .iter()
                .filter(|s| s.source == *event)
                .map(|s| s.call(args.to_vec())),
        );
        if calls.len() == before {
            return;
        }
        let name = source_device(event).map_or(String::new(), |dev| self.devices.name(dev));
        let names = source_device(event)
            .and_then(|dev| self.devices.get(dev))
            .map(Device::names);
        if let Some(line) = event_line(&name, names, event, args) {
            self.log_mut().activity(&line);
        }
    }

    /// Fires counter handlers whose count reached their threshold in this tick's reading.
    fn counter_calls(&mut self, calls: &mut Vec<Call<H>>) {
        if !self
            .handlers()
            .events
            .iter()
            .any(|s| matches!(s.source, Source::Counter { .. }))
        {
            return;
        }
        let tick = self.cycle().tick();
        let mut fired = Vec::new();
        // This tick's reading and the one before it (after the script's own clear, that is the
        // cleared count: `C29uDevice::clear_counter`).
        let fresh: Vec<Option<(Counts, Option<Counts>)>> = self
            .devices
            .iter()
            .map(|d| match d {
                Device::C29u(c) if c.counters().fresh(tick) => {
                    c.counters().current.map(|now| (now, c.counters().previous))
                }
                _ => None,
            })
            .collect();
        for s in &mut self.program.handlers_mut().events {
            let Source::Counter {
                dev,
                ch,
                threshold,
                armed,
            } = &mut s.source
            else {
                continue;
            };
            let Some((now, before)) = fresh.get(*dev).copied().flatten() else {
                continue;
            };
            let i = usize::from(*ch);
            let count = now[i];
            let last = before.map(|b| b[i]);
            // A count below the threshold, now or in the reading before, re-arms; so does a
            // count that went down (cleared, reset, wrapped: counting started again), even if
            // the pulses since took it past the threshold before a reading could show it low.
            if !*armed && (count < *threshold || last.is_some_and(|l| l < *threshold || count < l))
            {
                *armed = true;
            }
            if *armed && count >= *threshold {
                *armed = false;
                let (dev, ch, threshold) = (*dev, *ch, *threshold);
                calls.push(s.call(vec![Arg::Int(i64::from(count))]));
                fired.push((dev, ch, count, threshold));
            }
        }
        for (dev, ch, count, threshold) in fired {
            let device = self.devices.get(dev);
            let name = device.map_or("", Device::name);
            let point = shown(device.map(Device::names), &format!("DI{ch}"));
            let line = format!("{name}: counter {point} at {count} (threshold {threshold})");
            self.log_mut().activity(&line);
        }
    }

    /// Fires the timers that are due, each found by its timer (a tick costs the timers that
    /// fire, not the timers there are); a spent timer's handler goes with it.
    fn timer_calls(&mut self, calls: &mut Vec<Call<H>>) {
        let now = self.now();
        let boundary = self.cycle().boundary().unwrap_or(now);
        let (program, cycle) = (&mut self.program, &self.cycle);
        let handlers = program.handlers_mut();
        let fired = handlers
            .schedule
            .due_at_tick(now, boundary, || cycle.wall());
        let mut lines = Vec::new();
        for f in fired {
            let args = vec![Arg::Int(i64::try_from(f.missed).unwrap_or(i64::MAX))];
            let (call, line) = if f.last {
                let Some(mut sub) = handlers.remove_timer(f.id) else {
                    continue;
                };
                let cron_ends = sub.firings.cron;
                let line = firing_line(&sub.label, &mut sub.firings, &f, cron_ends, now);
                (sub.call(args), line)
            } else {
                let Some(sub) = handlers.timers.get_mut(&f.id) else {
                    continue;
                };
                let line = firing_line(&sub.label, &mut sub.firings, &f, false, now);
                (sub.call(args), line)
            };
            calls.push(call);
            lines.extend(line);
        }
        for l in lines {
            self.log_mut().activity(&l);
        }
    }
}

/// The log line of a timer firing, if this one is to be told: the first, a summary once
/// `TIMER_LOG_INTERVAL` has passed since the last line, and the last of a cron timer.
fn firing_line(
    label: &str,
    log: &mut Firings,
    f: &Fired,
    cron_ends: bool,
    now: Duration,
) -> Option<String> {
    log.count = log.count.saturating_add(1);
    log.missed = log.missed.saturating_add(f.missed);
    let due = match log.logged_at {
        None => true,
        Some(at) => now.saturating_sub(at) >= TIMER_LOG_INTERVAL,
    };
    if !due && !cron_ends {
        return None;
    }
    let mut line = match (log.logged_at, log.count) {
        (Some(at), n) if n > 1 => format!(
            "{label} fired {n} times in the last {}",
            format_duration(Duration::from_secs(now.saturating_sub(at).as_secs()))
        ),
        _ => format!("{label} fired"),
    };
    if log.missed > 0 {
        line.push_str(&format!(" ({} missed)", log.missed));
    }
    if cron_ends {
        line.push_str("; no later time matches it, so it ends");
    }
    log.logged_at = Some(now);
    log.count = 0;
    log.missed = 0;
    Some(line)
}

/// The device a source waits on, if it is a device event.
fn source_device(source: &Source) -> Option<usize> {
    match *source {
        Source::Press { dev, .. }
        | Source::Release { dev, .. }
        | Source::Turn { dev, .. }
        | Source::Rise { dev, .. }
        | Source::Fall { dev, .. }
        | Source::Counter { dev, .. } => Some(dev),
        Source::Timer(_) | Source::Stop | Source::Command(_) | Source::Message(_) => None,
    }
}

/// The events of `device` (at index `idx`) from its readings at `tick`, each as the source it
/// matches and the handler's arguments. The first reading is only a baseline.
fn device_events(idx: usize, device: &Device, tick: u64) -> Vec<(Source, Vec<Arg>)> {
    let mut events = Vec::new();
    match device {
        Device::Trc(d) => {
            if let Some((old, new)) = d.switches().change_at(tick) {
                let (pressed, released) = old.changes(&new);
                for switch in pressed {
                    events.push((
                        Source::Press { dev: idx, switch },
                        vec![Arg::Str(switch.name().into())],
                    ));
                }
                for switch in released {
                    events.push((
                        Source::Release { dev: idx, switch },
                        vec![Arg::Str(switch.name().into())],
                    ));
                }
            }
            if let Some((old, new)) = d.rotaries().change_at(tick) {
                for c in rotary_changes(&old, &new) {
                    events.push((
                        Source::Turn {
                            dev: idx,
                            rotary: c.rotary,
                        },
                        vec![Arg::Int(i64::from(c.delta)), Arg::Int(i64::from(c.value))],
                    ));
                }
            }
        }
        Device::C29u(d) => {
            if let Some((old, new)) = d.inputs().change_at(tick).filter(|(o, n)| o != n) {
                for ch in 0..8u8 {
                    let bit = 1u8 << ch;
                    let args = || vec![Arg::Int(i64::from(ch))];
                    if old & bit == 0 && new & bit != 0 {
                        events.push((Source::Rise { dev: idx, ch }, args()));
                    } else if old & bit != 0 && new & bit == 0 {
                        events.push((Source::Fall { dev: idx, ch }, args()));
                    }
                }
            }
        }
    }
    events
}

/// `point` with the name rig.toml gives it, if the device has `names`.
fn shown(names: Option<&PointNames>, point: &str) -> String {
    names.map_or_else(|| point.to_string(), |n| n.shown(point))
}

/// The log line of a device event on the device called `name`, its point shown with its
/// name (`io: DI0 "guard door" on`).
fn event_line(
    name: &str,
    names: Option<&PointNames>,
    event: &Source,
    args: &[Arg],
) -> Option<String> {
    let point = |p: &str| shown(names, p);
    Some(match (event, args) {
        (Source::Press { switch, .. }, _) => format!("{name}: {} pressed", point(switch.name())),
        (Source::Release { switch, .. }, _) => {
            format!("{name}: {} released", point(switch.name()))
        }
        (Source::Turn { rotary, .. }, [Arg::Int(delta), Arg::Int(value)]) => {
            format!(
                "{name}: {} turned {delta:+} (now {value})",
                point(rotary.name())
            )
        }
        (Source::Rise { ch, .. }, _) => format!("{name}: {} on", point(&format!("DI{ch}"))),
        (Source::Fall { ch, .. }, _) => format!("{name}: {} off", point(&format!("DI{ch}"))),
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use crate::protocol::trc1000::{Rotary, Switch};
    use crate::runtime::handlers::{Arg, Call, Source};
    use crate::runtime::testing::{TestRig, IO, PANEL};
    use std::time::Duration;

    const TICK: Duration = Duration::from_millis(20);

    /// One tick: what fires, as (handler, args).
    fn tick(r: &mut TestRig) -> Vec<(&'static str, Vec<Arg>)> {
        r.next_tick(TICK);
        let calls: Vec<Call<&'static str>> = r.rt.collect_calls();
        calls.into_iter().map(|c| (c.handler, c.args)).collect()
    }

    fn sub(r: &mut TestRig, source: Source, handler: &'static str) {
        r.rt.subscribe(source, handler, handler.into());
    }

    #[test]
    fn the_first_reading_is_a_baseline_then_input_edges_fire_their_handlers() {
        let mut r = TestRig::started();
        sub(&mut r, Source::Rise { dev: IO, ch: 3 }, "rise3");
        sub(&mut r, Source::Fall { dev: IO, ch: 3 }, "fall3");
        r.sim.set_input("io", 3, true).unwrap();
        assert!(tick(&mut r).is_empty(), "held at start is not a rise");
        r.sim.set_input("io", 3, false).unwrap();
        assert_eq!(tick(&mut r), [("fall3", vec![Arg::Int(3)])]);
        assert!(tick(&mut r).is_empty());
        r.sim.set_input("io", 3, true).unwrap();
        assert_eq!(tick(&mut r), [("rise3", vec![Arg::Int(3)])]);
        let log = r.log();
        assert!(
            log.contains("io: DI3 off") && log.contains("io: DI3 on"),
            "{log}"
        );
    }

    #[test]
    fn an_edge_nobody_waits_for_fires_nothing_and_is_not_logged() {
        let mut r = TestRig::started();
        sub(&mut r, Source::Rise { dev: IO, ch: 3 }, "rise3");
        tick(&mut r);
        r.sim.set_input("io", 5, true).unwrap();
        assert!(tick(&mut r).is_empty());
        assert!(!r.log().contains("DI5"), "{}", r.log());
    }

    #[test]
    fn switches_and_rotaries_fire_press_release_and_turn() {
        let mut r = TestRig::started();
        let s1 = Switch::from_name("S1").unwrap();
        let s41a = Rotary::from_name("S41A").unwrap();
        sub(
            &mut r,
            Source::Press {
                dev: PANEL,
                switch: s1,
            },
            "press",
        );
        sub(
            &mut r,
            Source::Release {
                dev: PANEL,
                switch: s1,
            },
            "release",
        );
        sub(
            &mut r,
            Source::Turn {
                dev: PANEL,
                rotary: s41a,
            },
            "turn",
        );
        tick(&mut r);
        r.sim.set_switch("panel", "S1", true).unwrap();
        r.sim.turn("panel", "S41A", 2).unwrap();
        assert_eq!(
            tick(&mut r),
            [
                ("press", vec![Arg::Str("S1".into())]),
                ("turn", vec![Arg::Int(2), Arg::Int(2)])
            ]
        );
        r.sim.set_switch("panel", "S1", false).unwrap();
        assert_eq!(tick(&mut r), [("release", vec![Arg::Str("S1".into())])]);
        let log = r.log();
        assert!(log.contains("panel: S1 pressed"), "{log}");
        assert!(log.contains("panel: S41A turned +2 (now 2)"), "{log}");
        assert!(log.contains("panel: S1 released"), "{log}");
    }

    #[test]
    fn a_counter_handler_fires_once_at_its_threshold_and_is_rearmed_below_it() {
        let mut r = TestRig::started();
        let at = |threshold| Source::Counter {
            dev: IO,
            ch: 2,
            threshold,
            armed: true,
        };
        sub(&mut r, at(3), "three");
        sub(&mut r, at(0), "zero");
        assert_eq!(
            tick(&mut r),
            [("zero", vec![Arg::Int(0)])],
            "also at the first reading"
        );
        r.sim.pulse("io", 2, 2).unwrap();
        assert!(tick(&mut r).is_empty());
        r.sim.pulse("io", 2, 1).unwrap();
        assert_eq!(tick(&mut r), [("three", vec![Arg::Int(3)])]);
        r.sim.pulse("io", 2, 5).unwrap();
        assert!(tick(&mut r).is_empty(), "once");
        r.rt.devices
            .c29u(IO)
            .unwrap()
            .driver()
            .clear_counter(2)
            .unwrap();
        assert_eq!(
            tick(&mut r),
            [("zero", vec![Arg::Int(0)])],
            "below again: re-armed; counting started again, so at 0 too"
        );
        r.sim.pulse("io", 2, 4).unwrap();
        assert_eq!(tick(&mut r), [("three", vec![Arg::Int(4)])]);
        assert!(
            r.log().contains("io: counter DI2 at 4 (threshold 3)"),
            "{}",
            r.log()
        );
    }

    #[test]
    fn a_clear_rearms_a_counter_handler_even_when_no_reading_shows_the_count_below() {
        let mut r = TestRig::started();
        let three = Source::Counter {
            dev: IO,
            ch: 2,
            threshold: 3,
            armed: true,
        };
        sub(&mut r, three, "three");
        assert!(tick(&mut r).is_empty());
        r.sim.pulse("io", 2, 5).unwrap();
        assert_eq!(tick(&mut r), [("three", vec![Arg::Int(5)])]);
        // The script clears it (as `io.clear_counter(2)` does), and four strokes come before
        // the next reading: the batch is not missed.
        r.rt.devices.c29u(IO).unwrap().clear_counter(2).unwrap();
        r.sim.pulse("io", 2, 4).unwrap();
        assert_eq!(
            tick(&mut r),
            [("three", vec![Arg::Int(4)])],
            "after the clear"
        );
        // Cleared from elsewhere (another program, a reset): seen only as a count that went
        // down, 4 -> 0 -> 3 between two readings.
        r.sim.pulse("io", 2, 4).unwrap();
        assert!(tick(&mut r).is_empty(), "8: still the same batch");
        r.rt.devices
            .c29u(IO)
            .unwrap()
            .driver()
            .clear_counter(2)
            .unwrap();
        r.sim.pulse("io", 2, 3).unwrap();
        assert_eq!(tick(&mut r), [("three", vec![Arg::Int(3)])], "went down");
        assert!(tick(&mut r).is_empty(), "once a batch");
    }

    #[test]
    fn device_events_come_first_by_device_then_counters_then_timers() {
        let mut r = TestRig::started();
        r.rt.after(TICK, "timer").unwrap();
        let s1 = Switch::from_name("S1").unwrap();
        let counter = Source::Counter {
            dev: IO,
            ch: 0,
            threshold: 1,
            armed: true,
        };
        sub(&mut r, counter, "counter");
        sub(
            &mut r,
            Source::Press {
                dev: PANEL,
                switch: s1,
            },
            "press",
        );
        sub(&mut r, Source::Rise { dev: IO, ch: 0 }, "rise");
        r.rt.cycle.next_tick();
        r.rt.collect_calls();
        r.sim.set_switch("panel", "S1", true).unwrap();
        r.sim.pulse("io", 0, 1).unwrap();
        r.sim.set_input("io", 0, true).unwrap();
        let order: Vec<&str> = tick(&mut r).into_iter().map(|(h, _)| h).collect();
        assert_eq!(order, ["rise", "press", "counter", "timer"]);
    }

    #[test]
    fn due_timers_fire_with_what_they_missed_and_spent_ones_go() {
        let mut r = TestRig::started();
        r.rt.every(Duration::from_millis(100), "every").unwrap();
        r.rt.after(Duration::from_millis(250), "after").unwrap();
        r.clock.advance(Duration::from_millis(280));
        let fired = tick(&mut r);
        assert_eq!(
            fired,
            [("every", vec![Arg::Int(2)]), ("after", vec![Arg::Int(0)])],
            "every: due at 100 ms, 200 and 300 missed at 300 ms"
        );
        assert_eq!(r.rt.handlers().len(), 1, "the spent `after` went");
        let log = r.log();
        assert!(log.contains("every 100ms fired (2 missed)"), "{log}");
        assert!(log.contains("after 250ms fired"), "{log}");
    }

    #[test]
    fn a_fast_timer_is_logged_once_then_once_an_hour() {
        let mut r = TestRig::started();
        r.rt.every(TICK, "fast").unwrap();
        let mut fired = 0;
        // Two hours and a bit of 20 ms ticks.
        for _ in 0..(2 * 180_000 + 10) {
            fired += tick(&mut r).len();
        }
        assert_eq!(fired, 2 * 180_000 + 10);
        let log = r.log();
        let lines: Vec<&str> = log.lines().filter(|l| l.contains("every 20ms")).collect();
        assert_eq!(lines.len(), 3, "{lines:?}");
        assert!(lines[0].ends_with("every 20ms fired"), "{lines:?}");
        assert!(
            lines[1].ends_with("every 20ms fired 180000 times in the last 1h"),
            "{lines:?}"
        );
    }

    #[test]
    fn a_cron_timer_that_ends_says_so() {
        let mut r = TestRig::started();
        // The rig's clock starts at the epoch; this matches one time only.
        r.rt.cron("0 0 0 1 1 * 1971", "once").unwrap();
        r.clock.advance(Duration::from_secs(365 * 86_400));
        assert_eq!(tick(&mut r).len(), 1);
        assert!(!r.rt.has_work());
        assert!(
            r.log()
                .contains("cron \"0 0 0 1 1 * 1971\" fired; no later time matches it, so it ends"),
            "{}",
            r.log()
        );
    }

    #[test]
    fn many_timers_fire_each_their_own_handler() {
        let mut r = TestRig::started();
        r.rt.limit_timers(50_000);
        let names: Vec<&'static str> = (0..5_000)
            .map(|i| &*Box::leak(format!("t{i}").into_boxed_str()))
            .collect();
        for (i, name) in names.iter().enumerate() {
            r.rt.every(Duration::from_millis(20 * (1 + i as u64 % 50)), name)
                .unwrap();
        }
        let mut seen = std::collections::HashMap::new();
        for _ in 0..50 {
            for (h, _) in tick(&mut r) {
                *seen.entry(h).or_insert(0u32) += 1;
            }
        }
        // Over 50 ticks of 20 ms, the timer of period 20 ms * k fires 50 / k times.
        for (i, name) in names.iter().enumerate() {
            let k = 1 + i as u32 % 50;
            assert_eq!(seen.get(name).copied().unwrap_or(0), 50 / k, "{name}");
        }
    }

    #[test]
    fn devices_nobody_waits_on_are_not_read() {
        let mut r = TestRig::started();
        r.rt.every(TICK, "timer").unwrap();
        let before = r.requests();
        for _ in 0..10 {
            tick(&mut r);
        }
        assert_eq!(r.requests(), before);
    }
}
