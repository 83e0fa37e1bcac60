//! Replays a journal in virtual time: the recorded rig, simulated, runs the recorded script
//! (or an edited one) tick by tick, the field set before each tick to what the run read in
//! it (`verify`'s actions, played by `verify::exec::act`), losses and returns, overruns and
//! the stop played where they came. The replay's own events are tallied as the journal's
//! were (`tally`), so the outputs compare entry by entry; the first that differs is the
//! divergence. What the replayed script read that the run never did is reported with the
//! value the simulator gave it.

use super::entry::{Entry, What};
use super::read::Journal;
use super::tally::{device, Tally, KINDS};
use crate::config::RigConfig;
use crate::protocol::trc1000::{Rotary, Switch};
use crate::runtime::devices::{FieldError, Opened, SimRig};
use crate::runtime::observe::{Bound, Kinds, Next, OperatorAct, Subscription};
use crate::script::builder::RigBuilder;
use crate::script::reads::Item;
use crate::script::rig::{Rig, RigError};
use crate::sim::rig::open_devices;
use crate::sync::lock;
use crate::time::clock::{Clock, VirtualClock};
use crate::time::zone::Zone;
use crate::verify::exec::{act, Step};
use crate::verify::plan::Action;
use crate::verify::testfile::AssertedStep;
use std::collections::{BTreeMap, BTreeSet};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// What to replay against, and how far.
#[derive(Debug, Clone, Default)]
pub struct Options {
    /// The script to run instead of the recorded one: (its text, its name in messages).
    pub script: Option<(String, String)>,
    /// Stop after this tick.
    pub until: Option<u64>,
    /// Keep the steps a test file would take (`to_test`), stopping at ticks in this window.
    pub steps_from: Option<u64>,
}

/// Where the replay first wrote otherwise than the run.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Divergence {
    /// The tick.
    pub tick: u64,
    /// What the run wrote there (none: it wrote nothing more).
    pub recorded: Option<Entry>,
    /// What the replay wrote there (none: nothing more).
    pub replayed: Option<Entry>,
    /// The field's entries of the ticks around it.
    pub around: Vec<Entry>,
}

/// A read the run never made, so the journal cannot say what it was.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct Unrecorded {
    /// Device.
    pub dev: String,
    /// What was read.
    pub item: String,
    /// What the simulator gave (its rest value).
    pub assumed: String,
}

/// What a replay came to.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// The script replayed is the recorded one (its hash).
    pub same_script: bool,
    /// Ticks run.
    pub ticks: u64,
    /// Outputs (and ends) the run wrote, up to `until`.
    pub recorded: Vec<Entry>,
    /// Outputs (and ends) the replay wrote.
    pub replayed: Vec<Entry>,
    /// The first difference, if any.
    pub divergence: Option<Divergence>,
    /// Reads the journal holds no value for.
    pub unrecorded: Vec<Unrecorded>,
    /// Steps a test file takes to the same effect (with `Options::steps_from`), and after
    /// each advance the outputs the run had written by then.
    pub steps: Vec<AssertedStep>,
    /// The wall time and zone the run began at.
    pub start: (chrono::DateTime<chrono::Utc>, String),
    /// What reading the journal noticed, and what the replay could not do exactly.
    pub notes: Vec<String>,
}

/// Why a replay could not run.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The recorded rig.toml does not read.
    #[error("the journal's rig.toml: {0}")]
    Config(String),
    /// The journal has no start.
    #[error("the journal holds no start of the script (the run ended before its top level ran)")]
    NoStart,
    /// The zone is unknown here.
    #[error("the journal's zone {0:?} is unknown here")]
    Zone(String),
    /// The rig did not start.
    #[error(transparent)]
    Start(Box<RigError>),
    /// The journal names a device the rig does not have.
    #[error("the journal does not fit its rig: {0}")]
    Field(#[from] FieldError),
}

/// Whether an entry is something the run wrote (compared), rather than took in.
fn written(what: &What) -> bool {
    matches!(what, What::Outputs { .. })
}

/// The field as the replay has set it, so each recorded reading becomes the change to it.
#[derive(Default)]
struct Field {
    switches: BTreeMap<String, BTreeSet<Switch>>,
    rotaries: BTreeMap<String, [u8; Rotary::COUNT]>,
}

