//! A reload: a new script swapped in at a tick boundary with the devices open and the outputs
//! as they are. The old script's handlers, timers and invariants are set aside, the new top
//! level runs (`is_reload()` true), the top-level variables both scripts have with the same
//! type get their old values, the `on_reload` handlers run; then the old setup is dropped.
//! A new script that fails on the way is dropped instead: the old one runs on, its setup, its
//! variables and the outputs it wanted put back. The text was read, checked and tested off
//! the loop (`Request::Reload`); here it is only compiled again and started.

use super::contract::{describe, Program};
use super::{Runner, State};
use crate::content_hash::{content_hash, short};
use crate::runtime::observe::{EventKind, RunEvent};
use crate::runtime::program_state::Setup;
use crate::runtime::requests::{Answer, Request};
use serde_json::json;
use std::time::Duration;

/// A swap done: the variables carried, the old script's setup, the outputs it wanted.
type Swapped<H> = (Vec<String>, Setup<H>, Vec<u8>);

/// What the run knows of the script it runs: for the log, the records and `status`.
#[derive(Debug, Clone, Default)]
pub(super) struct ScriptIdentity {
    /// The running script's content hash (`content_hash`).
    pub(super) hash: String,
    /// Its file, as the log names it.
    pub(super) file: String,
    /// Times it was reloaded.
    pub(super) reloads: u64,
    /// When last, on the run's wall clock.
    pub(super) reloaded: Option<String>,
}

/// A reload that may still be undone (`--rollback`): the old script's setup and the outputs
/// it wanted at the swap, until when, and which script it was.
pub(super) struct Undo<H> {
    setup: Setup<H>,
    wanted: Vec<u8>,
    until: Duration,
    hash: String,
    file: String,
}

impl<P: Program> Runner<P> {
    /// After each reload, goes back to the previous script (and the state it had at the swap)
    /// if the new one raises an error or finds an invariant false within `window` (`run
    /// --rollback`); `None`: a reload stands at once.
    pub fn set_rollback(&mut self, window: Option<Duration>) {
        self.rollback = window;
    }

    /// Lets a reload whose rollback window has passed stand; at every tick.
    fn undo_expired(&mut self) {
        let now = self.clock.now();
        if self.undo.as_ref().is_some_and(|u| u.until <= now) {
            let file = self
                .undo
                .as_ref()
                .map(|u| u.file.clone())
                .unwrap_or_default();
            self.settle_undo();
            self.rt.borrow_mut().log_mut().notice(&format!(
                "the reload stands: no error within the rollback window (no way back to {file})"
            ));
        }
    }

    /// Drops the way back to the script before the last reload.
    fn settle_undo(&mut self) {
        if let Some(undo) = self.undo.take() {
            // The old handlers (closures of the old script) go before the old script does.
            drop(undo.setup);
            self.program.settle();
        }
    }

    /// Goes back to the script before the last reload, if it is still within its rollback
    /// window, because of `why`; true if it did.
    pub(super) fn roll_back(&mut self, why: &str) -> bool {
        let Some(undo) = self.undo.take() else {
            return false;
        };
        let from = std::mem::replace(&mut self.identity.hash, undo.hash.clone());
        {
            let mut rt = self.rt.borrow_mut();
            rt.program.put_back(undo.setup);
            rt.want_outputs(&undo.wanted);
            rt.log_mut().error(&format!(
                "rolling back to {} ({}): the reloaded script failed within the rollback \
                 window: {why}",
                undo.file,
                short(&undo.hash)
            ));
            rt.record(
                "rollback",
                json!({"file": undo.file, "from": from, "to": undo.hash, "why": why}),
            );
        }
        self.program.swap_back();
        self.identity.file = undo.file.clone();
        if let Some(served) = self.served.as_mut() {
            served.script = undo.file;
            served.made = None;
        }
        true
    }

    /// Names the running script: its text (by its content hash, for `status` and reloads)
    /// and its file.
    pub fn name_script(&mut self, source: &str, file: &str) {
        self.identity.hash = content_hash(source);
        self.identity.file = file.to_string();
    }

    /// Swaps `source` (from `file`) in at the next tick's boundary, as a run's reload was:
    /// what a replay does where its journal says the run was reloaded.
    pub fn reload_at_next_tick(&mut self, source: String, file: String) {
        self.replayed_reloads.push((source, file));
    }

