//! The state of one run that scripts act on: devices, handlers and timers, records, the log,
//! and the stop request. The script layer binds it into Rhai; the scan loop drives it.
//!
//! `H` is the script layer's handler type (a Rhai function pointer); nothing here knows Rhai.

use super::devices::links::TransactionCounter;
use super::devices::{C29uDevice, Device, DeviceError, TrcDevice};
use super::invariants::Invariant;
use super::log::Logger;
use super::records::Records;
use super::schedule::{Schedule, ScheduleError, TimerId, TimerKind};
use crate::device::c29u::Latches;
use crate::device::trc1000::rotary_changes;
use crate::protocol::trc1000::{Rotary, RotaryValues, Switch, SwitchSet};
use crate::time::clock::SharedClock;
use crate::time::duration::format_duration;
use crate::time::zone::Zone;
use std::sync::atomic::Ordering;
use std::time::Duration;

/// How often a lost device is tried again.
pub const RETRY_INTERVAL: Duration = Duration::from_secs(1);

/// What a handler is subscribed to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Source {
    /// A TRC1000 switch going down.
    Press {
        /// Device index.
        dev: usize,
        /// Which switch.
        switch: Switch,
    },
    /// A TRC1000 switch coming up.
    Release {
        /// Device index.
        dev: usize,
        /// Which switch.
        switch: Switch,
    },
    /// A TRC1000 rotary moving.
    Turn {
        /// Device index.
        dev: usize,
        /// Which rotary.
        rotary: Rotary,
    },
    /// A TRP-C29U input becoming energized.
    Rise {
        /// Device index.
        dev: usize,
        /// Channel 0-7.
        ch: u8,
    },
    /// A TRP-C29U input being released.
    Fall {
        /// Device index.
        dev: usize,
        /// Channel 0-7.
        ch: u8,
    },
    /// A TRP-C29U counter reaching a threshold.
    Counter {
        /// Device index.
        dev: usize,
        /// Channel 0-7.
        ch: u8,
        /// The count that fires the handler.
        threshold: u16,
        /// Fires when the count is at or above the threshold; re-armed when a reading shows
        /// it below again (cleared, reset, wrapped).
        armed: bool,
    },
    /// A timer of the schedule.
    Timer(TimerId),
    /// The end of the run.
    Stop,
}

/// A handler and what it waits for.
#[derive(Debug, Clone)]
pub struct Subscription<H> {
    /// Returned to the script, for `cancel`.
    pub id: u64,
    /// What it waits for.
    pub source: Source,
    /// The script's function.
    pub handler: H,
    /// The handler in words for the log and error messages: `panel.on_press S1`.
    pub label: String,
    last_logged: Option<Duration>,
}

/// A value passed to a handler.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Arg {
    /// A number.
    Int(i64),
    /// A name.
    Str(String),
}

/// A handler to run now, with its arguments.
#[derive(Debug, Clone)]
pub struct Call<H> {
    /// The script's function.
    pub handler: H,
    /// Its arguments (the script layer passes as many as the function takes).
    pub args: Vec<Arg>,
    /// The handler in words.
    pub label: String,
}

/// The state of one run.
pub struct Runtime<H> {
    /// The one source of time.
    pub clock: SharedClock,
    /// The zone of cron, `now()` and the log.
    pub zone: Zone,
    /// The devices, in name order.
    pub devices: Vec<Device>,
    /// The script's timers.
    pub schedule: Schedule<Zone>,
    subs: Vec<Subscription<H>>,
    next_sub: u64,
    /// What the script states must hold after every tick (`runtime::invariants`).
    pub invariants: Vec<Invariant<H>>,
    /// Records and measurements.
    pub records: Records,
    /// The log.
    pub log: Logger,
    /// The current tick (0 while the top level runs at start).
    pub tick: u64,
    /// Monotonic time the run started.
    pub started: Duration,
    /// The script asked to stop, with this exit status.
    pub stop_request: Option<i64>,
    /// The handler running now, for the log lines of the outputs it changes.
    pub cause: String,
    /// A device has been lost for longer than its grace time: every device is held at its
    /// safe state until all are back.
    pub held_safe: bool,
    /// Requests sent on all links.
    pub transactions: TransactionCounter,
    /// How long a device may be lost before everything goes safe.
    pub grace: Duration,
}

