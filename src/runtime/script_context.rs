//! The script's one way into the scan loop: the narrow set of operations its bindings need
//! (devices by name, the tick's readings, wanted outputs, module operations done at once,
//! handlers and timers, the clock, messages, records, invariants, stop). The bindings see
//! these requests, never the runtime's state, and each borrows the runtime only for itself
//! (a handler runs while the loop holds no borrow).

use crate::config::PointNames;
use super::devices::links::TransactionCounter;
use super::devices::{C29uDevice, Device, DeviceError};
use super::handlers::{Source, TooManyStopHandlers};
use super::invariants::InvariantError;
use super::observe::RunEvent;
use super::records::Limits;
use super::runner::Shared;
use super::schedule::ScheduleError;
use crate::device::c29u::Latches;
use crate::protocol::trc1000::{Rotary, RotaryValues, SwitchSet};
use crate::time::clock::SharedClock;
use serde_json::Value;
use std::rc::Rc;
use std::sync::Arc;
use std::time::Duration;

/// The script's side of one run, over handlers of type `H`.
pub struct ScriptContext<H>(Shared<H>);

impl<H> Clone for ScriptContext<H> {
    fn clone(&self) -> Self {
        Self(Rc::clone(&self.0))
    }
}

/// The two kinds of device a script has a handle on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceKind {
    /// A TRC1000 panel.
    Trc1000,
    /// A TRP-C29U module.
    C29u,
}

impl<H: Clone> ScriptContext<H> {
    /// The script's side of the run `rt`.
    pub fn new(rt: &Shared<H>) -> Self {
        Self(Rc::clone(rt))
    }

    /// The run's clock (the script's time limits read it).
    pub fn clock(&self) -> SharedClock {
        Arc::clone(self.0.borrow().cycle().clock())
    }

    /// The counter of requests sent on all links (an exchange takes time: the script's
    /// limits read the clock again after each new one).
    pub fn transaction_counter(&self) -> TransactionCounter {
        Arc::clone(self.0.borrow().devices.transaction_counter())
    }

    /// The index of the device called `name`.
    pub fn device_index(&self, name: &str) -> Option<usize> {
        self.0.borrow().devices.index(name)
    }

    /// The name and kind of the device at `idx`.
    pub fn device(&self, idx: usize) -> Option<(Rc<str>, DeviceKind)> {
        let rt = self.0.borrow();
        let d = rt.devices().get(idx)?;
        let kind = match d {
            Device::Trc(_) => DeviceKind::Trc1000,
            Device::C29u(_) => DeviceKind::C29u,
        };
        Some((Rc::from(d.name()), kind))
    }

    /// The names rig.toml gives the points of the device at `idx` (none if there is no such
    /// device): fixed for the run, so a handle keeps its own.
    pub fn point_names(&self, idx: usize) -> Rc<PointNames> {
        let rt = self.0.borrow();
        Rc::new(rt.devices().get(idx).map(Device::names).cloned().unwrap_or_default())
    }

    /// The device names in index order.
    pub fn names(&self) -> Vec<String> {
        let rt = self.0.borrow();
        rt.devices().iter().map(|d| d.name().to_string()).collect()
    }

    /// The device names, for messages.
    pub fn device_names(&self) -> String {
        self.0.borrow().devices.names()
    }

    /// Whether the device at `idx` answers.
    pub fn online(&self, idx: usize) -> bool {
        self.0.borrow().devices.online(idx)
    }

    /// The relay the script wants on the TRC1000 at `idx` (0 if there is none); while the
    /// invariants are judged on what would be written, the relay forced over it.
    pub fn wanted_relay(&self, idx: usize) -> u8 {
        let mut rt = self.0.borrow_mut();
        let wanted = rt.devices.trc(idx).map_or(0, |d| d.wanted_relay());
        match rt.forces.judging() {
            true => rt.forces.relay(idx, wanted),
            false => wanted,
        }
    }

    /// Selects `relay` on the TRC1000 at `idx` at the end of the tick.
    pub fn set_relay(&self, idx: usize, relay: u8) {
        self.0.borrow_mut().set_relay(idx, relay);
    }

    /// The DO byte the script wants on the TRP-C29U at `idx` (0 if there is none); while the
    /// invariants are judged on what would be written, with the forces over it.
    pub fn wanted_outputs(&self, idx: usize) -> u8 {
        let mut rt = self.0.borrow_mut();
        let wanted = rt.devices.c29u(idx).map_or(0, |c| c.wanted_outputs());
        match rt.forces.judging() {
            true => rt.forces.outputs(idx, wanted),
            false => wanted,
        }
    }

    /// Writes `value` to the TRP-C29U at `idx` at the end of the tick.
    pub fn set_outputs(&self, idx: usize, value: u8) {
        self.0.borrow_mut().set_outputs(idx, value);
    }

    /// Turns output `ch` of the TRP-C29U at `idx` on or off in what the script wants.
    pub fn set_output(&self, idx: usize, ch: u8, on: bool) {
        let mut rt = self.0.borrow_mut();
        let v = rt.devices.c29u(idx).map_or(0, |c| c.wanted_outputs());
        rt.set_outputs(idx, if on { v | (1 << ch) } else { v & !(1 << ch) });
    }