impl Field {
    /// The actions that make the simulators read as `what` was read (none for what is not a
    /// reading or a loss).
    fn actions(&mut self, sim: &SimRig, what: &What) -> Result<Vec<Action>, FieldError> {
        let dev = |d: &str| Arc::<str>::from(d);
        Ok(match what {
            What::Inputs { dev: d, byte } => vec![Action::Inputs {
                dev: dev(d),
                byte: *byte,
            }],
            What::Counters { dev: d, values } => {
                let mut out = Vec::new();
                for (ch, v) in (0u8..).zip(values) {
                    let now = sim.counter(d, ch)?;
                    let n = v.wrapping_sub(now);
                    if n != 0 {
                        out.push(Action::Pulse {
                            dev: dev(d),
                            ch,
                            n: u32::from(n),
                        });
                    }
                }
                out
            }
            What::Switches { dev: d, pressed } => {
                let held = self.switches.entry(d.clone()).or_default();
                let want: BTreeSet<Switch> = pressed.iter().copied().collect();
                let mut out = Vec::new();
                for s in held.difference(&want) {
                    out.push(Action::Release {
                        dev: dev(d),
                        switch: *s,
                    });
                }
                for s in want.difference(held) {
                    out.push(Action::Press {
                        dev: dev(d),
                        switch: *s,
                    });
                }
                *held = want;
                out
            }
            What::Rotaries { dev: d, values } => {
                let at = self.rotaries.entry(d.clone()).or_default();
                let mut out = Vec::new();
                for (i, r) in Rotary::ALL.iter().enumerate() {
                    let (old, new) = (at[i], values[i]);
                    if old != new {
                        // The short way, as the runtime counts a change (8 bits, signed).
                        let half_turns = i32::from(new.wrapping_sub(old) as i8);
                        out.push(Action::Turn {
                            dev: dev(d),
                            rotary: *r,
                            half_turns,
                        });
                    }
                }
                *at = *values;
                out
            }
            What::Lost { dev: d, .. } => vec![Action::Fail { dev: dev(d) }],
            What::Back { dev: d } => vec![Action::Restore { dev: dev(d) }],
            What::Ended { reason, .. } if stopped_from_outside(reason) => vec![Action::Stop],
            _ => Vec::new(),
        })
    }
}

/// Sets the field before the script's top level runs, as tick 0's readings say (what a
/// reading can ask: inputs, pulses, switches, turns).
fn set_at_start(sim: &SimRig, action: &Action) -> Result<(), FieldError> {
    match action {
        Action::Inputs { dev, byte } => sim.set_inputs(dev, *byte),
        Action::Pulse { dev, ch, n } => sim.pulse(dev, *ch, *n),
        Action::Press { dev, switch } => sim.set_switch(dev, switch.name(), true),
        Action::Release { dev, switch } => sim.set_switch(dev, switch.name(), false),
        Action::Turn {
            dev,
            rotary,
            half_turns,
        } => sim.turn(dev, rotary.name(), *half_turns),
        _ => Ok(()),
    }
}

/// Whether a run's end came from outside it (a signal, a stop asked through the control
/// socket), by the words `EndReason` ends it with: the replay stops there too. Every other
/// end is the script's or the runner's own, which the replay must come to by itself.
fn stopped_from_outside(reason: &str) -> bool {
    (reason.starts_with("SIG") && reason.ends_with(" received"))
        || reason.starts_with("stop asked by")
}

/// A tick's field entries in the order they are played: counters last, so the edges that
/// inputs set make are in the count before the pulses that bring it to the reading.
fn field_order(mut entries: Vec<&Entry>) -> Vec<&Entry> {
    entries.sort_by_key(|e| matches!(e.what, What::Counters { .. }));
    entries
}

/// The rig a journal's header describes, every device simulated.
fn rig_config(journal: &Journal) -> Result<RigConfig, ReplayError> {
    let h = &journal.header;
    let mut config = match &h.config {
        Some(text) => RigConfig::parse(text, h.config_file.as_deref().unwrap_or("rig.toml"))
            .map_err(|e| ReplayError::Config(e.to_string()))?,
        None => RigConfig::simulated_default(),
    };
    config.limits.operations = h.operations;
    Ok(config)
}

