//! What fires handlers in a tick: edges between this tick's readings and the last ones
//! (press/release, turn, rise/fall), counters reaching their thresholds and due timers, in
//! that order, one log line per event handled.

use super::devices::Device;
use super::state::Runtime;
use super::subscriptions::{Arg, Call, Source};
use crate::device::trc1000::rotary_changes;
use std::time::Duration;

/// The inputs a device must be read for, by what its handlers wait for.
#[derive(Debug, Clone, Copy, Default)]
struct Needs {
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
        let mut needs = vec![Needs::default(); self.devices.len()];
        for s in &self.handlers.list {
            let Some(n) = source_device(&s.source).and_then(|dev| needs.get_mut(dev)) else {
                continue;
            };
            match s.source {
                Source::Press { .. } | Source::Release { .. } => n.switches = true,
                Source::Turn { .. } => n.rotaries = true,
                Source::Rise { .. } | Source::Fall { .. } => n.inputs = true,
                Source::Counter { .. } => n.counters = true,
                Source::Timer(_) | Source::Stop => {}
            }
        }
        let mut calls = Vec::new();
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
                .map(|d| device_events(dev, d, self.tick))
                .unwrap_or_default();
            for (event, args) in events {
                self.dispatch(&event, &args, &mut calls);
            }
        }
        self.counter_calls(&mut calls);
        self.timer_calls(&mut calls);
        calls
    }

    /// Adds the calls of the handlers waiting for `event`, logging it once if any.
    fn dispatch(&mut self, event: &Source, args: &[Arg], calls: &mut Vec<Call<H>>) {
        let before = calls.len();
        calls.extend(
            self.handlers
                .list
                .iter()
                .filter(|s| s.source == *event)
                .map(|s| s.call(args.to_vec())),
        );
        if calls.len() == before {
            return;
        }
        let name = source_device(event).map_or(String::new(), |dev| self.device_name(dev));
        if let Some(line) = event_line(&name, event, args) {
            self.log.activity(&line);
        }
    }

    /// Fires counter handlers whose count reached their threshold in this tick's reading.
    fn counter_calls(&mut self, calls: &mut Vec<Call<H>>) {
        let tick = self.tick;
        let mut lines = Vec::new();
        let fresh: Vec<Option<[u16; 8]>> = self
            .devices
            .iter()
            .map(|d| match d {
                Device::C29u(c) if c.counters.fresh(tick) => c.counters.current,
                _ => None,
            })
            .collect();
        for s in &mut self.handlers.list {
            let Source::Counter {
                dev,
                ch,
                threshold,
                armed,
            } = &mut s.source
            else {
                continue;
            };
            let Some(count) = fresh
                .get(*dev)
                .copied()
                .flatten()
                .and_then(|c| c.get(usize::from(*ch)).copied())
            else {
                continue;
            };
            if *armed && count >= *threshold {
                *armed = false;
                let (dev, ch, threshold) = (*dev, *ch, *threshold);
                calls.push(s.call(vec![Arg::Int(i64::from(count))]));
                let name = self.devices.get(dev).map_or("", Device::name);
                lines.push(format!(
                    "{name}: counter DI{ch} at {count} (threshold {threshold})"
                ));
            } else if !*armed && count < *threshold {
                *armed = true;
            }
        }
        for l in lines {
            self.log.activity(&l);
        }
    }

    /// Fires the timers that are due; logs each firing (at most once a second per timer, so
    /// a fast `every` does not flood the log).
    fn timer_calls(&mut self, calls: &mut Vec<Call<H>>) {
        let now = self.now();
        let fired = self.handlers.schedule.due(now, self.clock.wall());
        let mut lines = Vec::new();
        for f in fired {
            let Some(s) = self
                .handlers
                .list
                .iter_mut()
                .find(|s| s.source == Source::Timer(f.id))
            else {
                continue;
            };
            calls.push(s.call(vec![Arg::Int(i64::try_from(f.missed).unwrap_or(i64::MAX))]));
            let quiet = s
                .last_logged
                .is_some_and(|t| now.saturating_sub(t) < Duration::from_secs(1));
            if !quiet {
                s.last_logged = Some(now);
                let missed = if f.missed > 0 {
                    format!(" ({} missed)", f.missed)
                } else {
                    String::new()
                };
                lines.push(format!("{} fired{missed}", s.label));
            }
        }
        // Spent `after` timers go with their handlers.
        let schedule = &self.handlers.schedule;
        self.handlers.list.retain(|s| match s.source {
            Source::Timer(t) => schedule.contains(t),
            _ => true,
        });
        for l in lines {
            self.log.activity(&l);
        }
    }
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
        Source::Timer(_) | Source::Stop => None,
    }
}

/// The events of `device` (at index `idx`) from its readings at `tick`, each as the source it
/// matches and the handler's arguments. The first reading is only a baseline.
fn device_events(idx: usize, device: &Device, tick: u64) -> Vec<(Source, Vec<Arg>)> {
    let mut events = Vec::new();
    match device {
        Device::Trc(d) => {
            if let Some((old, new)) = d.switches.change_at(tick) {
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
            if let Some((old, new)) = d.rotaries.change_at(tick) {
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
            if let Some((old, new)) = d.inputs.change_at(tick) {
                for ch in 0..8u8 {
                    let bit = 1u8 << ch;
                    let args = vec![Arg::Int(i64::from(ch))];
                    if old & bit == 0 && new & bit != 0 {
                        events.push((Source::Rise { dev: idx, ch }, args));
                    } else if old & bit != 0 && new & bit == 0 {
                        events.push((Source::Fall { dev: idx, ch }, args));
                    }
                }
            }
        }
    }
    events
}

/// The log line of a device event on the device called `name`.
fn event_line(name: &str, event: &Source, args: &[Arg]) -> Option<String> {
    Some(match (event, args) {
        (Source::Press { switch, .. }, _) => format!("{name}: {switch} pressed"),
        (Source::Release { switch, .. }, _) => format!("{name}: {switch} released"),
        (Source::Turn { rotary, .. }, [Arg::Int(delta), Arg::Int(value)]) => {
            format!("{name}: {} turned {delta:+} (now {value})", rotary.name())
        }
        (Source::Rise { ch, .. }, _) => format!("{name}: DI{ch} on"),
        (Source::Fall { ch, .. }, _) => format!("{name}: DI{ch} off"),
        _ => return None,
    })
}