    /// The tick's switches of the TRC1000 at `idx` (`Runtime::switches`: read lazily).
    pub fn switches(&self, idx: usize) -> SwitchSet {
        self.0.borrow_mut().switches(idx)
    }

    /// The tick's rotaries of the TRC1000 at `idx`.
    pub fn rotaries(&self, idx: usize) -> RotaryValues {
        self.0.borrow_mut().rotaries(idx)
    }

    /// How far `rotary` of the TRC1000 at `idx` turned this tick.
    pub fn turned(&self, idx: usize, rotary: Rotary) -> i64 {
        self.0.borrow_mut().turned(idx, rotary)
    }

    /// The tick's inputs of the TRP-C29U at `idx`.
    pub fn inputs(&self, idx: usize) -> u8 {
        self.0.borrow_mut().inputs(idx)
    }

    /// The tick's counters of the TRP-C29U at `idx`.
    pub fn counters(&self, idx: usize) -> [u16; 8] {
        self.0.borrow_mut().counters(idx)
    }

    /// The tick's latches of the TRP-C29U at `idx`.
    pub fn latches(&self, idx: usize) -> Latches {
        self.0.borrow_mut().latches(idx)
    }

    /// Runs `op` on the TRP-C29U at `idx` at once, given the time now (refused while it is
    /// lost, `Runtime::command`).
    pub fn on_module<T>(
        &self,
        idx: usize,
        op: impl FnOnce(&mut C29uDevice, Duration) -> Result<T, DeviceError>,
    ) -> Result<T, DeviceError> {
        let mut rt = self.0.borrow_mut();
        let now = rt.now();
        rt.command(idx, |d| match d {
            Device::C29u(c) => op(c, now),
            Device::Trc(_) => Err(DeviceError::Offline {
                device: "not a TRP-C29U".into(),
                ago: Duration::ZERO,
                cause: String::new(),
            }),
        })
    }

    /// Adds a handler; returns its id.
    pub fn subscribe(&self, source: Source, handler: H, label: String) -> u64 {
        self.0.borrow_mut().subscribe(source, handler, label)
    }

    /// `every(period, fn)`.
    pub fn every(&self, period: Duration, handler: H) -> Result<u64, ScheduleError> {
        self.0.borrow_mut().every(period, handler)
    }

    /// `after(delay, fn)`.
    pub fn after(&self, delay: Duration, handler: H) -> Result<u64, ScheduleError> {
        self.0.borrow_mut().after(delay, handler)
    }

    /// `cron(expr, fn)`.
    pub fn cron(&self, expr: &str, handler: H) -> Result<u64, ScheduleError> {
        self.0.borrow_mut().cron(expr, handler)
    }

    /// Removes a handler or timer; false if there is none with that id.
    pub fn cancel(&self, id: u64) -> bool {
        self.0.borrow_mut().cancel(id)
    }

    /// `on_stop(fn)`; refused past `MAX_STOP_HANDLERS`.
    pub fn on_stop(&self, handler: H) -> Result<u64, TooManyStopHandlers> {
        self.0.borrow_mut().on_stop(handler)
    }

    /// Whether the top level runs for a reload (`is_reload()`).
    pub fn is_reload(&self) -> bool {
        self.0.borrow().program.reloading()
    }

    /// `on_reload(fn)`: runs once after this reload's top level, the variables carried; at a
    /// first start it is never called.
    pub fn on_reload(&self, handler: H) {
        let mut rt = self.0.borrow_mut();
        if rt.program.reloading() {
            rt.program.on_reload(handler);
        }
    }

    /// States an invariant (checked from the next tick on), stated at `at`.
    pub fn add_invariant(
        &self,
        name: &str,
        handler: H,
        at: Option<String>,
    ) -> Result<(), InvariantError> {
        self.0.borrow_mut().program.add_invariant(name, handler, at)
    }

    /// `stop(code)`: the run ends at the end of this tick; the first request stands.
    pub fn request_stop(&self, code: i64) {
        self.0.borrow_mut().program.request_stop(code);
    }

    /// The wall time now, as text in the run's zone.
    pub fn wall_text(&self) -> String {
        self.0.borrow().cycle().wall_text()
    }

    /// How long the run has been going.
    pub fn uptime(&self) -> Duration {
        self.0.borrow().cycle().uptime()
    }

    /// A line of the log at info level.
    pub fn info(&self, message: &str) {
        self.0.borrow_mut().log_mut().info(message);
    }

    /// A line of the log at warning level.
    pub fn warn(&self, message: &str) {
        self.0.borrow_mut().log_mut().warn(message);
    }

    /// Publishes `payload` on `topic` (the MQTT client carries it, if there is one).
    pub fn publish(&self, topic: String, payload: String) {
        let rt = self.0.borrow();
        rt.events()
            .publish(|| RunEvent::Published { topic, payload });
    }

    /// `record(name, value)`: one record, stamped now.
    pub fn record(&self, name: &str, value: Value) {
        self.0.borrow_mut().record(name, value);
    }

    /// `measure(name, value, limits)`: one measurement, stamped now and logged; whether it is
    /// within its limits.
    pub fn measure(&self, name: &str, value: f64, limits: &Limits) -> bool {
        self.0.borrow_mut().measure(name, value, limits)
    }
}