/// The zone a journal names (`local`: this machine's).
fn zone(name: &str) -> Result<Zone, ReplayError> {
    if name == "local" {
        return Ok(Zone::Local);
    }
    Zone::parse(name).map_err(|_| ReplayError::Zone(name.into()))
}

/// Takes what the replay's events say happened so far.
fn drain(sub: &mut Subscription, tally: &mut Tally, into: &mut Vec<Entry>) {
    while let Ok(next) = sub.handover(Duration::ZERO) {
        match next {
            Next::Event(e) => {
                if let Some(entry) = tally.take(sub.tick(), &e) {
                    into.push(entry);
                }
            }
            Next::Dropped(n) => into.push(tally.gap(sub.tick(), n)),
            Next::Quiet => {}
        }
    }
}

/// Replays `journal` (see the module's doc).
pub fn replay(journal: &Journal, options: &Options) -> Result<Outcome, ReplayError> {
    let _ends = crate::guardian::pulse::EndsLoop;
    let h = &journal.header;
    let since = journal
        .entries
        .iter()
        .find_map(|e| match e.what {
            What::Started { since, .. } => Some(since),
            _ => None,
        })
        .ok_or(ReplayError::NoStart)?;
    // No further than the journal goes: past its last entry nothing is known.
    let last = journal.entries.last().map_or(0, |e| e.tick);
    let until = options.until.unwrap_or(last).min(last);
    let mut notes = journal.notes.clone();
    // The field each tick took in, by tick.
    let mut field: BTreeMap<u64, Vec<&Entry>> = BTreeMap::new();
    let mut overruns: BTreeMap<u64, (u64, u64)> = BTreeMap::new();
    // The ticks the run made sooner than its script's schedule, for someone outside it: how
    // many periods after the tick before, and how late they started.
    let mut woken: BTreeMap<u64, (u64, u64)> = BTreeMap::new();
    // The reloads the run made, by tick: the replay makes them at the same boundaries.
    let mut reloads: BTreeMap<u64, Vec<(String, String)>> = BTreeMap::new();
    // What operators asked (forces, commands, messages), by the tick it was taken in.
    let mut operated: BTreeMap<u64, Vec<OperatorAct>> = BTreeMap::new();
    let mut recorded = Vec::new();
    // Readings made for watchers (`run --journal-image`) stand for the field only where the
    // run's script read nothing of that kind of that device: elsewhere the script's own
    // readings are the field as it read it, and one made between two of them could set the
    // simulator to a value the script never saw.
    let script_read: std::collections::HashSet<(String, std::mem::Discriminant<What>)> = journal
        .entries
        .iter()
        .filter_map(|e| Some((device(&e.what)?.to_string(), std::mem::discriminant(&e.what))))
        .collect();
    let shown: Vec<Entry> = journal
        .entries
        .iter()
        .filter(|e| e.tick <= until)
        .filter_map(|e| match &e.what {
            What::Shown(inner) => {
                let key = (device(inner)?.to_string(), std::mem::discriminant(&**inner));
                (!script_read.contains(&key)).then(|| Entry {
                    tick: e.tick,
                    what: (**inner).clone(),
                })
            }
            _ => None,
        })
        .collect();
    for e in journal
        .entries
        .iter()
        .filter(|e| e.tick <= until && !matches!(e.what, What::Shown(_)))
        .chain(shown.iter())
    {
        match &e.what {
            What::Overrun { late_us, work_us } => {
                overruns.insert(e.tick, (*late_us, *work_us));
            }
            What::Woken { periods, late_us } => {
                woken.insert(e.tick, (*periods, *late_us));
            }
            What::Operated(act) => operated.entry(e.tick).or_default().push(act.clone()),
            What::Reloaded { file, source, .. } => {
                notes.push(format!(
                    "the run was reloaded with {file} in tick {}: the replay reloads it there too",
                    e.tick
                ));
                reloads
                    .entry(e.tick)
                    .or_default()
                    .push((source.clone(), file.clone()));
            }
            What::Gap { events } => notes.push(format!(
                "the journal lost {events} event(s) in tick {}: the replay is not exact from there",
                e.tick
            )),
            w if written(w) => recorded.push(e.clone()),
            _ => field.entry(e.tick).or_default().push(e),
        }
    }
    let (source, file) = options
        .script
        .clone()
        .unwrap_or_else(|| (h.script.clone(), h.script_file.clone()));
    let same_script = crate::content_hash::content_hash(&source) == h.hash;
    let clock = VirtualClock::new(since);
    let period = Duration::from_micros(h.period_us);
    let sub: Arc<Mutex<Option<Subscription>>> = Arc::default();
    let slot = Arc::clone(&sub);
    // The top level reads what the run's did: the field of tick 0 is set before it runs.
    let at_start: Vec<Entry> = field
        .remove(&0)
        .unwrap_or_default()
        .into_iter()
        .cloned()
        .collect();
    let start_field: Arc<Mutex<Option<Result<Field, FieldError>>>> = Arc::default();
    let start_slot = Arc::clone(&start_field);
    let config = rig_config(journal)?;
    let names: Vec<String> = config.devices.keys().cloned().collect();
    let relays: BTreeSet<String> = config
        .devices
        .iter()
        .filter(|(_, d)| matches!(d, crate::config::DeviceConfig::Trc1000(_)))
        .map(|(n, _)| n.clone())
        .collect();
    let mut builder = RigBuilder::from_config(config)
        .simulated()
        .clock(Arc::new(clock.clone()))
        .zone(zone(&h.zone)?)
        .period(period)
        .log_to_stderr(false)
        .quiet()
        .budget(h.operations)
        .prepare(|p| p.track_coverage())
        .open_with(move |config, clock, simulate, count| {
            let opened: Opened = open_devices(config, clock, simulate, count)?;
            let mut f = Field::default();
            let set = (|| {
                for e in field_order(at_start.iter().collect()) {
                    for a in f.actions(&opened.sim, &e.what)? {
                        set_at_start(&opened.sim, &a)?;
                    }
                }
                Ok(f)
            })();
            *lock(&start_slot) = Some(set);
            Ok(opened)
        })
        .attach(move |events| {
            *lock(&slot) = events
                .subscribe_to("replay", Bound::events(1 << 16), Kinds::of(&KINDS))
                .ok();
        });
    if let Some(ms) = h.run_for_ms {
        builder = builder.run_for(Duration::from_millis(ms));
    }
    let mut rig = builder
        .start(&source, &file)
        .map_err(|e| ReplayError::Start(Box::new(e)))?;
    rig.runner
        .set_rollback(h.rollback_ms.map(Duration::from_millis));
    // A control queue, as the run had, only when an operator acted on the run.
    let ask = (!operated.is_empty()).then(|| {
        let (ask, requests) = crate::runtime::requests::queue(&Arc::default());
        rig.runner.serve(requests, &file, rig.sim.clone());
        ask
    });
    let mut f = lock(&start_field).take().unwrap_or(Ok(Field::default()))?;
    let mut sub = lock(&sub)
        .take()
        .ok_or_else(|| ReplayError::Config("too many consumers".into()))?;
    let mut tally = Tally::default();
    let mut replayed = Vec::new();
    drain(&mut sub, &mut tally, &mut replayed);
    let keep_steps = options.steps_from.is_some();
    let mut steps: Vec<AssertedStep> = Vec::new();
    // The outputs the run had written by each tick, for the test file's assertions.
    let mut outputs_so_far: BTreeMap<String, u8> = BTreeMap::new();
    let mut rec_i = 0;
    let mut last_stop = clock.now();
    let mut ticks = 0;
    while rig.runner.status().is_none() {
        let next = rig.runner.runtime().borrow().cycle().tick() + 1;
        if next > until {
            break;
        }
        // A tick the run made sooner than its script's schedule, for someone outside it (a
        // status asked, a page watching, a command), comes at the same time here, where nobody
        // watches; unless the replay's own schedule has a tick by then (an edited script's).
        let last = rig.runner.runtime().borrow().cycle().boundary();
        let woken_at = woken
            .get(&next)
            .zip(last)
            .map(|(&(periods, late_us), last)| {
                let periods = u32::try_from(periods).unwrap_or(u32::MAX);
                let at = last.saturating_add(period.saturating_mul(periods));
                (at, Duration::from_micros(late_us))
            })
            .filter(|&(at, _)| rig.runner.next_deadline() > at);
        let mut took = Vec::new();
        if let Some(entries) = field.remove(&next) {
            for e in field_order(entries) {
                // One entry at a time: an input's edge counts on its counter, so a counter's
                // pulses are reckoned from the simulator as the entries before left it.
                for a in f.actions(&rig.sim, &e.what)? {
                    act(&mut rig, &clock, &a, &mut took)?;
                }
            }
        }
        if keep_steps && !took.is_empty() {
            steps.extend(took.into_iter().map(|s| (s, Vec::new())));
        }
        if rig.runner.status().is_some() {
            break;
        }
        let acts = operated.remove(&next).unwrap_or_default();
        // What operators asked is asked when the tick is due, not when the last one ended:
        // a command brings the next tick to the first boundary from when it is asked, and
        // the run's came on its script's schedule unless it was woken for it.
        if woken_at.is_some() || !acts.is_empty() {
            let due = woken_at.map_or_else(|| rig.runner.next_deadline(), |(at, _)| at);
            rig.runner.wait_between_ticks(due);
        }
        for (source, file) in reloads.remove(&next).unwrap_or_default() {
            rig.runner.reload_at_next_tick(source, file);
        }
        if let Some(ask) = &ask {
            for act in acts {
                rig.runner.ask_replayed(ask, &act);
            }
        }
        if let Some((at, late)) = woken_at {
            rig.runner.tick_soon();
            // As late as the run's began (a timer due by then fires in it, as in the run): the
            // time goes by at once, as after an overrun, whatever the journal says it was.
            let by = at.saturating_add(late).saturating_sub(clock.now());
            if !by.is_zero() {
                act(&mut rig, &clock, &Action::Stall { by }, &mut Vec::new())?;
            }
        }
        let due = rig.runner.next_deadline();
        if rig.runner.step_toward(due).is_none() {
            break;
        }
        ticks = next;
        if let Some((late, work)) = overruns.get(&next) {
            // The run's tick went on past the next deadline: as much time goes by here.
            let end = due + Duration::from_micros(late + work);
            if end > clock.now() {
                let by = end - clock.now();
                act(&mut rig, &clock, &Action::Stall { by }, &mut Vec::new())?;
                if keep_steps {
                    steps.push((Step::Act(Action::Stall { by }), Vec::new()));
                }
            }
        }
        drain(&mut sub, &mut tally, &mut replayed);
        while let Some(e) = recorded.get(rec_i).filter(|e: &&Entry| e.tick <= next) {
            if let What::Outputs { dev, value, .. } = &e.what {
                outputs_so_far.insert(dev.clone(), *value);
            }
            rec_i += 1;
        }
        // The test file stops here if the next tick acts on the field or this one wrote.
        let wrote = recorded
            .iter()
            .skip(rec_i.saturating_sub(1))
            .any(|e| e.tick == next);
        let acts_next = field.contains_key(&(next + 1)) || overruns.contains_key(&(next + 1));
        if keep_steps && (acts_next || wrote) {
            let asserts = if options.steps_from.is_some_and(|from| next >= from) {
                outputs_so_far
                    .iter()
                    .map(|(d, v)| {
                        let kind = if relays.contains(d) {
                            "relay"
                        } else {
                            "outputs"
                        };
                        (d.clone(), kind, *v)
                    })
                    .collect()
            } else {
                Vec::new()
            };
            steps.push((Step::Advance(due.saturating_sub(last_stop)), asserts));
            last_stop = clock.now();
        }
    }
    drain(&mut sub, &mut tally, &mut replayed);
    let replayed: Vec<Entry> = replayed
        .into_iter()
        .filter(|e| written(&e.what) && e.tick <= until)
        .collect();
    let divergence = first_difference(journal, &recorded, &replayed);
    let unrecorded = unrecorded_reads(journal, &rig, &names);
    if !overruns.is_empty() {
        notes.push(format!(
            "the run overran {} tick(s): each is replayed as the time it took",
            overruns.len()
        ));
    }
    Ok(Outcome {
        same_script,
        ticks,
        recorded,
        replayed,
        divergence,
        unrecorded,
        steps,
        start: (since, h.zone.clone()),
        notes,
    })
}