impl<H: Clone> Runtime<H> {
    /// A run over `devices` (already opened) starting now.
    pub fn new(
        clock: SharedClock,
        zone: Zone,
        devices: Vec<Device>,
        records: Records,
        log: Logger,
        transactions: TransactionCounter,
        grace: Duration,
    ) -> Self {
        let started = clock.now();
        Self {
            clock,
            zone,
            devices,
            schedule: Schedule::with_time_zone(zone),
            subs: Vec::new(),
            next_sub: 1,
            invariants: Vec::new(),
            records,
            log,
            tick: 0,
            started,
            stop_request: None,
            cause: "top level".into(),
            held_safe: false,
            transactions,
            grace,
        }
    }

    /// Monotonic now.
    pub fn now(&self) -> Duration {
        self.clock.now()
    }

    /// Wall time now in the run's zone, as RFC 3339 with milliseconds.
    pub fn wall_text(&self) -> String {
        self.zone
            .at(self.clock.wall())
            .to_rfc3339_opts(chrono::SecondsFormat::Millis, false)
    }

    /// How long the run has been going.
    pub fn uptime(&self) -> Duration {
        self.now().saturating_sub(self.started)
    }

    /// Requests sent so far on all links.
    pub fn transaction_count(&self) -> u64 {
        self.transactions.load(Ordering::Relaxed)
    }

    /// The index of the device called `name`.
    pub fn device_index(&self, name: &str) -> Option<usize> {
        self.devices.iter().position(|d| d.name() == name)
    }

    /// The device names, for messages.
    pub fn device_names(&self) -> String {
        let names: Vec<&str> = self.devices.iter().map(Device::name).collect();
        names.join(", ")
    }

    /// The TRC1000 at `idx`.
    pub fn trc(&mut self, idx: usize) -> Option<&mut TrcDevice> {
        match self.devices.get_mut(idx) {
            Some(Device::Trc(d)) => Some(d),
            _ => None,
        }
    }

    /// The TRP-C29U at `idx`.
    pub fn c29u(&mut self, idx: usize) -> Option<&mut C29uDevice> {
        match self.devices.get_mut(idx) {
            Some(Device::C29u(d)) => Some(d),
            _ => None,
        }
    }

    /// Whether the device at `idx` answers.
    pub fn online(&self, idx: usize) -> bool {
        self.devices.get(idx).is_some_and(|d| d.health().online())
    }

    // ---- losing devices ------------------------------------------------------------------

    /// Notes a failed operation: a communication failure marks the device lost.
    pub fn note_failure(&mut self, idx: usize, error: &DeviceError) {
        if !error.is_comm_failure() {
            return;
        }
        let now = self.now();
        if let Some(d) = self.devices.get_mut(idx) {
            let name = d.name().to_string();
            if d.health_mut().lose(now, error, RETRY_INTERVAL) {
                self.log.warn(&format!(
                    "{name}: lost: {error}; trying again every {}",
                    format_duration(RETRY_INTERVAL)
                ));
            }
        }
    }

    /// Runs an operation the script asked for on the device at `idx`: refused while it is
    /// lost; a communication failure marks it lost.
    pub fn command<T>(
        &mut self,
        idx: usize,
        op: impl FnOnce(&mut Device) -> Result<T, DeviceError>,
    ) -> Result<T, DeviceError> {
        let now = self.now();
        let Some(d) = self.devices.get_mut(idx) else {
            return Err(DeviceError::Offline {
                device: format!("device #{idx}"),
                ago: Duration::ZERO,
                cause: "no such device".into(),
            });
        };
        if !d.health().online() {
            return Err(d.health().offline_error(d.name(), now));
        }
        let result = op(d);
        if let Err(e) = &result {
            self.note_failure(idx, e);
        }
        result
    }

