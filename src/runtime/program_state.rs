//! What the script set up on the run: its handlers and timers, its invariants, the stop it
//! asked for and the handler running now. The runtime composes it; the script changes it
//! through the runtime's registrations (`registrations`, `invariant_checks`).

use super::handlers::{Call, Handlers};
use super::invariants::{InvariantCheck, InvariantError, MAX_INVARIANTS};
use super::triggers::Needs;
use crate::time::zone::Zone;
use std::rc::Rc;

/// The script's side of the run.
pub struct ProgramState<H> {
    /// The script's handlers and timers.
    handlers: Handlers<H>,
    /// What the script states must hold after every tick (`invariants`).
    invariants: Rc<Vec<InvariantCheck<H>>>,
    /// Whether the invariants read device inputs when last evaluated (or have not been yet):
    /// then every tick runs, so the inputs they read are read every tick.
    invariants_read_inputs: bool,
    /// The script asked to stop, with this exit status (`request_stop`).
    stop_request: Option<i64>,
    /// The handler running now, for the log lines of the outputs it changes.
    cause: String,
    /// `collect_calls`'s lists, kept between ticks: a tick builds its calls without
    /// allocating the lists.
    needs: Vec<Needs>,
    calls: Vec<Call<H>>,
    /// The top level runs for a reload (`is_reload()`).
    reloading: bool,
    /// The `on_reload` handlers the top level of a reload added, in that order.
    on_reload: Vec<Call<H>>,
}

/// What a script set up, set aside while a reload starts its successor.
pub struct Setup<H> {
    handlers: Handlers<H>,
    invariants: Rc<Vec<InvariantCheck<H>>>,
    invariants_read_inputs: bool,
}

impl<H: Clone> ProgramState<H> {
    /// Nothing set up yet; cron in `zone`.
    pub fn new(zone: Zone) -> Self {
        Self {
            handlers: Handlers::new(zone),
            invariants: Rc::default(),
            invariants_read_inputs: true,
            stop_request: None,
            cause: "top level".into(),
            needs: Vec::new(),
            calls: Vec::new(),
            reloading: false,
            on_reload: Vec::new(),
        }
    }

    /// Takes what the script set up out (a reload), leaving nothing set up.
    pub fn take_setup(&mut self) -> Setup<H> {
        Setup {
            handlers: self.handlers.take(),
            invariants: std::mem::take(&mut self.invariants),
            invariants_read_inputs: std::mem::replace(&mut self.invariants_read_inputs, true),
        }
    }

    /// Drops what is set up now and puts `setup` back (the reload failed).
    pub fn put_back(&mut self, setup: Setup<H>) {
        self.forget();
        self.handlers.put_back(setup.handlers);
        self.invariants = setup.invariants;
        self.invariants_read_inputs = setup.invariants_read_inputs;
    }

    /// Whether the top level runs for a reload.
    pub fn reloading(&self) -> bool {
        self.reloading
    }

    /// Says whether the top level about to run is a reload's.
    pub fn set_reloading(&mut self, reloading: bool) {
        self.reloading = reloading;
    }

    /// `on_reload(fn)`: run once after a reload's top level, its variables carried.
    pub fn on_reload(&mut self, handler: H) {
        self.on_reload.push(Call {
            handler,
            args: Vec::new(),
            label: "on_reload".into(),
        });
    }

    /// The `on_reload` handlers to run now, taken (each runs once).
    pub fn take_reload_calls(&mut self) -> Vec<Call<H>> {
        std::mem::take(&mut self.on_reload)
    }

    /// The script's handlers and timers.
    pub fn handlers(&self) -> &Handlers<H> {
        &self.handlers
    }

    /// The script's handlers and timers, to add, fire or drop one.
    pub fn handlers_mut(&mut self) -> &mut Handlers<H> {
        &mut self.handlers
    }

    /// Whether every tick has work for the script: a handler polls inputs, or an invariant
    /// read device inputs when last evaluated (one that reads only outputs, script state or
    /// time can change only in a tick that runs anyway).
    pub fn polls_inputs(&self) -> bool {
        self.handlers.polls_inputs() || (!self.invariants.is_empty() && self.invariants_read_inputs)
    }

    /// The invariants the script stated, in that order.
    pub fn invariants(&self) -> &[InvariantCheck<H>] {
        &self.invariants
    }

    /// How to evaluate each invariant, in the order they were stated: the list itself, shared
    /// (the checks call the script, which may borrow the runtime meanwhile).
    pub fn invariant_checks(&self) -> Rc<Vec<InvariantCheck<H>>> {
        Rc::clone(&self.invariants)
    }

    /// States an invariant (checked from the next tick on).
    pub fn add_invariant(
        &mut self,
        name: &str,
        handler: H,
        at: Option<String>,
    ) -> Result<(), InvariantError> {
        if name.trim().is_empty() {
            return Err(InvariantError::NoName);
        }
        if self.invariants.iter().any(|i| i.name == name) {
            return Err(InvariantError::Duplicate(name.to_string()));
        }
        if self.invariants.len() >= MAX_INVARIANTS {
            return Err(InvariantError::TooMany);
        }
        Rc::make_mut(&mut self.invariants).push(InvariantCheck {
            call: Call {
                handler,
                args: Vec::new(),
                label: format!("invariant {name:?}").into(),
            },
            name: name.to_string(),
            at,
        });
        Ok(())
    }

    /// Notes whether the invariants read device inputs in the checks just made.
    pub fn note_invariants_read_inputs(&mut self, read: bool) {
        self.invariants_read_inputs = read;
    }

    /// The script's `stop(code)`: the first request made stands.
    pub fn request_stop(&mut self, code: i64) {
        self.stop_request.get_or_insert(code);
    }

    /// The exit status the script asked to stop with, if it did.
    pub fn stop_requested(&self) -> Option<i64> {
        self.stop_request
    }

    /// The handler running now.
    pub fn cause(&self) -> &str {
        &self.cause
    }

    /// The handler about to run is `label` (its buffer kept: this is every call).
    pub fn set_cause(&mut self, label: &str) {
        self.cause.clear();
        self.cause.push_str(label);
    }

    /// The lists a tick builds its calls in, empty, with what they held before.
    pub(super) fn take_buffers(&mut self) -> (Vec<Needs>, Vec<Call<H>>) {
        (
            std::mem::take(&mut self.needs),
            std::mem::take(&mut self.calls),
        )
    }

    /// Takes back the needs list `take_buffers` gave.
    pub(super) fn keep_needs(&mut self, needs: Vec<Needs>) {
        self.needs = needs;
    }

    /// Takes back the calls list `take_buffers` gave, once its calls are made.
    pub(super) fn keep_calls(&mut self, mut calls: Vec<Call<H>>) {
        calls.clear();
        self.calls = calls;
    }

    /// Drops every handler, timer and invariant, and with them the script's closures that
    /// hold handles to the runtime (a cycle of `Rc`s otherwise).
    pub fn forget(&mut self) {
        self.handlers.clear();
        self.invariants = Rc::default();
        self.on_reload.clear();
    }

    /// Forgets everything the script set up, before it is started again.
    pub fn reset(&mut self) {
        self.forget();
        self.invariants_read_inputs = true;
        self.stop_request = None;
    }
}