/// The first entry where the replay's outputs differ from the run's, by tick, device and
/// value (the cause is words and may differ with an edited script's labels).
fn first_difference(
    journal: &Journal,
    recorded: &[Entry],
    replayed: &[Entry],
) -> Option<Divergence> {
    let same = |a: &Entry, b: &Entry| match (&a.what, &b.what) {
        (
            What::Outputs {
                dev: d1, value: v1, ..
            },
            What::Outputs {
                dev: d2, value: v2, ..
            },
        ) => a.tick == b.tick && d1 == d2 && v1 == v2,
        _ => a == b,
    };
    let n = recorded.len().max(replayed.len());
    (0..n).find_map(|i| {
        let (r, p) = (recorded.get(i), replayed.get(i));
        if let (Some(r), Some(p)) = (r, p) {
            if same(r, p) {
                return None;
            }
        }
        let tick = match (r, p) {
            (Some(r), Some(p)) => r.tick.min(p.tick),
            (Some(e), None) | (None, Some(e)) => e.tick,
            (None, None) => return None,
        };
        let around = journal
            .entries
            .iter()
            .filter(|e| {
                e.tick + 5 >= tick
                    && e.tick <= tick + 1
                    && !written(&e.what)
                    && device(&e.what).is_some()
            })
            .cloned()
            .collect();
        Some(Divergence {
            tick,
            recorded: r.cloned(),
            replayed: p.cloned(),
            around,
        })
    })
}