    // ---- lazy input reads ----------------------------------------------------------------

    /// The switches of the TRC1000 at `idx`: read at the first access in a tick; the last
    /// reading (or nothing pressed) while the board is lost.
    pub fn switches(&mut self, idx: usize) -> SwitchSet {
        let tick = self.tick;
        let online = self.online(idx);
        let Some(d) = self.trc(idx) else {
            return SwitchSet::new();
        };
        if online && !d.switches.fresh(tick) {
            if let Err(e) = d.read_switches(tick) {
                self.note_failure(idx, &e);
            }
        }
        self.trc(idx)
            .and_then(|d| d.switches.current)
            .unwrap_or_default()
    }

    /// The rotaries of the TRC1000 at `idx`, read lazily like `switches`.
    pub fn rotaries(&mut self, idx: usize) -> RotaryValues {
        let tick = self.tick;
        let online = self.online(idx);
        let Some(d) = self.trc(idx) else {
            return RotaryValues::default();
        };
        if online && !d.rotaries.fresh(tick) {
            if let Err(e) = d.read_rotaries(tick) {
                self.note_failure(idx, &e);
            }
        }
        self.trc(idx)
            .and_then(|d| d.rotaries.current)
            .unwrap_or_default()
    }

    /// How far a rotary of the TRC1000 at `idx` moved between the last two readings, if the
    /// last one was made this tick (0 otherwise).
    pub fn turned(&mut self, idx: usize, rotary: Rotary) -> i64 {
        self.rotaries(idx);
        let tick = self.tick;
        self.trc(idx)
            .and_then(|d| d.rotaries.change_at(tick))
            .map_or(0, |(old, new)| {
                i64::from(crate::protocol::trc1000::rotary_delta(
                    old.get(rotary),
                    new.get(rotary),
                ))
            })
    }

    /// The inputs of the TRP-C29U at `idx` (bit n = DIn energized), read lazily.
    pub fn inputs(&mut self, idx: usize) -> u8 {
        let tick = self.tick;
        let online = self.online(idx);
        let Some(d) = self.c29u(idx) else { return 0 };
        if online && !d.inputs.fresh(tick) {
            if let Err(e) = d.read_inputs(tick) {
                self.note_failure(idx, &e);
            }
        }
        self.c29u(idx).and_then(|d| d.inputs.current).unwrap_or(0)
    }

    /// The counters of the TRP-C29U at `idx`, read lazily.
    pub fn counters(&mut self, idx: usize) -> [u16; 8] {
        let tick = self.tick;
        let online = self.online(idx);
        let Some(d) = self.c29u(idx) else {
            return [0; 8];
        };
        if online && !d.counters.fresh(tick) {
            if let Err(e) = d.read_counters(tick) {
                self.note_failure(idx, &e);
            }
        }
        self.c29u(idx)
            .and_then(|d| d.counters.current)
            .unwrap_or([0; 8])
    }

    /// The latches of the TRP-C29U at `idx`, read lazily.
    pub fn latches(&mut self, idx: usize) -> Latches {
        let tick = self.tick;
        let online = self.online(idx);
        let none = Latches { low: 0, high: 0 };
        let Some(d) = self.c29u(idx) else { return none };
        if online && !d.latches.fresh(tick) {
            if let Err(e) = d.read_latches(tick) {
                self.note_failure(idx, &e);
            }
        }
        self.c29u(idx)
            .and_then(|d| d.latches.current)
            .unwrap_or(none)
    }

    // ---- outputs -------------------------------------------------------------------------