    /// The reloads waiting, each done or refused and answered; before the tick's handlers.
    pub(super) fn reload_waiting(&mut self) {
        for (source, file) in std::mem::take(&mut self.replayed_reloads) {
            // A refusal is logged and recorded as the run's own would be.
            let _ = self.reload(&source, &file, "the journal's replay");
        }
        let waiting = match self.served.as_mut() {
            Some(served) if !served.reloads.is_empty() => std::mem::take(&mut served.reloads),
            _ => {
                self.undo_expired();
                return;
            }
        };
        for later in waiting {
            let answer = match &later.request {
                Request::Reload { source, file, by } => match self.reload(source, file, by) {
                    Ok(()) => Answer::Accepted,
                    Err(why) => Answer::Refused(why),
                },
                _ => Answer::Refused("not a reload".into()),
            };
            later.answer(answer);
        }
    }

    /// Swaps `source` (the file `file`, asked by `by`) in for the running script now (call it
    /// at a tick boundary); refused with why, the old script running on.
    pub fn reload(&mut self, source: &str, file: &str, by: &str) -> Result<(), String> {
        let old = self.identity.hash.clone();
        let old_file = self.identity.file.clone();
        let new = content_hash(source);
        let result = self.swap_in(source, file).map(|(carried, setup, wanted)| {
            match self.rollback {
                Some(window) => {
                    self.undo = Some(Undo {
                        setup,
                        wanted,
                        until: self.clock.now().saturating_add(window),
                        hash: old.clone(),
                        file: old_file,
                    });
                }
                None => {
                    // The old handlers (closures of the old script) go before it does.
                    drop(setup);
                    self.program.settle();
                }
            }
            carried
        });
        let mut rt = self.rt.borrow_mut();
        let (from, to) = (short(&old), short(&new));
        match &result {
            Ok(carried) => {
                let kept = if carried.is_empty() {
                    "none".to_string()
                } else {
                    carried.join(", ")
                };
                rt.log_mut().notice(&format!(
                    "reloaded {file} ({from} -> {to}), asked by {by}; variables carried: {kept}"
                ));
                rt.record(
                    "reload",
                    json!({"file": file, "from": old, "to": new, "by": by, "carried": carried}),
                );
                if rt.events().wants(EventKind::Reloaded) {
                    rt.events().publish(|| RunEvent::Reloaded {
                        file: file.to_string(),
                        hash: new.clone(),
                        source: source.to_string(),
                    });
                }
                self.identity.hash = new;
                self.identity.file = file.to_string();
                self.identity.reloads = self.identity.reloads.saturating_add(1);
                self.identity.reloaded = Some(rt.cycle().wall_text());
            }
            Err(why) => {
                rt.log_mut().error(&format!(
                    "reload of {file} ({from} -> {to}) asked by {by} refused: {why}; the old \
                     script runs on"
                ));
                rt.record(
                    "reload_refused",
                    json!({"file": file, "from": old, "to": new, "by": by, "why": why}),
                );
            }
        }
        drop(rt);
        if result.is_ok() {
            if let Some(served) = self.served.as_mut() {
                served.script = file.to_string();
                served.made = None;
            }
        }
        result.map(|_| ())
    }

    /// The swap itself: the names of the variables carried, the old script's setup and the
    /// outputs it wanted (to drop, or keep for a rollback), or why the old script runs on.
    fn swap_in(&mut self, source: &str, file: &str) -> Result<Swapped<P::Handler>, String> {
        if self.state != State::Running || self.status().is_some() {
            return Err(
                "the script is not running (waiting to restart, or the run ending)".to_string(),
            );
        }
        if source.trim().is_empty() {
            return Err("the script is empty".into());
        }
        self.program.stage(source, file)?;
        // A reload still within its rollback window stands once another comes.
        self.settle_undo();
        let (wanted, setup) = {
            let mut rt = self.rt.borrow_mut();
            let setup = rt.program.take_setup();
            rt.program.set_reloading(true);
            rt.set_cause("top level (reload)");
            (rt.wanted_outputs(), setup)
        };
        let mut result = self
            .program
            .swap()
            .map_err(|f| describe(&f, "top level (reload)"));
        if result.is_ok() {
            let calls = self.rt.borrow_mut().program.take_reload_calls();
            for call in calls {
                self.rt.borrow_mut().set_cause(&call.label);
                if let Err(f) = self.program.call(&call) {
                    result = Err(describe(&f, &call.label));
                    break;
                }
            }
        }
        let mut rt = self.rt.borrow_mut();
        rt.program.set_reloading(false);
        match result {
            Ok(carried) => Ok((carried, setup, wanted)),
            Err(why) => {
                // The new script's handlers go before it does; the old setup comes back.
                rt.program.put_back(setup);
                rt.want_outputs(&wanted);
                drop(rt);
                self.program.swap_back();
                Err(why)
            }
        }
    }
}