/// What the replayed script read that the journal holds no reading of.
fn unrecorded_reads(journal: &Journal, rig: &Rig, names: &[String]) -> Vec<Unrecorded> {
    let Some(c) = rig.runner.program().coverage() else {
        return Vec::new();
    };
    let mut reads = c.script_reads.clone();
    for r in c.invariant_reads.values() {
        reads.union(r);
    }
    // A reading made for watchers (`run --journal-image`) is a recorded value too.
    let recorded = |dev: &str, kind: fn(&What) -> bool| {
        journal.entries.iter().any(|e| {
            let w = match &e.what {
                What::Shown(inner) => inner,
                w => w,
            };
            device(w) == Some(dev) && kind(w)
        })
    };
    let mut out = BTreeSet::new();
    for (idx, item) in reads.items() {
        let Some(dev) = names.get(idx) else { continue };
        let (kind, assumed): (fn(&What) -> bool, &str) = match item {
            Item::Switch(_) => (|w| matches!(w, What::Switches { .. }), "released"),
            Item::Rotary(_) => (|w| matches!(w, What::Rotaries { .. }), "0"),
            Item::Input(_) => (|w| matches!(w, What::Inputs { .. }), "off"),
            Item::Counter(_) => (|w| matches!(w, What::Counters { .. }), "0"),
            Item::Latches => (|_| false, "none latched"),
            _ => continue,
        };
        if !recorded(dev, kind) {
            out.insert(Unrecorded {
                dev: dev.clone(),
                item: item.to_string(),
                assumed: assumed.into(),
            });
        }
    }
    out.into_iter().collect()
}

#[cfg(test)]
mod tests {
    use super::stopped_from_outside;
    use crate::runtime::runner::EndReason;

    #[test]
    fn only_a_signal_or_a_stop_asked_is_an_end_from_outside() {
        assert!(stopped_from_outside(
            &EndReason::Signal(libc::SIGTERM).to_string()
        ));
        assert!(stopped_from_outside(
            &EndReason::Requested("rigscript stop".into()).to_string()
        ));
        for own in [
            EndReason::Finished("ran for 3s".into()),
            EndReason::Stopped(1),
            EndReason::Error("x".into()),
            EndReason::Violated("invariant \"a\" is false".into()),
        ] {
            assert!(!stopped_from_outside(&own.to_string()), "{own}");
        }
    }
}