    /// Sets the DO byte the script wants on the TRP-C29U at `idx` (written at the end of the
    /// tick).
    pub fn set_outputs(&mut self, idx: usize, value: u8) {
        let cause = self.cause.clone();
        if let Some(d) = self.c29u(idx) {
            if d.outputs != value {
                d.outputs = value;
                d.outputs_cause = cause;
            }
        }
    }

    /// Sets the relay the script wants on the TRC1000 at `idx` (selected at the end of the
    /// tick).
    pub fn set_relay(&mut self, idx: usize, relay: u8) {
        let cause = self.cause.clone();
        if let Some(d) = self.trc(idx) {
            if d.relay != relay {
                d.relay = relay;
                d.relay_cause = cause;
            }
        }
    }

    /// Writes what changed, one transaction per device: the DO byte the script wants (the
    /// safe value while held safe), the relay it wants (the safe relay while held safe).
    pub fn flush_outputs(&mut self) {
        for idx in 0..self.devices.len() {
            if !self.online(idx) {
                continue;
            }
            let held = self.held_safe;
            let result = match self.devices.get_mut(idx) {
                Some(Device::Trc(d)) => {
                    let target = if held {
                        d.config.safe_relay
                    } else {
                        Some(d.relay)
                    };
                    match target {
                        Some(relay) if d.relay_written != Some(relay) => {
                            let before = d.relay_written;
                            let line = format!(
                                "{}: relay {} -> {relay} ({})",
                                d.name,
                                before.map_or("?".to_string(), |r| r.to_string()),
                                if held { "held safe" } else { &d.relay_cause }
                            );
                            d.select_relay(relay).map(|()| Some(line))
                        }
                        _ => Ok(None),
                    }
                }
                Some(Device::C29u(d)) => {
                    let target = if held { d.config.safe_value } else { d.outputs };
                    if d.outputs_written == Some(target) {
                        Ok(None)
                    } else {
                        let before = d.outputs_written;
                        let line = format!(
                            "{}: outputs {} -> {target:#04x} ({})",
                            d.name,
                            before.map_or("?".to_string(), |v| format!("{v:#04x}")),
                            if held { "held safe" } else { &d.outputs_cause }
                        );
                        d.write_outputs(target).map(|()| Some(line))
                    }
                }
                None => Ok(None),
            };
            match result {
                Ok(Some(line)) => self.log.activity(&line),
                Ok(None) => {}
                Err(e) if e.is_safe_mode() => self.regain_control(idx),
                Err(e) => {
                    let name = self.devices.get(idx).map_or("", Device::name).to_string();
                    if !e.is_comm_failure() {
                        self.log
                            .error(&format!("{name}: writing outputs failed: {e}"));
                    }
                    self.note_failure(idx, &e);
                }
            }
        }
    }

    /// The TRP-C29U at `idx` refused a write because its watchdog has fired (the runner was
    /// too late to feed it): take control of it again as when it comes back after a loss.
    pub fn regain_control(&mut self, idx: usize) {
        let name = self.devices.get(idx).map_or("", Device::name).to_string();
        self.log.warn(&format!(
            "{name}: the module is in safe mode (its host watchdog fired: it was not fed in \
             time); taking control again"
        ));
        self.take_control(idx);
    }

    /// Puts the device at `idx` under supervision (again): a TRP-C29U gets its safe and
    /// power-on values, its outputs (the safe value while held safe) and its watchdog; a
    /// TRC1000 gets its relay selected again at the next write. False if it failed.
    pub fn take_control(&mut self, idx: usize) -> bool {
        let now = self.now();
        let held = self.held_safe;
        let result = match self.devices.get_mut(idx) {
            Some(Device::C29u(d)) => {
                let target = if held { d.config.safe_value } else { d.outputs };
                let name = d.name.clone();
                d.take_control(target, now).map(|notes| {
                    let mut lines = Vec::new();
                    if notes.left_safe_mode {
                        lines.push(format!(
                            "{name}: was in safe mode (its host watchdog had fired); its \
                             watchdog was turned off to leave it"
                        ));
                    }
                    if let Some(was) = notes.safe_value_was {
                        lines.push(format!(
                            "{name}: stored safe value {was:#04x} -> {:#04x}",
                            d.config.safe_value
                        ));
                    }
                    if let (Some(was), Some(v)) =
                        (notes.power_on_value_was, d.config.power_on_value)
                    {
                        lines.push(format!(
                            "{name}: stored power-on value {was:#04x} -> {v:#04x}"
                        ));
                    }
                    if let Some(own) = notes.adopted_watchdog {
                        lines.push(format!(
                            "{name}: its host watchdog is on ({}) though rig.toml sets none; \
                             the runner feeds it",
                            format_duration(own.as_duration())
                        ));
                    }
                    lines
                })
            }
            Some(Device::Trc(d)) => {
                d.relay_written = None;
                d.probe().map(|()| Vec::new())
            }
            None => Ok(Vec::new()),
        };
        match result {
            Ok(lines) => {
                for l in lines {
                    self.log.info(&l);
                }
                true
            }
            Err(e) => {
                let name = self.devices.get(idx).map_or("", Device::name).to_string();
                if !e.is_comm_failure() {
                    self.log
                        .error(&format!("{name}: taking control failed: {e}"));
                }
                self.note_failure(idx, &e);
                false
            }
        }
    }

    /// Feeds each host watchdog the runner keeps, at a quarter of its timeout (or every
    /// tick, if the period is longer than that).
    pub fn feed_watchdogs(&mut self) {
        let now = self.now();
        for idx in 0..self.devices.len() {
            if !self.online(idx) {
                continue;
            }
            let Some(d) = self.c29u(idx) else { continue };
            let Some(t) = d.watchdog else { continue };
            if let Err(e) = d.feed(now, t.as_duration() / 4) {
                self.note_failure(idx, &e);
            }
        }
    }

    /// Checks that the modules still drive what was written (a module reset or power cycled
    /// by someone else goes back to its power-on value) and selects each relay again (a board
    /// that was unplugged forgets it); run every few seconds.
    pub fn verify_outputs(&mut self) {
        for idx in 0..self.devices.len() {
            if !self.online(idx) {
                continue;
            }
            let result = match self.devices.get_mut(idx) {
                Some(Device::C29u(d)) => match d.outputs_written {
                    Some(written) => {
                        d.driver
                            .read_outputs()
                            .map_err(DeviceError::from)
                            .map(|actual| {
                                (actual != written).then(|| {
                                    d.outputs_written = None;
                                    format!(
                                        "{}: outputs read {actual:#04x} but {written:#04x} was \
                                     written (module reset or power cycled?); writing them again",
                                        d.name
                                    )
                                })
                            })
                    }
                    None => Ok(None),
                },
                Some(Device::Trc(d)) => {
                    d.relay_written = None;
                    Ok(None)
                }
                None => Ok(None),
            };
            match result {
                Ok(Some(line)) => self.log.warn(&line),
                Ok(None) => {}
                Err(e) => self.note_failure(idx, &e),
            }
        }
    }

    // ---- handlers ------------------------------------------------------------------------

    /// Adds a handler; returns its id.
    pub fn subscribe(&mut self, source: Source, handler: H, label: String) -> u64 {
        let id = self.next_sub;
        self.next_sub = self.next_sub.saturating_add(1);
        self.subs.push(Subscription {
            id,
            source,
            handler,
            label,
            last_logged: None,
        });
        id
    }

    /// `every(period, fn)`.
    pub fn every(&mut self, period: Duration, handler: H) -> Result<u64, ScheduleError> {
        let id = self.schedule.every(period, self.now())?;
        let label = format!("every {}", format_duration(period));
        Ok(self.subscribe(Source::Timer(id), handler, label))
    }

    /// `after(delay, fn)`.
    pub fn after(&mut self, delay: Duration, handler: H) -> u64 {
        let id = self.schedule.after(delay, self.now());
        let label = format!("after {}", format_duration(delay));
        self.subscribe(Source::Timer(id), handler, label)
    }

    /// `cron(expr, fn)`.
    pub fn cron(&mut self, expr: &str, handler: H) -> Result<u64, ScheduleError> {
        let id = self.schedule.cron(expr, self.clock.wall())?;
        let label = format!("cron {expr:?}");
        Ok(self.subscribe(Source::Timer(id), handler, label))
    }

    /// Removes a handler or timer; false if there is none with that id.
    pub fn cancel(&mut self, id: u64) -> bool {
        let Some(pos) = self.subs.iter().position(|s| s.id == id) else {
            return false;
        };
        let sub = self.subs.remove(pos);
        if let Source::Timer(t) = sub.source {
            self.schedule.cancel(t);
        }
        true
    }

    /// Whether the script still waits for anything (handlers other than `on_stop`, timers).
    pub fn has_work(&self) -> bool {
        self.subs.iter().any(|s| s.source != Source::Stop)
    }

    /// Whether some handler waits for device inputs, or an invariant is stated (then every
    /// tick runs: invariants are checked every tick).
    pub fn polls_inputs(&self) -> bool {
        !self.invariants.is_empty()
            || self
                .subs
                .iter()
                .any(|s| !matches!(s.source, Source::Timer(_) | Source::Stop))
    }

    /// When the next tick has something to do, if no handler polls inputs: the earliest
    /// timer, watchdog feed or retry of a lost device. `None` when every tick has work.
    pub fn idle_until(&self) -> Option<Duration> {
        if self.polls_inputs() {
            return None;
        }
        let now = self.now();
        let mut next = self.schedule.next_deadline(now, self.clock.wall());
        for d in &self.devices {
            let h = d.health();
            let due = if !h.online() {
                Some(h.next_retry)
            } else {
                match d {
                    Device::C29u(c) => c
                        .watchdog
                        .map(|t| c.last_feed.saturating_add(t.as_duration() / 4)),
                    Device::Trc(_) => None,
                }
            };
            next = match (next, due) {
                (Some(a), Some(b)) => Some(a.min(b)),
                (a, b) => a.or(b),
            };
        }
        Some(next.unwrap_or(Duration::MAX))
    }

    /// The handlers, for inspection.
    pub fn subscriptions(&self) -> &[Subscription<H>] {
        &self.subs
    }

    /// The `on_stop` handlers, in the order they were added.
    pub fn stop_calls(&self) -> Vec<Call<H>> {
        self.subs
            .iter()
            .filter(|s| s.source == Source::Stop)
            .map(|s| Call {
                handler: s.handler.clone(),
                args: Vec::new(),
                label: s.label.clone(),
            })
            .collect()
    }

    /// Forgets every handler and timer and the script's outputs (back to the safe values),
    /// before the script is started again.
    pub fn reset_program(&mut self) {
        self.subs.clear();
        self.invariants.clear();
        self.schedule = Schedule::with_time_zone(self.zone);
        self.stop_request = None;
        for d in &mut self.devices {
            match d {
                Device::Trc(t) => {
                    if let Some(r) = t.config.safe_relay {
                        t.relay = r;
                    }
                }
                Device::C29u(c) => c.outputs = c.config.safe_value,
            }
        }
    }

    /// Reads the inputs the handlers wait for and turns what changed, and the timers that are
    /// due, into handler calls, in order: device events (by device, then switch, rotary,
    /// input, counter), then timers (deadline order). Logs one line per event handled.
    pub fn collect_calls(&mut self) -> Vec<Call<H>> {
        let mut needs = vec![[false; 4]; self.devices.len()];
        for s in &self.subs {
            let (dev, what) = match s.source {
                Source::Press { dev, .. } | Source::Release { dev, .. } => (dev, 0),
                Source::Turn { dev, .. } => (dev, 1),
                Source::Rise { dev, .. } | Source::Fall { dev, .. } => (dev, 2),
                Source::Counter { dev, .. } => (dev, 3),
                Source::Timer(_) | Source::Stop => continue,
            };
            if let Some(n) = needs.get_mut(dev).and_then(|n| n.get_mut(what)) {
                *n = true;
            }
        }
        let mut calls = Vec::new();
        for (dev, need) in needs.iter().enumerate() {
            let [switches, rotaries, inputs, counters] = *need;
            if switches {
                self.switches(dev);
            }
            if rotaries {
                self.rotaries(dev);
            }
            if inputs {
                self.inputs(dev);
            }
            if counters {
                self.counters(dev);
            }
            for (event, args) in self.device_events(dev) {
                self.dispatch(&event, &args, &mut calls);
            }
        }
        self.counter_calls(&mut calls);
        self.timer_calls(&mut calls);
        calls
    }

    /// The events of the device at `idx` from this tick's readings, each as the source it
    /// matches and the handler's arguments.
    fn device_events(&mut self, idx: usize) -> Vec<(Source, Vec<Arg>)> {
        let tick = self.tick;
        let mut events = Vec::new();
        match self.devices.get(idx) {
            Some(Device::Trc(d)) => {
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
            Some(Device::C29u(d)) => {
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
            None => {}
        }
        events
    }

    /// Adds the calls of the handlers waiting for `event`, logging it once if any.
    fn dispatch(&mut self, event: &Source, args: &[Arg], calls: &mut Vec<Call<H>>) {
        let before = calls.len();
        for s in self.subs.iter().filter(|s| s.source == *event) {
            calls.push(Call {
                handler: s.handler.clone(),
                args: args.to_vec(),
                label: s.label.clone(),
            });
        }
        if calls.len() == before {
            return;
        }
        let name = |dev: usize| self.devices.get(dev).map_or("", Device::name).to_string();
        let line = match (event, args) {
            (Source::Press { dev, switch }, _) => format!("{}: {switch} pressed", name(*dev)),
            (Source::Release { dev, switch }, _) => {
                format!("{}: {switch} released", name(*dev))
            }
            (Source::Turn { dev, rotary }, [Arg::Int(delta), Arg::Int(value)]) => format!(
                "{}: {} turned {delta:+} (now {value})",
                name(*dev),
                rotary.name()
            ),
            (Source::Rise { dev, ch }, _) => format!("{}: DI{ch} on", name(*dev)),
            (Source::Fall { dev, ch }, _) => format!("{}: DI{ch} off", name(*dev)),
            _ => return,
        };
        self.log.activity(&line);
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
        for s in &mut self.subs {
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
                calls.push(Call {
                    handler: s.handler.clone(),
                    args: vec![Arg::Int(i64::from(count))],
                    label: s.label.clone(),
                });
                let name = self.devices.get(*dev).map_or("", Device::name);
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
        let fired = self.schedule.due(now, self.clock.wall());
        let mut lines = Vec::new();
        for f in fired {
            let Some(s) = self
                .subs
                .iter_mut()
                .find(|s| s.source == Source::Timer(f.id))
            else {
                continue;
            };
            calls.push(Call {
                handler: s.handler.clone(),
                args: vec![Arg::Int(i64::try_from(f.missed).unwrap_or(i64::MAX))],
                label: s.label.clone(),
            });
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
        let schedule = &self.schedule;
        self.subs.retain(|s| match s.source {
            Source::Timer(t) => schedule.contains(t),
            _ => true,
        });
        for l in lines {
            self.log.activity(&l);
        }
    }

    /// What a timer was made from.
    pub fn timer_kind(&self, id: TimerId) -> Option<&TimerKind> {
        self.schedule.kind(id)
    }
}
